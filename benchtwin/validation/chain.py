"""The chain against the truth: every decoded channel of the Recording compared with the Trace.

Which Trace channel a role measures, to which resolution, and which imperfections the setup declares
for it are said by each device (:meth:`~benchtwin.sensors.base.Device.truth_channels`,
:meth:`~benchtwin.sensors.base.Device.error_budget`); this module names no device kind.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
from scipy.ndimage import maximum_filter1d

from benchtwin.config.setup import SetupConfig
from benchtwin.recording import Channel, Flag, Recording
from benchtwin.sensors import devices
from benchtwin.sensors.base import TruthChannel
from benchtwin.sensors.imperfections import hold_sample
from benchtwin.trace import SpooledTrace, Trace
from benchtwin.validation.report import Check

__all__ = ["chain_checks"]


def _chain_truth(setup: SetupConfig) -> dict[str, TruthChannel]:
    """Role -> its Trace channel, unit factor, hold and resolution, from every device of the setup."""
    out: dict[str, TruthChannel] = {}
    for d in devices(setup):
        out.update(d.truth_channels())
    return out


def _error_budget(setup: SetupConfig) -> dict[str, tuple[Any, Any, float]]:
    """Role -> (ChannelErrors or None, LinkErrors, extra static error) from every device of the setup."""
    out: dict[str, tuple[Any, Any, float]] = {}
    for d in devices(setup):
        out.update(d.error_budget())
    return out


def chain_checks(trace: Trace, recording: Recording, setup: SetupConfig, *, profile: str = "ideal",
                 roles: Iterable[str] | None = None) -> list[Check]:
    """Compare every decoded channel with the Trace.

    With the ``ideal`` profile each channel must equal the truth within half its resolution (plus the
    converter's rounding) and carry no flag. With ``realistic`` the error of each unflagged sample must
    be explained by the imperfections the setup declares for that sensor: a bound of
    ``|offset| + |gain error| |x| + 4 noise_std + resolution + |dx/dt| (latency + filter time constant +
    sample period + |clock offset| + |drift| t)``; at least 99 % of the samples must lie within it (the
    rest are stuck-at intervals, reordered frames and other faults the setup asked for).

    ``roles`` restricts the checks to those roles (default: every role of the setup's devices).

    Returns
    -------
    list of Check
        One check per channel; the worst sample (ideal) or the fraction inside the bound (realistic).
    """
    checks: list[Check] = []
    kept = recording.loaded()
    for role, check in _chain_checks(trace, recording, setup, profile, roles):
        checks.append(check)
        if role not in kept:  # a lazy Recording: one channel in memory at a time
            recording.drop([role])
    return checks


#: Recording samples compared at a time (with the Trace window around them): the checks hold a block of a channel,
#: never the whole channel of the campaign. A block's temporaries (the samples, the truth, the error bound, the
#: Trace window's gradient and maximum filter) are about 30 arrays of its length: 1 << 18 keeps them near 40 MB
#: (1 << 20 made the chain checks' traced peak 147 MB, paper x3)
CHECK_BLOCK_SAMPLES = 1 << 18
#: diffs of a channel's timestamps gathered whole for their median; more are selected in passes (:func:`_kth`)
MEDIAN_CAP = 1 << 19


def _chain_checks(trace: Trace, recording: Recording, setup: SetupConfig, profile: str,
                  roles: Iterable[str] | None) -> Iterator[tuple[str, Check]]:
    """The checks of :func:`chain_checks`, one per role, as they are made (each a block of the channel at a time)."""
    budget = _error_budget(setup) if profile != "ideal" else {}
    wanted = set(roles) if roles is not None else None
    dt_s = _plant_step(trace)  # the median plant step: once (a median over the whole time base, by blocks)
    for role, tc in sorted(_chain_truth(setup).items()):
        if wanted is not None and role not in wanted:
            continue
        name, res = tc.trace, tc.resolution
        if role not in recording or name not in trace:
            yield role, Check("chain", f"chain.{role}", float("nan"), float("nan"), float("nan"), res, "abs", "",
                              False, "channel missing from the recording")
            continue
        yield role, _check(trace, dt_s, recording[role], tc, profile, budget.get(role, (None, None, 0.0)))


def _blocks(ch: Channel, span_s: float = np.inf) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The channel's (timestamps, values, flags) a block at a time (a lazy channel reads only the block): at most
    :data:`CHECK_BLOCK_SAMPLES` samples, cut where the times pass ``span_s`` after the block's first (so the Trace
    window beside a slow channel's block is bounded too)."""
    size, a, n = CHECK_BLOCK_SAMPLES, 0, len(ch)
    while a < n:
        t, v, f = ch.block(a, a + size)
        over = np.flatnonzero(t > t[0] + span_s)
        if over.size:
            k = int(over[0])
            t, v, f = t[:k], v[:k], f[:k]
        a += len(t)
        yield t, v, f


class _TruthWindow:
    """The Trace channel (times the unit factor) around a block of Recording times: ``margin`` plant samples more on
    each side than the block's span needs, so what is computed from neighbouring samples (gradient, maximum
    filter, interpolation, hold) equals the same computed on the whole channel."""

    def __init__(self, trace: Trace, name: str, factor: float, t: np.ndarray, margin: int) -> None:
        tt = trace.time_s
        n = len(tt)
        if np.isfinite(t).all():
            lo = int(np.searchsorted(tt, np.min(t), side="right")) - 1 - margin
            hi = int(np.searchsorted(tt, np.max(t), side="left")) + 1 + margin
        else:  # a time that is not a number (bad input): the whole channel, as interpolation would see it
            lo, hi = 0, n
        self.a, self.b = max(lo, 0), min(max(hi, 0), n)
        self.time = tt[self.a:self.b]
        raw = trace.read(name, self.a, self.b) if isinstance(trace, SpooledTrace) else trace[name][self.a:self.b]
        self.x = raw * factor


def _check(trace: Trace, dt_s: float, ch: Channel, tc: TruthChannel, profile: str,
           budget: tuple[Any, Any, float]) -> Check:
    """One channel against the truth, block by block (the statistics accumulated: the same as on the whole);
    ``dt_s`` is the Trace's plant step."""
    role, hold, res = ch.name, tc.hold, tc.resolution
    degc = 0.0065 * (ch.unit == "degC")

    def truth_of(win: _TruthWindow, t: np.ndarray) -> np.ndarray:
        return hold_sample(win.time, win.x, t) if hold else np.interp(t, win.time, win.x)

    # the check's domain: a truth beyond what the wire can carry reaches the acquisition saturated (e.g. a displayed
    # SOC the plant drives below 0 % when a campaign's SOC runs on): those samples are counted, not compared
    lo, hi = tc.span if tc.span is not None else (-np.inf, np.inf)
    lo, hi = lo - 0.5 * res, hi + 0.5 * res

    def in_span(truth: np.ndarray) -> np.ndarray:
        return (truth >= lo) & (truth <= hi)

    def usable(t: np.ndarray, v: np.ndarray, f: np.ndarray, truth: np.ndarray) -> np.ndarray:
        return np.isfinite(truth) & np.isfinite(v) & (f & int(Flag.bad()) == 0) & in_span(truth)

    span_s = CHECK_BLOCK_SAMPLES * dt_s if len(trace) > 1 else np.inf

    def domain_of(n_out: int) -> str:
        return (f"; {n_out} samples whose truth lies outside the wire's range [{lo + 0.5 * res:g}, {hi - 0.5 * res:g}] "
                f"{ch.unit} left out (saturated on the wire: outside the check's domain)") if n_out else ""

    if profile == "ideal":
        n_flag, n_ok, n_out, t_max = 0, 0, 0, 0.0
        worst: tuple[float, float, float, float] | None = None  # |err|, value, truth, err: the first largest
        for t, v, f in _blocks(ch, span_s):
            n_flag += int(np.count_nonzero(f))
            truth = truth_of(_TruthWindow(trace, tc.trace, tc.factor, t, 2), t)
            n_out += int(np.count_nonzero(np.isfinite(truth) & ~in_span(truth)))
            ok = usable(t, v, f, truth)
            if not ok.any():
                continue
            n_ok += int(np.count_nonzero(ok))
            err = v[ok] - truth[ok]
            k = int(np.argmax(np.abs(err)))
            if worst is None or abs(err[k]) > worst[0]:
                worst = (abs(float(err[k])), float(v[ok][k]), float(truth[ok][k]), float(err[k]))
        domain = domain_of(n_out)
        if n_ok == 0:
            return Check("chain", f"chain.{role}", float("nan"), float("nan"), float("nan"), res, "abs", ch.unit,
                         False, "no usable sample" + domain)
        assert worst is not None
        # half a step; thermocouples add the 0.5 uV input converter (~0.013 degC at 39 uV/degC)
        tol = 0.5 * res + degc + 1e-9
        passed = bool(worst[0] <= tol and n_flag == 0)
        note = (f"{n_flag} flagged samples" if n_flag else "half a resolution step") + domain
        return Check("chain", f"chain.{role}", worst[1], worst[2], worst[3], tol, "abs", ch.unit, passed, note)
    errs, link, extra = budget
    # the local slope over a window covering the lags (max of the slope around each sample)
    lag = 0.0
    if errs is not None and errs.bandwidth_hz > 0:
        lag += 3.0 / (2 * np.pi * errs.bandwidth_hz)
    lag += _median_step(ch) if len(ch) > 1 else 0.0
    drift = 0.0
    if link is not None:
        lag += link.latency_s + abs(link.clock_offset_s)
        drift = abs(link.clock_drift_ppm) * 1e-6

    def width(t_max: float) -> int:
        """The maximum filter's half width (plant samples) for the latest usable time ``t_max``."""
        lag_max = lag + drift * t_max if link is not None else lag
        return max(int(np.ceil(float(max(lag_max, lag)) / max(dt_s, 1e-9))) + 1, 1)

    # one pass counts the usable samples and those the bound explains, with the width of the latest usable time
    # guessed as the channel's latest time (its last sample is usable but on a faulty run): when the pass finds
    # another latest usable time whose width differs, it is made again with that width (the same numbers as a
    # counting pass followed by a bounding one; the truth at a sample does not depend on the window's margin)
    w = width(_latest_time(ch))
    while True:
        n_flag, n_ok, n_out, t_max, n_in = _bound_pass(trace, ch, tc, span_s, w, lag, drift, link is not None, errs,
                                                       0.5 * res * (1 + 1e-6) + 1e-9 + extra + degc, truth_of,
                                                       in_span, usable)
        if n_ok == 0 or width(t_max) == w:
            break
        w = width(t_max)
    domain = domain_of(n_out)
    if n_ok == 0:
        return Check("chain", f"chain.{role}", float("nan"), float("nan"), float("nan"), res, "abs", ch.unit, False,
                     "no usable sample" + domain)
    inside = n_in / n_ok
    return Check("chain", f"chain.{role}", inside, 0.99, inside, 0.99, "min", "-", inside >= 0.99,
                 f"fraction of unflagged samples whose error the setup's declared imperfections explain; "
                 f"{n_flag} flagged samples{domain}")


def _latest_time(ch: Channel) -> float:
    """``max(|t|)`` of the channel's first and last timestamps that are finite (0 when neither is): the latest
    usable time of a channel whose times rise and whose last sample is usable."""
    n = len(ch)
    if n == 0:
        return 0.0
    ends = np.abs(np.concatenate([ch.block(0, 1)[0], ch.block(n - 1, n)[0]]))
    ends = ends[np.isfinite(ends)]
    return float(ends.max()) if ends.size else 0.0


def _bound_pass(trace: Trace, ch: Channel, tc: TruthChannel, span_s: float, w: int, lag: float, drift: float,
                linked: bool, errs: Any, base: float, truth_of: Any, in_span: Any,
                usable: Any) -> tuple[int, int, int, float, int]:
    """One pass of the realistic check over the channel's blocks with the maximum filter's half width ``w``:
    (flagged, usable, outside the wire's range, latest usable time, usable within the bound) samples."""
    n_flag, n_ok, n_out, t_max, n_in = 0, 0, 0, 0.0, 0
    for t, v, f in _blocks(ch, span_s):
        n_flag += int(np.count_nonzero(f))
        win = _TruthWindow(trace, tc.trace, tc.factor, t, w + 3)
        truth = truth_of(win, t)
        n_out += int(np.count_nonzero(np.isfinite(truth) & ~in_span(truth)))
        ok = usable(t, v, f, truth)
        if not ok.any():
            continue
        n_ok += int(np.count_nonzero(ok))
        err, tk, xv = v[ok] - truth[ok], t[ok], truth[ok]
        t_max = max(t_max, float(np.max(np.abs(tk))))
        bound = np.full(xv.shape, base)
        if errs is not None:
            bound += abs(errs.offset) + abs(errs.gain_error_frac) * np.abs(xv) + 4.0 * errs.noise_std
            bound += errs.quantisation_step
        lag_t = lag + drift * np.abs(tk) if linked else np.full(tk.shape, lag)
        dxdt = np.abs(np.gradient(win.x, win.time)) if len(trace) > 1 else np.zeros_like(win.x)
        slope = maximum_filter1d(dxdt, size=2 * w + 1, mode="nearest")
        bound += np.interp(tk, win.time, slope) * lag_t
        n_in += int(np.count_nonzero(np.abs(err) <= bound))
    return n_flag, n_ok, n_out, t_max, n_in


def _median_step(ch: Channel) -> float:
    """``np.median(np.diff(ch.timestamps))``, read a block at a time (exact: an order statistic selected in
    passes over the blocks when the diffs are too many to gather)."""
    def diffs() -> Iterator[np.ndarray]:
        last = None
        for t, _v, _f in _blocks(ch):
            yield np.diff(t) if last is None else np.diff(t, prepend=last)
            last = t[-1:]

    n = len(ch) - 1
    if n <= MEDIAN_CAP:
        return float(np.median(np.concatenate(list(diffs()))))
    return _median_of(diffs, n, lambda a, b: np.diff(ch.block(a, b + 1)[0]))


def _plant_step(trace: Trace) -> float:
    """``trace.dt_s`` (the median step of the time base), the steps taken a block at a time (exact: selected in
    passes when they are too many to gather, as :func:`_median_step`)."""
    n = len(trace) - 1
    if n < 1:
        return float("nan")
    if n <= MEDIAN_CAP:
        return float(np.median(np.diff(trace.time_s)))

    def diffs() -> Iterator[np.ndarray]:
        for a in range(0, n, CHECK_BLOCK_SAMPLES):
            # the time base got again for each block: a spooled Trace maps its file anew, so only this block's pages
            # are mapped (one map held over the passes made the whole time base resident: 8.4 MB per paper campaign)
            yield np.diff(trace.time_s[a:a + CHECK_BLOCK_SAMPLES + 1])

    return _median_of(diffs, n, lambda a, b: np.diff(trace.time_s[a:b + 1]))


#: values of the sample a bracket of the median is guessed from (:func:`_median_of`), in this many pieces spread
#: over the values. A channel's time steps round differently as its times grow (a 500 Hz channel of the paper
#: campaign: the steps near t = 0 are 0.002 within 1e-18, later ones within 1e-13 to 4e-10): 8 pieces gave its
#: first 2 % of the times an eighth of the sample, the bracket missed the median and the selection took its passes
#: over the 5.2 M steps; 64 pieces of 512 follow the whole
SAMPLE_VALUES, SAMPLE_PIECES = 1 << 15, 64


def _median_of(arrays: Any, n: int, piece: Any) -> float:
    """The median of the ``n`` values ``arrays()`` yields, as ``np.median`` gives it (the middle one, or the mean of
    the two middle ones): first in one pass inside a bracket guessed from a sample (``piece(a, b)``: values
    ``a:b``; :func:`_bracketed`), else selected in passes (:func:`_kth`)."""
    ks = [n // 2] if n % 2 else [n // 2 - 1, n // 2]
    size = max(min(SAMPLE_VALUES // SAMPLE_PIECES, CHECK_BLOCK_SAMPLES - 1), 1)  # its times: at most a block
    starts = np.unique(np.linspace(0, max(n - size, 0), SAMPLE_PIECES).astype(np.int64))
    got = _bracketed(arrays, ks, n, np.concatenate([piece(int(a), int(a) + size) for a in starts]))
    if got is None:
        got = [_kth(arrays, k) for k in ks]
    return float(got[0]) if len(got) == 1 else float(np.mean(got))


def _bracketed(arrays: Any, ks: list[int], n: int, sample: np.ndarray) -> list[float] | None:
    """The ``ks``-th smallest (0-based) of the ``n`` values ``arrays()`` yields, in one pass: the values between two
    quantiles of ``sample`` around the ``ks`` (about half :data:`MEDIAN_CAP` of them when the sample is like the
    whole) are gathered and the values below counted. None when the bracket does not hold every ``ks``-th value or
    holds more than :data:`MEDIAN_CAP` values that are not all equal (the caller then selects in passes): a guess
    that misses costs a pass, never a wrong number."""
    s = sample[np.isfinite(sample)]
    if not s.size or n < 1:
        return None
    f = 0.25 * MEDIAN_CAP / n
    lo = float(np.quantile(s, max(min(ks) / n - f, 0.0)))
    hi = float(np.quantile(s, min((max(ks) + 1) / n + f, 1.0)))
    below, n_in, mn, mx = 0, 0, np.inf, -np.inf
    kept: list[np.ndarray] | None = []
    # over the cap, the bracket's distinct values and their counts (a channel's time steps are a few dozen numbers:
    # the period and its rounding neighbours); dropped when they are too many
    vals: np.ndarray | None = None
    cnts = np.zeros(0, np.int64)
    for a in arrays():
        below += int(np.count_nonzero(a < lo))
        sel = a[(a >= lo) & (a <= hi)]
        n_in += sel.size
        if sel.size:
            mn, mx = min(mn, float(sel.min())), max(mx, float(sel.max()))
        if kept is not None:
            kept.append(sel)
            if n_in > MEDIAN_CAP:
                vals, cnts = np.unique(np.concatenate(kept), return_counts=True)
                kept = None
        elif vals is not None and sel.size:
            u, c = np.unique(sel, return_counts=True)
            vals, inv = np.unique(np.concatenate([vals, u]), return_inverse=True)
            cnts = np.bincount(inv.ravel(), weights=np.concatenate([cnts, c]), minlength=vals.size).astype(np.int64)
        if vals is not None and vals.size > MEDIAN_CAP // 8:
            vals = None
    if not all(below <= k < below + n_in for k in ks):
        return None
    if mn == mx:
        return [mn] * len(ks)
    if kept is not None:
        part = np.partition(np.concatenate(kept), [k - below for k in ks])
        return [float(part[k - below]) for k in ks]
    if vals is None:
        return None
    cum = np.cumsum(cnts)
    return [float(vals[int(np.searchsorted(cum, k - below, side="right"))]) for k in ks]


def _kth(arrays: Any, k: int, bins: int = 4096) -> float:
    """The ``k``-th smallest (0-based) of the values ``arrays()`` yields (called once per pass): each pass narrows an
    interval holding it by a histogram, until the values in it are few enough to gather (:data:`MEDIAN_CAP`) or all
    equal. NaN sorts last (as in :func:`numpy.partition`)."""
    lo, hi, below = -np.inf, np.inf, 0  # the k-th lies in [lo, hi]; ``below`` values are < lo
    while True:
        n_in, mn, mx, kept = 0, np.inf, -np.inf, []
        for a in arrays():
            sel = a[(a >= lo) & (a <= hi)]
            n_in += sel.size
            if sel.size:
                mn, mx = min(mn, float(sel.min())), max(mx, float(sel.max()))
            if kept is not None:
                kept = [*kept, sel] if n_in <= MEDIAN_CAP else None
        if n_in == 0:  # only NaN left
            return float("nan")
        if kept is not None:
            return float(np.partition(np.concatenate(kept), k - below)[k - below])
        if mn == mx:
            return mn
        if np.nextafter(mn, np.inf) == mx:  # two neighbouring numbers: no bin between them
            n_mn = sum(int(np.count_nonzero(a == mn)) for a in arrays())
            return mn if k - below < n_mn else mx
        edges = np.linspace(mn, mx, bins + 1)
        counts = np.zeros(bins, np.int64)
        # equal bins by range: numpy's bins are then the same ``edges`` (it corrects its index against them), found
        # without sorting each block as explicit edges need (numpy refuses a range too narrow for distinct edges)
        uniform = bool(np.isfinite(mx - mn) and np.all(edges[:-1] < edges[1:]))
        for a in arrays():
            sel = a[(a >= mn) & (a <= mx)]
            counts += np.histogram(sel, bins, (mn, mx))[0] if uniform else np.histogram(sel, edges)[0]
        cum = np.cumsum(counts)
        j = int(np.searchsorted(cum, k - below, side="right"))
        below += int(cum[j - 1]) if j else 0
        # bin j is [edges[j], edges[j+1]) (the last one closed): the next interval stops just below its upper edge
        lo = float(edges[j])
        hi = float(edges[j + 1]) if j == bins - 1 else float(np.nextafter(edges[j + 1], -np.inf))
