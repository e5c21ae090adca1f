"""Steady-state detection: find the windows of a Recording where the powertrain holds still.

The paper's efficiency methods (transmission, motor, engine) use "stationary conditions": speed and
load constant and stable. :func:`find_steady_windows` finds such windows by itself: the channels
are brought onto one grid (flagged samples excluded), a window of ``window_s`` slides over it, and a
window start is steady when, over the window, every tested channel has a standard deviation and a
regression slope under its tolerance, every state channel (gear, clutches) is constant and no sample
is flagged. Consecutive steady starts form one steady window; windows shorter than
``min_duration_s`` are dropped, longer ones may be cut into pieces of ``max_duration_s``. The
segment table narrows the search to segments of the given kinds when the Recording has them; it
is never required.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from benchtwin.errors import DataError
from benchtwin.identification._reuse import fingerprint, reused
from benchtwin.identification._signals import (
    Grid,
    gather,
    runs,
    segment_mask,
    segments_span,
    time_ordered,
    to_source,
)
from benchtwin.identification._sum_kernels import centred_sums
from benchtwin.identification._window_sums import cut_windows, running_sums, window_groups
from benchtwin.identification._windows import MARGIN_S, reads_by_block, window_of
from benchtwin.identification.steady_windowed import find_steady_windows_by_piece, window_stats
from benchtwin.recording import Channel, Recording
from benchtwin.roles import unit_of_role
from benchtwin.segments import SegmentIndex

__all__ = [
    "SteadyWindow",
    "SteadyWindows",
    "Tolerance",
    "default_tolerance",
    "detect_steady",
    "find_steady_windows",
]


@dataclass(frozen=True)
class Tolerance:
    """Steadiness thresholds of one channel over a window.

    A window is steady for the channel when ``std <= std_abs + std_rel |mean|`` and
    ``|slope| <= slope_abs + slope_rel |mean|`` (slope per second, from a straight-line fit).
    """

    std_abs: float
    std_rel: float = 0.0
    slope_abs: float = 0.0
    slope_rel: float = 0.0


#: default thresholds by engineering unit
_BY_UNIT: dict[str, Tolerance] = {
    "km/h": Tolerance(0.3, 0.0, 0.3),
    "rpm": Tolerance(15.0, 0.005, 5.0, 0.0025),
    "Nm": Tolerance(2.0, 0.02, 1.0, 0.01),
    "bar": Tolerance(0.2, 0.02, 0.3, 0.02),
    "N": Tolerance(20.0, 0.02, 20.0, 0.02),
    "W": Tolerance(200.0, 0.02, 300.0, 0.02),
    "A": Tolerance(1.0, 0.02, 1.0, 0.02),
    "V": Tolerance(1.0, 0.005, 1.0, 0.005),
    "g/s": Tolerance(0.01, 0.02, 0.02, 0.02),
    "%": Tolerance(0.5, 0.0, 0.5),
}


def default_tolerance(name: str, unit: str | None = None) -> Tolerance:
    """Default steadiness thresholds for a channel, chosen by its unit (role unit when not given)."""
    unit = unit_of_role(name) if unit is None else unit
    return _BY_UNIT.get(unit, Tolerance(0.0, 0.02, 0.0, 0.02))


@dataclass
class SteadyWindow:
    """One steady window.

    Attributes
    ----------
    start_s, end_s:
        Span on the grid's clock.
    i0, i1:
        Half-open index range on the grid.
    means, stds:
        Mean and standard deviation of every gathered channel over the window.
    states:
        Value of each state channel (constant over the window).
    segment:
        Name of the segment holding the window's midpoint ('' when none).
    """

    start_s: float
    end_s: float
    i0: int
    i1: int
    means: dict[str, float]
    stds: dict[str, float]
    states: dict[str, float]
    segment: str = ""

    @property
    def duration_s(self) -> float:
        """Length of the window, s."""
        return self.end_s - self.start_s


@dataclass
class SteadyWindows:
    """The steady windows found in a Recording, with the grid they were found on.

    Attributes
    ----------
    windows:
        The windows, in time order.
    grid:
        The grid (every gathered channel), for averaging derived quantities over the windows.
    n_excluded:
        Grid samples inside the searched span that were excluded because a source sample was
        flagged (clipped, status error, timeout ...).
    searched_s:
        Length of grid searched, s.
    """

    windows: list[SteadyWindow]
    grid: Grid
    n_excluded: int = 0
    searched_s: float = 0.0
    reasons: list[str] = field(default_factory=list)
    #: found piece by piece (:mod:`~benchtwin.identification.steady_windowed`): ``grid`` holds no samples
    windowed: bool = False

    def __len__(self) -> int:
        return len(self.windows)

    def means(self, name: str) -> np.ndarray:
        """Window means of channel ``name``."""
        return np.array([w.means.get(name, np.nan) for w in self.windows])

    def state(self, name: str) -> np.ndarray:
        """Per-window value of state ``name`` (NaN when not gathered)."""
        return np.array([w.states.get(name, np.nan) for w in self.windows])

    def average(self, x: np.ndarray) -> np.ndarray:
        """Mean of a grid-aligned array (e.g. a product such as power) over each window."""
        if self.windowed:
            raise DataError("steady windows found piece by piece keep no grid: average over them with raw_average")
        x = np.asarray(x, dtype=float)
        fin = np.isfinite(x)
        c1 = np.concatenate(([0.0], np.cumsum(np.where(fin, x, 0.0))))
        cn = np.concatenate(([0], np.cumsum(fin)))
        a = np.array([w.i0 for w in self.windows], dtype=int)
        b = np.array([w.i1 for w in self.windows], dtype=int)
        cnt = cn[b] - cn[a]
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(cnt > 0, (c1[b] - c1[a]) / np.maximum(cnt, 1), np.nan)

    def raw_average(self, rec: Recording, name: str, other: str | None = None) -> np.ndarray:
        """Mean of a channel's own good samples over each window (all the source's samples, not the grid's).

        With ``other`` (a channel of the same source on the same timestamps, e.g. the voltage of a
        current), the mean of the sample-by-sample product; on different timestamps, the product of
        the two means. Timestamps get the grid's clock shifts (:func:`source_shifts`). A channel of a lazy
        Recording read here goes again afterwards (one channel at its own rate in memory at a time).
        """
        kept = rec.loaded()
        try:
            if self.windowed:
                return self._raw_average_windowed(rec, name, other)
            return self._raw_average(rec, name, other)
        finally:
            rec.drop([n for n in (name, other) if n is not None and n not in kept])

    def _raw_average(self, rec: Recording, name: str, other: str | None) -> np.ndarray:
        if not self.windows:
            return np.array([])
        ch = rec[name]
        ch2 = rec[other] if other is not None else None
        arrays = (ch.timestamps, ch.values, ch.flags) + (() if ch2 is None else (ch2.timestamps, ch2.values, ch2.flags))
        edges = np.array([(w.start_s, w.end_s) for w in self.windows])
        shifts = self.grid.shifts
        key = (fingerprint(edges), shifts.get(ch.source, 0.0), None if ch2 is None else shifts.get(ch2.source, 0.0))
        # the type B re-runs average the channels they do not move over the same windows again (see _reuse)
        return reused("raw_average", arrays, key, lambda: self._raw_average_of(rec, name, other))

    def _raw_average_windowed(self, rec: Recording, name: str, other: str | None) -> np.ndarray:
        """:meth:`raw_average` of windows found piece by piece: a channel in memory (or one its store reads only
        whole) is averaged as by the whole search; one read by blocks is read once per group of nearby windows
        (:func:`window_groups`), with the very sums of the whole pass (its running sums carried from group to
        group)."""
        if not self.windows:
            return np.array([])
        ch = rec[name]
        ch2 = rec[other] if other is not None else None
        if not (reads_by_block(ch) and (ch2 is None or reads_by_block(ch2))):
            return self._raw_average(rec, name, other)
        edges = np.array([(w.start_s, w.end_s) for w in self.windows])
        shifts = self.grid.shifts
        key = (fingerprint(edges), shifts.get(ch.source, 0.0), None if ch2 is None else shifts.get(ch2.source, 0.0))
        objs = (ch,) if ch2 is None else (ch, ch2)
        # keyed by the channel objects: the type B re-runs keep every channel they do not move (see _reuse)
        return reused("raw_average_windowed", objs, key,  # type: ignore[arg-type]
                      lambda: self._grouped_average(rec, ch, ch2))

    def _grouped_average(self, rec: Recording, ch: Channel, ch2: Channel | None) -> np.ndarray:
        shift = self.grid.shifts.get(ch.source, 0.0)
        shift2 = shift if ch2 is None else self.grid.shifts.get(ch2.source, 0.0)
        # a window longer than a group is read in pieces (the same sums: see cut_windows)
        starts, ends, first = cut_windows(np.array([w.start_s for w in self.windows]),
                                          np.array([w.end_s for w in self.windows]))
        cs = np.zeros(starts.size + 1)
        cn = np.zeros(starts.size + 1, dtype=np.int64)
        for i, j in window_groups(starts, ends):
            lo_s, hi_s = float(starts[i:j].min()), float(ends[i:j].max())
            k0, ts, vals, fl = window_of(ch, float(to_source(lo_s, shift)) - MARGIN_S,
                                         float(to_source(hi_s, shift)) + MARGIN_S)
            pair = None
            if ch2 is not None:
                k2, ts2, vals2, fl2 = window_of(ch2, float(to_source(lo_s, shift2)) - MARGIN_S,
                                                float(to_source(hi_s, shift2)) + MARGIN_S)
                if not (shift2 == shift and k2 == k0 and ts2.shape == ts.shape and np.array_equal(ts2, ts)):
                    # on different timestamps: the product of the two means (as the whole search)
                    return (self._raw_average_windowed(rec, ch.name, None)
                            * self._raw_average_windowed(rec, ch2.name, None))
                pair = (vals2, fl2)
                del ts2, vals2, fl2
            cs[i:j + 1], cn[i:j + 1] = running_sums(ts, vals, fl, pair, shift, starts[i:j], ends[i:j],
                                                     float(cs[i]), int(cn[i]))
            del ts, vals, fl, pair  # this group's read goes before the next is read
        at = np.append(first, starts.size)  # each window's first piece, and the end of the last
        cs, cn = cs[at], cn[at]
        cnt = cn[1:] - cn[:-1]
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(cnt > 0, (cs[1:] - cs[:-1]) / np.maximum(cnt, 1), np.nan)

    def _raw_average_of(self, rec: Recording, name: str, other: str | None) -> np.ndarray:
        shifts = self.grid.shifts
        ch = rec[name]
        shift = shifts.get(ch.source, 0.0)
        ts, vals, fl = time_ordered(ch)
        pair = None
        if other is not None:
            ch2 = rec[other]
            ts2, vals2, fl2 = time_ordered(ch2)
            if not (ts2 is ts or (ts2.shape == ts.shape and shifts.get(ch2.source, 0.0) == shift
                                  and np.array_equal(ts2, ts))):
                return self.raw_average(rec, name) * self.raw_average(rec, other)
            pair = (vals2, fl2)
        if not self.windows:
            return np.array([])
        starts = np.array([w.start_s for w in self.windows])
        ends = np.array([w.end_s for w in self.windows])
        cs, cn = running_sums(ts, vals, fl, pair, shift, starts, ends, 0.0, 0)
        cnt = cn[1:] - cn[:-1]
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(cnt > 0, (cs[1:] - cs[:-1]) / np.maximum(cnt, 1), np.nan)

    def segments(self, keep: np.ndarray | None = None) -> list[str]:
        """Names of the segments the (kept) windows came from."""
        ws = self.windows if keep is None else [w for w, k in zip(self.windows, keep) if k]
        return sorted({w.segment for w in ws if w.segment})

    def select(self, keep: np.ndarray) -> SteadyWindows:
        """A copy holding only the windows where ``keep`` is true."""
        return SteadyWindows([w for w, k in zip(self.windows, keep) if k], self.grid, self.n_excluded,
                             self.searched_s, list(self.reasons), self.windowed)


def detect_steady(dt: float, signals: Mapping[str, np.ndarray], tolerances: Mapping[str, Tolerance], *,
                  valid: np.ndarray | None = None, states: Mapping[str, np.ndarray] | None = None,
                  window_s: float = 2.0, min_duration_s: float = 3.0,
                  max_duration_s: float | None = None, trim_s: float = 0.0) -> list[tuple[int, int]]:
    """Steady index ranges of uniformly sampled signals.

    Parameters
    ----------
    dt:
        Sample step, s.
    signals:
        Name -> values, all of one length; each is tested against its tolerance.
    tolerances:
        Name -> :class:`Tolerance` (every name of ``signals`` must have one).
    valid:
        Samples that may be used (False for flagged, outside the searched segments ...).
    states:
        Name -> discrete state values that must be constant over a window (gear, clutches).
    window_s:
        Length of the sliding window.
    min_duration_s:
        Shortest steady window kept.
    max_duration_s:
        Longer windows are cut into pieces of about this length (more points per hold).
    trim_s:
        Time dropped at both ends of each window (the edges of a hold still carry the
        approach to it).

    Returns
    -------
    list of (i0, i1)
        Half-open index ranges.
    """
    if not signals:
        raise DataError("steady-state detection needs at least one signal")
    n = len(next(iter(signals.values())))
    w = max(round(window_s / dt), 3)
    if n < w:
        return []
    ok = np.ones(n - w + 1, dtype=bool)
    usable = np.ones(n, dtype=bool) if valid is None else np.asarray(valid, dtype=bool).copy()
    k = np.arange(w) - (w - 1) / 2.0
    kk = float(k @ k)
    for name, x in signals.items():
        x = np.asarray(x, dtype=float)
        fin = np.isfinite(x)
        usable &= fin
        tol = tolerances[name]
        # window sums from cumulative sums (shifted by the median for accuracy)
        ref = float(np.median(x[fin])) if fin.any() else 0.0
        if x.ndim == 1:  # one pass free of the GIL, the same numbers (_sum_kernels; x is float64 here)
            c1, c2, ci, _cn = centred_sums(x, ref, True)
        else:
            xc = np.where(fin, x - ref, 0.0)
            i = np.arange(n, dtype=float)
            c1 = np.concatenate(([0.0], np.cumsum(xc)))
            c2 = np.concatenate(([0.0], np.cumsum(xc * xc)))
            ci = np.concatenate(([0.0], np.cumsum(i * xc)))
        s1 = c1[w:] - c1[:-w]
        s2 = c2[w:] - c2[:-w]
        si = ci[w:] - ci[:-w]
        mean_c = s1 / w
        std = np.sqrt(np.clip(s2 / w - mean_c**2, 0.0, None))
        mean = mean_c + ref
        # least-squares slope: sum((i - centre) x) / sum(k^2), centre = j + (w - 1) / 2
        centre = np.arange(n - w + 1, dtype=float) + (w - 1) / 2.0
        slope = (si - centre * s1) / kk / dt
        ok &= std <= tol.std_abs + tol.std_rel * np.abs(mean) + 1e-12 * max(abs(ref), 1.0)
        ok &= np.abs(slope) <= tol.slope_abs + tol.slope_rel * np.abs(mean) + 1e-9 * max(abs(ref), 1.0)
    for x in (states or {}).values():
        x = np.asarray(x, dtype=float)
        usable &= np.isfinite(x)
        # constant over a window: no change between consecutive samples inside it
        change = np.concatenate(([0], np.cumsum(np.diff(np.where(np.isfinite(x), x, -1e300)) != 0)))
        ok &= change[w - 1:] - change[: n - w + 1] == 0
    # every sample of the window usable: a window sum of the unusable count must be zero
    bad_count = np.convolve((~usable).astype(np.int32), np.ones(w, dtype=np.int32), mode="valid")
    ok &= bad_count == 0
    out: list[tuple[int, int]] = []
    min_len = int(np.ceil(min_duration_s / dt))
    piece = None if max_duration_s is None else max(round(max_duration_s / dt), w)
    trim = round(trim_s / dt)
    for j0, j1 in runs(ok):
        i0, i1 = j0 + trim, j1 - 1 + w - trim
        if i1 - i0 < min_len:
            continue
        if piece is None or i1 - i0 < 2 * piece:
            out.append((i0, i1))
            continue
        m = (i1 - i0) // piece
        edges = np.linspace(i0, i1, m + 1).round().astype(int)
        out.extend((int(a), int(b)) for a, b in itertools.pairwise(edges))
    return out


def find_steady_windows(rec: Recording, channels: Sequence[str], *, states: Iterable[str] = (),
                        extra: Iterable[str] = (), optional: Iterable[str] = (),
                        kinds: Iterable[str] | None = None, rate_hz: float = 10.0, window_s: float = 2.0,
                        min_duration_s: float = 3.0, max_duration_s: float | None = None, trim_s: float = 0.5,
                        tolerances: Mapping[str, Tolerance] | None = None,
                        valid: np.ndarray | None = None, grid: Grid | None = None) -> SteadyWindows:
    """Find steady windows of a Recording by themselves.

    Parameters
    ----------
    rec:
        The Recording.
    channels:
        Channels that must be steady (required).
    states:
        State channels (gear_actual, k0_closed, lockup_closed, gear_target ...) that must be
        constant over a window; used when present.
    extra:
        Further required channels that are averaged but not tested.
    optional:
        Channels averaged when present.
    kinds:
        Segment kinds to search in (e.g. ``("ramp_up", "constant_drive")``); ignored when the
        Recording has no segment of these kinds.
    rate_hz, window_s, min_duration_s, max_duration_s, trim_s:
        Grid rate and window lengths (see :func:`detect_steady`).
    tolerances:
        Per-channel overrides of :func:`default_tolerance`.
    valid:
        Extra mask over the grid (only with ``grid``).
    grid:
        A grid already gathered by the caller holding every channel named (skips resampling).

    Returns
    -------
    SteadyWindows

    Raises
    ------
    MissingChannelError
        A required channel is absent.
    """
    channels = list(channels)
    state_names = [s for s in states if s in rec]
    extra = [e for e in extra if e not in channels]
    if grid is None and valid is None and kinds is not None:
        # the segments' points only, one piece at a time: memory bounded by a piece, not by the Recording
        tol = dict(tolerances or {})
        tols = {c: tol.get(c, default_tolerance(c, rec[c].unit or None)) for c in channels}
        found = find_steady_windows_by_piece(rec, channels, state_names, extra, list(optional), list(kinds),
                                             rate_hz, window_s, min_duration_s, max_duration_s, trim_s, tols,
                                             detect_steady, SteadyWindow, SteadyWindows)
        if found is not None:
            return found
    if grid is None:
        grid = gather(rec, channels + extra, rate_hz, optional=[*state_names, *optional],
                      what="steady-state detection", span=segments_span(rec, kinds))
    usable = ~grid.bad
    seg = segment_mask(rec, grid.t, kinds)
    reasons: list[str] = []
    if seg is not None:
        usable &= seg
        searched = seg
    else:
        searched = np.ones(grid.t.shape, dtype=bool)
        if kinds is not None:
            reasons.append(f"no segment of kind {', '.join(sorted(set(kinds)))}: searched the whole recording")
    if valid is not None:
        usable &= np.asarray(valid, dtype=bool)
    tol = dict(tolerances or {})
    tols = {c: tol.get(c, default_tolerance(c, rec[c].unit or None)) for c in channels}
    st = {s: grid[s] for s in state_names if s in grid}
    spans = detect_steady(grid.dt, {c: grid[c] for c in channels}, tols, valid=usable, states=st,
                          window_s=window_s, min_duration_s=min_duration_s, max_duration_s=max_duration_s,
                          trim_s=trim_s)
    mids = [grid.t[(a + b - 1) // 2] for a, b in spans]
    stats_ = window_stats(grid, spans)
    windows = []
    segnames = SegmentIndex(rec.segments).names_at(mids)
    for k, (a, b) in enumerate(spans):
        means = {name: float(v[0][k]) for name, v in stats_.items() if np.isfinite(v[0][k])}
        stds = {name: float(v[1][k]) for name, v in stats_.items() if np.isfinite(v[0][k])}
        states_v = {s: float(grid[s][a]) for s in st}
        windows.append(SteadyWindow(float(grid.t[a]), float(grid.t[b - 1] + grid.dt), a, b, means, stds, states_v,
                                    segnames[k]))
    n_excl = int((grid.flagged & searched).sum())
    return SteadyWindows(windows, grid, n_excl, float(searched.sum() * grid.dt), reasons)
