"""A bus's frames split into its streams in one pass: each known identifier's times, lengths and data words.

:func:`split_streams` is what the acquisition does first with every chunk of a bus
(:meth:`Acquisition._decode_bus <benchtwin.chain.acquisition.Acquisition>`): one counting sort over the frame
records (a small numba kernel, no GIL held) writes each stream's three columns contiguously, in frame order,
instead of sorting the identifiers, gathering whole records per stream and copying their columns apart. The
result is :func:`~benchtwin.chain.decoding.group_ids` followed by those per-stream copies, value for value
(``tests/chain/test_split_streams.py`` checks it on malformed and edge frames). :func:`dlc_histogram` is the
bus-load histogram of :class:`~benchtwin.chain.decoding.BusLoad` in one pass, :func:`hold_cut` where a chunk's
stream is cut (and whether its times go back).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from benchtwin.wire.frames import FRAME_DTYPE

__all__ = ["Streams", "dlc_histogram", "hold_cut", "split_streams"]

#: identifiers at or above this are not standard ones: never a known stream (as ``group_ids``' lookup table)
_ID_LIMIT = 0x800


@dataclass
class Streams:
    """One chunk of a bus split by identifier.

    Attributes
    ----------
    t, dlc, words:
        Every known stream's frame times (float64), data length codes (uint8) and data bytes as one
        little-endian 8-byte word (uint64), stream after stream (identifiers in increasing order), each stream's
        frames in their order in the table.
    bounds:
        Identifier -> ``(start, stop)`` of its frames in the columns (only identifiers with frames).
    unknown:
        Counts of the frames of identifiers with no decoder (extended frames included), by identifier.
    """

    t: np.ndarray
    dlc: np.ndarray
    words: np.ndarray
    bounds: dict[int, tuple[int, int]]
    unknown: dict[int, int]

    def stream(self, cid: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The times, lengths and words of identifier ``cid`` (views on the columns)."""
        a, b = self.bounds[cid]
        return self.t[a:b], self.dlc[a:b], self.words[a:b]


@numba.njit(cache=True, nogil=True)
def _split(ids: np.ndarray, ext: np.ndarray, ts: np.ndarray, dlc: np.ndarray, words: np.ndarray,
           lut: np.ndarray, nkeys: int) -> tuple:  # pragma: no cover - numba
    """Counting sort of the frames by ``lut[id]`` (0: unknown): the known frames' columns and the unknown ids."""
    n = ids.size
    code = np.empty(n, np.int32)
    counts = np.zeros(nkeys + 1, np.int64)
    for i in range(n):
        c = 0
        if not ext[i]:
            j = ids[i]
            c = lut[j] if j < _ID_LIMIT else 0
        code[i] = c
        counts[c] += 1
    starts = np.zeros(nkeys + 2, np.int64)  # of code c's frames among the known ones (c >= 1)
    for c in range(1, nkeys + 1):
        starts[c + 1] = starts[c] + counts[c]
    pos = starts.copy()
    m = n - counts[0]
    out_t = np.empty(m, np.float64)
    out_d = np.empty(m, np.uint8)
    out_w = np.empty(m, np.uint64)
    out_id = np.empty(counts[0], np.uint32)
    u = 0
    for i in range(n):
        c = code[i]
        if c == 0:
            out_id[u] = ids[i]
            u += 1
        else:
            p = pos[c]
            pos[c] = p + 1
            out_t[p] = ts[i]
            out_d[p] = dlc[i]
            out_w[p] = words[i]
    return starts, out_t, out_d, out_w, out_id


@numba.njit(cache=True, nogil=True)
def _hist(dlc: np.ndarray, ext: np.ndarray) -> np.ndarray:  # pragma: no cover - numba
    out = np.zeros(32, np.int64)
    for i in range(dlc.size):
        d = dlc[i]
        out[(min(d, 15) << 1) | (1 if ext[i] else 0)] += 1
    return out


@numba.njit(cache=True, nogil=True)
def _hold_cut(t: np.ndarray, hold: int) -> int:  # pragma: no cover - numba
    n = t.size
    for i in range(1, n):
        if t[i] < t[i - 1]:
            return -1
    j = n - hold
    while j > 0 and t[j] == t[j - 1]:
        j -= 1
    return max(j, 0)


def hold_cut(t: np.ndarray, hold: int) -> int:
    """Where a stream's frames (times ``t``) are cut to hold back at least its last ``hold`` frames: the index ``j``
    of the first frame held back, moved back while it shares its time with the frame before it (0: every frame is
    held back); -1 when the times go back somewhere (the stream is not in time order).

    Raises
    ------
    ValueError
        If ``hold`` is under 1.
    """
    if hold < 1:
        raise ValueError(f"hold_cut: hold must be at least 1, got {hold}")
    return int(_hold_cut(np.ascontiguousarray(t, dtype=np.float64), int(hold)))


def _columns(frames: np.ndarray) -> tuple[np.ndarray, ...]:
    """The frames' identifier, extended flag, time, length and data-word columns (views on the records)."""
    if frames.dtype != FRAME_DTYPE:
        raise ValueError(f"frames must have FRAME_DTYPE, got {frames.dtype}")
    f = np.ascontiguousarray(frames)
    offset = FRAME_DTYPE.fields["data"][1]
    words = np.ndarray((len(f),), dtype="<u8", buffer=f.data, offset=offset, strides=(FRAME_DTYPE.itemsize,)) \
        if len(f) else np.zeros(0, "<u8")
    return f["arbitration_id"], f["is_extended"], f["timestamp"], f["dlc"], words


def split_streams(frames: np.ndarray, ids_known: list[int] | tuple[int, ...]) -> Streams:
    """Split a bus's frames (FRAME_DTYPE) into the streams of the known standard identifiers.

    Parameters
    ----------
    frames:
        The frame records (any order; each stream keeps the table's order).
    ids_known:
        The identifiers with a decoder (11-bit: extended frames and identifiers from 0x800 up are unknown).

    Returns
    -------
    Streams
        The known streams' columns and the unknown identifiers' counts.

    Raises
    ------
    ValueError
        If ``frames`` is not FRAME_DTYPE or a known identifier is not in 0..0x7FF.
    """
    keys = sorted({int(k) for k in ids_known})
    if keys and not (keys[0] >= 0 and keys[-1] < _ID_LIMIT):
        raise ValueError(f"known identifiers must be standard (0..0x7FF), got {keys[0]:#x}..{keys[-1]:#x}")
    lut = np.zeros(_ID_LIMIT, dtype=np.int32)
    for k, cid in enumerate(keys):
        lut[cid] = k + 1
    ids, ext, ts, dlc, words = _columns(frames)
    starts, t, d, w, unknown_ids = _split(ids, ext, ts, dlc, words, lut, len(keys))
    bounds = {cid: (int(starts[k + 1]), int(starts[k + 2])) for k, cid in enumerate(keys)
              if starts[k + 2] > starts[k + 1]}
    u_ids, u_counts = np.unique(unknown_ids, return_counts=True)
    return Streams(t, d, w, bounds, {int(i): int(c) for i, c in zip(u_ids, u_counts)})


def dlc_histogram(frames: np.ndarray) -> np.ndarray:
    """Frames per ``(min(dlc, 15) << 1) | is_extended`` (32 bins, int64): the bus-load histogram in one pass."""
    if frames.dtype != FRAME_DTYPE:
        raise ValueError(f"frames must have FRAME_DTYPE, got {frames.dtype}")
    return _hist(frames["dlc"], frames["is_extended"])
