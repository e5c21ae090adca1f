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

__all__ = ["FRAME_DTYPE", "DeviceOutputs", "FrameTable", "ProcessImage", "RegisterSnapshots"]

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

    def n_frames(self) -> int:
        """Total CAN frames over all buses."""
        return sum(len(t) for t in self.can.values())
