"""python-can's in-process ``virtual`` bus: the embedded default transport."""

from __future__ import annotations

import itertools
import os
import time
from typing import Any, ClassVar

import can
from can.interfaces.virtual import VirtualBus

from benchtwin.chain.transports.base import Transport

__all__ = ["VirtualDeviceBus", "VirtualTransport"]


class VirtualDeviceBus(VirtualBus):
    """The device side of a virtual channel: keeps the timestamps it is given (the time a frame is due
    on the emulated bus); a message without one (timestamp 0, e.g. from canopen) is stamped now."""

    def __init__(self, channel: str, **kwargs: Any) -> None:
        super().__init__(channel=channel, receive_own_messages=False, preserve_timestamps=True, **kwargs)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send ``msg`` to the other buses of the channel."""
        if not msg.timestamp:
            msg.timestamp = time.time()
        super().send(msg, timeout)

_instances = itertools.count()


class VirtualTransport(Transport):
    """Every named bus is a python-can virtual channel private to this transport instance.

    The channel names carry the process id and an instance number, so two transports in one
    process (e.g. two tests) never see each other's frames. Acquisitions must live in the same
    process (python-can's virtual bus does not cross processes).
    """

    name: ClassVar[str] = "virtual"
    cross_process: ClassVar[bool] = False

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._prefix = f"benchtwin-{os.getpid()}-{next(_instances)}"

    def channel(self, bus: str) -> str:
        """The python-can virtual channel name of ``bus``."""
        return self.channel_map.get(bus, f"{self._prefix}-{bus}")

    def _open_device_bus(self, bus: str) -> can.BusABC:
        return VirtualDeviceBus(self.channel(bus))

    def client_kwargs(self, bus: str) -> dict[str, Any]:
        return {"interface": "virtual", "channel": self.channel(bus)}
