"""Road load F0, F1, F2 from a coastdown: ``F(v) = -m_test dv/dt = F0 + F1 v + F2 v^2`` (v in km/h).

The coastdown is found by itself: samples in neutral (gear 0), without accelerator or brake pedal,
decelerating, above ``v_min``, in runs at least ``min_run_s`` long that lose at least
``min_drop_kmh``; a segment table with ``coastdown`` segments narrows the search. The speed is the
dyno roller speed when recorded (else the vehicle speed).

Two estimators:

- ``"regression"`` (default): a Savitzky-Golay derivative of the speed over ``smooth_s`` gives
  ``dv/dt`` at every sample; least squares of ``-m dv/dt`` on ``[1, v, v^2]``. Points are taken
  half a smoothing window apart so that their errors are nearly independent.
- ``"intervals"``: GTR 15 style: the time to pass from ``v_j + dv/2`` to ``v_j - dv/2`` gives the
  mean deceleration at ``v_j``; least squares on those points.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import TypeVar

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import DataError, InsufficientDataError
from benchtwin.identification._fit import FitResult, linear_fit
from benchtwin.identification._resample_blocks import rate_of
from benchtwin.identification._signals import (
    Grid,
    check_spread,
    runs,
    segment_names,
    smooth_derivative,
)
from benchtwin.identification._windows import gather_at, grid_bounds, segment_pieces
from benchtwin.recording import Recording
from benchtwin.segments import inside_any

__all__ = ["BLOCK", "coastdown_runs", "fit_road_load", "identify_road_load"]

_T = TypeVar("_T")

_PRESSURES = ("brake_pressure_fl_bar", "brake_pressure_fr_bar", "brake_pressure_rl_bar", "brake_pressure_rr_bar")


#: grid points gathered at a time (at the speed's 100 Hz: 164 s); a candidate coasting run open at a block's end is
#: carried into the next block, so memory is bounded by a block plus the longest candidate run, not by the campaign
BLOCK = 1 << 14


class _Run:
    """One coastdown run, reduced: its first and last grid times, the names of the segments it touches, and the
    speed, force points it gives the fit."""

    __slots__ = ("f", "segments", "t0", "t1", "v")

    def __init__(self, t0: float, t1: float, segments: list[str], v: np.ndarray, f: np.ndarray) -> None:
        self.t0, self.t1, self.segments, self.v, self.f = t0, t1, segments, v, f


def _grid_blocks(rec: Recording, ch: str, rate_hz: float, kinds: Iterable[str] | None, optional: Sequence[str],
                 per: int) -> Iterator[tuple[Grid, bool]]:
    """The grid ``coastdown_runs`` searches, at most ``per`` points at a time: over the segments of ``kinds`` (only
    the points inside them, as ``piece_grids``) or, without such segments, over the whole span (as ``gather``).
    Each block comes with whether it goes on from the previous one (False at a piece's first block); its
    ``first_index`` places it in the whole grid. The bounds are checked before the first block."""
    pieces = segment_pieces(rec, kinds)
    span = None if pieces is None else (min(p[0] for p in pieces), max(p[1] for p in pieces))
    lo, n, shifts = grid_bounds(rec, [ch], rate_hz, what="road load", span=span)
    segs = [s for s in rec.segments if s.kind in set(kinds or ())] if pieces is not None else []
    kept = rec.loaded()

    def spans() -> Iterator[tuple[int, int]]:
        if pieces is None:
            yield 0, n
            return
        for start, end in pieces:  # piece_grids' points: the grid's, inside a searched segment
            ka = max(int(np.floor((start - lo) * rate_hz)) - 1, 0)
            kb = min(int(np.ceil((end - lo) * rate_hz)) + 2, n)
            if kb <= ka:
                continue
            t_all = lo + np.arange(ka, kb) / rate_hz
            inside = inside_any(segs, t_all)  # by bisection: not a pass over the piece per test of the campaign
            for j0, j1 in runs(inside):
                yield ka + j0, ka + j1

    def blocks() -> Iterator[tuple[Grid, bool]]:
        ordered: dict[int, bool] = {}
        try:
            for a0, b0 in spans():
                for a in range(a0, b0, per):
                    g = gather_at(rec, [ch], lo + np.arange(a, min(a + per, b0)) / rate_hz, rate_hz, shifts,
                                  optional=optional, ordered=ordered)
                    g.first_index = a
                    yield g, a > a0
        finally:  # a channel read whole here (no block reads) goes again, as after ``gather``
            rec.drop([c for c in [ch, *optional] if c in rec and c not in kept])

    return blocks()


def _candidates(g: Grid, ch: str, no_gear: bool, extra: tuple[str, ...], v_min: float, v_max: float | None,
                max_motor_torque_nm: float) -> np.ndarray:
    """The grid points that may be coasting: not bad, above ``v_min`` (below ``v_max``), in neutral (or without
    motor torque and brake pressure), no pedal (a point's own values only)."""
    v = g[ch]
    cand = ~g.bad & (v > v_min)
    if v_max is not None:
        cand &= v < v_max
    if "gear_actual" in g:
        cand &= np.nan_to_num(g["gear_actual"], nan=-1.0) == 0
    if no_gear and "em_torque_nm" in g:
        cand &= np.abs(np.nan_to_num(g["em_torque_nm"], nan=np.inf)) <= max_motor_torque_nm
    for p in (c for c in extra if c in _PRESSURES and c in g):
        cand &= np.nan_to_num(g[p], nan=np.inf) <= 0.5
    for pedal in ("pedal_pct", "brake_pedal_pct"):
        if pedal in g:
            cand &= np.nan_to_num(g[pedal], nan=100.0) <= 0.5
    return cand


def coastdown_runs(rec: Recording, reduce: Callable[[np.ndarray, np.ndarray, np.ndarray], _T], *,
                   speed_channel: str | None = None, kinds: Iterable[str] | None = ("coastdown",),
                   rate_hz: float | None = None, v_min: float = 15.0, v_max: float | None = None,
                   smooth_s: float = 3.0, min_run_s: float = 20.0, min_drop_kmh: float = 20.0,
                   max_motor_torque_nm: float = 2.0) -> tuple[list[_T], int, str]:
    """The coastdown runs of a Recording, each reduced by ``reduce`` as soon as it is found.

    Without a gear signal (a BEV's one fixed ratio has no neutral), coasting is where the motor torque stays
    within ``max_motor_torque_nm`` of zero and no brake pressure is applied.

    The grid (the speed channel's, over the segments of ``kinds`` when the table has them, else over the whole
    span) is read :data:`BLOCK` points at a time; the points of a candidate coasting run still open at a block's
    end are carried into the next, so that each run's derivative and tests see the whole run: the same runs and
    numbers as over the whole grid, with memory bounded by a block and the longest candidate run.

    Parameters
    ----------
    rec:
        The Recording.
    reduce:
        ``reduce(t, v, dvdt)`` of one run's grid time (s), speed (km/h) and smoothed derivative (m/s^2); what it
        returns is kept (the run's arrays are not).
    speed_channel, kinds, rate_hz, v_min, v_max, smooth_s, min_run_s, min_drop_kmh, max_motor_torque_nm:
        As for :func:`identify_road_load`; a run lasts at least ``min_run_s`` and loses ``min_drop_kmh``.

    Returns
    -------
    reduced, n_flagged, channel
        ``reduce``'s results in time order, the flagged grid points excluded and the speed channel used.
    """
    ch = speed_channel or ("dyno_speed_kmh" if "dyno_speed_kmh" in rec else "vehicle_speed_kmh")
    if rate_hz is None:
        rate_hz = rate_of(rec[ch])
    no_gear = "gear_actual" not in rec
    extra = ("em_torque_nm", *_PRESSURES) if no_gear else ()
    optional = ("gear_actual", "pedal_pct", "brake_pedal_pct", *extra)
    out: list[_T] = []
    n_flagged = 0
    dt = 1.0 / rate_hz
    tail: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # an open candidate run: t, v, cand

    def close(t: np.ndarray, v: np.ndarray, cand: np.ndarray) -> None:
        """The runs of closed candidate runs (each whole in ``t``, ``v``, ``cand``)."""
        if not cand.any():
            return
        dvdt = smooth_derivative(v / 3.6, dt, smooth_s, valid=cand)
        dec = cand & (dvdt < 0)
        for a, b in runs(dec):
            if (b - a) * dt >= min_run_s and v[a] - v[b - 1] >= min_drop_kmh:
                out.append(reduce(t[a:b], v[a:b], dvdt[a:b]))

    for g, goes_on in _grid_blocks(rec, ch, rate_hz, kinds, optional, BLOCK):
        cand = _candidates(g, ch, no_gear, extra, v_min, v_max, max_motor_torque_nm)
        n_flagged += int(g.flagged.sum())
        t, v = g.t, g[ch]
        if tail is not None:
            if goes_on:  # the open run goes on in this block
                t, v, cand = (np.concatenate([x, y]) for x, y in zip(tail, (t, v, cand), strict=True))
            else:
                close(*tail)
            tail = None
        off = np.flatnonzero(~cand)
        cut = int(off[-1]) + 1 if off.size else 0  # from ``cut`` on, a candidate run open at the block's end
        close(t[:cut], v[:cut], cand[:cut])
        if cut < t.size:
            tail = (t[cut:].copy(), v[cut:].copy(), cand[cut:].copy())
    if tail is not None:
        close(*tail)
    return out, n_flagged, ch


def fit_road_load(v_kmh: np.ndarray, force_n: np.ndarray, *, segments: Sequence[str] = (), n_excluded: int = 0,
                  min_points: int = 10, min_span_kmh: float = 30.0, what: str = "road_load",
                  min_r2: float = 0.9) -> FitResult:
    """Least squares ``F = F0 + F1 v + F2 v^2`` (v km/h, F N) with full statistics.

    A fit with R^2 below ``min_r2`` or a negative F0 or F2 is flagged with the reason.

    Raises
    ------
    InsufficientDataError, NoExcitationError, CollinearError
    """
    v = np.asarray(v_kmh, dtype=float)
    f = np.asarray(force_n, dtype=float)
    if v.size < min_points:
        raise InsufficientDataError(f"{what}: {v.size} coastdown points; need at least {min_points}")
    check_spread(v, min_span_kmh, what, "coastdown speed", "km/h")
    fit = linear_fit(np.column_stack([np.ones_like(v), v, v**2]), f, ["F0", "F1", "F2"],
                     units=["N", "N/(km/h)", "N/(km/h)^2"], segments=segments, min_points=min_points,
                     n_excluded=n_excluded, what=what)
    vc = np.linspace(0.0, float(v.max()), 200)
    fit.data.update(v_kmh=v, force_n=f, force_fit_n=fit.data["y_fit"], v_curve_kmh=vc,
                    force_curve_n=fit.value("F0") + fit.value("F1") * vc + fit.value("F2") * vc**2)
    if fit.value("F0") < 0 or fit.value("F2") < 0:
        fit.flag("negative F0 or F2: the coastdown does not look like a road-load curve")
    if not fit.r2 >= min_r2:
        fit.flag(f"R^2 = {fit.r2:.2f} < {min_r2}: the decelerations do not follow a road-load curve")
    return fit


def identify_road_load(rec: Recording, specs: VehicleSpecs, *, method: str = "regression",
                       speed_channel: str | None = None, kinds: Iterable[str] | None = ("coastdown",),
                       rate_hz: float | None = None, v_min: float = 15.0, v_max: float | None = None,
                       smooth_s: float = 4.0, interval_kmh: float = 4.0, step_kmh: float = 4.0) -> FitResult:
    """F0, F1, F2 from the coastdown(s) of a Recording.

    Parameters
    ----------
    rec:
        The Recording (``dyno_speed_kmh`` or ``vehicle_speed_kmh``; ``gear_actual``, ``pedal_pct``,
        ``brake_pedal_pct`` used when present; without ``gear_actual``, ``em_torque_nm`` and the brake
        pressures tell coasting, see :func:`coastdown_runs`).
    specs:
        ``test_mass_kg``.
    method:
        ``"regression"`` or ``"intervals"`` (see the module docstring).
    speed_channel:
        Speed channel to use (default: roller speed when present).
    kinds:
        Segment kinds searched when the table has them.
    v_min, v_max:
        Speed range used, km/h.
    rate_hz:
        Grid rate; default the speed channel's own rate (every sample counts: the speed's
        resolution, e.g. 0.01 km/h, is the main noise of the derivative).
    smooth_s:
        Savitzky-Golay window of the derivative.
    interval_kmh, step_kmh:
        Width and spacing of the GTR 15 speed intervals.

    Returns
    -------
    FitResult
        ``F0`` (N), ``F1`` (N/(km/h)), ``F2`` (N/(km/h)^2) with data ``v_kmh``, ``force_n`` and the curve.

    Raises
    ------
    InsufficientDataError
        No coastdown found.
    """
    if method not in ("regression", "intervals"):
        raise DataError(f"road load: method must be 'regression' or 'intervals', got {method!r}")
    ch = speed_channel or ("dyno_speed_kmh" if "dyno_speed_kmh" in rec else "vehicle_speed_kmh")
    if rate_hz is None:
        rate_hz = rate_of(rec[ch]) if ch in rec else 10.0
    m = specs.test_mass_kg
    step = max(round(smooth_s / 2 * rate_hz), 1)

    def reduce(t: np.ndarray, v: np.ndarray, dvdt: np.ndarray) -> _Run:
        """One run's points: every ``step``-th sample (regression) or its speed intervals (GTR 15)."""
        segs = segment_names(rec, t)
        if method == "regression":
            return _Run(float(t[0]), float(t[-1]), segs, v[::step].copy(), -m * dvdt[::step])
        vv, tt = v[::-1], t[::-1]  # increasing speed for interpolation
        if np.any(np.diff(vv) <= 0):
            keep = np.concatenate(([True], np.diff(vv) > 0))
            vv, tt = vv[keep], tt[keep]
        vs, fs = [], []
        centres = np.arange(np.ceil((vv[0] + interval_kmh / 2) / step_kmh) * step_kmh,
                            vv[-1] - interval_kmh / 2 + 1e-9, step_kmh)
        for vc in centres:
            t_hi = np.interp(vc + interval_kmh / 2, vv, tt)
            t_lo = np.interp(vc - interval_kmh / 2, vv, tt)
            if t_lo > t_hi:
                vs.append(vc)
                fs.append(m * interval_kmh / 3.6 / (t_lo - t_hi))
        return _Run(float(t[0]), float(t[-1]), segs, np.array(vs, dtype=float), np.array(fs, dtype=float))

    rr, n_flagged, ch = coastdown_runs(rec, reduce, speed_channel=speed_channel, kinds=kinds, rate_hz=rate_hz,
                                       v_min=v_min, v_max=v_max, smooth_s=smooth_s)
    if not rr:
        raise InsufficientDataError(
            f"road load: no coastdown found in {ch} (neutral, no pedals, decelerating for at least 20 s and 20 km/h "
            f"above {v_min} km/h)")
    v_pts = np.concatenate([r.v for r in rr])
    f_pts = np.concatenate([r.f for r in rr])
    segs = sorted({name for r in rr for name in r.segments})
    fit = fit_road_load(v_pts, f_pts, segments=segs, n_excluded=n_flagged)
    fit.data["runs_s"] = np.array([[r.t0, r.t1] for r in rr])
    fit.data["n_runs"] = np.array([len(rr)])
    return fit
