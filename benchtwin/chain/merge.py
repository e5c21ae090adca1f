"""Fast merging of time-sorted frame arrays (FRAME_DTYPE) without per-field structured copies.

numpy gathers structured arrays with a sub-array field slowly; these helpers move whole records
through a ``void`` view, skip the sort when the data are already in time order, and insert a few
frames into a long sorted table with a binary search instead of re-sorting it.
"""

from __future__ import annotations

import numpy as np

from benchtwin.chain.frames import FRAME_DTYPE

__all__ = ["insert_frames", "merge_frames", "take_frames"]

_VOID = np.dtype((np.void, FRAME_DTYPE.itemsize))


def take_frames(frames: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``frames[index]`` for a FRAME_DTYPE array, copying whole records."""
    return np.take(np.ascontiguousarray(frames).view(_VOID), index).view(FRAME_DTYPE)


def _is_sorted(t: np.ndarray) -> bool:
    return bool(t.size < 2 or np.all(t[1:] >= t[:-1]))


def merge_frames(parts: list[np.ndarray]) -> np.ndarray:
    """Concatenate frame arrays and sort them by timestamp (stable: equal times keep part order)."""
    parts = [p for p in parts if len(p)]
    if not parts:
        return np.zeros(0, FRAME_DTYPE)
    if len(parts) == 1:
        out = np.ascontiguousarray(parts[0])
    else:
        # few long parts and many short ones: insert the short ones, sort only when it pays
        parts.sort(key=len, reverse=True)
        big = np.concatenate([p for p in parts if len(p) * 50 >= len(parts[0])])
        small = [p for p in parts if len(p) * 50 < len(parts[0])]
        out = big
        if not _is_sorted(out["timestamp"]):
            out = take_frames(out, np.argsort(out["timestamp"], kind="stable"))
        for p in small:
            out = insert_frames(out, p)
        return out
    if _is_sorted(out["timestamp"]):
        return out
    return take_frames(out, np.argsort(out["timestamp"], kind="stable"))


def insert_frames(frames: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """Insert ``extra`` frames into a time-sorted ``frames`` array (each after frames of equal time)."""
    if len(extra) == 0:
        return frames
    if not _is_sorted(extra["timestamp"]):
        extra = take_frames(extra, np.argsort(extra["timestamp"], kind="stable"))
    pos = np.searchsorted(frames["timestamp"], extra["timestamp"], side="right")
    return np.insert(np.ascontiguousarray(frames).view(_VOID), pos, extra.view(_VOID)).view(FRAME_DTYPE)
