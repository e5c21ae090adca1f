"""Brakes: pressure-to-torque gains per axle, the static distribution k_f / k_r (eq. 41), blending maps.

Gains: braking in neutral at constant dyno speed, the rollers carry the brake forces, so the axle
brake torque is ``-roller force x wheel radius`` (roller forces are positive when the vehicle
pushes). Per axle, least squares of that torque on ``[p, 1]`` with ``p`` the mean caliper pressure
of the axle: the slope is the gain ``m`` (Nm/bar), the intercept the tyre rolling loss on the
rollers. ``k_f = m_f / (m_f + m_r)``, ``k_r = 1 - k_f`` with delta-method uncertainty.

Blending (Figure 24): during braking in gear (WLTC, decelerations), the hydraulic torques are
``m_f p_f`` and ``m_r p_r``; the powertrain (regenerative) torque at the rear wheels is the rear
roller torque minus the rear hydraulic torque (rear-wheel drive), the identified rolling loss
removed from both roller torques. The shares of the total braking torque (regenerative, hydraulic,
front) are binned over speed x deceleration; all wheels turn at one speed, so torque shares equal
power shares.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import IdentificationError, InsufficientDataError, MissingChannelError
from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate, linear_fit
from benchtwin.identification._gum import t975
from benchtwin.identification._signals import (
    Grid,
    check_spread,
    gather,
    raise_all_failed,
    segments_span,
    smooth_derivative,
)
from benchtwin.identification._windows import piece_grids
from benchtwin.identification.steady import SteadyWindows, Tolerance, find_steady_windows
from benchtwin.recording import Recording
from benchtwin.segments import touched

__all__ = ["brake_gain_windows", "brake_gains_from", "fit_brake_gain", "identify_brake_blending",
           "identify_brake_gains", "identify_brakes"]

_FRONT = ("brake_pressure_fl_bar", "brake_pressure_fr_bar")
_REAR = ("brake_pressure_rl_bar", "brake_pressure_rr_bar")


def _axle_channels(rec: Recording, names: Sequence[str], axle: str) -> list[str]:
    present = [n for n in names if n in rec]
    if not present:
        raise MissingChannelError(f"brakes: no {axle} caliper pressure recorded (need one of {', '.join(names)})")
    return present


def fit_brake_gain(p_bar: np.ndarray, torque_nm: np.ndarray, axle: str, *, segments: Sequence[str] = (),
                   n_excluded: int = 0, min_points: int = 4, intercept: bool = True, min_r2: float = 0.9) -> FitResult:
    """Least squares ``T = m p + c`` for one axle (``c`` omitted with ``intercept=False``).

    A non-positive gain or an R^2 below ``min_r2`` flags the fit with the reason.

    Raises
    ------
    InsufficientDataError, NoExcitationError, CollinearError
    """
    p = np.asarray(p_bar, dtype=float)
    t = np.asarray(torque_nm, dtype=float)
    what = f"brakes.{axle}"
    if p.size < min_points:
        raise InsufficientDataError(f"{what}: {p.size} steady braking points; need at least {min_points}")
    check_spread(p, 5.0, what, f"{axle} brake pressure", "bar")
    tag = axle[0]
    if intercept:
        fit = linear_fit(np.column_stack([p, np.ones_like(p)]), t, [f"m_{tag}", f"c_{tag}"], units=["Nm/bar", "Nm"],
                         segments=segments, min_points=min_points, n_excluded=n_excluded, what=what)
    else:
        fit = linear_fit(p[:, None], t, [f"m_{tag}"], units=["Nm/bar"], segments=segments, min_points=min_points,
                         n_excluded=n_excluded, what=what)
    pc = np.linspace(0.0, float(p.max()), 100)
    fit.data.update(p_bar=p, torque_nm=t, torque_fit_nm=fit.data["y_fit"], p_curve_bar=pc,
                    torque_curve_nm=fit.value(f"m_{tag}") * pc + (fit.value(f"c_{tag}") if intercept else 0.0))
    if fit.value(f"m_{tag}") <= 0:
        fit.flag(f"{axle} gain is not positive: check the sign of the roller force")
    if not fit.r2 >= min_r2:
        fit.flag(f"R^2 = {fit.r2:.2f} < {min_r2}: torque and pressure are not proportional in these points")
    return fit


def brake_gain_windows(rec: Recording, *, kinds: Iterable[str] | None = ("neutral_braking",), rate_hz: float = 20.0,
                       tolerances: dict[str, Tolerance] | None = None, window_s: float = 1.0,
                       min_duration_s: float = 1.5, trim_s: float = 0.25,
                       max_motor_torque_nm: float = 2.0) -> tuple[SteadyWindows, list[str], list[str]]:
    """The steady neutral-braking windows the gains are fitted on, and the front and rear pressure channels.

    Windows with the rollers turning (> 5 km/h) and, when the gear is recorded, in neutral. Shared by
    :func:`identify_brake_gains` and the planner; the arguments are those of :func:`identify_brake_gains`.
    """
    front = _axle_channels(rec, _FRONT, "front")
    rear = _axle_channels(rec, _REAR, "rear")
    forces = ["dyno_force_front_n", "dyno_force_rear_n"]
    tol = {"dyno_speed_kmh": Tolerance(0.5, 0.0, 0.5)}
    tol.update(tolerances or {})
    no_gear = "gear_actual" not in rec and "em_torque_nm" in rec
    sw = find_steady_windows(rec, [*front, *rear, *forces, "dyno_speed_kmh"], states=("gear_actual",), kinds=kinds,
                             rate_hz=rate_hz, tolerances=tol, window_s=window_s, min_duration_s=min_duration_s,
                             trim_s=trim_s, extra=("em_torque_nm",) if no_gear else ())
    keep = sw.means("dyno_speed_kmh") > 5.0
    if "gear_actual" in sw.grid:
        keep &= np.nan_to_num(sw.state("gear_actual"), nan=-1) == 0
    elif no_gear and len(sw):
        keep &= np.abs(np.nan_to_num(sw.raw_average(rec, "em_torque_nm"), nan=np.inf)) <= max_motor_torque_nm
    if len(sw) and not any(seg.kind in set(kinds or ()) for seg in rec.segments):
        # no neutral-braking segment to stay in: an unbraked window gives the rolling-loss intercept only at the
        # speed of the braked ones (within 1 km/h); elsewhere its rolling loss is another one
        p_all = np.nan_to_num(np.mean([sw.raw_average(rec, c) for c in [*front, *rear]], axis=0), nan=0.0)
        v_all = sw.means("dyno_speed_kmh")
        braked = keep & (p_all > 0.5)
        if braked.any():
            near = (v_all >= v_all[braked].min() - 1.0) & (v_all <= v_all[braked].max() + 1.0)
            keep &= braked | near
    return sw.select(keep), front, rear


def identify_brake_gains(rec: Recording, specs: VehicleSpecs, *, kinds: Iterable[str] | None = ("neutral_braking",),
                         rate_hz: float = 20.0, intercept: bool = True, min_points: int = 4,
                         tolerances: dict[str, Tolerance] | None = None, window_s: float = 1.0,
                         min_duration_s: float = 1.5, trim_s: float = 0.25,
                         max_motor_torque_nm: float = 2.0) -> IdentificationResult:
    """Front and rear pressure-to-torque gains and the distribution k_f, k_r from neutral braking.

    Parameters
    ----------
    rec:
        The Recording: caliper pressures (at least one per axle), ``dyno_force_front_n``,
        ``dyno_force_rear_n``, ``dyno_speed_kmh`` (``gear_actual`` used when present: neutral only; without
        it, ``em_torque_nm``: no motor torque).
    specs:
        ``wheel_radius_m``.
    kinds:
        Segment kinds searched when the table has them.
    intercept:
        Fit the rolling-loss intercept.
    window_s, min_duration_s, trim_s:
        Steady-state detection (pressure steps are often held only a few seconds).
    max_motor_torque_nm:
        Without a gear signal (a BEV's one fixed ratio has no neutral), a window counts as neutral braking
        when its mean motor torque is within this of zero (no regenerative share in the dyno force).

    Returns
    -------
    IdentificationResult
        ``brakes.front`` (``m_f``, ``c_f``), ``brakes.rear`` (``m_r``, ``c_r``) and
        ``brakes.distribution`` (``k_f``, ``k_r``).
    """
    sw, front, rear = brake_gain_windows(rec, kinds=kinds, rate_hz=rate_hz, tolerances=tolerances, window_s=window_s,
                                         min_duration_s=min_duration_s, trim_s=trim_s,
                                         max_motor_torque_nm=max_motor_torque_nm)
    r = specs.wheel_radius_m
    p_f = np.mean([sw.raw_average(rec, c) for c in front], axis=0) if len(sw) else np.array([])
    p_r = np.mean([sw.raw_average(rec, c) for c in rear], axis=0) if len(sw) else np.array([])
    t_f = -sw.raw_average(rec, "dyno_force_front_n") * r if len(sw) else np.array([])
    t_r = -sw.raw_average(rec, "dyno_force_rear_n") * r if len(sw) else np.array([])
    out = IdentificationResult()
    failures: dict[str, IdentificationError] = {}
    segs = sw.segments()
    for axle, p, t in (("front", p_f, t_f), ("rear", p_r, t_r)):
        ok = np.isfinite(p) & np.isfinite(t)
        try:
            out.fits[f"brakes.{axle}"] = fit_brake_gain(p[ok], t[ok], axle, segments=segs,
                                                        n_excluded=sw.n_excluded + int((~ok).sum()),
                                                        min_points=min_points, intercept=intercept)
        except IdentificationError as exc:
            out.errors[f"brakes.{axle}"] = f"{type(exc).__name__}: {exc}"
            failures[f"brakes.{axle}"] = exc
    if not out.fits:
        raise_all_failed("brakes (front and rear gains)", failures)
    if "brakes.front" in out.fits and "brakes.rear" in out.fits:
        out.fits["brakes.distribution"] = _distribution(out.fits["brakes.front"], out.fits["brakes.rear"])
    return out


def _distribution(ff: FitResult, fr: FitResult) -> FitResult:
    mf, mr = ff["m_f"], fr["m_r"]
    s = mf.value + mr.value
    kf = mf.value / s
    # delta method, independent fits: dk/dm_f = m_r / s^2, dk/dm_r = -m_f / s^2
    se = math.sqrt((mr.value / s**2 * mf.std_error) ** 2 + (mf.value / s**2 * mr.std_error) ** 2)
    dof = max(min(mf.n_points, mr.n_points) - 2, 1)
    tq = t975(dof)
    n = mf.n_points + mr.n_points
    r2 = min(ff.r2, fr.r2)
    segs = sorted(set(ff.segments) | set(fr.segments))
    params = {
        "k_f": ParameterEstimate("k_f", kf, se, (kf - tq * se, kf + tq * se), r2, n, "-", segs),
        "k_r": ParameterEstimate("k_r", 1 - kf, se, (1 - kf - tq * se, 1 - kf + tq * se), r2, n, "-", segs),
    }
    fit = FitResult(params, r2, float("nan"), float("nan"), n, ff.n_excluded + fr.n_excluded, segs)
    if ff.status != "ok" or fr.status != "ok":
        fit.flag("a gain fit is flagged: " + "; ".join(ff.reasons + fr.reasons))
    return fit


def brake_gains_from(gains: IdentificationResult | Sequence[float]) -> tuple[float, float, float, float]:
    """``(m_f, m_r, c_f, c_r)`` from an :func:`identify_brake_gains` result or a 2- or 4-sequence."""
    if isinstance(gains, IdentificationResult):
        try:
            ff, fr = gains.fits["brakes.front"], gains.fits["brakes.rear"]
        except KeyError as exc:
            raise InsufficientDataError(f"brake blending needs both axle gains; missing {exc}") from None
        return (ff.value("m_f"), fr.value("m_r"), ff.params["c_f"].value if "c_f" in ff.params else 0.0,
                fr.params["c_r"].value if "c_r" in fr.params else 0.0)
    g = [float(x) for x in gains]
    if len(g) == 2:
        return g[0], g[1], 0.0, 0.0
    if len(g) == 4:
        return g[0], g[1], g[2], g[3]
    raise IdentificationError("gains must be (m_f, m_r) or (m_f, m_r, c_f, c_r)")


def _binned_mean(x: np.ndarray, y: np.ndarray, z: np.ndarray, xe: np.ndarray, ye: np.ndarray, min_count: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    cnt, _, _ = np.histogram2d(x, y, bins=[xe, ye])
    tot, _, _ = np.histogram2d(x, y, bins=[xe, ye], weights=z)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(cnt >= min_count, tot / np.maximum(cnt, 1), np.nan)
    return mean.T, cnt.T  # rows: deceleration bins, columns: speed bins


def identify_brake_blending(rec: Recording, specs: VehicleSpecs, gains: IdentificationResult | Sequence[float], *,
                            kinds: Iterable[str] | None = ("deceleration", "cycle"), rate_hz: float = 10.0,
                            speed_edges_kmh: Sequence[float] | None = None,
                            decel_edges_mps2: Sequence[float] | None = None, min_count: int = 5,
                            min_torque_nm: float = 50.0, min_decel_mps2: float = 0.1, smooth_s: float = 1.0,
                            max_rate_per_s: float | None = 0.5, speed_channel: str | None = None) -> FitResult:
    """Brake-blending maps over speed x deceleration (Figure 24).

    Parameters
    ----------
    rec:
        The Recording: caliper pressures, roller forces, a speed channel.
    specs:
        ``wheel_radius_m``.
    gains:
        The result of :func:`identify_brake_gains` (or ``(m_f, m_r[, c_f, c_r])``).
    kinds:
        Segment kinds searched when the table has them.
    speed_edges_kmh, decel_edges_mps2:
        Bin edges (defaults: 10 km/h and 0.25 m/s^2 steps).
    min_count:
        Fewest grid samples for a bin to get a value.
    min_torque_nm, min_decel_mps2:
        A sample is "braking" when the total braking torque and the deceleration exceed these.
    max_rate_per_s:
        Leave out samples where the total or the hydraulic braking torque changes faster than this
        fraction of the total per second (brake onsets and releases, the hand-over at the cut-off
        speed): there the pressure, roller and speed sources, each with its own latency and filter,
        disagree. None keeps every braking sample.

    Returns
    -------
    FitResult
        Parameters ``regen_share_mean``, ``hydraulic_share_mean``, ``front_share_mean`` (means over
        braking samples) and ``regen_torque_p95_nm`` (95th percentile of the regenerative torque), SE
        and 95 % interval from a moving-block bootstrap; R^2 is NaN (no regression); data: per-sample
        ``time_s``, ``v_kmh``, ``decel_mps2``, ``torque_total_nm``, ``torque_regen_nm``, ``torque_front_nm``,
        ``torque_rear_hyd_nm``, ``regen_share``, ``hydraulic_share``, ``front_share`` and the maps
        ``map_speed_edges_kmh``, ``map_decel_edges_mps2``, ``map_regen_share``, ``map_hydraulic_share``,
        ``map_front_share``, ``map_count`` (rows: deceleration, columns: speed).
    """
    m_f, m_r, c_f, c_r = brake_gains_from(gains)
    front = _axle_channels(rec, _FRONT, "front")
    rear = _axle_channels(rec, _REAR, "rear")
    vch = speed_channel or ("dyno_speed_kmh" if "dyno_speed_kmh" in rec else "vehicle_speed_kmh")
    names = [vch, *front, *rear, "dyno_force_front_n", "dyno_force_rear_n"]
    grids = piece_grids(rec, names, rate_hz, kinds, what="brake blending")
    if grids is None:
        grids = iter([gather(rec, names, rate_hz, what="brake blending", span=segments_span(rec, kinds))])
    parts = []  # per grid (a piece of the segments, or the whole span): the braking samples only
    n_transient = n_flagged = 0
    for g in grids:
        sel, fast, flagged = _braking_samples(g, vch, front, rear, (m_f, m_r, c_f, c_r, specs.wheel_radius_m),
                                              smooth_s, min_torque_nm, min_decel_mps2, max_rate_per_s)
        parts.append(sel)
        n_transient += fast
        n_flagged += flagged
        del g
    vb, db, tt, t_regen_b, t_hf_b, t_hr_b, t_brk, front_resid = (np.concatenate([q[k] for q in parts])
                                                                 for k in range(8))
    n_brk = int(vb.size)
    if n_brk < max(min_count, 10):
        raise InsufficientDataError(
            f"brake blending: {n_brk} braking samples (total braking torque > {min_torque_nm} Nm and deceleration > "
            f"{min_decel_mps2} m/s^2); need at least {max(min_count, 10)}")
    regen_share = t_regen_b / tt
    hyd_share = (t_hf_b + t_hr_b) / tt
    front_share = t_hf_b / tt
    se = np.asarray(speed_edges_kmh, dtype=float) if speed_edges_kmh is not None else \
        np.arange(0.0, max(10.0, float(np.ceil(vb.max() / 10) * 10)) + 1e-9, 10.0)
    de = np.asarray(decel_edges_mps2, dtype=float) if decel_edges_mps2 is not None else \
        np.arange(0.0, max(0.25, float(np.ceil(db.max() / 0.25) * 0.25)) + 1e-9, 0.25)
    maps = {}
    for name, z in (("regen", regen_share), ("hydraulic", hyd_share), ("front", front_share)):
        maps[f"map_{name}_share"], cnt = _binned_mean(vb, db, z, se, de, min_count)
    searched = [s for s in rec.segments if s.kind in set(kinds or ())]
    segs = sorted({s.name for s, hit in zip(searched, touched(searched, t_brk), strict=True) if hit})

    # consecutive samples are correlated (smoothing, slow manoeuvres): a moving-block bootstrap over
    # blocks of one smoothing window gives the standard errors and percentile intervals
    block = max(round(smooth_s * rate_hz), 1)
    rng = np.random.default_rng(0)
    n_blocks = int(np.ceil(n_brk / block))
    starts = rng.integers(0, max(n_brk - block, 0) + 1, (200, n_blocks))
    boot_idx = (starts[:, :, None] + np.arange(block)[None, None, :]).reshape(200, -1)[:, :n_brk]

    def est(name: str, z: np.ndarray, stat: str, unit: str = "-") -> ParameterEstimate:
        def f(x: np.ndarray, axis: int | None = None) -> np.ndarray:
            return np.mean(x, axis=axis) if stat == "mean" else np.percentile(x, 95, axis=axis)

        val = float(f(z))
        reps = f(z[boot_idx], axis=1)
        lo, hi = float(np.percentile(reps, 2.5)), float(np.percentile(reps, 97.5))
        return ParameterEstimate(name, val, float(np.std(reps, ddof=1)), (min(lo, val), max(hi, val)), float("nan"),
                                 int(z.size), unit, segs)

    params = {
        "regen_share_mean": est("regen_share_mean", regen_share, "mean"),
        "hydraulic_share_mean": est("hydraulic_share_mean", hyd_share, "mean"),
        "front_share_mean": est("front_share_mean", front_share, "mean"),
        "regen_torque_p95_nm": est("regen_torque_p95_nm", t_regen_b, "p95", "Nm"),
    }
    fit = FitResult(params, float("nan"), float("nan"), float("nan"), n_brk, n_flagged, segs)
    fit.data.update(time_s=t_brk, v_kmh=vb, decel_mps2=db, torque_total_nm=tt, torque_regen_nm=t_regen_b,
                    torque_front_nm=t_hf_b, torque_rear_hyd_nm=t_hr_b, regen_share=regen_share,
                    hydraulic_share=hyd_share, front_share=front_share, map_speed_edges_kmh=se,
                    map_decel_edges_mps2=de, map_count=cnt, **maps)
    # the front axle has no powertrain: its roller torque must match the front hydraulic torque
    fit.data["front_check_residual_nm"] = front_resid
    rel = float(np.median(np.abs(front_resid)) / max(float(np.median(tt)), 1.0))
    if rel > 0.05:
        fit.reasons.append(f"front roller torque and front gain x pressure differ by {rel:.0%} of the total braking "
                           "torque (median): the gains may not hold for this test")
    if n_transient:
        fit.reasons.append(f"{n_transient} braking samples left out as transients (onsets, releases)")
    if np.nanmin(regen_share) < -0.05:
        fit.reasons.append("some samples show negative regenerative share: powertrain drag or a gain error")
    return fit


def _braking_samples(g: Grid, vch: str, front: list[str], rear: list[str], gains: tuple[float, ...], smooth_s: float,
                     min_torque_nm: float, min_decel_mps2: float, max_rate_per_s: float | None
                     ) -> tuple[tuple[np.ndarray, ...], int, int]:
    """The braking samples of one grid (every point searched): speed, deceleration, total, regenerative, front and
    rear hydraulic torques, time and the front roller residual; transient samples left out; flagged points."""
    m_f, m_r, c_f, c_r, r = gains
    use = ~g.bad
    v = g[vch]
    decel = -smooth_derivative(v / 3.6, g.dt, smooth_s, valid=use)
    p_f = np.mean([g[c] for c in front], axis=0)
    p_r = np.mean([g[c] for c in rear], axis=0)
    t_hf = m_f * p_f
    t_hr = m_r * p_r
    t_rear = -g["dyno_force_rear_n"] * r - c_r
    t_regen = t_rear - t_hr
    t_tot = t_hf + t_rear
    brk = use & np.isfinite(decel) & (t_tot > min_torque_nm) & (decel > min_decel_mps2)
    n_fast = 0
    if max_rate_per_s is not None:
        rate = smooth_derivative(t_tot, g.dt, smooth_s, valid=use, polyorder=2)
        rate_h = smooth_derivative(t_hf + t_hr, g.dt, smooth_s, valid=use, polyorder=2)
        fast = brk & ~((np.abs(rate) <= max_rate_per_s * np.abs(t_tot))
                       & (np.abs(rate_h) <= max_rate_per_s * np.abs(t_tot)))
        n_fast = int(fast.sum())
        brk &= ~fast
    front_resid = (-g["dyno_force_front_n"] * r - c_f - t_hf)[brk]
    return ((v[brk], decel[brk], t_tot[brk], t_regen[brk], t_hf[brk], t_hr[brk], g.t[brk], front_resid), n_fast,
            int(g.flagged.sum()))


def identify_brakes(rec: Recording, specs: VehicleSpecs, *, gains_kwargs: dict[str, object] | None = None,
                    blending_kwargs: dict[str, object] | None = None) -> IdentificationResult:
    """Brake gains, distribution and (when the Recording has braking in gear) the blending maps.

    Returns
    -------
    IdentificationResult
        ``brakes.front``, ``brakes.rear``, ``brakes.distribution`` and ``brakes.blending``; the
        blending maps' failure (e.g. no deceleration test) is in ``errors``.

    Raises
    ------
    IdentificationError
        When neither gain can be identified.
    """
    out = identify_brake_gains(rec, specs, **dict(gains_kwargs or {}))  # type: ignore[arg-type]
    try:
        out.fits["brakes.blending"] = identify_brake_blending(rec, specs, out, **dict(blending_kwargs or {}))  # type: ignore[arg-type]
    except IdentificationError as exc:
        out.errors["brakes.blending"] = f"{type(exc).__name__}: {exc}"
    return out
