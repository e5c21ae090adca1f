"""Kernel SocketCAN interfaces (``vcan0`` ...) through python-can's ``socketcan`` interface.

Only where the kernel has AF_CAN: :meth:`SocketcanTransport.unavailable_reason` probes
``socket.socket(AF_CAN, SOCK_RAW, CAN_RAW)`` (errno 97 "address family not supported" where
CONFIG_CAN is unset). Each named bus maps to an interface through ``channel_map``; by default the
buses take ``vcan0``, ``vcan1``, ... in order. Create them with ``ip link add dev vcan0 type vcan``.
"""

from __future__ import annotations

import socket
from typing import Any, ClassVar

import can

from benchtwin.chain.transports.base import Transport

__all__ = ["SocketcanTransport", "af_can_unavailable_reason"]


def af_can_unavailable_reason() -> str | None:
    """``None`` when a raw CAN socket can be opened here, else the reason."""
    family = getattr(socket, "AF_CAN", None)
    if family is None:
        return "this Python has no socket.AF_CAN (not Linux)"
    try:
        s = socket.socket(family, socket.SOCK_RAW, getattr(socket, "CAN_RAW", 1))
    except OSError as exc:
        return f"the kernel has no SocketCAN (socket(AF_CAN) failed: errno {exc.errno} {exc.strerror})"
    s.close()
    return None


class SocketcanTransport(Transport):
    """Named buses on kernel CAN interfaces (virtual ``vcan`` or real adapters)."""

    name: ClassVar[str] = "socketcan"
    cross_process: ClassVar[bool] = True
    per_cpu_queues: ClassVar[bool] = True

    @classmethod
    def unavailable_reason(cls) -> str | None:
        return af_can_unavailable_reason()

    def interface(self, bus: str) -> str:
        """The kernel interface carrying ``bus``."""
        if bus in self.channel_map:
            return self.channel_map[bus]
        return f"vcan{list(self.bitrates).index(bus)}"

    def _open_device_bus(self, bus: str) -> can.BusABC:
        return can.Bus(interface="socketcan", channel=self.interface(bus), receive_own_messages=False)

    def client_kwargs(self, bus: str) -> dict[str, Any]:
        return {"interface": "socketcan", "channel": self.interface(bus)}
