"""Channels of a Recording on a grid over time windows: read only the spans a method uses.

:func:`~benchtwin.identification._signals.gather` puts the channels on one grid over the whole searched span, so its
arrays (and the channels it reads whole) grow with the campaign. The helpers here give the same grid's points over
one window at a time: :func:`grid_bounds` fixes the grid (its origin and length, as ``gather`` would), and
:func:`gather_at` samples the channels at some of its points, reading each channel only around them
(a lazy channel that reads blocks from its store, such as the acquisition's chunk files, is then read over that
span alone, found on a sparse index of its timestamps).
The sampled values are the very numbers ``gather`` gives at those points: the interpolation uses the whole
channel's sample indices (see ``_sample_block``).
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Iterable, Iterator, Sequence

import numpy as np

from benchtwin.identification._derivative import runs
from benchtwin.identification._reuse import fingerprint, reused
from benchtwin.identification._signals import (
    SAMPLE_BLOCK,
    STATE_ROLES,
    Grid,
    Shift,
    _IndexCache,
    _sample_block,
    grid_origin,
    time_ordered,
    to_source,
)
from benchtwin.recording import Channel, LazyChannel, Recording
from benchtwin.segments import inside_any

__all__ = ["at_times", "channel_bounds", "gather_at", "gather_span", "grid_bounds", "ordered_by_blocks", "piece_grids",
           "read_parts", "reads_by_block", "segment_pieces", "window_of"]

#: seconds read beyond each end of a window (clock shifts are applied after the read: the margin absorbs the
#: rounding of ``t - shift``; more samples than needed change nothing, the interpolation looks at its neighbours)
MARGIN_S = 1.0


#: samples compared at a time by the time-order check (bounds its temporaries on a long channel)
ORDER_BLOCK = 1 << 16


def _ordered(ts: np.ndarray) -> bool:
    """Whether ``ts`` never decreases (checked block by block: no temporary as long as the channel)."""
    last = ts.size - 1  # pairs (k, k + 1) for k < last
    for k in range(0, max(last, 0), ORDER_BLOCK):
        b = min(k + ORDER_BLOCK, last)
        if bool(np.any(ts[k + 1:b + 1] < ts[k:b])):
            return False
    return True


#: one timestamp in this many is kept by the time index of a channel read by blocks (a window read covers at most
#: twice this many samples beyond the window)
INDEX_STRIDE = 4096

#: samples read at a time while building a time index
INDEX_BLOCK = 1 << 16


class _TimeIndex:
    """Every ``INDEX_STRIDE``-th timestamp of a channel read block by block (``Channel.block``), and whether the
    channel is in time order: finds a span's samples with one read around them."""

    def __init__(self, ch: Channel) -> None:
        n = len(ch)
        self.n = n
        self.ordered = True
        marks = []
        last = -np.inf
        for a in range(0, n, INDEX_BLOCK):
            ts = ch.block(a, min(a + INDEX_BLOCK, n))[0]
            if ts.size and (ts[0] < last or not _ordered(ts)):
                self.ordered = False
                break
            if ts.size:
                last = ts[-1]
                marks.append(ts[::INDEX_STRIDE].copy())  # INDEX_BLOCK is a multiple of the stride
        self.marks = np.concatenate(marks) if marks and self.ordered else np.zeros(0)
        #: first and last timestamp of a time-ordered channel (its bounds without reading its ends again)
        self.bounds = (float(self.marks[0]), float(last)) if self.marks.size else None
        self.median_step: float | None = None  #: kept by ``_resample_blocks.rate_of`` (a property of the times)
        self.typical_step: float | None = None  #: kept by ``_resample_blocks._typical_step`` (the same)
        #: the same on the reference clock, per clock shift (``_resample_blocks._typical_step`` with a shift)
        self.shifted_steps: dict[object, float] = {}
        #: the timestamps ``(ts[j], ts[j + 1])`` at every strided step ``j`` the typical step takes (kept by
        #: ``_resample_blocks._typical_step``: its steps on any clock map without reading the channel again)
        self.step_pairs: tuple[np.ndarray, np.ndarray] | None = None


_indexes: dict[int, tuple[weakref.ref[Channel], _TimeIndex]] = {}
_indexes_lock = threading.Lock()


def _time_index(ch: Channel) -> _TimeIndex:
    """The channel's time index, built once per channel object (held while the channel lives)."""
    with _indexes_lock:
        hit = _indexes.get(id(ch))
        if hit is not None and hit[0]() is ch and hit[1].n == len(ch):
            return hit[1]
    index = _TimeIndex(ch)
    with _indexes_lock:
        for k in [k for k, (r, _) in _indexes.items() if r() is None]:
            del _indexes[k]
        _indexes[id(ch)] = (weakref.ref(ch), index)
    return index


def share_time_index(new: Channel, orig: Channel) -> None:
    """Give ``new`` the time index of ``orig`` (the same timestamps: a type B re-run's moved copy)."""
    index = _time_index(orig)
    with _indexes_lock:
        _indexes[id(new)] = (weakref.ref(new), index)


def time_index(ch: Channel) -> _TimeIndex:
    """The time index of a channel read by blocks (built once per channel object)."""
    return _time_index(ch)


def reads_by_block(ch: Channel) -> bool:
    """Whether ``ch`` is a lazy channel not in memory that reads blocks from its store without loading it whole."""
    # LazyChannel.block reads from the store only with a block loader (else it loads the channel whole)
    return isinstance(ch, LazyChannel) and not ch.loaded and getattr(ch, "_block_loader", None) is not None


def ordered_by_blocks(ch: Channel) -> bool:
    """Whether a channel read by blocks (:func:`reads_by_block`) is in time order (from its time index)."""
    return _time_index(ch).ordered


def _window(ch: Channel, start_s: float, end_s: float, ordered: dict[int, bool] | None = None
            ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray] | None:
    """The samples from the last at or before ``start_s`` (else the first) to the first at or after ``end_s`` (else
    the last) of a time-ordered channel, with the index ``k0`` of the first: interpolating or holding any time of
    the span gives the same numbers as on the whole channel. A lazy channel not in memory that reads blocks is read
    around the span only (found on its time index). None when empty or not in time order. ``ordered`` keeps
    whether a channel in memory is in time order (by ``id``) for the calls of one search: checked once, not once a
    window."""
    n = len(ch)
    if n == 0:
        return None
    if reads_by_block(ch):
        index = _time_index(ch)
        if not index.ordered:
            return None
        j = int(np.searchsorted(index.marks, start_s, side="right")) - 1  # sample j*S at or before start_s
        jb = int(np.searchsorted(index.marks, end_s, side="left"))  # sample jb*S at or after end_s
        a = max(j, 0) * INDEX_STRIDE
        b = min(jb * INDEX_STRIDE + 1, n)
        ts, vs, fl = ch.block(a, b)
        k0 = a + max(int(np.searchsorted(ts, start_s, side="right")) - 1, 0) if j >= 0 else 0
        k1 = max(min(a + int(np.searchsorted(ts, end_s, side="left")) + 1, n), k0 + 1)
        return k0, ts[k0 - a:k1 - a], vs[k0 - a:k1 - a], fl[k0 - a:k1 - a]
    ts = ch.timestamps
    if ordered is None:
        ordered = {}
    if id(ch) not in ordered:
        ordered[id(ch)] = _ordered(ts)
    if not ordered[id(ch)]:
        return None
    k0 = max(int(np.searchsorted(ts, start_s, side="right")) - 1, 0)
    k1 = max(min(int(np.searchsorted(ts, end_s, side="left")) + 1, n), k0 + 1)
    return k0, ts[k0:k1], ch.values[k0:k1], ch.flags[k0:k1]  # type: ignore[index]


def window_of(ch: Channel, start_s: float, end_s: float, ordered: dict[int, bool] | None = None
              ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """``(k0, timestamps, values, flags)`` around ``[start_s, end_s]`` (the channel's own clock), in time order:
    the channel's window when it is time-ordered, else the whole channel sorted (``k0`` 0)."""
    w = _window(ch, start_s, end_s, ordered)
    if w is not None:
        return w
    ts, vs, fl = time_ordered(ch)
    return 0, ts, vs, fl


#: longest span of times sampled from one read by :func:`at_times`
AT_SPAN_S = 300.0


def at_times(ch: Channel, t: np.ndarray, *, hold: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``ch.at(t, hold=hold)`` and ``ch.flags_at(t)``; a channel read by blocks is read around runs of nearby times
    only (at most :data:`AT_SPAN_S` each): the same bracketing samples, so the same numbers."""
    t = np.asarray(t, dtype=np.float64)
    if t.size == 0 or not reads_by_block(ch) or not ordered_by_blocks(ch) or not np.all(np.isfinite(t)):
        return ch.at(t, hold=hold), ch.flags_at(t)
    order = np.argsort(t, kind="stable")
    ts_sorted = t[order]
    v = np.empty(t.shape)
    f = np.empty(t.shape, dtype=np.uint16)
    i = 0
    while i < t.size:
        j = max(int(np.searchsorted(ts_sorted, ts_sorted[i] + AT_SPAN_S, side="right")), i + 1)
        tb = ts_sorted[i:j]
        _, tw, vw, fw = window_of(ch, float(tb[0]) - MARGIN_S, float(tb[-1]) + MARGIN_S)
        part = Channel(ch.name, ch.unit, tw, vw, fw, ch.source)  # its ends are the channel's where tb passes them
        v[order[i:j]] = part.at(tb, hold=hold)
        f[order[i:j]] = part.flags_at(tb)
        i = j
    return v, f


def channel_bounds(ch: Channel) -> tuple[float, float]:
    """First and last timestamp of a non-empty channel (read from its ends when it is time-ordered; from its time
    index when it reads by blocks)."""
    if reads_by_block(ch):
        bounds = _time_index(ch).bounds
        if bounds is not None:
            return bounds
    a, b = _window(ch, -np.inf, -np.inf), _window(ch, np.inf, np.inf)
    if a is not None and b is not None:
        return float(a[1][0]), float(b[1][-1])
    ts = ch.timestamps
    return float(ts.min()), float(ts.max())


def grid_bounds(rec: Recording, names: Sequence[str], rate_hz: float, *, what: str = "identification",
                span: tuple[float, float] | None = None, align: bool = True
                ) -> tuple[float, int, dict[str, Shift]]:
    """The grid :func:`~benchtwin.identification._signals.gather` would build: its first time, its number of points
    and the sources' clock shifts (point ``k`` is at ``lo + k / rate_hz``); the same errors as ``gather``."""
    _, lo, n, shifts, _ = grid_origin(rec, names, rate_hz, what=what, span=span, align=align, bounds=channel_bounds)
    return lo, n, shifts


#: longest span of grid time sampled from one read of a channel read by blocks (:func:`gather_at`): a run of grid
#: points inside segments that touch one another can last as long as the campaign, and a 500 Hz channel read over it
#: whole held 24 MB (paper campaign) to 66 MB (three times as long) at once; 300 s of it are 2.7 MB
READ_SPAN_S = 300.0


def read_parts(t: np.ndarray, span_s: float | None = None) -> list[tuple[int, int]]:
    """Runs ``[i, j)`` of the increasing times ``t`` each spanning at most ``span_s`` (default
    :data:`READ_SPAN_S`; at least one time each), in order and covering ``t``."""
    if span_s is None:
        span_s = READ_SPAN_S
    if not span_s > 0:
        raise ValueError(f"read_parts: span_s must be positive, got {span_s}")
    out = []
    i = 0
    while i < t.size:
        j = max(int(np.searchsorted(t, t[i] + span_s, side="right")), i + 1)
        out.append((i, j))
        i = j
    return out


def _sample_at(ch: Channel, t: np.ndarray, hold: bool, cache: _IndexCache, shift_s: Shift,
               ordered: dict[int, bool] | None = None,
               parts: Sequence[tuple[tuple[int, int], _IndexCache]] = ()) -> tuple[np.ndarray, np.ndarray]:
    """``_sample`` of the channel's samples around ``t`` only. A channel read by blocks is read around each of
    ``parts`` (runs of ``t`` with their index caches) in turn, one read let go before the next: the same bracketing
    samples and whole-channel indices, so the same numbers as from one read around ``t``."""
    if not parts or not reads_by_block(ch):
        parts = (((0, t.size), cache),)

    def compute() -> tuple[np.ndarray, np.ndarray]:
        v = np.empty(t.shape, dtype=float)
        flagged = np.empty(t.shape, dtype=bool)
        for (i, j), part_cache in parts:
            tp = t[i:j]
            k0, ts, vs, fl = window_of(ch, float(to_source(float(tp[0]), shift_s)) - MARGIN_S,
                                       float(to_source(float(tp[-1]), shift_s)) + MARGIN_S, ordered)
            fidx = part_cache.fidx(ts, shift_s, k0)
            for k in range(0, tp.size, SAMPLE_BLOCK):
                blk = slice(k, k + SAMPLE_BLOCK)
                out = slice(i + k, min(i + k + SAMPLE_BLOCK, j))
                v[out], flagged[out] = _sample_block(ts, vs, fl, tp[blk], fidx[blk], hold, shift_s, k0)
            del ts, vs, fl, fidx  # this part's read goes before the next is read
        return v, flagged

    # keyed by the channel object: the type B re-runs keep every channel they do not move (see _reuse)
    tkey = cache.key() if cache.t is t else fingerprint(t)  # the grid's fingerprint once for all its channels
    return reused("sample_at", (ch,), (t.size, float(t[0]), tkey, hold, shift_s), compute)  # type: ignore[arg-type]


def gather_at(rec: Recording, names: Sequence[str], t: np.ndarray, rate_hz: float, shifts: dict[str, Shift], *,
              optional: Iterable[str] = (), hold: Iterable[str] = (), ordered: dict[int, bool] | None = None) -> Grid:
    """The channels at grid points ``t`` (a part of the grid of :func:`grid_bounds`), as ``gather`` gives them there.

    Parameters
    ----------
    rec:
        The Recording.
    names:
        Required channels (present and non-empty: :func:`grid_bounds` checked them).
    t:
        Grid times, increasing, at least one.
    rate_hz:
        The grid's rate.
    shifts:
        Source -> clock shift (from :func:`grid_bounds`).
    optional, hold:
        As for ``gather``.
    ordered:
        Whether each channel in memory is in time order, kept over the calls of one search (see ``_window``).

    Returns
    -------
    Grid
        Over ``t`` only.
    """
    held = set(hold) | STATE_ROLES
    values: dict[str, np.ndarray] = {}
    bad = np.zeros(t.shape, dtype=bool)
    flagged = np.zeros(t.shape, dtype=bool)
    cache = _IndexCache(t)
    # runs of at most READ_SPAN_S for the channels read by blocks (their index caches shared by the channels)
    parts = [((i, j), _IndexCache(t[i:j])) for i, j in read_parts(t)]
    for n in names:
        c = rec[n]
        v, fl = _sample_at(c, t, n in held, cache, shifts.get(c.source, 0.0), ordered, parts)
        values[n] = v
        flagged |= fl
        bad |= fl | ~np.isfinite(v)
    present = set()
    for n in optional:
        if n in rec and len(rec[n]) and n not in values:
            c = rec[n]
            v, fl = _sample_at(c, t, n in held, cache, shifts.get(c.source, 0.0), ordered, parts)
            v = v.copy()
            v[fl] = np.nan
            values[n] = v
            present.add(n)
    return Grid(t, values, bad, flagged, rate_hz, present, shifts)


def gather_span(rec: Recording, names: Sequence[str], rate_hz: float, *, span: tuple[float, float],
                optional: Iterable[str] = (), hold: Iterable[str] = (), what: str = "identification") -> Grid:
    """``gather(rec, names, rate_hz, optional=optional, hold=hold, what=what, span=span)``: the same grid and numbers,
    each channel read around the span only (a lazy channel read by blocks is never loaded whole; one loaded here
    goes again)."""
    kept = rec.loaded()
    try:
        lo, n, shifts = grid_bounds(rec, names, rate_hz, what=what, span=span)
        return gather_at(rec, names, lo + np.arange(n) / rate_hz, rate_hz, shifts, optional=optional, hold=hold)
    finally:
        rec.drop(rec.loaded() - kept)


def segment_pieces(rec: Recording, kinds: Iterable[str] | None) -> list[tuple[float, float]] | None:
    """The time covered by segments of the given kinds as separate pieces (overlapping or touching segments
    merged), in time order; None when there is no such segment (or no kinds)."""
    if kinds is None:
        return None
    kinds = set(kinds)
    spans = sorted((s.start_s, s.end_s) for s in rec.segments if s.kind in kinds and s.end_s > s.start_s)
    if not spans:
        return None
    out = [spans[0]]
    for a, b in spans[1:]:
        if a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def piece_grids(rec: Recording, names: Sequence[str], rate_hz: float, kinds: Iterable[str] | None, *,
                optional: Iterable[str] = (), what: str = "identification") -> Iterator[Grid] | None:
    """The grid ``gather(rec, names, rate_hz, optional=..., span=segments_span(rec, kinds))`` would build, restricted
    to the points inside segments of ``kinds``, one run of such points at a time (a :class:`Grid` each, to be let
    go before the next); None when the Recording has no segment of these kinds (gather the whole span instead).

    The bounds are checked at once (the same errors as ``gather``); the grids come as the iterator is consumed.
    """
    pieces = segment_pieces(rec, kinds)
    if pieces is None:
        return None
    kinds_set = set(kinds or ())
    segs = [s for s in rec.segments if s.kind in kinds_set]
    lo, n, shifts = grid_bounds(rec, names, rate_hz, what=what,
                                span=(min(p[0] for p in pieces), max(p[1] for p in pieces)))
    optional = list(optional)

    def grids() -> Iterator[Grid]:
        ordered: dict[int, bool] = {}  # channels in memory checked for time order once in this search
        for start, end in pieces:
            ka = max(int(np.floor((start - lo) * rate_hz)) - 1, 0)
            kb = min(int(np.ceil((end - lo) * rate_hz)) + 2, n)
            if kb <= ka:
                continue
            t_all = lo + np.arange(ka, kb) / rate_hz  # the whole grid's points, the same numbers
            inside = inside_any(segs, t_all)  # by bisection: not a pass over the piece per test of the campaign
            for j0, j1 in runs(inside):
                g = gather_at(rec, names, t_all[j0:j1], rate_hz, shifts, optional=optional, ordered=ordered)
                g.first_index = ka + j0
                yield g

    return grids()
