"""Plans of the extension fits: ``battery.rc``, ``battery.soc_per_ah``, ``motor.loss`` and ``engine.can_torque``.

These fits were added to identification after :mod:`benchtwin.studies.plan_fits`; each is planned here the way
that module plans the paper's fits (:mod:`benchtwin.studies.plan`): at the operating points the identification
finds on the plan's noise-free Recording, with each channel's random error from the setup's error budget
(:mod:`benchtwin.studies.plan_noise`).

- ``battery.soc_per_ah`` (the slope of the displayed SOC against the coulomb-counted charge,
  :func:`~benchtwin.identification.battery.refine_soc`) is linear in the current's errors: ``k = S_xy / S_xx`` with
  ``x`` the charge counted per block and ``y`` the displayed SOC (CAN, without random error on the paper bench),
  so ``dk = sum_j (y_j - 2 k x_j) dQ_j / S_xx`` (block-centred), ``dQ`` the running sum of the grid current's
  errors (trapezoid), and each grid sample interpolates two readings. The linearised variance is exact here (the
  slope's rules, ``k > 0`` and blocks whose SOC moves, do not depend on the current's noise).
- ``battery.rc`` is not linearised: its time constants come from a grid and Nelder-Mead search, and its branches
  are dropped by rules that read the fit's own residual (on the noise-free Recording the paper campaign's constant
  drives keep one branch, while every noisy seed drops it and fits eq. 30 with the temperature term). So the
  readings of the channels it reads are drawn (the quantised noisy reading at its noise-free value, with the
  sensor's gain and offset) on the plan's Recording and the identification's own fit is run on each draw: the
  standard error is the std over :data:`BATTERY_RC_DRAWS` draws (known to about ``1/sqrt(2 (K-1))``, 11 %).
- ``motor.loss`` is linear in the motor inverter's DC power, ``P_hpcu - P_lv / eta_dcdc``, with ``eta_dcdc`` the
  Willans fit's (a smooth function of the same powers): the identification's own fits are differentiated at the
  planned points in each window's mean power (the delta method, as :func:`~benchtwin.studies.plan_fits.plan_motor`).
- ``engine.can_torque`` regresses the ECU's torque on a reference built from the window-mean shaft torque through
  ``transmission.drag``, whose ``(k_T, k_w)`` come from a search with a rule that drops the speed term: not
  linearised either. The window means of every channel the points are made of are drawn (normal, with the variance
  of each window's mean) and the transmission's identification is re-run on the drawn points
  (:data:`CAN_TORQUE_DRAWS` draws, std known to about 5 %). Windows that move with the noise (gears 1-2's hybrid
  ramp-ups, :mod:`benchtwin.studies.plan_windows`) are not drawn: the points are the plan's.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import numpy as np

from benchtwin.config.vehicle import VehicleConfig
from benchtwin.errors import BenchtwinError
from benchtwin.identification.battery import BATTERY_SEGMENT_KINDS, battery_samples, refine_soc
from benchtwin.identification.battery_rc import identify_battery_rc
from benchtwin.identification.engine_torque import ENGINE_TORQUE_KEY
from benchtwin.identification.motor import MotorPoints, identify_motor, motor_points
from benchtwin.identification.transmission import OIL_ROLE, identify_transmission, transmission_points
from benchtwin.recording import Recording
from benchtwin.segments import Segment
from benchtwin.studies.plan_fits import PlannedParameter
from benchtwin.studies.plan_noise import (
    ChannelNoise,
    product_mean_variance,
    sample_variances,
    window_mean_variance,
)
from benchtwin.studies.plan_windows import noisy_readings

__all__ = ["BATTERY_RC_DRAWS", "CAN_TORQUE_DRAWS", "plan_battery_rc", "plan_can_torque",
           "plan_motor_loss", "plan_soc_slope", "soc_slope_variance"]

#: draws of the readings through the ``battery.rc`` fit (its std known to about 1 / sqrt(2 (K - 1)): 11 %)
BATTERY_RC_DRAWS = 40
#: draws of the window means through the transmission's fits for ``engine.can_torque`` (about 5 %)
CAN_TORQUE_DRAWS = 200
#: the channels the battery fits read
_BATTERY_ROLES = ("battery_voltage_v", "battery_current_a", "displayed_soc_pct", "battery_temp_degc")
_HIDDEN = ("a branch that moves the pack voltage less than the fit's noisy residual: a quieter pack-voltage sensor, "
           "or tests with larger current steps")
#: the grid of battery.rc's samples (identify_battery_rc's default rate; every usable sample)
RC_RATE_HZ = 2.0
_RC_TEST = ("add [[tests]] kind = \"constant_drive\" tests that discharge and charge the pack (battery.rc fits every "
            "usable battery sample)")


def soc_slope_variance(rec: Recording, noise: Mapping[str, ChannelNoise], t: np.ndarray, current_a: np.ndarray,
                       soc_pct: np.ndarray, use: np.ndarray) -> tuple[float, float]:
    """``(k, var k)`` of :func:`~benchtwin.identification.battery.refine_soc`'s slope from the current's noise.

    Linear in the grid current's errors ``e``: ``dQ_j = -(1/3600) sum_{m<=j} (e_m + e_{m-1}) dt_m / 2``, and
    ``dk = sum_j g_j dQ_j`` with ``g_j = (y_j - 2 k x_j) / S_xx`` over the blocks' centred values. The gradient is
    carried back to each grid sample (a reverse running sum), then to the current's readings, each grid sample
    interpolating two of them (``(1-a)``, ``a``); readings are independent, so ``var k = sum_r c_r^2 var_r``.
    Returns ``(nan, nan)`` where the identification would not refine (no block whose SOC moves, ``k <= 0``).
    """
    i = np.nan_to_num(np.asarray(current_a, dtype=float))
    dt = np.diff(t)
    q = np.cumsum(np.r_[0.0, -0.5 * (i[1:] + i[:-1]) * dt] / 3600.0)
    edges = np.flatnonzero(np.diff(np.r_[0, use.astype(np.int8), 0]))
    g = np.zeros(t.size)
    sxy = sxx = 0.0
    blocks = []
    for a, b in zip(edges[::2], edges[1::2]):
        if b - a < 3 or np.ptp(soc_pct[a:b]) <= 0:
            continue
        dq, ds = q[a:b] - q[a:b].mean(), soc_pct[a:b] - soc_pct[a:b].mean()
        sxy += float(dq @ ds)
        sxx += float(dq @ dq)
        blocks.append((a, b, dq, ds))
    if not blocks or not sxx > 0 or not sxy / sxx > 0:
        return float("nan"), float("nan")
    k = sxy / sxx
    for a, b, dq, ds in blocks:
        g[a:b] = (ds - 2.0 * k * dq) / sxx
    # dQ_j = sum_{m=1..j} -(e_m + e_{m-1}) dt_{m-1} / 7200: the weight of e_m is -(G_m dt_{m-1} + G_{m+1} dt_m) / 7200
    # with G_m = sum_{j>=m} g_j (the reverse running sum)
    big_g = np.cumsum(g[::-1])[::-1]
    w = np.zeros(t.size)
    w[1:] -= big_g[1:] * dt / 7200.0
    w[:-1] -= big_g[1:] * dt / 7200.0
    sv = sample_variances(rec, noise, "battery_current_a")
    if sv is None:
        return k, 0.0
    ts = rec["battery_current_a"].timestamps
    j = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, ts.size - 2)
    a = np.clip((t - ts[j]) / np.maximum(ts[j + 1] - ts[j], 1e-12), 0.0, 1.0)
    c = np.bincount(j, (1.0 - a) * w, minlength=ts.size) + np.bincount(j + 1, a * w, minlength=ts.size)
    return k, float(c @ (c * sv))


def plan_soc_slope(rec: Recording, noise: Mapping[str, ChannelNoise], segments: list[Segment],
                   name: str = "battery.soc_per_ah", rate_hz: float | None = None,
                   kinds: tuple[str, ...] | None = BATTERY_SEGMENT_KINDS) -> PlannedParameter:
    """``soc_per_ah`` of the eq. 30 fit on its grid (:func:`soc_slope_variance`), or why it is not identifiable.

    ``rate_hz`` and ``kinds`` are the grid and the tests of the fit that reports it: the eq. 30 fit's own (native
    rate, the constant drives), or ``battery.rc``'s (2 Hz, every usable sample).
    """
    test = "add [[tests]] kind = \"constant_drive\" that moves the displayed SOC by a few % (its slope against the Ah)"
    if kinds is not None and not any(s.kind in kinds for s in segments):
        return PlannedParameter(name, "%/Ah", float("nan"), float("nan"), False, "no constant_drive test", test)
    try:
        d, use, _segs, _n_bad = battery_samples(rec, soc=True, rate_hz=rate_hz, kinds=kinds)
    except BenchtwinError as exc:
        return PlannedParameter(name, "%/Ah", float("nan"), float("nan"), False, str(exc), test)
    _soc, k_id, _se, n_blocks = refine_soc(d["t"], d["battery_current_a"], d["displayed_soc_pct"], use)
    k, var = soc_slope_variance(rec, noise, d["t"], d["battery_current_a"], d["displayed_soc_pct"], use)
    if not math.isfinite(k):
        return PlannedParameter(name, "%/Ah", float("nan"), float("nan"), False,
                                "the displayed SOC does not move within a block of usable samples", test)
    assert abs(k - k_id) <= 1e-9 * abs(k_id), (k, k_id)  # the same slope as the identification's
    return PlannedParameter(name, "%/Ah", k, math.sqrt(max(var, 0.0)), True,
                            f"{n_blocks} blocks, {int(use.sum())} samples: the current's noise through the coulomb "
                            "count (linear)", "", int(use.sum()))


def plan_battery_rc(rec: Recording, vehicle: VehicleConfig, noise: Mapping[str, ChannelNoise], segments: list[Segment],
                    draws: int = BATTERY_RC_DRAWS, seed: int = 0) -> list[PlannedParameter]:
    """``battery.rc``: the std of each estimate over draws of the readings through the identification's fit.

    One row per parameter the draws report (``battery.rc.alpha``, ``beta_discharge``, ``beta_charge``,
    ``beta_temp_per_k`` with the pack temperature logged, ``r1_ohm``/``tau1_s``... when branches are kept) and
    ``soc_per_ah`` (planned linearised by :func:`plan_soc_slope` on the fit's grid). A parameter the draws report
    only sometimes (a branch kept on some draws) gets no standard error (its spread is a mixture), with the count in
    its reason; one the noise-free data report but no draw does is not identifiable. The value is the noise-free
    fit's, else the draws' mean.
    """
    specs = vehicle.specs
    try:
        clean = identify_battery_rc(rec, specs)
    except BenchtwinError as exc:
        return [PlannedParameter("battery.rc.*", "", float("nan"), float("nan"), False, str(exc), _RC_TEST)]
    rng = np.random.default_rng(seed)
    est: dict[str, list[float]] = {}
    n_branch: list[int] = []
    fails = 0
    for _ in range(draws):
        try:
            f = identify_battery_rc(noisy_readings(rec, noise, _BATTERY_ROLES, rng), specs)
        except BenchtwinError:
            fails += 1
            continue
        n_branch.append(int(f.data["n_branches"]))
        for k, p in f.params.items():
            est.setdefault(k, []).append(p.value)
    n_ok = draws - fails
    kept = {nb: n_branch.count(nb) for nb in sorted(set(n_branch))}
    why = (f"std over {n_ok} draws of the readings through the fit (a search over the time constants and branch "
           f"rules: not linearised); RC branches kept: " + ", ".join(f"{nb} in {c}" for nb, c in kept.items())
           + f" draws ({int(clean.data['n_branches'])} on the noise-free data)")
    out: list[PlannedParameter] = []
    for k in list(dict.fromkeys([*est, *clean.params])):
        v = np.asarray(est.get(k, []), dtype=float)
        p0 = clean.params.get(k)
        value = p0.value if p0 is not None else (float(np.mean(v)) if v.size else float("nan"))
        unit = p0.unit if p0 is not None else ""
        if k == "soc_per_ah":  # copied from the eq. 30 fit on battery.rc's grid: linear, planned exactly
            out.append(plan_soc_slope(rec, noise, segments, name="battery.rc.soc_per_ah", rate_hz=RC_RATE_HZ,
                                      kinds=None))
            continue
        if v.size == 0:
            out.append(PlannedParameter(f"battery.rc.{k}", unit, value, float("nan"), False,
                                        "the noise-free data report it but no draw does: the noise hides it; " + why,
                                        _HIDDEN, int(clean.data["t"].size)))
            continue
        if v.size < 2 or v.size < n_ok:
            out.append(PlannedParameter(f"battery.rc.{k}", unit, value, float("nan"), True,
                                        f"reported on {v.size} of {n_ok} draws: SE not predicted; " + why, "",
                                        int(clean.data["t"].size)))
            continue
        out.append(PlannedParameter(f"battery.rc.{k}", unit, value, float(np.std(v, ddof=1)), True, why, "",
                                    int(clean.data["t"].size)))
    return out


def plan_motor_loss(rec: Recording, vehicle: VehicleConfig, noise: Mapping[str, ChannelNoise]
                    ) -> list[PlannedParameter]:
    """``motor.loss``: the identification's fits differentiated in each window's mean HPCU and DC/DC power."""
    specs = vehicle.specs
    hint = "add [[tests]] kind = \"ramp_up\" with pedal_steps_pct and brake_steps_pct over several speeds"
    try:
        pts = motor_points(rec)
    except BenchtwinError as exc:
        return [PlannedParameter("motor.loss.*", "", float("nan"), float("nan"), False,
                                 f"no steady motor point: {exc}", hint)]
    wins = pts.windows
    assert wins is not None
    st = np.array([w.start_s for w in wins.windows])
    en = np.array([w.end_s for w in wins.windows])
    var_h = product_mean_variance(rec, noise, "hpcu_current_a", "hpcu_voltage_v", st, en)
    var_lv = (product_mean_variance(rec, noise, "dcdc_lv_current_a", "dcdc_lv_voltage_v", st, en)
              if pts.p_lv_w is not None else None)

    def fit(ph: np.ndarray, pl: np.ndarray | None) -> dict[str, float] | str:
        try:
            r = identify_motor(rec, specs, points=MotorPoints(pts.torque_nm, pts.speed_rpm, ph, pl, pts.segments,
                                                              pts.n_flagged, wins))
        except BenchtwinError as exc:
            return str(exc)
        f = r.fits.get("motor.loss")
        return r.errors.get("motor.loss", "not fitted") if f is None else {k: p.value for k, p in f.params.items()}

    x0 = fit(pts.p_hpcu_w, pts.p_lv_w)
    if isinstance(x0, str):
        return [PlannedParameter("motor.loss.*", "", float("nan"), float("nan"), False, x0, hint,
                                 int(pts.torque_nm.size))]
    var = dict.fromkeys(x0, 0.0)
    for which, v in ((0, var_h), (1, var_lv)):
        base = pts.p_hpcu_w if which == 0 else pts.p_lv_w
        if base is None or v is None:
            continue
        for j in np.flatnonzero(np.isfinite(v) & (v > 0)):
            h = 1e-3 * max(abs(float(base[j])), 1.0)
            up, dn = base.copy(), base.copy()
            up[j] += h
            dn[j] -= h
            fu = fit(up, pts.p_lv_w) if which == 0 else fit(pts.p_hpcu_w, up)
            fd = fit(dn, pts.p_lv_w) if which == 0 else fit(pts.p_hpcu_w, dn)
            if isinstance(fu, str) or isinstance(fd, str):
                continue
            for k in var:
                var[k] += ((fu[k] - fd[k]) / (2 * h)) ** 2 * float(v[j])
    why = (f"{int(pts.torque_nm.size)} steady points (both sides): the fits differentiated in each window's mean "
           "power (delta method)")
    return [PlannedParameter(f"motor.loss.{k}", "", x0[k], math.sqrt(var[k]), True, why, "", int(pts.torque_nm.size))
            for k in x0]


def _window_errors(rec: Recording, noise: Mapping[str, ChannelNoise], st: np.ndarray, en: np.ndarray
                   ) -> dict[str, np.ndarray]:
    """Role -> the std of each window's mean (roles with a random error that the transmission's points read)."""
    out = {}
    for role in ("shaft_torque_nm", "vehicle_speed_kmh", "em_torque_nm", "engine_torque_nm", "em_speed_rpm",
                 OIL_ROLE):
        sv = sample_variances(rec, noise, role)
        if sv is not None:
            out[role] = np.sqrt(window_mean_variance(rec, role, sv, st, en))
    return out


def plan_can_torque(rec: Recording, vehicle: VehicleConfig, noise: Mapping[str, ChannelNoise],
                    draws: int = CAN_TORQUE_DRAWS, seed: int = 0) -> list[PlannedParameter]:
    """``engine.can_torque`` ``gain`` and ``offset``: the std over draws of the points' window means.

    Each draw adds to each window's mean of every noisy channel the transmission's points read (shaft torque,
    vehicle speed, motor and engine torque and speed, oil temperature) a normal error with that mean's variance,
    forms the points as :func:`~benchtwin.identification.transmission.transmission_points` does, and runs
    :func:`~benchtwin.identification.transmission.identify_transmission` on them (eq. 14, ``transmission.drag`` and
    the calibration).
    """
    specs = vehicle.specs
    names = [(f"{ENGINE_TORQUE_KEY}.gain", "-"), (f"{ENGINE_TORQUE_KEY}.offset", "Nm")]
    hint = ("add [[tests]] kind = \"ramp_up\" with mode = \"hybrid\", engine = \"on\", k0 = \"closed\" in a gear that "
            "also has an electric ramp_up (motor-only points)")
    try:
        pts = transmission_points(rec, specs)
        r0 = identify_transmission(rec, specs, points=pts)
    except BenchtwinError as exc:
        return [PlannedParameter(n, u, float("nan"), float("nan"), False, str(exc), hint) for n, u in names]
    if pts.engine_in is None or pts.c_engine is None:
        return []  # the engine drives the gearbox alone (a conventional car): no calibration is fitted
    f0 = r0.fits.get(ENGINE_TORQUE_KEY)
    if f0 is None:
        why = str(r0.meta.get(ENGINE_TORQUE_KEY, {}).get("not_fitted", "not fitted"))
        return [PlannedParameter(n, u, float("nan"), float("nan"), False, why, hint) for n, u in names]
    wins = pts.windows
    assert wins is not None
    st = np.array([w.start_s for w in wins.windows])
    en = np.array([w.end_s for w in wins.windows])
    sd = _window_errors(rec, noise, st, en)
    k0 = pts.engine_in if pts.engine_in is not None else np.zeros(pts.gear.size, dtype=bool)
    t_em = pts.c_in - (pts.c_engine if pts.c_engine is not None else 0.0)
    t_eng = pts.c_engine if pts.c_engine is not None else np.zeros(pts.gear.size)
    k_w = specs.final_drive_ratio / specs.wheel_radius_m / 3.6
    rng = np.random.default_rng(seed)

    def err(role: str) -> np.ndarray | float:
        return rng.normal(0.0, sd[role]) if role in sd else 0.0

    vals: dict[str, list[float]] = {"gain": [], "offset": []}
    for _ in range(draws):
        t_out = pts.t_out + err("shaft_torque_nm")
        w_out = pts.w_out + k_w * err("vehicle_speed_kmh")
        e_em = t_em + err("em_torque_nm")
        e_eng = t_eng + err("engine_torque_nm")
        c_in = np.where(k0, e_em + e_eng, e_em)
        w_in = pts.w_in + (2.0 * np.pi / 60.0) * err("em_speed_rpm")
        oil = None if pts.oil_degc is None else pts.oil_degc + err(OIL_ROLE)
        drawn = dataclasses.replace(pts, c_in=c_in, w_in=w_in, t_out=t_out, w_out=w_out, p_in=c_in * w_in,
                                    p_out=t_out * w_out, oil_degc=oil,
                                    c_engine=None if pts.c_engine is None else np.where(k0, e_eng, 0.0))
        try:
            f = identify_transmission(rec, specs, points=drawn).fits.get(ENGINE_TORQUE_KEY)
        except BenchtwinError:
            f = None
        if f is not None:
            for k in vals:
                vals[k].append(f.value(k))
    n_pts = int(f0.data["c_engine_ref"].size)
    why = (f"{n_pts} engine points; std over {len(vals['gain'])} of {draws} draws of the window means through the "
           "transmission's fits (transmission.drag's search: not linearised)")
    out = []
    for (n, u), k in zip(names, ("gain", "offset")):
        v = np.asarray(vals[k])
        se = float(np.std(v, ddof=1)) if v.size >= 2 else float("nan")
        out.append(PlannedParameter(n, u, f0.value(k), se, v.size >= 2, why, "", n_pts))
    return out

