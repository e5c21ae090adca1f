"""python-can's in-process ``virtual`` bus: the embedded default transport."""

from __future__ import annotations

import itertools
import os
from typing import Any, ClassVar

import can

from benchtwin.chain.transports.base import Transport

__all__ = ["VirtualTransport"]

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
        return can.Bus(interface="virtual", channel=self.channel(bus), receive_own_messages=False)

    def client_kwargs(self, bus: str) -> dict[str, Any]:
        return {"interface": "virtual", "channel": self.channel(bus)}
