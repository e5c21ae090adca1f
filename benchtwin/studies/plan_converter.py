"""Planned torque-converter standard errors: the sandwich of its two linear fits at the planned points.

The identification's own selection and regressors (:func:`~benchtwin.identification.torque_converter_points.
converter_points`, :func:`~benchtwin.identification.torque_converter.converter_design`) run on the noise-free
Recording, and its own fit (:func:`~benchtwin.identification.torque_converter.fit_torque_converter`) gives the
coupling point, the rows each mode keeps (outlier rejection) and the values. With those rows fixed, both fits
are linear in their right-hand sides:

- converter mode (eq. 37-38), stacked ``[t_p; t_t] = A x``: ``x = (A'A)^-1 A' b``, whose covariance is the
  sandwich with the variance of each row: the motor torque's grid sample for the pump rows, the shaft torque's
  over ``k_out^2`` (``k_out = i_g eta_m``) for the turbine rows (a grid sample interpolated between two readings
  at fraction ``a`` has ``(1-a)^2`` and ``a^2`` of their variances);
- coupling mode (eq. 39), ``t_t = D x`` with the identification's coupling design ``D``
  (:func:`~benchtwin.identification.torque_converter.coupling_design`: ``x = (a6, a8)`` and ``a7 = -a6 - a8``
  with no torque without slip, ``x = a6`` alone over too narrow an SR span), mapped to ``a_678 = M x``: the
  turbine rows of the coupling points (with ``coupling_torque="pump"``: ``t_p - J dw_p``, the pump rows and
  the pump inertia ``J`` of the converter fit through ``-M (D'D)^-1 D' dw_p``);
- the transmission model each turbine torque goes through (``T_out / (i_g eta_m) + C0``) is itself estimated
  from the same seed's shaft torque: its planned ``eta_m`` and ``C0`` standard errors of each gear move all
  the turbine rows that use that gear's model together, in both fits (``-(t_t - C0) / eta_m`` and ``1``; a
  gear without a model of its own uses the nearest one's), taken as independent.

The transmission table the turbine torque goes through is the one a bench finds: the identification's own
transmission fit on the Recording with every channel free of random error as the plan's bench run recorded it
(the CAN motor and engine torques carry errors of their own that are the same every seed) and the shaft torque
with its declared gain, lagged as its readings are (:func:`~benchtwin.studies.plan_windows.reading_lag_line`:
the paper bench's telemetry clock drifts, 19 ms at the start of the paper campaign and 0.26 s at 10,000 s). On the
paper campaign the fit on the truth put eta_m up to 0.6 % and C0 up to 2 Nm away from the bench's, the
turbine-torque scale at 1.005 against the bench's 0.982, and the turbine side's ratios over 20 seeds at 1.5-3.5.

The derived parameters (``gamma_coupling``, ``k_at_gamma`` with its coupling point, ``sr_zero_torque``) follow
by the delta method on the joint covariance.

The turbine torque of eq. 32 is scaled by the median over the gears of ``T_motor / T_t`` where the lock-up is
closed (:func:`~benchtwin.identification.torque_converter_points.turbine_torque_scale`): each draw recomputes it
from the drawn readings of those samples (with the same transmission-model draws) and scales the turbine rows by it.
The readings are drawn around their noise-free values as the sensor gives them
(:func:`~benchtwin.studies.plan_noise.sensor_response`: its filter, clock and latency): with the truth lagged by one
delay instead, the first grid sample after the paper campaign's first pedal step fell on the other side of the
calibration's ``shaft_torque_nm > 0`` rule (gear 2: 474 samples against the bench's 475 in that test), and the
median of an even count averaged two ranks. The scale's spread over :data:`SCALE_DRAWS` draws is its standard
error: with one calibrated gear (quick campaign: 1.35e-5 against 1.39e-5 over 20 seeds) as with several, where the
calibration's samples take the readings on the telemetry's clock map (:data:`MAPPED_SETS`): on their own timestamps
(64 ms away on the paper campaign) they carried errors not of their noise-free values, and over 8 gears the draws
scattered 2.7 times the seeds. Mapping the converter's points as well put a0 / a1 out of the factor 1.5 (0.35 /
0.63 over 20 seeds), so they stay on their own timestamps. The spread over several gears is heavy-tailed.

The rows themselves change with the seed: the 5-sigma outlier rejection scales its bound with the residuals'
spread, and the split at the refined coupling point moves with it. So the rows are decided by the
identification's own fit on :data:`CONVERTER_DRAWS` draws of the readings as the bench records them, and the
planned variance is the mean of the linear term at each draw's rows plus the variance of the noise-free estimate
over them (over every set of rows the draws meet, :data:`RARE_ROWS`). One draw is one error per shaft-torque
reading, quantised at the value the bench's sensor reads (the truth with its gain and offset, lagged), shared by
the converter's points, the turbine-torque calibration's samples and the transmission table's fit to the same
readings (:mod:`~benchtwin.studies.plan_converter_draws`): drawn independently at the unlagged truth, the paper
campaign's split at the coupling point fell at 0.8540-0.8551 against the bench's 0.8536-0.8541 over 20 seeds, so
three points beside it never changed fits (a6..a8 2.2 times the plan over the seeds, J_pump 3.4). The shaft torque's
noise-free value is the sensor's own response where the plan has it (``sensed``), else the truth lagged by a line
in time (:func:`~benchtwin.studies.plan_windows.reading_lag_line`). The CAN
signals the points are made of are taken as recorded (:data:`CONVERTER_RECORDED`: their quantisation is the
same every seed) and the shaft torque with its declared gain and offset, so the derivatives are taken where a
bench's estimates are.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.errors import BenchtwinError
from benchtwin.identification.run import identify_all
from benchtwin.identification.torque_converter import (
    _zero_torque_sr,
    converter_design,
    coupling_coefficients,
    coupling_design,
    coupling_point,
    fit_torque_converter,
    identify_torque_converter,
)
from benchtwin.identification.torque_converter_gearbox import converter_gearbox_table
from benchtwin.identification.torque_converter_points import (
    ConverterPoints,
    converter_points,
    turbine_torque_scale,
)
from benchtwin.recording import Channel, Recording
from benchtwin.segments import Segment
from benchtwin.studies.plan_converter_draws import shared_shaft_draws
from benchtwin.studies.plan_fits import PlannedParameter
from benchtwin.studies.plan_noise import ChannelNoise, grid_error_sampler, grid_variance
from benchtwin.studies.plan_windows import reading_lag_line

__all__ = ["CONVERTER_DRAWS", "CONVERTER_RECORDED", "HEAVY_TAILED", "MAPPED_SETS", "ROBUST_MAD", "SCALE_DRAWS",
           "plan_converter"]

#: draws of the noise that decide the rows: the selection term's std is known to about 1 / sqrt(2 (K - 1)) (8 % at
#: 80); one draw is one fit at the planned points (a few ms)
CONVERTER_DRAWS = 80
#: a set of rows met on fewer than this share of the draws is rare: left out of the standard error, and named.
#: 0: every set counts (the law of total variance over all draws). With the shaft torque drawn as one error per
#: reading, shared by the points, the calibration and the transmission table, the paper campaign's draws meet a
#: dozen sets, most on 1-4 of 80 draws, which together carry the pump side's spread over seeds (a0 and J_pump
#: fall in 4-5 clusters over 20 seeds); leaving out those under 5 % put a0 at 0.34 of the seeds' spread.
RARE_ROWS = 0.0

#: channels of the converter's points that the plan takes as recorded when they carry no random error: their
#: quantisation and latency are the same every seed, and the narrow coupling range's ``a6..a8`` (and the slope of
#: ``k_at_gamma`` along the coupling point) move with them; a noisy channel it reads keeps its truth with the
#: sensor's declared gain and offset (also the same every seed), so the derivatives are taken where a run is
CONVERTER_RECORDED = ("em_speed_rpm", "em_torque_nm", "vehicle_speed_kmh")

#: draws of the turbine-torque scale (the calibration alone, a few ms each): over the paper campaign's draws its
#: spread is heavy-tailed (excess kurtosis 16 over 400: a gear's median now and then jumps a quantisation level), so
#: the std of K draws is known to about sqrt((kurtosis + 2) / (4 K)): 24 % at 80, 11 % at 400
SCALE_DRAWS = 400
#: the normal's std over its median absolute deviation: the robust width of a spread is ROBUST_MAD * MAD
ROBUST_MAD = 1.4826
#: the words the turbine-torque scale's reason carries when its spread over the draws is heavy-tailed (several
#: calibrated gears): a std over tens of seeds then scatters far more than a normal's (benchmarks/bench_plan.py
#: also sets the robust widths side by side)
HEAVY_TAILED = "heavy-tailed"
#: which sets of grid times the shared shaft-torque draws read on the telemetry's clock map: (the converter's
#: points, the turbine-torque calibration's samples); see the module docstring
MAPPED_SETS = (False, True)

nan = float("nan")
_HINT = "add [[tests]] kind = \"acceleration\" (converter mode at the launch)"
_POINT_OPTS = ("rate_hz", "max_pump_accel_rpm_s", "min_pump_speed_rpm", "min_pump_torque_nm", "shift_hold_s",
               "derivative_window_s", "calibrate_turbine_speed", "min_calibration_points", "lockup_slip_tol",
               "calibrate_turbine_torque")
_FIT_OPTS = ("gamma", "min_points", "outlier_sigma", "coupling_zero_slip", "coupling_torque", "min_coupling_span")


def _defaults() -> dict[str, object]:
    """The identification's own default options (one source of truth)."""
    return {k: p.default for k, p in inspect.signature(identify_torque_converter).parameters.items()
            if p.default is not inspect.Parameter.empty}


def _transmission_table(tx: Sequence[PlannedParameter]) -> dict[int, tuple[float, float, float, float]]:
    """Gear -> (eta_m, C0, se eta_m, se C0) of the identifiable drive fits of the transmission plan."""
    by = {p.name: p for p in tx}
    out = {}
    for name, p in by.items():
        if not (name.startswith("transmission.gear") and name.endswith(".eta_m") and "_coast" not in name):
            continue
        g = int(name[len("transmission.gear"):-len(".eta_m")])
        c0 = by.get(f"transmission.gear{g}.C0")
        if p.identifiable and c0 is not None and c0.identifiable:
            out[g] = (p.value, c0.value, p.se if math.isfinite(p.se) else 0.0, c0.se if math.isfinite(c0.se) else 0.0)
    return out


def _bench_table(view: Recording, specs: VehicleSpecs, planned: Mapping[int, tuple[float, float, float, float]]
                 ) -> dict[int, tuple[float, float, float, float]]:
    """The transmission table the bench's turbine torque goes through, with the planned standard errors.

    The values are the identification's own table on ``view`` (:func:`~benchtwin.identification.
    torque_converter_gearbox.converter_gearbox_table`: the CAN signals as recorded, the shaft torque with its
    declared gain and lag), where a bench's estimates are: on the paper bench they differ from the fit on the
    truth by up to 0.6 % in eta_m and 2 Nm in C0 (the CAN motor torque's own error), which moved the turbine-torque
    scale by 2.3 % and the coupling point by 0.01. A gear the fit on ``view`` lacks keeps the planned value; the
    standard errors are the planned ones (0 for a gear the plan lacks).
    """
    try:
        found = converter_gearbox_table(identify_all(view, specs, methods=["transmission"], type_b=False))[0]
    except BenchtwinError:
        found = {}
    out = dict(planned)
    for g, (eta, c0) in found.items():
        _e, _c, se_eta, se_c0 = planned.get(g, (eta, c0, 0.0, 0.0))
        out[g] = (eta, c0, se_eta, se_c0)
    return out


def _delta(func: Callable[[np.ndarray], float], z: np.ndarray, cov: np.ndarray) -> float:
    """Variance of ``func(z)`` by the delta method (central differences)."""
    grad = np.zeros(z.size)
    for i in range(z.size):
        h = 1e-6 * max(1.0, abs(float(z[i])))
        up, dn = z.copy(), z.copy()
        up[i] += h
        dn[i] -= h
        grad[i] = (func(up) - func(dn)) / (2 * h)
    return float(grad @ cov @ grad)


def plan_converter(rec: Recording, vehicle: VehicleConfig, noise: Mapping[str, ChannelNoise],
                   segments: list[Segment], tx: Sequence[PlannedParameter], *, seed: int = 0,
                   draws: int = CONVERTER_DRAWS, scale_draws: int = SCALE_DRAWS,
                   recorded: Mapping[str, Channel] | None = None,
                   sensed: Mapping[str, Channel] | None = None) -> list[PlannedParameter]:
    """Predicted standard errors of ``a0..a8``, ``J_pump_kgm2``, the coupling point and its derived values.

    Parameters
    ----------
    rec:
        The noise-free truth Recording.
    vehicle:
        Gear ratios, final drive, wheel radius.
    noise:
        Role -> random error of its readings.
    segments:
        The campaign's tests.
    tx:
        The transmission plan (:func:`~benchtwin.studies.plan_fits.plan_transmission`): the table the turbine
        torque goes through, and its standard errors.
    recorded:
        Role -> the channel as the bench recorded it (:data:`CONVERTER_RECORDED`); a role without random error
        on the setup is taken from here instead of its truth.
    sensed:
        Role -> the noise-free value each of its readings measures
        (:func:`~benchtwin.studies.plan_noise.sensor_response`); a noisy role found here is taken from it (with
        its declared gain and offset) instead of its truth lagged by :func:`~benchtwin.studies.plan_windows.
        reading_lag_line`.
    seed, draws:
        Seed and number of the draws of the noise that decide the rows the fits keep (module docstring).
    scale_draws:
        Draws of the turbine-torque calibration's readings whose spread gives the scale's standard error (the
        first ``draws`` of them are those of the fits).

    Returns
    -------
    list of PlannedParameter
        ``torque_converter.converter.*`` and ``torque_converter.coupling.*``, or one row
        ``torque_converter.*`` flagged not identifiable with the test to add.
    """
    specs = vehicle.specs
    if not any(s.kind in ("acceleration", "deceleration") for s in segments):
        return [PlannedParameter("torque_converter.*", "", float("nan"), float("nan"), False,
                                 "missing: accelerations or decelerations (lock-up open)", _HINT)]
    opts = _defaults()
    truth = rec
    swap = {n: ch for n, ch in (recorded or {}).items() if n not in noise and n in rec}
    for n in ("shaft_torque_nm", *CONVERTER_RECORDED):
        if n in noise and n in rec and (noise[n].gain or noise[n].offset or (sensed and n in sensed)):
            ch = rec[n]
            if sensed and n in sensed:  # the sensor's own noise-free response (filter, clock, latency)
                y = sensed[n].values
            else:  # the readings lag the truth as the bench's do: the launches' torque moves fast
                a, b = reading_lag_line(ch, recorded[n], noise[n]) if recorded and n in recorded else (0.0, 0.0)
                y = np.interp(ch.timestamps - (a + b * ch.timestamps), ch.timestamps, ch.values) if a or b \
                    else ch.values
            swap[n] = Channel(n, ch.unit, ch.timestamps, (1.0 + noise[n].gain) * y + noise[n].offset,
                              ch.flags, ch.source)
    if swap:
        view = Recording(segments=list(rec.segments), meta=rec.meta)
        for name, ch in rec.channels.items():
            view.add(swap.get(name, ch))
        rec = view
    table = _bench_table(rec, specs, _transmission_table(tx))
    try:
        pts = converter_points(rec, specs, transmission={g: v[:2] for g, v in table.items()} or None,
                               **{k: opts[k] for k in _POINT_OPTS})  # type: ignore[arg-type]
        res = fit_torque_converter(pts.w_p, pts.w_t, pts.t_p, pts.t_t, dw_p=pts.dw_p,
                                   **{k: opts[k] for k in _FIT_OPTS})  # type: ignore[arg-type]
    except BenchtwinError as exc:
        return [PlannedParameter("torque_converter.*", "", float("nan"), float("nan"), False,
                                 f"no converter fit at the planned points: {exc}", _HINT)]
    # variance of each point's pump torque (motor torque) and turbine torque (shaft torque over k_out)
    v_tp = grid_variance(truth, noise, "em_torque_nm", pts.t)
    v_tt = grid_variance(truth, noise, "shaft_torque_nm", pts.t) / pts.k_out**2
    e_tp = grid_error_sampler(truth, noise, "em_torque_nm", pts.t)
    model_gear = _model_gears(pts.gear, table)
    zero_slip = bool(opts["coupling_zero_slip"])
    lin = [_propagate(pts, res, v_tp, v_tt, table, zero_slip)]
    tscales: list[float] = []
    n_lost = 0
    if np.any(v_tp > 0) or np.any(v_tt > 0):
        # the rows each fit keeps (outlier rejection, whose bound scales with the residuals' spread) and the mode
        # split at the refined coupling point change with the noise: over draws of it, the identification's own fit
        # decides the rows, and the plan adds the variance of the noise-free estimate at those rows
        rng = np.random.default_rng(seed)
        lin = []
        cal = pts.torque_calibration
        cal_gear = _model_gears(cal.gear, table) if cal is not None else None
        shaft = noise.get("shaft_torque_nm")
        # one error per shaft-torque reading, shared by the points, the calibration and the table's fit; the
        # calibration's samples take the readings on the clock map, as its grid does (module docstring)
        shared = (shared_shaft_draws(rec, specs, ChannelNoise(shaft.sigma, shaft.q), [pts.t] + (
            [cal.t] if cal is not None else []), table, mapped=MAPPED_SETS) if shaft is not None else None)
        e_tp_cal = grid_error_sampler(truth, noise, "em_torque_nm", cal.t) if cal is not None else None
        # the first ``draws`` draws decide the converter's rows; the turbine-torque scale, cheap to redraw alone,
        # takes SCALE_DRAWS draws (its spread is heavy-tailed: module docstring)
        for k in range(max(draws, scale_draws if cal is not None else 0)):
            fit = k < draws
            # the readings as the bench quantises them: the rounding's bias decides rows as it does on a bench
            sd = shared(rng) if shared is not None else None
            if fit:
                t_t = pts.t_t + (sd.grid[0] / pts.k_out if sd is not None else 0.0)
                t_p = pts.t_p + (e_tp(rng) if e_tp is not None else 0.0)
            if cal is not None:
                ct = cal.t_t + (sd.grid[1] / cal.k_out if sd is not None else 0.0)
                cp = cal.t_p + (e_tp_cal(rng) if e_tp_cal is not None else 0.0)
            for gear, (eta, c0, se_eta, se_c0) in table.items():
                d_eta, d_c0 = sd.table[gear] if sd is not None else (rng.normal(0.0, se_eta), rng.normal(0.0, se_c0))
                if fit:
                    sel = model_gear == gear
                    t_t[sel] += -(pts.t_t[sel] - c0) / eta * d_eta + d_c0
                if cal is not None:
                    cs = cal_gear == gear
                    ct[cs] += -(cal.t_t[cs] - c0) / eta * d_eta + d_c0
            if cal is not None:
                # the turbine-torque scale the identification would find on these readings (the points carry
                # the noise-free one)
                s_draw, _, n_s = turbine_torque_scale(cal.gear, cp, ct, cal.min_points)
                if n_s:
                    tscales.append(s_draw)
                    if fit:
                        t_t *= s_draw / pts.tscale
            if not fit:
                continue
            try:
                rows = fit_torque_converter(pts.w_p, pts.w_t, t_p, t_t,
                                            dw_p=pts.dw_p, **{k: opts[k] for k in _FIT_OPTS})  # type: ignore[arg-type]
                lin.append(_propagate(pts, rows, v_tp, v_tt, table, zero_slip))
            except BenchtwinError:
                n_lost += 1
        if len(lin) < 2:
            return [PlannedParameter("torque_converter.*", "", float("nan"), float("nan"), False,
                                     f"the converter fit fails on {n_lost} of {draws} draws of the noise", _HINT)]
    # the row sets the draws meet; one met on fewer than RARE_ROWS of the draws is left out of the standard error
    # (a sweep of tens of seeds seldom meets it, and its jump would dominate the variance) and named in the reason
    count: dict[bytes, int] = {}
    for x in lin:
        count[x.key] = count.get(x.key, 0) + 1
    modal = max(count, key=lambda k: count[k])
    first = next(x for x in lin if x.key == modal)
    names = first.names
    same = [x for x in lin if x.names == names and count[x.key] >= RARE_ROWS * len(lin)]
    n_rare = sum(c for k, c in count.items() if c < RARE_ROWS * len(lin))
    z = np.array([x.z for x in same])
    var = np.mean([np.diag(x.cov) for x in same], axis=0)
    if len(same) > 1:
        var = var + np.var(z, axis=0, ddof=1)
    n1, n2 = first.n1, first.n2
    n_sets = sum(c >= RARE_ROWS * len(lin) for c in count.values())
    why = (f"{n1} converter-mode and {n2} coupling-mode points (SR 0..{float(np.max(pts.w_t / pts.w_p)):.2f}), "
           f"Gamma {first.g:.3f}"
           + (f"; over {len(lin)} draws of the noise the fits keep {n_sets} set(s) of rows" if len(lin) > 1 else "")
           + (f" (and rarer ones on {n_rare} draws, left out)" if n_rare else "")
           + (f"; the fit fails on {n_lost} draws" if n_lost else ""))
    v0 = {f"converter.{p}": q.value for p, q in res["converter"].params.items()}
    v0.update({f"coupling.{p}": q.value for p, q in res["coupling"].params.items()} if "coupling" in res else {})
    out = []
    for i, name in enumerate(names):
        side = "coupling" if name in ("a6", "a7", "a8") else "converter"
        unit = "kg*m^2" if name == "J_pump_kgm2" else "Nm*s^2/rad^2"
        out.append(PlannedParameter(f"torque_converter.{side}.{name}", unit, v0.get(f"{side}.{name}", nan),
                                    _se(float(var[i]), float(first.z[i])), True, why, "",
                                    n1 if side == "converter" else n2))
    for side, name, func in _DERIVED:
        if side == "coupling" and "a6" not in names:
            continue
        vals = np.array([func(x.z, x.k1) for x in same])
        if name == "sr_zero_torque" and zero_slip:
            dv = 0.0  # 1 by construction (no torque without slip); a numerical derivative would give rounding
        else:
            dv = float(np.mean([_delta(lambda zz, x=x, f=func: f(zz, x.k1), x.z, x.cov) for x in same]))
            if len(same) > 1:
                dv += float(np.var(vals, ddof=1))
        out.append(PlannedParameter(f"torque_converter.{side}.{name}", "Nm*s^2/rad^2" if name == "k_at_gamma" else "",
                                    v0.get(f"{side}.{name}", nan), _se(dv, float(vals[0])), True, why, "",
                                    n1 if side == "converter" else n2))
    calib_noisy = any(r in noise for r in ("em_speed_rpm", "vehicle_speed_kmh"))
    out.append(PlannedParameter("torque_converter.converter.turbine_speed_scale", "", pts.scale,
                                float("nan") if calib_noisy else 0.0, True,
                                "SE not predicted (a median of noisy speed ratios)" if calib_noisy else
                                "the speeds it reads are free of random error on this setup", "", pts.n_cal))
    # the scale's spread over the draws is its standard error, with one calibrated gear (quick campaign, gear 4:
    # 1.35e-5 over 80 draws against 1.39e-5 over 20 seeds) as with several (paper campaign, 8 gears, the
    # calibration's samples on the clock map: module docstring)
    ts_noisy = len(tscales) > 1 and float(np.ptp(tscales)) > 0
    tcal = pts.torque_calibration
    cal_gears = 0 if tcal is None else sum(int((tcal.gear == k).sum() >= tcal.min_points) for k in np.unique(tcal.gear))
    if not ts_noisy:
        ts_se, ts_why = 0.0, "the torques it reads are free of random error on this setup"
    else:
        ts_se = float(np.std(tscales, ddof=1))
        ts = np.asarray(tscales)
        robust = ROBUST_MAD * float(np.median(np.abs(ts - np.median(ts))))
        ts_why = (f"one gear's median torque ratio: its spread over {len(tscales)} draws of the readings"
                  if cal_gears == 1 else
                  f"a median over {cal_gears} gears' median torque ratios: its spread over {len(tscales)} draws of "
                  f"the readings; {HEAVY_TAILED} (robust width {robust:.3g}"
                  + (f", std {ts_se / robust:.2g} times it" if robust > 0 else "")
                  + "): a gear's median now and then jumps a quantisation level")
    out.append(PlannedParameter("torque_converter.converter.turbine_torque_scale", "", pts.tscale, ts_se, True,
                                ts_why, "", pts.n_tcal))
    if "a6" not in names:
        out.append(PlannedParameter("torque_converter.coupling.*", "", float("nan"), float("nan"), False,
                                    f"{n2} coupling-mode points", "add [[tests]] kind = \"acceleration\" "
                                    "with the lock-up open up to a higher speed (SR above the coupling point)", n2))
    order = {n: k for k, n in enumerate(_ORDER)}
    return sorted(out, key=lambda p: order.get(p.name.split(".")[-1], 99))


@dataclass
class _Linear:
    """Both fits at one set of rows: parameter names, the noise-free estimates, their noise covariance."""

    names: list[str]
    z: np.ndarray
    cov: np.ndarray
    k1: int
    n1: int
    n2: int
    g: float
    key: bytes = b""


def _model_gears(gear: np.ndarray, table: Mapping[int, object]) -> np.ndarray:
    """The gear whose transmission model each point's turbine torque goes through: its own, else the nearest
    identified one (ties: the lower), as :func:`~benchtwin.identification.torque_converter_points.converter_points`
    does."""
    if not table:
        return np.zeros(gear.shape, dtype=int)
    near = {int(k): min(table, key=lambda j: (abs(j - int(k)), j)) for k in np.unique(gear)}
    return np.array([near[int(k)] for k in gear], dtype=int)


def _propagate(pts: ConverterPoints, rows: Mapping[str, Any], v_tp: np.ndarray, v_tt: np.ndarray,
               table: Mapping[int, tuple[float, float, float, float]], zero_slip: bool = True) -> _Linear:
    """The linear map of both fits at the rows ``rows`` (a result of the fit) kept, on the noise-free points;
    ``zero_slip`` as the coupling fit's ``coupling_zero_slip`` (its torque and a slip-only design are read from
    ``rows['coupling'].data``)."""
    model_gear = _model_gears(pts.gear, table)
    data = rows["torque_ratio"].data
    g = float(data["gamma"][0])
    inlier = data["inlier"] > 0.5
    sr = pts.w_t / pts.w_p
    m1 = (sr < g) & inlier
    m2 = (sr >= g) & inlier
    A1 = converter_design(pts.w_p[m1], pts.w_t[m1], pts.dw_p[m1])
    L1 = np.linalg.solve(A1.T @ A1, A1.T)  # x_conv = L1 [t_p; t_t]
    n1 = int(m1.sum())
    x1 = L1 @ np.r_[pts.t_p[m1], pts.t_t[m1]]
    cov1 = (L1 * np.r_[v_tp[m1], v_tt[m1]]) @ L1.T
    names = [f"a{k}" for k in range(6)] + ["J_pump_kgm2"]
    k1 = len(names)
    coupled = "coupling" in rows and int(m2.sum()) >= 3
    if coupled:
        cdata = rows["coupling"].data
        turbine = cdata.get("torque", "turbine") == "turbine"
        one = bool(cdata.get("slip_only", False))
        d2 = coupling_design(pts.w_p[m2], pts.w_t[m2], zero_slip, one)
        # a_678 = M x of the fit's unknowns x (a6, a8 with no torque without slip; a6 alone slip-only)
        m678 = np.column_stack([coupling_coefficients(e, zero_slip, one) for e in np.eye(d2.shape[1])])
        L2 = m678 @ np.linalg.solve(d2.T @ d2, d2.T)
        if turbine:  # the coupling torque read on the turbine side: its noise, no pump inertia
            x2 = L2 @ pts.t_t[m2]
            cov2 = (L2 * v_tt[m2]) @ L2.T
            dj = np.zeros(3)
        else:
            x2 = L2 @ (pts.t_p[m2] - x1[6] * pts.dw_p[m2])
            cov2 = (L2 * v_tp[m2]) @ L2.T
            dj = -L2 @ pts.dw_p[m2]  # d a678 / d J
    # the transmission model of each gear moves its turbine rows together (in both fits when the coupling fit
    # reads the turbine torque)
    tx = []
    for gear, (eta, c0, se_eta, se_c0) in table.items():
        sel = model_gear[m1] == gear
        sel2 = model_gear[m2] == gear if coupled and turbine else np.zeros(int(m2.sum()), dtype=bool)
        if not sel.any() and not sel2.any():
            continue
        d_eta = np.r_[np.zeros(n1), np.where(sel, -(pts.t_t[m1] - c0) / eta, 0.0)]
        d_c0 = np.r_[np.zeros(n1), sel.astype(float)]
        d2_eta = np.where(sel2, -(pts.t_t[m2] - c0) / eta, 0.0)
        tx += [(L1 @ d_eta, d2_eta, se_eta), (L1 @ d_c0, sel2.astype(float), se_c0)]
    for u, _, se in tx:
        cov1 += np.outer(u, u) * se**2
    if not coupled:
        return _Linear(names, x1, cov1, k1, n1, int(m2.sum()), g, np.packbits(np.r_[m1, m2]).tobytes())
    cov = np.zeros((k1 + 3, k1 + 3))
    cov[:k1, :k1] = cov1
    cov[k1:, k1:] = cov2 + np.outer(dj, dj) * cov1[6, 6]
    cov[k1:, :k1] = np.outer(dj, cov1[6])
    for u1, d2, se in tx:
        u2 = L2 @ d2 if turbine else np.zeros(3)
        cov[k1:, k1:] += np.outer(u2, u2) * se**2
        cov[k1:, :k1] += np.outer(u2, u1) * se**2
    cov[:k1, k1:] = cov[k1:, :k1].T
    return _Linear([*names, "a6", "a7", "a8"], np.r_[x1, x2], cov, k1, n1, int(m2.sum()), g,
                   np.packbits(np.r_[m1, m2]).tobytes())


def _se(var: float, value: float) -> float:
    """The standard error, 0 below float rounding of the value (a parameter that reads no noisy row)."""
    se = math.sqrt(max(var, 0.0))
    return 0.0 if se <= 1e-12 * max(abs(value), 1e-300) else se


def _gamma(z: np.ndarray, _k1: int) -> float:
    return coupling_point(z[:6], lo=0.3, hi=1.0)


def _k_at_gamma(z: np.ndarray, k1: int) -> float:
    gg = _gamma(z, k1)
    return float(z[k1] + z[k1 + 1] * gg + z[k1 + 2] * gg**2)


def _sr0(z: np.ndarray, k1: int) -> float:
    return _zero_torque_sr(z[k1:k1 + 3])


_DERIVED: tuple[tuple[str, str, Callable[[np.ndarray, int], float]], ...] = (
    ("converter", "gamma_coupling", _gamma), ("coupling", "k_at_gamma", _k_at_gamma),
    ("coupling", "sr_zero_torque", _sr0))
_ORDER = ("a0", "a1", "a2", "a3", "a4", "a5", "J_pump_kgm2", "gamma_coupling", "turbine_speed_scale",
          "turbine_torque_scale", "a6", "a7", "a8", "k_at_gamma", "sr_zero_torque")
