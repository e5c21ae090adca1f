"""Fast merging of time-sorted frame arrays (FRAME_DTYPE) without per-field structured copies.

numpy copies, joins, masks and gathers structured arrays with a sub-array field slowly (a field-by-field
copy, about five times the time of moving the same bytes); these helpers move whole records through a
``void`` view, merge already-sorted runs in one pass (a small numba k-way merge, without the GIL, copying each
record once from its part into the result) instead of sorting everything again, and insert a few frames into a
long sorted table with a binary search.
"""

from __future__ import annotations

from itertools import pairwise

import numba
import numpy as np

from benchtwin.wire.frames import FRAME_DTYPE

__all__ = ["concat_frames", "copy_frames", "insert_frames", "mask_frames", "merge_frames", "take_frames", "void_view"]

_VOID = np.dtype((np.void, FRAME_DTYPE.itemsize))


def void_view(frames: np.ndarray) -> np.ndarray:
    """The frames as one opaque record each (for whole-record copies)."""
    return np.ascontiguousarray(frames).view(_VOID)


def take_frames(frames: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``frames[index]`` for a FRAME_DTYPE array, copying whole records."""
    return np.take(np.ascontiguousarray(frames).view(_VOID), index).view(FRAME_DTYPE)


def concat_frames(parts: list[np.ndarray]) -> np.ndarray:
    """``np.concatenate(parts)`` for FRAME_DTYPE arrays, copying whole records (a new array, also for one part)."""
    if not parts:
        return np.zeros(0, FRAME_DTYPE)
    return np.concatenate([void_view(p) for p in parts]).view(FRAME_DTYPE)


def copy_frames(frames: np.ndarray) -> np.ndarray:
    """``frames.copy()`` for a FRAME_DTYPE array, copying whole records."""
    return void_view(frames).copy().view(FRAME_DTYPE)


def mask_frames(frames: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``frames[mask]`` (a boolean mask) for a FRAME_DTYPE array, copying whole records."""
    return void_view(frames)[mask].view(FRAME_DTYPE)


def _is_sorted(t: np.ndarray) -> bool:
    return bool(t.size < 2 or np.all(t[1:] >= t[:-1]))


@numba.njit(cache=True, nogil=True)
def _kway_order(ts: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:  # pragma: no cover - numba
    """Order of a k-way merge of the sorted runs ``ts[starts[p]:ends[p]]`` (ties: lower run first)."""
    k = starts.size
    pos = starts.copy()
    out = np.empty(ts.size, np.int64)
    for j in range(ts.size):
        best = -1
        bt = 0.0
        for p in range(k):
            if pos[p] < ends[p]:
                t = ts[pos[p]]
                if best < 0 or t < bt:
                    best = p
                    bt = t
        out[j] = pos[best]
        pos[best] += 1
    return out


#: bytes of one FRAME_DTYPE record (the row width of the merge kernel's byte views)
_ROW = FRAME_DTYPE.itemsize


@numba.njit(cache=True, nogil=True)
def _kway_gather(ts: tuple, rows: tuple, total: int) -> np.ndarray:  # pragma: no cover - numba
    """The k-way merge of the sorted runs ``ts[p]`` (ties: lower run first), each record copied once from its
    part's bytes ``rows[p]`` (``(n_p, _ROW)`` uint8) into the result: what ``take(concat(rows), _kway_order)`` gives."""
    k = len(ts)
    pos = np.zeros(k, np.int64)
    ends = np.empty(k, np.int64)
    for p in range(k):
        ends[p] = ts[p].size
    out = np.empty((total, _ROW), np.uint8)
    for j in range(total):
        best = -1
        bt = 0.0
        for p in range(k):
            if pos[p] < ends[p]:
                t = ts[p][pos[p]]
                if best < 0 or t < bt:
                    best = p
                    bt = t
        src = rows[best]
        i = pos[best]
        for b in range(_ROW):
            out[j, b] = src[i, b]
        pos[best] = i + 1
    return out


def merge_frames(parts: list[np.ndarray]) -> np.ndarray:
    """Concatenate frame arrays and sort them by timestamp (stable: equal times keep part order).

    Each part is put in time order first (a no-op for the sensors' outputs, which already are);
    the runs are then merged in one pass (numba k-way merge) and the records gathered once.
    """
    parts = [np.ascontiguousarray(p) for p in parts if len(p)]
    if not parts:
        return np.zeros(0, FRAME_DTYPE)
    times = []
    for i, p in enumerate(parts):
        t = np.ascontiguousarray(p["timestamp"])
        if not _is_sorted(t):
            order = np.argsort(t, kind="stable")
            parts[i], t = take_frames(p, order), t[order]
        times.append(t)
    if len(parts) == 1:
        return parts[0]
    if all(a[-1] <= b[0] for a, b in pairwise(times)):  # the runs follow each other: sorted already
        return concat_frames(parts)
    rows = tuple(p.view(np.uint8).reshape(len(p), _ROW) for p in parts)
    return _kway_gather(tuple(times), rows, sum(len(p) for p in parts)).view(FRAME_DTYPE).reshape(-1)


def insert_frames(frames: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """Insert ``extra`` frames into a time-sorted ``frames`` array (each after frames of equal time)."""
    if len(extra) == 0:
        return frames
    if not _is_sorted(extra["timestamp"]):
        extra = take_frames(extra, np.argsort(extra["timestamp"], kind="stable"))
    pos = np.searchsorted(frames["timestamp"], extra["timestamp"], side="right")
    return np.insert(np.ascontiguousarray(frames).view(_VOID), pos, extra.view(_VOID)).view(FRAME_DTYPE)
