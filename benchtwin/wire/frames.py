"""Device outputs as arrays: the contract between sensors, delivery (batch and live) and acquisition.

No per-frame Python objects in batch mode: a CAN bus is a :class:`FrameTable` (a structured numpy
array of timestamp, identifier, DLC and 8 data bytes), a Modbus device is a :class:`RegisterSnapshots`
(register values over time), and a CANopen node is a :class:`ProcessImage` (its object-dictionary
values over time, which batch delivery packs into PDO frames and live delivery writes into a
canopen LocalNode).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from benchtwin.errors import DataError

__all__ = ["FRAME_DTYPE", "POLL_OK", "POLL_TIMEOUT", "DeviceOutputs", "FrameTable", "PollLog", "ProcessImage",
           "RegisterSnapshots", "TransportEvent"]

#: one CAN frame: time (s, on the sending device's clock as seen by the bus), 11/29-bit identifier,
#: extended flag, data length code and eight data bytes (unused bytes zero)
FRAME_DTYPE = np.dtype(
    [("timestamp", "f8"), ("arbitration_id", "u4"), ("is_extended", "?"), ("dlc", "u1"), ("data", "u1", (8,))]
)


@dataclass
class FrameTable:
    """All frames of one CAN bus, sorted by timestamp.

    Attributes
    ----------
    bus:
        Bus name from the setup file (``powertrain``, ``vehicle``, ``instrument``).
    frames:
        Structured array of :data:`FRAME_DTYPE`.
    bitrate:
        Nominal bit rate, bit/s (for bus load).
    """

    bus: str
    frames: np.ndarray
    bitrate: int = 500_000

    def __post_init__(self) -> None:
        if self.frames.dtype != FRAME_DTYPE:
            raise DataError(f"bus {self.bus!r}: frames must have FRAME_DTYPE, got {self.frames.dtype}")

    def __len__(self) -> int:
        return int(self.frames.shape[0])

    @classmethod
    def empty(cls, bus: str, n: int = 0, bitrate: int = 500_000) -> FrameTable:
        """A table of ``n`` zeroed frames."""
        return cls(bus, np.zeros(n, dtype=FRAME_DTYPE), bitrate)

    @classmethod
    def concat(cls, bus: str, parts: list[np.ndarray], bitrate: int = 500_000) -> FrameTable:
        """Merge frame arrays and sort them by timestamp (stable, so equal times keep their order)."""
        frames = np.concatenate(parts) if parts else np.zeros(0, dtype=FRAME_DTYPE)
        order = np.argsort(frames["timestamp"], kind="stable")
        return cls(bus, frames[order], bitrate)

    def bus_load(self, window_s: float | None = None) -> float:
        """Mean bus load (0..1) from the frame bit lengths (worst-case stuffing) over the span.

        Parameters
        ----------
        window_s:
            Span to divide by; defaults to the frames' own time span.
        """
        if len(self) == 0:
            return 0.0
        dlc = self.frames["dlc"].astype(np.float64)
        ext = self.frames["is_extended"]
        # frame bits without stuffing: 47 (standard) / 67 (extended) + 8 per data byte;
        # worst-case stuffing adds one bit per four of the stuffed region
        base = np.where(ext, 67.0, 47.0) + 8.0 * dlc
        stuffed = np.where(ext, 54.0, 34.0) + 8.0 * dlc
        bits = float(np.sum(base + np.floor((stuffed - 1.0) / 4.0)))
        span = window_s if window_s is not None else float(self.frames["timestamp"][-1] - self.frames["timestamp"][0])
        if span <= 0:
            return float("nan")
        return bits / (self.bitrate * span)


@dataclass
class RegisterSnapshots:
    """Register values of one Modbus device over time (what the device holds after each update).

    Attributes
    ----------
    device:
        Device name from the setup file.
    unit_id:
        Modbus device (unit) id.
    first_register:
        Address of column 0 of ``registers``.
    times:
        Update times, seconds (device clock).
    registers:
        uint16 array ``(n_updates, n_registers)``.
    kind:
        ``"input"`` (function code 4) or ``"holding"`` (function code 3).
    """

    device: str
    unit_id: int
    first_register: int
    times: np.ndarray
    registers: np.ndarray
    kind: str = "input"

    def __post_init__(self) -> None:
        self.times = np.asarray(self.times, dtype=np.float64)
        self.registers = np.asarray(self.registers, dtype=np.uint16)
        if self.registers.ndim != 2 or self.registers.shape[0] != self.times.shape[0]:
            raise DataError(f"modbus device {self.device!r}: registers {self.registers.shape} vs times "
                            f"{self.times.shape}")


@dataclass
class ProcessImage:
    """Object-dictionary values of one CANopen node over time.

    Attributes
    ----------
    node:
        Node name from the setup file.
    node_id:
        CANopen node id (1..127).
    times:
        Update times, seconds (node clock).
    entries:
        ``(index, subindex)`` of each column, as in the node's EDS.
    values:
        Raw integer values ``(n_updates, n_entries)`` in the EDS data types' units.
    """

    node: str
    node_id: int
    times: np.ndarray
    entries: list[tuple[int, int]]
    values: np.ndarray

    def __post_init__(self) -> None:
        self.times = np.asarray(self.times, dtype=np.float64)
        self.values = np.asarray(self.values)
        if self.values.shape != (self.times.shape[0], len(self.entries)):
            raise DataError(f"canopen node {self.node!r}: values {self.values.shape} vs "
                            f"({self.times.shape[0]}, {len(self.entries)})")


@dataclass
class DeviceOutputs:
    """Everything the instruments put on their wires during a run."""

    can: dict[str, FrameTable] = field(default_factory=dict)
    modbus: dict[str, RegisterSnapshots] = field(default_factory=dict)
    canopen: dict[str, ProcessImage] = field(default_factory=dict)
    #: a chunk of a run: the plant time up to which it was encoded (None: the run's end, nothing follows)
    until_s: float | None = None

    def n_frames(self) -> int:
        """Total CAN frames over all buses."""
        return sum(len(t) for t in self.can.values())


#: status of one Modbus poll in a :class:`PollLog`: 0 ok, 1..11 the Modbus exception code, -1 timeout
POLL_OK = 0
POLL_TIMEOUT = -1


@dataclass
class PollLog:
    """Every poll an acquisition made of one Modbus device (what came back, or why nothing did).

    Batch delivery makes it by sampling :class:`RegisterSnapshots` at the poll times with the
    configured poll faults; the live recorder fills it from a pymodbus client. Either way the
    acquisition decodes it the same way.

    Attributes
    ----------
    device:
        Device name from the setup file.
    unit_id:
        Modbus device (unit) id polled.
    function_code:
        3 (read holding registers) or 4 (read input registers).
    first_register:
        Address of column 0 of ``values``.
    times:
        Time each answer (or timeout) was logged, seconds on the acquisition's clock, shape ``(N,)``.
    values:
        uint16 ``(N, count)``; rows of failed polls hold zeros and must not be used.
    status:
        int16 ``(N,)``: :data:`POLL_OK` (0), a Modbus exception code 1..11, or :data:`POLL_TIMEOUT` (-1).
    """

    device: str
    unit_id: int
    function_code: int
    first_register: int
    times: np.ndarray
    values: np.ndarray
    status: np.ndarray

    def __post_init__(self) -> None:
        self.times = np.asarray(self.times, dtype=np.float64)
        self.values = np.asarray(self.values, dtype=np.uint16)
        self.status = np.asarray(self.status, dtype=np.int16)
        n = self.times.shape[0]
        if self.values.ndim != 2 or self.values.shape[0] != n or self.status.shape != (n,):
            raise DataError(f"poll log {self.device!r}: times {self.times.shape}, values {self.values.shape} and "
                            f"status {self.status.shape} do not match")
        if self.function_code not in (3, 4):
            raise DataError(f"poll log {self.device!r}: function code {self.function_code} is not 3 or 4")

    def __len__(self) -> int:
        return int(self.times.shape[0])

    def part(self, start: int, stop: int) -> PollLog:
        """Polls ``start`` to ``stop`` (indices) as a poll log of their own (views, not copies)."""
        return PollLog(self.device, self.unit_id, self.function_code, self.first_register, self.times[start:stop],
                       self.values[start:stop], self.status[start:stop])

    @property
    def count(self) -> int:
        """Registers read per poll."""
        return int(self.values.shape[1])

    @classmethod
    def empty(cls, device: str, unit_id: int, function_code: int, first_register: int, count: int) -> PollLog:
        """A log without polls (e.g. to fill while recording live)."""
        return cls(device, unit_id, function_code, first_register, np.zeros(0), np.zeros((0, count), np.uint16),
                   np.zeros(0, np.int16))

    @classmethod
    def concat(cls, parts: list[PollLog]) -> PollLog:
        """Join logs of one device (e.g. chunks flushed while recording), sorted by time."""
        if not parts:
            raise DataError("no poll logs to join")
        first = parts[0]
        for p in parts[1:]:
            if (p.device, p.unit_id, p.function_code, p.first_register, p.count) != (
                    first.device, first.unit_id, first.function_code, first.first_register, first.count):
                raise DataError(f"poll logs of {first.device!r} and {p.device!r} have different layouts")
        times = np.concatenate([p.times for p in parts])
        order = np.argsort(times, kind="stable")
        return cls(first.device, first.unit_id, first.function_code, first.first_register, times[order],
                   np.concatenate([p.values for p in parts])[order], np.concatenate([p.status for p in parts])[order])


@dataclass
class TransportEvent:
    """Something a transport did during a run that the Recording must flag (a drop, a reconnect).

    Attributes
    ----------
    time_s:
        When it happened, seconds on the acquisition's clock.
    source:
        Bus name, Modbus device or CANopen node concerned (``"*"`` for all).
    kind:
        ``"drop"`` (connection lost), ``"reconnect"``, ``"overrun"`` (frames lost in a buffer) or ``"end"``.
    end_s:
        For a drop, when the data came back (``inf`` if never); equal to ``time_s`` otherwise.
    detail:
        Free text (error message).
    """

    time_s: float
    source: str
    kind: str
    end_s: float = float("nan")
    detail: str = ""
