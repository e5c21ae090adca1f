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

from collections.abc import Iterable, Sequence

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import DataError, InsufficientDataError
from benchtwin.identification._fit import FitResult, linear_fit
from benchtwin.identification._resample_blocks import rate_of
from benchtwin.identification._signals import (
    Grid,
    check_spread,
    gather,
    runs,
    segment_names,
    segments_span,
    smooth_derivative,
)
from benchtwin.identification._windows import piece_grids
from benchtwin.recording import Recording

__all__ = ["coastdown_runs", "fit_road_load", "identify_road_load"]

_PRESSURES = ("brake_pressure_fl_bar", "brake_pressure_fr_bar", "brake_pressure_rl_bar", "brake_pressure_rr_bar")


def coastdown_runs(rec: Recording, *, speed_channel: str | None = None, kinds: Iterable[str] | None = ("coastdown",),
                   rate_hz: float | None = None, v_min: float = 15.0, v_max: float | None = None, smooth_s: float = 3.0,
                   min_run_s: float = 20.0, min_drop_kmh: float = 20.0, max_motor_torque_nm: float = 2.0
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[int, int]], int, str]:
    """The coastdown runs of a Recording.

    Without a gear signal (a BEV's one fixed ratio has no neutral), coasting is where the motor torque stays
    within ``max_motor_torque_nm`` of zero and no brake pressure is applied.

    Returns
    -------
    t, v, dvdt, runs, n_flagged, channel
        Grid time (s), speed (km/h) and smoothed deceleration derivative (m/s^2) over the runs only (the runs'
        grid points one run after the other), the runs as index ranges into them, flagged grid samples excluded,
        and the speed channel used. With segments of ``kinds`` the grid is gathered one piece of segments at a
        time (the same points and numbers as over the whole span; memory bounded by a piece).
    """
    ch = speed_channel or ("dyno_speed_kmh" if "dyno_speed_kmh" in rec else "vehicle_speed_kmh")
    if rate_hz is None:
        rate_hz = rate_of(rec[ch])
    no_gear = "gear_actual" not in rec
    extra = ("em_torque_nm", *_PRESSURES) if no_gear else ()
    optional = ("gear_actual", "pedal_pct", "brake_pedal_pct", *extra)
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[int, int]], int]] = []
    grids = piece_grids(rec, [ch], rate_hz, kinds, optional=optional, what="road load")
    if grids is None:
        g = gather(rec, [ch], rate_hz, optional=optional, what="road load", span=segments_span(rec, kinds))
        parts.append(_coast_piece(g, None, ch, no_gear, extra, v_min, v_max, smooth_s, min_run_s, min_drop_kmh,
                                  max_motor_torque_nm))
    else:
        for g in grids:  # every point of a piece is inside the searched segments
            parts.append(_coast_piece(g, None, ch, no_gear, extra, v_min, v_max, smooth_s, min_run_s, min_drop_kmh,
                                      max_motor_torque_nm))
    out: list[tuple[int, int]] = []
    k = 0
    for _, pv, _, rr, _ in parts:
        out += [(k + a, k + b) for a, b in rr]
        k += pv.size
    cat = [np.concatenate([p[i] for p in parts]) if parts else np.zeros(0) for i in range(3)]
    return cat[0], cat[1], cat[2], out, sum(p[4] for p in parts), ch


def _coast_piece(g: Grid, seg: np.ndarray | None, ch: str, no_gear: bool, extra: tuple[str, ...], v_min: float,
                 v_max: float | None, smooth_s: float, min_run_s: float, min_drop_kmh: float,
                 max_motor_torque_nm: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[int, int]], int]:
    """The coastdown runs in one grid (``seg``: its points inside the searched segments, None: all of them):
    time, speed and derivative over the runs only, the runs as ranges into them, flagged points excluded."""
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
    for name in ("gear_actual", "pedal_pct", "brake_pedal_pct"):
        g.values.pop(name, None)  # used up: a grid at the speed's own rate over a long log is large
    if seg is not None:
        cand &= seg
    dvdt = smooth_derivative(v / 3.6, g.dt, smooth_s, valid=cand)
    dec = cand & (dvdt < 0)
    rr = [(a, b) for a, b in runs(dec) if (b - a) * g.dt >= min_run_s and v[a] - v[b - 1] >= min_drop_kmh]
    n_flagged = int((g.flagged & (seg if seg is not None else True)).sum())
    idx = np.concatenate([np.arange(a, b) for a, b in rr]) if rr else np.zeros(0, dtype=np.int64)
    compact, k = [], 0
    for a, b in rr:
        compact.append((k, k + b - a))
        k += b - a
    return g.t[idx], v[idx], dvdt[idx], compact, n_flagged


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
    t, v, dvdt, rr, n_flagged, ch = coastdown_runs(rec, speed_channel=speed_channel, kinds=kinds, rate_hz=rate_hz,
                                                   v_min=v_min, v_max=v_max, smooth_s=smooth_s)
    if not rr:
        raise InsufficientDataError(
            f"road load: no coastdown found in {ch} (neutral, no pedals, decelerating for at least 20 s and 20 km/h "
            f"above {v_min} km/h)")
    m = specs.test_mass_kg
    vs, fs = [], []
    if method == "regression":
        step = max(round(smooth_s / 2 * rate_hz), 1)
        for a, b in rr:
            idx = np.arange(a, b, step)
            vs.append(v[idx])
            fs.append(-m * dvdt[idx])
    else:
        for a, b in rr:
            vv, tt = v[a:b][::-1], t[a:b][::-1]  # increasing speed for interpolation
            if np.any(np.diff(vv) <= 0):
                keep = np.concatenate(([True], np.diff(vv) > 0))
                vv, tt = vv[keep], tt[keep]
            centres = np.arange(np.ceil((vv[0] + interval_kmh / 2) / step_kmh) * step_kmh,
                                vv[-1] - interval_kmh / 2 + 1e-9, step_kmh)
            for vc in centres:
                t_hi = np.interp(vc + interval_kmh / 2, vv, tt)
                t_lo = np.interp(vc - interval_kmh / 2, vv, tt)
                if t_lo > t_hi:
                    vs.append(np.array([vc]))
                    fs.append(np.array([m * interval_kmh / 3.6 / (t_lo - t_hi)]))
    v_pts = np.concatenate(vs) if vs else np.array([])
    f_pts = np.concatenate(fs) if fs else np.array([])
    segs = segment_names(rec, np.concatenate([t[a:b] for a, b in rr]))
    fit = fit_road_load(v_pts, f_pts, segments=segs, n_excluded=n_flagged)
    fit.data["runs_s"] = np.array([[t[a], t[b - 1]] for a, b in rr])
    fit.data["n_runs"] = np.array([len(rr)])
    return fit
