"""The transport base: named device-side buses, acquisition-side clients, bulk frame sends.

A :class:`Transport` is a template: a backend says how to make the device-side python-can bus of a
named bus (:meth:`Transport._open_device_bus`) and how an acquisition reaches it
(:meth:`Transport.client_kwargs`); the base owns the life cycle (``start``/``close``/``with``), the
bookkeeping of buses and the bulk path that turns rows of a frame table into CAN messages
(:meth:`Transport.send_frames`, which fast backends override).
"""

from __future__ import annotations

import logging
import time
from abc import ABC, abstractmethod
from collections.abc import Iterable, Mapping
from typing import Any, ClassVar

import can
import numpy as np

from benchtwin.errors import ConfigError, TransportError
from benchtwin.wire.frames import FRAME_DTYPE

__all__ = ["Transport", "frames_to_messages", "message_to_frame", "messages_to_frames"]

log = logging.getLogger(__name__)


def frames_to_messages(frames: np.ndarray, timestamp: float | np.ndarray | None = None) -> list[can.Message]:
    """Rows of :data:`FRAME_DTYPE` as python-can messages.

    Parameters
    ----------
    frames:
        Structured array of :data:`FRAME_DTYPE`.
    timestamp:
        Timestamp of every message (one value, or one per row, e.g. the wall-clock times the frames
        are due on the bus); default: the rows' own.
    """
    ids = frames["arbitration_id"].tolist()
    ext = frames["is_extended"].tolist()
    dlc = frames["dlc"].tolist()
    data = frames["data"].tobytes()
    if timestamp is None:
        ts = frames["timestamp"].tolist()
    elif np.ndim(timestamp):
        ts = np.asarray(timestamp, dtype=np.float64).tolist()
    else:
        ts = [float(timestamp)] * len(ids)
    return [
        can.Message(timestamp=ts[i], arbitration_id=ids[i], is_extended_id=ext[i], dlc=dlc[i],
                    data=data[8 * i: 8 * i + dlc[i]], check=False)
        for i in range(len(ids))
    ]


def message_to_frame(msg: can.Message) -> tuple[float, int, bool, int, bytes]:
    """One python-can message as a row tuple of :data:`FRAME_DTYPE` (data padded to 8 bytes)."""
    data = bytes(msg.data[:8]).ljust(8, b"\0")
    return (float(msg.timestamp), int(msg.arbitration_id), bool(msg.is_extended_id), int(msg.dlc) & 0xF,
            np.frombuffer(data, dtype=np.uint8))


def messages_to_frames(messages: Iterable[can.Message]) -> np.ndarray:
    """Messages as a structured array of :data:`FRAME_DTYPE` (in the order given)."""
    msgs = list(messages)
    out = np.zeros(len(msgs), dtype=FRAME_DTYPE)
    if not msgs:
        return out
    out["timestamp"] = [m.timestamp for m in msgs]
    out["arbitration_id"] = [m.arbitration_id for m in msgs]
    out["is_extended"] = [m.is_extended_id for m in msgs]
    out["dlc"] = [min(int(m.dlc), 8) for m in msgs]
    raw = bytearray(8 * len(msgs))
    for i, m in enumerate(msgs):
        d = bytes(m.data[:8])
        raw[8 * i: 8 * i + len(d)] = d
    out["data"] = np.frombuffer(bytes(raw), dtype=np.uint8).reshape(-1, 8)
    return out


class Transport(ABC):
    """Carries named CAN buses from emulated devices to acquisitions.

    Parameters
    ----------
    buses:
        Bus name -> nominal bit rate (bit/s), or just the bus names (500 kbit/s each).
    host, port:
        Where a network endpoint listens (always a loopback address; port 0 picks a free one).
    channel_map:
        Bus name -> backend channel (e.g. ``{"powertrain": "vcan0"}`` for ``socketcan``).
    """

    #: registry name of the backend
    name: ClassVar[str] = ""
    #: True when acquisitions in other processes can reach the buses
    cross_process: ClassVar[bool] = False
    #: True when frames sent from different CPUs may overtake each other (the kernel queues each on the sending
    #: CPU's receive backlog): the live pacing thread then stays on one CPU while it sends
    per_cpu_queues: ClassVar[bool] = False

    def __init__(self, buses: Mapping[str, int] | Iterable[str], *, host: str = "127.0.0.1", port: int = 0,
                 channel_map: Mapping[str, str] | None = None) -> None:
        self.bitrates: dict[str, int] = (dict(buses) if isinstance(buses, Mapping)
                                         else {b: 500_000 for b in buses})
        if not self.bitrates:
            raise ConfigError(f"transport {self.name!r}: no buses to carry")
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise ConfigError(f"transport {self.name!r}: host {host!r} is not a loopback address; "
                              "every endpoint binds 127.0.0.1")
        self.host = "127.0.0.1" if host == "localhost" else host
        self.port = int(port)
        self.channel_map = dict(channel_map or {})
        self._device_buses: dict[str, can.BusABC] = {}
        self._clients: list[can.BusABC] = []
        self._started = False

    # ----------------------------------------------------------------- backend hooks
    @classmethod
    def unavailable_reason(cls) -> str | None:
        """``None`` when the backend works on this machine, else why not (e.g. no AF_CAN)."""
        return None

    @abstractmethod
    def _open_device_bus(self, bus: str) -> can.BusABC:
        """Create the device-side python-can bus of ``bus``."""

    @abstractmethod
    def client_kwargs(self, bus: str) -> dict[str, Any]:
        """Keyword arguments of ``can.Bus(...)`` with which an acquisition reaches ``bus``."""

    def _start_backend(self) -> None:  # noqa: B027 - optional hook
        """Start servers before the device buses open (network backends)."""

    def _close_backend(self) -> None:  # noqa: B027 - optional hook
        """Stop servers after the buses closed."""

    def endpoints(self) -> list[str]:
        """Human-readable description of where each bus can be reached."""
        return [f"{bus}: {self.client_kwargs(bus)}" for bus in self.bitrates]

    # ----------------------------------------------------------------- life cycle
    def start(self) -> Transport:
        """Start the backend and open one device-side bus per named bus."""
        if self._started:
            return self
        reason = self.unavailable_reason()
        if reason is not None:
            raise TransportError(f"transport {self.name!r} is unavailable here: {reason}")
        self._start_backend()
        try:
            for bus in self.bitrates:
                self._device_buses[bus] = self._open_device_bus(bus)
        except (can.CanError, OSError) as exc:
            self.close()
            raise TransportError(f"transport {self.name!r}: cannot open a device bus: {exc}") from exc
        self._started = True
        return self

    def close(self) -> None:
        """Shut every bus this transport opened and stop the backend."""
        for b in [*self._clients, *self._device_buses.values()]:
            try:
                b.shutdown()
            except Exception as exc:  # a failing shutdown must not keep the others open
                log.debug("shutdown of %s failed: %s", b, exc)
        self._clients.clear()
        self._device_buses.clear()
        self._close_backend()
        self._started = False

    def __enter__(self) -> Transport:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----------------------------------------------------------------- use
    def device_bus(self, bus: str) -> can.BusABC:
        """The device-side bus of ``bus`` (frames sent here reach every acquisition)."""
        if not self._started:
            raise TransportError(f"transport {self.name!r} is not started")
        try:
            return self._device_buses[bus]
        except KeyError:
            raise ConfigError(f"transport {self.name!r} carries no bus {bus!r} "
                              f"(has: {', '.join(self.bitrates)})") from None

    def open_client(self, bus: str, **kwargs: Any) -> can.BusABC:
        """Open an acquisition-side python-can bus on ``bus`` (closed with the transport)."""
        if not self._started:
            raise TransportError(f"transport {self.name!r} is not started")
        try:
            client = can.Bus(**{**self.client_kwargs(bus), **kwargs})
        except (can.CanError, OSError) as exc:
            raise TransportError(f"transport {self.name!r}: cannot open a client on {bus!r}: {exc}") from exc
        self._clients.append(client)
        return client

    def send_frames(self, bus: str, frames: np.ndarray, timestamp: float | np.ndarray | None = None) -> int:
        """Put rows of :data:`FRAME_DTYPE` on ``bus`` in order; return how many were sent.

        ``timestamp`` (Unix seconds, one or one per row) is the time the frames are on the emulated
        bus, which backends that can stamp frames (virtual, socketcand) hand to the acquisition as a
        hardware-timestamping interface would; ``None`` stamps them now. The base converts rows to
        messages and sends them one by one; network backends override this with a bulk path.
        """
        dev = self.device_bus(bus)
        sent = 0
        for msg in frames_to_messages(frames, time.time() if timestamp is None else timestamp):
            try:
                dev.send(msg)
            except can.CanError as exc:
                log.warning("%s/%s: send failed: %s", self.name, bus, exc)
                continue
            sent += 1
        return sent

    def stats(self) -> dict[str, Any]:
        """Backend counters (clients, bytes, drops); empty for in-process backends."""
        return {}
