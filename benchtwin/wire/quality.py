"""Quality of a received stream, judged from the wire alone, and the sink decoders write into.

Every device's decoder (``benchtwin/sensors/<kind>.py``) uses these, so a lost, doubled or reordered
frame is judged the same way on every bus: :func:`counter_flags` from a cyclic message counter,
:func:`timing_flags` from the spacing of a stream without one, :func:`split_bad` for frames of the
wrong length or content, and :func:`mark_after` for the sample after a transport drop. Decoded
channels and the counts of what went wrong go into a :class:`DecodeSink`. :func:`counter_flags` and
:func:`split_bad` each run one small numba kernel (the same arithmetic as the numpy paths they
replaced, kept as their references: ``tests/chain/test_decode_kernels.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np

from benchtwin.recording import Channel, Flag, Recording

__all__ = ["FLAG", "DecodeSink", "FrameStream", "counter_flags", "mark_after", "split_bad", "stale_length",
           "stale_runs", "timing_flags"]

#: flag name -> bit (plain ints for numpy in-place ors)
FLAG: dict[str, int] = {f.name: int(f) for f in Flag}


@numba.njit(cache=True, nogil=True)
def _counter_flags_kernel(c: np.ndarray, bits: int, lost_bit: int, dup_bit: int, ooo_bit: int
                          ) -> np.ndarray:  # pragma: no cover - numba
    """:func:`_counter_flags_numpy` in one pass (``bits`` at most 8): every difference of two counters is taken
    mod ``2**bits`` (``& mask``), as the numpy path's uint8 and int16 differences are."""
    n = c.size
    flags = np.zeros(n, np.uint16)
    mask = (1 << bits) - 1
    half = (1 << bits) // 2
    usual = True
    for i in range(1, n):
        if ((c[i] - c[i - 1]) & mask) != 1:
            usual = False
            break
    if usual:
        return flags
    keep = np.empty(n, np.int64)  # the frames that do not repeat the counter before them
    r = 0
    for i in range(n):
        if i > 0 and ((c[i] - c[i - 1]) & mask) == 0:
            flags[i] = dup_bit
        else:
            keep[r] = i
            r += 1
    # judged without the duplicates (removing them never makes two kept neighbours equal)
    for j in range(1, r):
        cj, cp = c[keep[j]], c[keep[j - 1]]
        d1 = (cj - cp) & mask
        ooo = d1 > half
        gap = d1 >= 2 and d1 <= half
        nxt_back = False
        if j < r - 1:
            cn = c[keep[j + 1]]
            nxt_back = ((cn - cj) & mask) > half and ((cj - cn) & mask) == 1
        prev_ooo_d2 = False
        if j >= 2:
            cpp = c[keep[j - 2]]
            prev_ooo_d2 = ((cp - cpp) & mask) > half and ((cj - cpp) & mask) == 1
        f = 0
        if gap and not nxt_back and not prev_ooo_d2:
            f |= lost_bit
        if ooo or (gap and nxt_back):
            f |= ooo_bit
        flags[keep[j]] = f
    return flags


def counter_flags(counter: np.ndarray, bits: int) -> np.ndarray:
    """LOST_FRAME / DUPLICATE / OUT_OF_ORDER from a cyclic counter (per sample, arrival order).

    A repeated counter is a duplicate; the other samples are then judged without the duplicates. An int64 column
    of a counter of up to 8 bits is judged in one numba kernel (:func:`_counter_flags_kernel`), anything else by
    the numpy path (:func:`_counter_flags_numpy`); the two agree flag for flag (``tests/chain/test_decode_kernels.py``).

    Parameters
    ----------
    counter:
        Counter values in arrival order.
    bits:
        Width of the counter (it wraps at ``2**bits``).
    """
    if isinstance(counter, np.ndarray) and counter.dtype == np.int64 and counter.ndim == 1 and 0 < bits <= 8:
        return _counter_flags_kernel(counter, bits, FLAG["LOST_FRAME"], FLAG["DUPLICATE"], FLAG["OUT_OF_ORDER"])
    return _counter_flags_numpy(counter, bits)


def _counter_flags_numpy(counter: np.ndarray, bits: int) -> np.ndarray:
    """The numpy path of :func:`counter_flags` (its reference)."""
    n = counter.shape[0]
    flags = np.zeros(n, dtype=np.uint16)
    if n < 2:
        return flags
    c8 = counter.astype(np.uint8)
    step = (c8[1:] - c8[:-1]) & np.uint8((1 << bits) - 1)
    if np.all(step == 1):  # the usual case: nothing lost, doubled or reordered
        return flags
    c_all = counter.astype(np.int16)
    dup = np.zeros(n, bool)
    dup[1:] = step == 0
    if dup.any():
        keep = np.flatnonzero(~dup)
        flags[keep] = _counter_flags_numpy(c_all[keep], bits)
        flags[dup] |= FLAG["DUPLICATE"]
        return flags
    m = 1 << bits
    mask = np.int16(m - 1)
    c = c_all
    d1 = np.zeros(n, dtype=np.int16)
    d1[1:] = (c[1:] - c[:-1]) & mask
    ooo = np.zeros(n, bool)
    ooo[1:] = d1[1:] > m // 2
    gap = (d1 >= 2) & (d1 <= m // 2)
    gap[0] = False
    # a reorder looks like "skip one, go back one, skip one": do not call those losses
    nxt_back = np.zeros(n, bool)
    nxt_back[:-1] = ooo[1:] & (((c[:-1] - c[1:]) & mask) == 1)
    d2 = np.zeros(n, dtype=np.int16)
    d2[2:] = (c[2:] - c[:-2]) & mask
    prev_ooo = np.zeros(n, bool)
    prev_ooo[1:] = ooo[:-1]
    reordered_gap = gap & nxt_back
    lost = gap & ~nxt_back & ~(prev_ooo & (d2 == 1))
    flags[lost] |= FLAG["LOST_FRAME"]
    flags[ooo | reordered_gap] |= FLAG["OUT_OF_ORDER"]
    return flags


def timing_flags(t: np.ndarray, period_s: float, words: np.ndarray | None = None) -> np.ndarray:
    """LOST_FRAME where the spacing exceeds 1.5 periods, DUPLICATE where it is under a quarter period and the
    payload (``words``, when given) repeats the one before (streams without a counter: a frame sent twice
    follows its first copy at once, with the same bytes)."""
    flags = np.zeros(t.shape[0], dtype=np.uint16)
    if t.shape[0] > 1 and period_s > 0:
        dt = np.diff(t)
        flags[1:][dt > 1.5 * period_s] |= FLAG["LOST_FRAME"]
        dup = dt < 0.25 * period_s
        if words is not None:
            dup &= words[1:] == words[:-1]
        flags[1:][dup] |= FLAG["DUPLICATE"]
    return flags


def stale_runs(values: np.ndarray, usable: np.ndarray, noise_std: float, step: float, p_false: float = 1e-6
               ) -> tuple[np.ndarray, np.ndarray]:
    """Runs of bit-identical readings too long for a channel with white noise ``noise_std`` and step ``step``.

    Two readings of one steady value fall on one step with probability at most ``p = erf(step / (2 sigma))``
    (their difference is N(0, 2 sigma^2) and must stay under one step), so ``L`` identical readings in a row
    happen by chance with at most ``p**(L-1)``; runs longer than the ``L`` with ``N p**(L-1) < p_false``
    (``N`` readings) are a frozen output, not a steady hold. Readings not ``usable`` (held, clipped,
    out of range) break runs. Returns start and end (exclusive) indices; none where ``p`` is near 1 (noise
    far below the step: a frozen output cannot be told from a steady one).
    """
    n = int(values.shape[0])
    length = stale_length(n, noise_std, step, p_false)
    if length is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    same = (values[1:] == values[:-1]) & usable[1:] & usable[:-1]
    e = np.flatnonzero(np.diff(np.concatenate([[0], same.astype(np.int8), [0]])))
    a, b = e[::2], e[1::2] + 1  # pairs i..j-1 equal -> readings i..j
    long_ = b - a >= length
    return a[long_], b[long_]


def stale_length(n: int, noise_std: float, step: float, p_false: float = 1e-6) -> int | None:
    """The shortest run of identical readings :func:`stale_runs` calls frozen among ``n`` readings (None: none is)."""
    if n < 3 or noise_std <= 0:
        return None
    p = math.erf(step / (2.0 * noise_std)) if step > 0 else 0.0
    if p >= 0.99:
        return None
    return max(5, math.ceil(math.log(p_false / n) / math.log(max(p, 1e-12))) + 1)


def mark_after(flags: np.ndarray, t: np.ndarray, bad_times: np.ndarray, bit: int) -> None:
    """Flag the first sample at or after each of ``bad_times`` with ``bit`` (in place)."""
    if bad_times.size == 0 or t.size == 0:
        return
    idx = np.searchsorted(t, bad_times, side="left")
    idx = idx[idx < t.size]
    flags[idx] |= bit


def split_bad(dlc: np.ndarray, length: int, extra_bad: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, int]:
    """Split a stream into its good frames and the PROTOCOL_ERROR flag of the good frame after each bad one.

    Parameters
    ----------
    dlc:
        Data length of each frame of the stream.
    length:
        The layout's length (0: any length is good).
    extra_bad:
        Frames bad for another reason (e.g. a wrong multiplexer byte).

    Returns
    -------
    good, proto, n_bad
        Boolean mask of the good frames, the flag column of the good frames, and the count of bad ones (a uint8
        column of lengths in one numba kernel, :func:`_split_bad_kernel`; anything else by :func:`_split_bad_numpy`).
    """
    if (isinstance(dlc, np.ndarray) and dlc.ndim == 1 and dlc.dtype == np.uint8
            and (extra_bad is None or (isinstance(extra_bad, np.ndarray) and extra_bad.dtype == np.bool_
                                       and extra_bad.shape == dlc.shape))):
        extra = extra_bad if extra_bad is not None else np.zeros(0, np.bool_)
        good, proto, nbad = _split_bad_kernel(dlc, int(length), extra, extra_bad is not None,
                                              FLAG["PROTOCOL_ERROR"])
        return good, proto, int(nbad)
    return _split_bad_numpy(dlc, length, extra_bad)


@numba.njit(cache=True, nogil=True)
def _split_bad_kernel(dlc: np.ndarray, length: int, extra: np.ndarray, use_extra: bool, proto_bit: int
                      ) -> tuple:  # pragma: no cover - numba
    """:func:`_split_bad_numpy` in two passes: the good mask and the count of bad frames, then ``proto_bit`` on the
    first good frame after one or more bad ones."""
    n = dlc.size
    good = np.empty(n, np.bool_)
    nbad = 0
    for i in range(n):
        bad = (length != 0 and dlc[i] != length) or (use_extra and extra[i])
        good[i] = not bad
        if bad:
            nbad += 1
    proto = np.zeros(n - nbad, np.uint16)
    seen, j = False, 0
    for i in range(n):
        if not good[i]:
            seen = True
        else:
            if seen:
                proto[j] = proto_bit
                seen = False
            j += 1
    return good, proto, nbad


def _split_bad_numpy(dlc: np.ndarray, length: int, extra_bad: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, int]:
    """The numpy path of :func:`split_bad` (its reference)."""
    bad = dlc != length if length else np.zeros(dlc.shape[0], bool)
    if extra_bad is not None:
        bad = bad | extra_bad
    proto = np.zeros(int(dlc.shape[0] - np.count_nonzero(bad)), dtype=np.uint16)
    nbad = int(bad.sum())
    if nbad:
        before = np.cumsum(bad)[~bad]
        prev = np.concatenate([[0], before[:-1]])
        proto[before > prev] = FLAG["PROTOCOL_ERROR"]
    return ~bad, proto, nbad


@dataclass
class FrameStream:
    """The frames of one identifier on one bus, in arrival order, as columns.

    Attributes
    ----------
    bus, frame_id:
        Where the frames came from.
    t:
        Timestamps (s).
    dlc:
        Data lengths.
    words:
        The eight data bytes as little-endian 64-bit words (what :class:`~benchtwin.wire.codec.MessageCodec`
        unpacks).
    drops:
        Times at which the transport dropped (the next sample gets TRANSPORT_DROP).
    """

    bus: str
    frame_id: int
    t: np.ndarray
    dlc: np.ndarray
    words: np.ndarray
    drops: np.ndarray

    @property
    def where(self) -> str:
        """``bus:0xID``, the key of this stream's protocol-error counts."""
        return f"{self.bus}:0x{self.frame_id:X}"


@dataclass
class DecodeSink:
    """Collects decoded channels and counts of what the decoders saw, for the Recording."""

    rec: Recording = field(default_factory=Recording)
    counts: dict[str, Any] = field(default_factory=lambda: {"protocol_errors": {}, "unknown_ids": {}, "frames": {}})
    #: fault evidence: (kind, device, channel, start times, end times), see :meth:`fault`
    evidence: list[tuple[str, str, str, np.ndarray, np.ndarray]] = field(default_factory=list)

    def add(self, name: str, unit: str, t: np.ndarray, v: np.ndarray, flags: np.ndarray, source: str,
            value_texts: dict[int, str] | None = None) -> None:
        """Add one decoded channel (``value_texts``: the value table of a state signal)."""
        self.rec.add(Channel(name, unit, t, v, flags, source, value_texts))

    def protocol_error(self, where: str, n: int) -> None:
        """Count ``n`` malformed frames or answers at ``where``."""
        if n:
            self.counts["protocol_errors"][where] = self.counts["protocol_errors"].get(where, 0) + int(n)

    def fault(self, kind: str, source: str, t: np.ndarray, end: np.ndarray | None = None, channel: str = "") -> None:
        """Evidence of a fault of ``kind`` at times ``t`` (spans to ``end``) on a device (and a channel)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if t.size:
            e = t if end is None else np.atleast_1d(np.asarray(end, dtype=np.float64))
            self.evidence.append((kind, source, channel, t, e))

    def count(self, key: str, name: str, n: int) -> None:
        """Add ``n`` to the count ``counts[key][name]``."""
        d = self.counts.setdefault(key, {})
        d[name] = d.get(name, 0) + int(n)
