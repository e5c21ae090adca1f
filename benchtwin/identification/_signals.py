"""Helpers that pull channels out of a Recording for identification.

A Recording keeps each source on its own time base with quality flags per sample. Identification
methods need the channels they use on one uniform grid, with a mask of the grid samples that must
not be used (flagged at the source, missing, outside a channel's span). :func:`gather` does that,
counting the flagged samples so every fit can report them as excluded. The other helpers restrict
the grid to segments of given kinds (when the Recording has a segment table), find contiguous runs,
differentiate smoothly and check that a regressor really varies.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from benchtwin.errors import (
    DataError,
    IdentificationError,
    InsufficientDataError,
    MissingChannelError,
    NoExcitationError,
)
from benchtwin.identification._clock import ClockShift, Shift, source_shifts, to_ref, to_source
from benchtwin.identification._derivative import runs, smooth_derivative
from benchtwin.identification._reuse import fingerprint, reused
from benchtwin.identification._sample_kernel import sample_block
from benchtwin.recording import Channel, Flag, Recording
from benchtwin.segments import inside_any, touched

__all__ = [
    "BAD_FLAGS",
    "STATE_ROLES",
    "ClockShift",
    "Grid",
    "Shift",
    "check_spread",
    "gap_mask",
    "gather",
    "native_rate",
    "raise_all_failed",
    "runs",
    "segment_mask",
    "segment_names",
    "segments_span",
    "smooth_derivative",
    "source_shifts",
    "strict_resample",
    "time_ordered",
    "to_ref",
    "to_source",
]

#: roles that are discrete states: zero-order hold, never interpolated
STATE_ROLES = frozenset({"gear_target", "gear_actual", "k0_closed", "lockup_closed", "hybrid_mode", "engine_on"})

_BAD = int(Flag.bad())
BAD_FLAGS = _BAD  #: the Flag bits that make a sample unusable


@dataclass
class Grid:
    """Channels of a Recording on one uniform time base.

    Attributes
    ----------
    t:
        Grid times, s.
    values:
        Channel name -> values on the grid (NaN where the channel has no data).
    bad:
        Grid samples unusable for any of the *required* channels (flagged, missing, non-finite).
    flagged:
        Grid samples excluded because a required channel carried a bad quality flag there
        (a subset of ``bad``; these are what fits report as excluded).
    rate_hz:
        Grid rate.
    present:
        Names of optional channels that were present.
    shifts:
        Source -> seconds added to its timestamps, a constant or a :class:`ClockShift` (clock alignment, see
        :func:`source_shifts`).
    first_index:
        Index of ``t[0]`` in the whole grid (a piece of it), else 0.
    """

    t: np.ndarray
    values: dict[str, np.ndarray]
    bad: np.ndarray
    flagged: np.ndarray
    rate_hz: float
    present: set[str] = field(default_factory=set)
    shifts: dict[str, Shift] = field(default_factory=dict)
    #: index of ``t[0]`` in the whole grid when this is a piece of it (``_windows.piece_grids``)
    first_index: int = 0

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.values[name]
        except KeyError:
            raise MissingChannelError(f"channel {name!r} was not gathered") from None

    def __contains__(self, name: object) -> bool:
        return name in self.values

    @property
    def dt(self) -> float:
        """Grid step, s."""
        return 1.0 / self.rate_hz


def time_ordered(ch: Channel, shift_s: Shift = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Timestamps (plus ``shift_s``), values and flags of a channel in time order (samples delivered out
    of order are sorted, stably; interpolation and window sums need increasing time)."""
    ts, vs, fl = _in_order(ch)
    return (to_ref(ts, shift_s) if shift_s else ts), vs, fl


def _in_order(ch: Channel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Timestamps, values and flags of a channel in time order (stable sort when delivered out of order)."""
    ts, vs, fl = ch.timestamps, ch.values, ch.flags
    # checked on every call: a channel's arrays may be changed in place between calls
    if ts.size > 1 and bool(np.any(ts[1:] < ts[:-1])):
        order = np.argsort(ts, kind="stable")
        ts, vs, fl = ts[order], vs[order], fl[order]
    return ts, vs, fl


class _IndexCache:
    """Fractional sample indices of grid times per time base (channels of one source share it)."""

    def __init__(self, t: np.ndarray) -> None:
        self.t = t
        self._cache: list[tuple[weakref.ref[np.ndarray], Shift, np.ndarray, int]] = []
        self._key: tuple | None = None

    def key(self) -> tuple:
        """:func:`~benchtwin.identification._reuse.fingerprint` of the grid times, worked out once for the channels
        sampled at them (the cache lives while they are sampled: the times are not changed meanwhile)."""
        if self._key is None:
            self._key = fingerprint(self.t)
        return self._key

    def fidx(self, ts: np.ndarray, shift_s: Shift = 0.0, k0: int = 0) -> np.ndarray:
        """Fractional index into ``ts + shift_s`` of every grid time (``ts`` in time order; ``k0``: the index of
        ``ts[0]`` in the whole channel when ``ts`` is a part of it, so the indices are the whole channel's)."""
        for ref, s0, f, kk in self._cache:
            # the time bases are held weakly: a lazy Recording's channel dropped after gathering lets its go
            ts0 = ref()
            if ts0 is not None and s0 == shift_s and kk == k0 and (
                    ts0 is ts or (ts0.shape == ts.shape and ts0[0] == ts[0] and ts0[-1] == ts[-1]
                                  and np.array_equal(ts0, ts))):
                return f
        # np.interp walks sorted queries in one pass (a binary search per query costs more on long logs)
        f = np.interp(self.t, to_ref(ts, shift_s) if shift_s else ts, np.arange(k0, k0 + ts.size, dtype=float))
        self._cache = [c for c in self._cache if c[0]() is not None]
        self._cache.append((weakref.ref(ts), shift_s, f, k0))
        return f


#: grid points sampled at a time by :func:`_sample` (bounds its index and weight temporaries on long logs)
SAMPLE_BLOCK = 1 << 20


def _sample(ch: Channel, t: np.ndarray, hold: bool, cache: _IndexCache | None = None, shift_s: Shift = 0.0
            ) -> tuple[np.ndarray, np.ndarray]:
    """Values of ``ch`` at ``t`` (linear, or zero-order hold; NaN outside its span) and a mask of grid
    samples touched by a flagged or non-finite source sample."""
    def compute() -> tuple[np.ndarray, np.ndarray]:
        ts, vs, fl = _in_order(ch)
        fidx = (cache if cache is not None else _IndexCache(t)).fidx(ts, shift_s)
        v = np.empty(t.shape, dtype=float)
        flagged = np.empty(t.shape, dtype=bool)
        for k in range(0, t.size, SAMPLE_BLOCK):  # block by block: the same numbers, bounded temporaries
            part = slice(k, k + SAMPLE_BLOCK)
            v[part], flagged[part] = _sample_block(ts, vs, fl, t[part], fidx[part], hold, shift_s)
        return v, flagged

    # the type B re-runs sample the channels they do not move on the same grid again (see _reuse)
    return reused("sample", (ch.timestamps, ch.values, ch.flags),
                  (t.size, float(t[0]) if t.size else 0.0,
                   cache.key() if cache is not None and cache.t is t else fingerprint(t), hold, shift_s), compute)


def _sample_block(ts: np.ndarray, vs: np.ndarray, fl: np.ndarray, t: np.ndarray, fidx: np.ndarray, hold: bool,
                  shift_s: Shift, k0: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """One block of :func:`_sample`; ``ts, vs, fl`` may be a part of the channel starting at its sample ``k0``
    (``fidx`` then holds whole-channel indices, so the weights are the same numbers as on the whole channel)."""
    if ts.size and all(a.dtype == np.float64 for a in (ts, vs, t, fidx)) and fl.dtype == np.uint16:
        # one pass free of the GIL with the same operations (_sample_kernel); a non-finite index: the NumPy path
        affine = isinstance(shift_s, ClockShift)
        offset, rate = (shift_s.offset_s, shift_s.rate) if isinstance(shift_s, ClockShift) else (shift_s, 0.0)
        done, v, flagged = sample_block(ts, vs, fl, t, fidx, hold, affine, float(offset), float(rate), int(k0), _BAD)
        if done:
            return v, flagged
    n = ts.size
    first, last = to_ref(ts[0], shift_s), to_ref(ts[-1], shift_s)
    idx = np.floor(fidx).astype(np.int64)
    if k0:
        idx -= k0
    idx[t < first] = -1
    i0 = np.clip(idx, 0, n - 1)
    i1 = np.clip(idx + 1, 0, n - 1)
    v0 = vs[i0]
    # flags and finiteness looked up at the samples used only (not over the whole channel)
    flagged = ((fl[i0] & _BAD) != 0) | ~np.isfinite(v0)
    if hold:
        v = v0.astype(float)
    else:
        v1 = vs[i1]
        frac = fidx - (np.clip(idx, 0, None) + k0 if k0 else np.clip(idx, 0, None))
        v = v0 + frac * (v1 - v0)
        # a linearly interpolated value depends on the sample after as well
        flagged |= (((fl[i1] & _BAD) != 0) | ~np.isfinite(v1)) & (to_ref(ts[i1], shift_s) > t)
    outside = (idx < 0) | (t > last)
    v[outside] = np.nan
    flagged &= ~outside
    return v, flagged


def grid_origin(rec: Recording, names: Sequence[str], rate_hz: float, *, what: str = "identification",
                span: tuple[float, float] | None = None, align: bool = True,
                bounds: Callable[[Channel], tuple[float, float]] | None = None
                ) -> tuple[list[Channel], float, int, dict[str, Shift], set[str]]:
    """The required channels checked, and the first time and number of points of their common grid.

    Returns ``(channels, lo, n, shifts, kept)``: point ``k`` of the grid is at ``lo + k / rate_hz`` on the reference
    clock, ``shifts`` the sources' clock maps (:func:`source_shifts`, empty without ``align``) and ``kept`` the
    channels that were in memory before (others are dropped again once read). ``bounds`` gives a channel's first
    and last timestamp (default: its timestamps' extremes). Raises :class:`MissingChannelError` for an absent
    channel, :class:`DataError` for a non-positive rate, an empty channel or channels that do not overlap.
    """
    names = list(names)
    missing = [n for n in names if n not in rec]
    if missing:
        raise MissingChannelError(f"{what}: the recording lacks {', '.join(missing)} "
                                  f"(has: {', '.join(sorted(rec.channels)) or 'none'})")
    if not rate_hz > 0:
        raise DataError(f"{what}: grid rate must be positive, got {rate_hz}")
    chans = [rec[n] for n in names]
    empty = [c.name for c in chans if len(c) == 0]
    if empty:
        raise DataError(f"{what}: channels without samples: {', '.join(empty)}")
    shifts = source_shifts(rec) if align else {}
    # a lazy Recording (Recording.open, a log imported on demand): a channel read here goes again once it has
    # given its span and its values on the grid, so one channel at its own rate is in memory at a time
    kept = rec.loaded()
    lo, hi = -np.inf, np.inf
    for c in chans:
        first, last = bounds(c) if bounds is not None else (float(c.timestamps.min()), float(c.timestamps.max()))
        lo = max(lo, float(to_ref(first, shifts.get(c.source, 0.0))))
        hi = min(hi, float(to_ref(last, shifts.get(c.source, 0.0))))
        if c.name not in kept:
            rec.drop([c.name])
    if span is not None:
        lo, hi = max(lo, float(span[0])), min(hi, float(span[1]))
    if not hi > lo:
        raise DataError(f"{what}: channels {', '.join(names)} do not overlap in time")
    return chans, lo, int(np.floor((hi - lo) * rate_hz)) + 1, shifts, kept


def gather(rec: Recording, names: Sequence[str], rate_hz: float, *, optional: Iterable[str] = (),
           hold: Iterable[str] = (), what: str = "identification", span: tuple[float, float] | None = None,
           align: bool = True) -> Grid:
    """Resample required and optional channels of ``rec`` onto one grid.

    Parameters
    ----------
    rec:
        The Recording.
    names:
        Required channels; the grid spans their common overlap.
    rate_hz:
        Grid rate, Hz.
    optional:
        Channels used when present (NaN outside their span; they do not make samples bad).
    hold:
        Extra channels to zero-order hold (state roles are always held).
    what:
        Name of the method, for messages.
    span:
        Restrict the grid to this time span (e.g. :func:`segments_span`).
    align:
        Put every source on one clock with the offsets the acquisition detected
        (:func:`source_shifts`); the grid's time is then the reference clock's.

    Returns
    -------
    Grid

    Raises
    ------
    MissingChannelError
        If a required channel is absent.
    DataError
        If a required channel is empty or the channels do not overlap in time.
    """
    chans, lo, n, shifts, kept = grid_origin(rec, names, rate_hz, what=what, span=span, align=align)
    t = lo + np.arange(n) / rate_hz
    held = set(hold) | STATE_ROLES
    values: dict[str, np.ndarray] = {}
    bad = np.zeros(t.shape, dtype=bool)
    flagged = np.zeros(t.shape, dtype=bool)
    cache = _IndexCache(t)
    for c in chans:
        v, fl = _sample(c, t, c.name in held, cache, shifts.get(c.source, 0.0))
        values[c.name] = v
        flagged |= fl
        bad |= fl | ~np.isfinite(v)
        if c.name not in kept:
            rec.drop([c.name])
    present = set()
    for n in optional:
        if n in rec and len(rec[n]) and n not in values:
            v, fl = _sample(rec[n], t, n in held, cache, shifts.get(rec[n].source, 0.0))
            v[fl] = np.nan
            values[n] = v
            present.add(n)
            if n not in kept:
                rec.drop([n])
    return Grid(t, values, bad, flagged, rate_hz, present, shifts)


def segment_mask(rec: Recording, t: np.ndarray, kinds: Iterable[str] | None) -> np.ndarray | None:
    """Grid samples inside segments of the given kinds, or None when the table has none of them.

    None means "search the whole recording": the segment table narrows the search when it can,
    but is never required.
    """
    if kinds is None:
        return None
    kinds = set(kinds)
    segs = [s for s in rec.segments if s.kind in kinds]
    if not segs:
        return None
    return inside_any(segs, t)


def segments_span(rec: Recording, kinds: Iterable[str] | None) -> tuple[float, float] | None:
    """Time span covering every segment of the given kinds, or None (no such segment, or no kinds)."""
    if kinds is None:
        return None
    kinds = set(kinds)
    segs = [s for s in rec.segments if s.kind in kinds]
    if not segs:
        return None
    return min(s.start_s for s in segs), max(s.end_s for s in segs)


def segment_names(rec: Recording, times: Iterable[float]) -> list[str]:
    """Names of the segments containing any of ``times`` (sorted, unique)."""
    times = np.asarray(list(times), dtype=float)
    return sorted({s.name for s, hit in zip(rec.segments, touched(rec.segments, times), strict=True) if hit})


def check_spread(x: np.ndarray, min_spread: float, what: str, name: str, unit: str = "") -> None:
    """Raise NoExcitationError when ``x`` spans less than ``min_spread``.

    Parameters
    ----------
    x:
        Regressor values over the points used.
    min_spread:
        Smallest acceptable ``max(x) - min(x)``.
    what, name, unit:
        Method, regressor and unit, for the message.
    """
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return
    spread = float(x.max() - x.min())
    if spread < min_spread:
        raise NoExcitationError(
            f"{what}: {name} spans only {spread:.4g} {unit} over {x.size} points (from {x.min():.4g} to "
            f"{x.max():.4g}); at least {min_spread:.4g} {unit} is needed to separate the parameters"
        )


def raise_all_failed(what: str, errors: dict[str, IdentificationError]) -> None:
    """Raise when every sub-fit of a method failed: the common error class if they agree, else
    InsufficientDataError, with every reason in the message."""
    detail = "; ".join(f"{k}: {v}" for k, v in errors.items()) or "no usable points"
    classes = {type(e) for e in errors.values()}
    cls = classes.pop() if len(classes) == 1 else InsufficientDataError
    raise cls(f"{what}: nothing could be fitted ({detail})")


def native_rate(ch: Channel, *, max_hz: float = 200.0) -> float:
    """A channel's own sample rate (median spacing), capped at ``max_hz``; 10 Hz when undefined."""
    if len(ch) < 2:
        return 10.0
    d = float(np.median(np.diff(ch.timestamps)))
    return min(1.0 / d, max_hz) if d > 0 else 10.0


def gap_mask(rec: Recording, names: list[str], t: np.ndarray, factor: float = 3.0) -> np.ndarray:
    """Grid points that fall in a gap of any channel longer than ``factor`` times its median interval.

    Interpolating across a pause in the log would invent samples; those grid points are left out.
    """
    out = np.zeros(t.shape, dtype=bool)
    kept = rec.loaded()  # a lazy Recording: a channel read here goes again once used
    for n in names:
        ts = rec[n].timestamps
        if n not in kept:
            rec.drop([n])  # ts stays with this loop
        if ts.size < 3:
            continue
        dt = np.diff(ts)
        typical = np.median(dt[:: max(1, dt.size // 20000)])  # a strided sample is enough for the typical step
        big = dt > factor * typical
        if not big.any():
            continue
        idx = np.searchsorted(ts, t, side="right") - 1  # sample at or before each grid point
        inside = (idx >= 0) & (idx < dt.size)
        gap = np.zeros(t.shape, dtype=bool)
        gap[inside] = big[idx[inside]] & (t[inside] > ts[idx[inside]])
        out |= gap
    return out


def strict_resample(rec: Recording, names: list[str], rate_hz: float, *, hold: tuple[str, ...] = ()
                    ) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """:meth:`Recording.resample` that also drops grid points next to a bad sample or inside a gap.

    A grid point interpolated between a good and a flagged sample carries part of the flagged value;
    one inside a pause of the log carries an invented value. Both are marked bad here.
    """
    t, v, bad = rec.resample(names, rate_hz, hold=hold)
    kept = rec.loaded()  # a lazy Recording: a channel read here goes again once used
    for n in names:
        ch = rec[n]
        if n in hold or len(ch) < 2:
            continue
        sbad = ~ch.good
        if sbad.any():
            nxt = np.clip(np.searchsorted(ch.timestamps, t, side="left"), 0, len(ch) - 1)
            bad |= sbad[nxt] | ((ch.flags[nxt] & int(Flag.bad())) != 0)
        if n not in kept:
            rec.drop([n])
    bad |= gap_mask(rec, [n for n in names if n not in hold], t)
    return t, v, bad
