"""Per-family planners: the design of each fit at the truth's operating points, and its excitation.

Each function takes the noise-free truth Recording (:func:`~benchtwin.studies.plan_noise.truth_recording`)
and the noise of the setup's channels (:func:`~benchtwin.studies.plan_noise.noise_budget`) and returns
one :class:`PlannedParameter` per parameter: see :mod:`benchtwin.studies.plan`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from benchtwin.config.vehicle import VehicleConfig
from benchtwin.errors import BenchtwinError
from benchtwin.identification.battery import (
    BATTERY_SEGMENT_KINDS,
    battery_samples,
    eq30_design,
    load_literature_maps,
    refine_soc,
)
from benchtwin.identification.keys import FitKey
from benchtwin.identification.motor import motor_points, side_points
from benchtwin.identification.shifts import find_shift_events
from benchtwin.identification.transmission import RPM, direction_points, efficiency_design, transmission_points
from benchtwin.recording import Recording
from benchtwin.segments import Segment
from benchtwin.studies.plan_noise import (
    ChannelNoise,
    product_mean_variance,
    sample_variances,
    sandwich_covariance,
    window_mean_variance,
)
from benchtwin.studies.plan_windows import window_draws

__all__ = ["PlannedParameter", "noise_free", "plan_battery", "plan_motor", "plan_presence",
           "plan_shifts", "plan_transmission"]


@dataclass
class PlannedParameter:
    """The plan of one parameter.

    Attributes
    ----------
    name:
        ``fit.parameter`` as identification names it (e.g. ``transmission.gear5.eta_m``).
    unit:
        Unit of the value.
    value:
        The value identification gives on noise-free data at the planned points (NaN when not fitted).
    se:
        Predicted standard error from the sensor noise (NaN: not predicted or not identifiable).
    identifiable:
        Whether the planned tests excite the parameter enough for its fit.
    reason:
        Why not (or what the prediction rests on).
    suggestion:
        The test to add, in the campaign's TOML terms ('' when none is needed).
    n_points:
        Rows of the fit (steady windows or grid samples).
    """

    name: str
    unit: str
    value: float
    se: float
    identifiable: bool
    reason: str = ""
    suggestion: str = ""
    n_points: int = 0

    @property
    def rel_se(self) -> float:
        """Standard error relative to the value."""
        return abs(self.se / self.value) if self.value and math.isfinite(self.value) else float("nan")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (NaN as null)."""
        d = asdict(self)
        d["rel_se"] = self.rel_se
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


def plan_transmission(rec: Recording, vehicle: VehicleConfig, noise: Mapping[str, ChannelNoise],
                      segments: list[Segment], *, recorded: Mapping[str, Any] | None = None,
                      sensed: Mapping[str, Any] | None = None, keep: dict[str, Any] | None = None
                      ) -> list[PlannedParameter]:
    """``eta_m`` and ``C0`` of every gear, drive and coast (eq. 15-17), on the identification's steady points.

    Each point's efficiency is a ratio of window means of the shaft torque, the input torque and the two
    speeds; its residual is linearised in all four (the shaft torque enters both ``eta`` and ``C`` of a
    coast point), and the weighted fit's sandwich covariance gives ``eta_m``; ``C0 = (eta_m C0) / eta_m``
    by the delta method. The windows themselves move with the noise where the signals still settle as a
    hold begins: the variance of the noise-free estimates over draws of the windows is added
    (:mod:`~benchtwin.studies.plan_windows`; ``recorded``: the searched channels as the plan's bench run
    recorded them, role -> Channel, for the lag of their readings; ``sensed``: role -> the noise-free value
    of each reading, :func:`~benchtwin.studies.plan_noise.sensor_response`, drawn around instead).
    A gear or direction with fewer than 3 points, or one torque level only, is not identifiable: the
    suggestion is a ramp-up in that gear (with brake steps for the coast side). ``eta_m_C0``, the fit's second
    coefficient, is planned from the same covariance (its selection term: the product over the draws). ``keep``:
    when given, gets ``"points"`` (the noise-free points) and ``"drawn"`` (each draw's points found on its noisy
    readings) for the drag model's plan (:func:`~benchtwin.studies.plan_drag.plan_drag`).
    """
    specs = vehicle.specs
    ratios = np.asarray(specs.gear_ratios, dtype=float)
    out: list[PlannedParameter] = []
    try:
        pts = transmission_points(rec, specs)
    except BenchtwinError as exc:  # a campaign without any steady transmission point
        pts, why = None, f"no steady point: {exc}"
    k_w = specs.final_drive_ratio / 3.6 / specs.wheel_radius_m
    drawn: list[Any] = []
    moved = window_draws(rec, specs, noise, recorded=recorded, sensed=sensed, keep=drawn) if pts is not None else {}
    if keep is not None:
        keep.update(points=pts, drawn=drawn)
    ramp_gears = {int(s.settings.get("gear", 0)) for s in segments if s.kind == "ramp_up"}
    for g in range(1, ratios.size + 1):
        for direction in ("drive", "coast"):
            key = str(FitKey.transmission(g, direction))
            test = (f"add a [[tests]] kind = \"ramp_up\" with gear = {g}"
                    + (" and brake_steps_pct = [5.0, 10.0, 20.0] (regenerative coast points)" if direction == "coast"
                       else " and pedal_steps_pct over at least three levels, lockup = \"closed\""))
            if g in ramp_gears and direction == "coast":
                test = f"add brake_steps_pct = [5.0, 10.0, 20.0] to the ramp_up test in gear {g}"
            names = [(f"{key}.eta_m", "-"), (f"{key}.C0", "Nm"), (f"{key}.eta_m_C0", "Nm")]
            if pts is None:
                out += [PlannedParameter(n, u, float("nan"), float("nan"), False, why, test) for n, u in names]
                continue
            m, dom, c, eta = direction_points(pts, g, direction, ratios[g - 1])
            c, eta = c[dom], eta[dom]
            idx = np.flatnonzero(m)[dom]
            rel_spread = float(np.ptp(1.0 / c) / np.mean(1.0 / c)) if c.size else 0.0
            if c.size < 3 or rel_spread < 0.1:
                why = (f"{c.size} steady {direction} points in gear {g} (need 3)" if c.size < 3 else
                       f"1/C spans {rel_spread:.2f} of its mean (need 0.1): one torque level only")
                out += [PlannedParameter(n, u, float("nan"), float("nan"), False, why, test, int(c.size))
                        for n, u in names]
                continue
            A, w = efficiency_design(c)
            x0 = np.linalg.lstsq(A * np.sqrt(w)[:, None], eta * np.sqrt(w), rcond=None)[0]
            eta_m, k = float(x0[0]), float(x0[1])
            wins = pts.windows
            assert wins is not None
            st = np.array([wins.windows[j].start_s for j in idx])
            en = np.array([wins.windows[j].end_s for j in idx])

            def mean_var(name: str, st: np.ndarray = st, en: np.ndarray = en) -> np.ndarray:
                sv = sample_variances(rec, noise, name)
                return np.zeros(st.size) if sv is None else window_mean_variance(rec, name, sv, st, en)

            k0 = np.nan_to_num(wins.state("k0_closed")[idx], nan=1.0) > 0.5  # engine torque counted in C_in
            v_cin = mean_var("em_torque_nm") + k0 * mean_var("engine_torque_nm")
            v_tout = mean_var("shaft_torque_nm")
            v_wout = mean_var("vehicle_speed_kmh") * k_w**2
            v_win = mean_var("em_speed_rpm") * RPM**2
            c_in, t_out = pts.c_in[idx], pts.t_out[idx]
            w_in, w_out = pts.w_in[idx], pts.w_out[idx]
            if direction == "drive":
                s2 = ((eta / t_out) ** 2 * v_tout + (eta / c_in + k / c_in**2) ** 2 * v_cin
                      + (eta / w_out) ** 2 * v_wout + (eta / w_in) ** 2 * v_win)
            else:
                ig = ratios[g - 1]
                s2 = ((eta / t_out + np.sign(t_out) * k / (c**2 * ig)) ** 2 * v_tout + (eta / c_in) ** 2 * v_cin
                      + (eta / w_out) ** 2 * v_wout + (eta / w_in) ** 2 * v_win)
            cov = sandwich_covariance(A, w, s2)
            grad_c0 = np.array([-k / eta_m**2, 1.0 / eta_m])
            v_eta, v_c0 = max(cov[0, 0], 0.0), max(float(grad_c0 @ cov @ grad_c0), 0.0)
            # eta_m C0 is the fit's second coefficient: its variance is the covariance's own entry (the product of
            # eta_m and C0 through their joint covariance, d(eta C0) = C0 d eta + eta d C0, to first order)
            v_k = max(float(cov[1, 1]), 0.0)
            why = f"{c.size} steady windows, C {c.min():.0f}..{c.max():.0f} Nm"
            drawn = moved.get(key)
            if drawn is not None and len(drawn) >= 2:
                sel = np.var(drawn, axis=0, ddof=1)
                v_eta, v_c0 = v_eta + float(sel[0]), v_c0 + float(sel[1])
                v_k += float(np.var(drawn[:, 0] * drawn[:, 1], ddof=1))
                if sel[0] > 0.1 * cov[0, 0]:
                    why += (f"; the windows move with the noise: {sel[0] / v_eta:.0%} of eta_m's variance "
                            f"over {len(drawn)} draws")
            se_eta, se_c0 = math.sqrt(v_eta), math.sqrt(v_c0)
            out.append(PlannedParameter(names[0][0], "-", eta_m, se_eta, True, why, "", int(c.size)))
            out.append(PlannedParameter(names[1][0], "Nm", k / eta_m, se_c0, True, why, "", int(c.size)))
            out.append(PlannedParameter(f"{key}.eta_m_C0", "Nm", k, math.sqrt(v_k), True,
                                        why + "; eta_m_C0: the fit's coefficient (eta_m and C0 with their covariance)",
                                        "", int(c.size)))
    return out


def plan_battery(rec: Recording, vehicle: VehicleConfig, noise: Mapping[str, ChannelNoise],
                 segments: list[Segment]) -> list[PlannedParameter]:
    """``alpha``, ``beta_discharge``, ``beta_charge`` of eq. 30 on the constant drives' grid samples.

    Each grid sample interpolates two readings of the shunt's voltage and current; the residual carries
    the voltage noise over the cell count and the current noise through the resistance term (errors in
    the regressor). A current direction with fewer than 10 samples, or spanning less than 10 A, is not
    identifiable: the suggestion is a constant drive that discharges or charges the pack.
    """
    specs = vehicle.specs
    test = ("add a [[tests]] kind = \"constant_drive\" (mode = \"electric\" to discharge; mode = \"hybrid\" at a "
            "low SOC to charge)")
    names = [("battery.alpha", "-"), ("battery.beta_discharge", "-"), ("battery.beta_charge", "-")]
    if not any(s.kind in BATTERY_SEGMENT_KINDS for s in segments):
        return [PlannedParameter(n, u, float("nan"), float("nan"), False, "no constant_drive test", test)
                for n, u in names]
    maps = load_literature_maps()
    d, use, _segs, _n_bad = battery_samples(rec, soc=True, rate_hz=None, kinds=BATTERY_SEGMENT_KINDS)
    soc, *_ = refine_soc(d["t"], d["battery_current_a"], d["displayed_soc_pct"], use)
    s, i = soc[use], d["battery_current_a"][use]
    cols = eq30_design(s, i, maps)
    out: list[PlannedParameter] = []
    fitted = ["alpha"]
    for name, m, what in (("beta_discharge", i > 0, "discharge"), ("beta_charge", i < 0, "charge")):
        n = int(m.sum())
        span = float(np.ptp(i[m])) if n else 0.0
        if n < 10 or span < 10.0:
            why = (f"only {n} {what} samples in the constant drives (need 10)" if n < 10 else
                   f"{what} current spans {span:.3g} A (need 10 A)")
            out.append(PlannedParameter(f"battery.{name}", "-", float("nan"), float("nan"), False, why,
                                        test.replace("(mode", f"that {what}s the pack (mode")))
            if n < 10:
                continue
        fitted.append(name)
    A = np.column_stack([cols[n] for n in fitted])
    y = d["battery_voltage_v"][use] / specs.n_cells_series
    x0 = np.linalg.lstsq(A, y, rcond=None)[0]
    # each grid sample interpolates two readings of each channel
    t = d["t"][use]
    s2 = np.zeros(t.size)
    dmodel_di = np.zeros(t.size)
    for j, name in enumerate(fitted):
        if name == "beta_discharge":
            dmodel_di -= x0[j] * maps.r_discharge(s) * (i > 0)
        elif name == "beta_charge":
            dmodel_di -= x0[j] * maps.r_charge(s) * (i < 0)
    for role, sens in (("battery_voltage_v", np.full(t.size, 1.0 / specs.n_cells_series)),
                       ("battery_current_a", dmodel_di)):
        sv = sample_variances(rec, noise, role)
        if sv is None:
            continue
        ts = rec[role].timestamps
        k = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, ts.size - 2)
        a = np.clip((t - ts[k]) / np.maximum(ts[k + 1] - ts[k], 1e-12), 0.0, 1.0)
        s2 += sens**2 * ((1.0 - a) ** 2 * sv[k] + a**2 * sv[k + 1])
    cov = sandwich_covariance(A, None, s2)
    why = f"{t.size} samples of the constant drives"
    for j, name in enumerate(fitted):
        out.append(PlannedParameter(f"battery.{name}", "-", float(x0[j]), math.sqrt(max(cov[j, j], 0.0)), True,
                                    why, "", int(t.size)))
    order = {n: k for k, (n, _u) in enumerate(names)}
    return sorted(out, key=lambda p: order.get(p.name, 99))


def plan_motor(rec: Recording, vehicle: VehicleConfig, noise: Mapping[str, ChannelNoise],
               segments: list[Segment]) -> list[PlannedParameter]:
    """Willans lines, motoring and generating, by the delta method on the identification's own fits.

    The regressors hold the HPCU power (and the DC/DC power): noisy products of IVT readings, in a
    normalised form and with derived parameters (``e``, ``W_loss``, ``eta_dcdc``, ``eta_peak``). Rather
    than re-deriving each, the fit function is differentiated at the noise-free planned points: with
    ``J`` the derivative of every parameter with respect to each point's window-mean powers,
    ``Var = sum_i J_i^2 var_i`` (the linearised covariance of the same estimator).
    """
    specs = vehicle.specs
    hint = {"motoring": "add [[tests]] kind = \"ramp_up\" with pedal_steps_pct over several levels (motoring points)",
            "generating": "add brake_steps_pct to a ramp_up test (generating points)"}
    try:
        pts = motor_points(rec)
    except BenchtwinError as exc:
        return [PlannedParameter(f"motor.{side}.*", "", float("nan"), float("nan"), False,
                                 f"no steady motor point: {exc}", hint[side]) for side in hint]
    wins = pts.windows
    assert wins is not None
    st = np.array([w.start_s for w in wins.windows])
    en = np.array([w.end_s for w in wins.windows])
    var_h = product_mean_variance(rec, noise, "hpcu_current_a", "hpcu_voltage_v", st, en)
    lv = pts.p_lv_w is not None
    var_lv = product_mean_variance(rec, noise, "dcdc_lv_current_a", "dcdc_lv_voltage_v", st, en) if lv else None
    out: list[PlannedParameter] = []
    for side, sel, func in side_points(pts):
        t, n, ph = pts.torque_nm[sel], pts.speed_rpm[sel], pts.p_hpcu_w[sel]
        pl = pts.p_lv_w[sel] if pts.p_lv_w is not None else None

        def fit(ph: np.ndarray, pl: np.ndarray | None, t: np.ndarray = t, n: np.ndarray = n,
                func: Callable[..., Any] = func) -> dict[str, float]:
            f = func(specs, t, n, ph, pl)
            return {k: p.value for k, p in f.params.items()}

        try:
            x0 = fit(ph, pl)
        except BenchtwinError as exc:
            out.append(PlannedParameter(f"motor.{side}.*", "", float("nan"), float("nan"), False, str(exc),
                                        hint[side], int(sel.sum())))
            continue
        var = dict.fromkeys(x0, 0.0)
        for inputs, v in ((ph, var_h[sel]), (pl, None if var_lv is None else var_lv[sel])):
            if inputs is None or v is None:
                continue
            for j in np.flatnonzero(v > 0):
                h = 1e-3 * max(abs(float(inputs[j])), 1.0)
                up, dn = inputs.copy(), inputs.copy()
                up[j] += h
                dn[j] -= h
                fu = fit(up, pl) if inputs is ph else fit(ph, up)
                fd = fit(dn, pl) if inputs is ph else fit(ph, dn)
                for k in var:
                    var[k] += ((fu[k] - fd[k]) / (2 * h)) ** 2 * float(v[j])
        why = f"{int(sel.sum())} steady {side} points, {np.abs(t).min():.0f}..{np.abs(t).max():.0f} Nm"
        out += [PlannedParameter(f"motor.{side}.{k}", "", x0[k], math.sqrt(var[k]), True, why, "", int(sel.sum()))
                for k in x0]
    return out


def noise_free(roles: Iterable[str], noise: Mapping[str, ChannelNoise]) -> bool:
    """Whether none of the roles carries a random error on the setup (the estimate is then the same every seed)."""
    return not any(r in noise for r in roles)


def _zero_or_nan(roles: Iterable[str], noise: Mapping[str, ChannelNoise]) -> tuple[float, str]:
    roles = sorted(set(roles))
    if noise_free(roles, noise):
        return 0.0, "every channel it reads is free of random error on this setup: the same estimate every seed"
    return float("nan"), f"SE not predicted (reads noisy {', '.join(r for r in roles if r in noise)})"


def plan_shifts(rec: Recording, n_gears: int, noise: Mapping[str, ChannelNoise], roles: Iterable[str]
                ) -> list[PlannedParameter]:
    """Excitation of the shift lines: every pair and direction needs 3 events spread over 10 % of pedal.

    One row per pair and direction (``shifts.up_1_2.*``); its standard error is 0 when no channel the
    method reads carries a random error, else not predicted.
    """
    se0, note = _zero_or_nan(roles, noise)
    out: list[PlannedParameter] = []
    try:
        ev = find_shift_events(rec)
    except BenchtwinError:  # no target-gear channel: every pair unexcited
        ev = {"from_gear": np.array([]), "to_gear": np.array([]), "pedal_pct": np.array([])}
    keep = np.asarray(ev.get("good", []), dtype=bool) & np.asarray(ev.get("crossing", []), dtype=bool)
    fr = np.asarray(ev.get("from_gear", []), dtype=float)[keep]
    to = np.asarray(ev.get("to_gear", []), dtype=float)[keep]
    ped = np.asarray(ev.get("pedal_pct", []), dtype=float)[keep]
    for g in range(1, n_gears):
        for name, a, b, hint in ((f"shifts.up_{g}_{g + 1}", g, g + 1,
                                  "add [[tests]] kind = \"acceleration\" at other pedal_pct values (e.g. 20, 50, 80) "
                                  "with end_speed_kmh above the upshift"),
                                 (f"shifts.down_{g + 1}_{g}", g + 1, g,
                                  "add [[tests]] kind = \"ramp_down\" at other pedal_pct values (or a deceleration) "
                                  "from start_speed_kmh above the downshift")):
            m = (fr == a) & (to == b)
            n = int(m.sum())
            spread = float(np.ptp(ped[m])) if n else 0.0
            ok = n >= 3 and spread >= 10.0
            why = f"{n} events, pedal spread {spread:.0f} %" + ("" if ok else " (need 3 events over 10 % of pedal)")
            out.append(PlannedParameter(name + ".*", "km/h", float("nan"), se0 if ok else float("nan"), ok,
                                        why + ("; " + note if ok else ""), "" if ok else hint, n))
    return out


#: excitation of the families without a design of their own here: (test present?, what, the test to add)
_PRESENCE: dict[str, tuple[Callable[[list[Segment]], bool], str, str]] = {
    "road_load": (lambda segs: any(s.kind == "coastdown" for s in segs), "a coastdown",
                  "add [[tests]] kind = \"coastdown\" from start_speed_kmh = 130"),
    "engine": (lambda segs: any(s.kind == "ramp_up" and s.settings.get("mode") != "electric"
                                and s.settings.get("engine") in ("on", "auto") for s in segs),
               "a ramp_up with the engine on",
               "add [[tests]] kind = \"ramp_up\" with mode = \"hybrid\", engine = \"on\", k0 = \"closed\""),
}


def plan_presence(family: str, segments: list[Segment], noise: Mapping[str, ChannelNoise],
                  roles: Iterable[str]) -> list[PlannedParameter]:
    """One row ``<family>.*``: whether its tests are planned, and a standard error of 0 when it reads no noisy
    channel (else not predicted)."""
    has, what, hint = _PRESENCE[family]
    ok = bool(has(segments))
    se0, note = _zero_or_nan(roles, noise)
    return [PlannedParameter(f"{family}.*", "", float("nan"), se0 if ok else float("nan"), ok,
                             f"{'planned' if ok else 'missing'}: {what}" + ("; " + note if ok else ""),
                             "" if ok else hint)]
