"""The recorder's spool: append-only files a killed recorder leaves behind, and how they are read back.

Frames are appended as fixed-size FRAME_DTYPE records and polls as fixed-size poll records, flushed at
least every :data:`SPOOL_FLUSH_BOUND_S`; a partial last record (a crash mid-write) is dropped on reading.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from benchtwin.wire.frames import FRAME_DTYPE, FrameTable, PollLog

__all__ = ["SPOOL_FLUSH_BOUND_S", "poll_dtype", "read_frame_spool", "read_poll_spool", "write_atomic"]

#: the longest time (wall seconds) received data may stay in the recorder's memory before it is handed to
#: the operating system: killing the recorder loses at most this much of what it received
SPOOL_FLUSH_BOUND_S = 1.0


def write_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file and a rename (never a half-written file)."""
    p = Path(path)
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, p)
    return p


def poll_dtype(count: int) -> np.dtype:
    """Record layout of a poll spool file: time, status and ``count`` registers."""
    return np.dtype([("time", "<f8"), ("status", "<i2"), ("values", "<u2", (count,))])


def read_frame_spool(path: str | Path, bus: str | None = None, bitrate: int = 500_000) -> FrameTable:
    """Frames of a spool file (a partial last record, from a crash mid-write, is dropped)."""
    p = Path(path)
    raw = p.read_bytes()
    n = len(raw) // FRAME_DTYPE.itemsize
    frames = np.frombuffer(raw[:n * FRAME_DTYPE.itemsize], dtype=FRAME_DTYPE).copy()
    return FrameTable(bus or p.stem, frames, bitrate)


def read_poll_spool(path: str | Path, device: str, unit_id: int, function_code: int, first_register: int,
                    count: int) -> PollLog:
    """Polls of a spool file as a :class:`~benchtwin.wire.frames.PollLog`."""
    dt = poll_dtype(count)
    raw = Path(path).read_bytes()
    rec = np.frombuffer(raw[:len(raw) // dt.itemsize * dt.itemsize], dtype=dt)
    return PollLog(device, unit_id, function_code, first_register, rec["time"].copy(),
                   rec["values"].reshape(len(rec), count).copy(), rec["status"].copy())
