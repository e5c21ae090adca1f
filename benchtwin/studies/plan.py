"""Identifiability before driving: the standard error each parameter will have, from the plan alone.

:func:`plan_campaign` predicts, for a vehicle, a setup and a campaign, the standard error of every
parameter the identification fits, without identifying anything from measured data:

1. The operating points come from the plant: the campaign's Trace (from the disk cache,
   :mod:`benchtwin.emulator.cache`) is pushed once through the batch chain for the recording's
   timestamps and flags, and every recorded channel is then replaced by the truth it measures
   (:meth:`~benchtwin.sensors.base.Device.truth_channels`): a noise-free Recording on the bench's own
   clock. Planning is a study of the plan, so it may read the truth; identification never does.
2. The identification's own selection rules and regressors run on that Recording
   (:func:`~benchtwin.identification.transmission.transmission_points`,
   :func:`~benchtwin.identification.transmission.direction_points`,
   :func:`~benchtwin.identification.transmission.efficiency_design`,
   :func:`~benchtwin.identification.battery.battery_samples`,
   :func:`~benchtwin.identification.battery.eq30_design`): the design matrix ``A`` at the points a
   fit will use, with its row weights ``W``.
3. Each recorded channel's random error per sample is taken from the setup's error budget
   (:meth:`~benchtwin.sensors.base.Device.error_budget`): white noise ``sigma`` and quantisation
   ``q`` (the wire's step or the sensor's own, the larger), as the variance of the quantised noisy
   reading averaged over the reading's position within a step (:func:`reading_variance`:
   ``sigma^2 + q^2/12`` for ``sigma >> q``, about ``q sigma / sqrt(pi)`` for ``sigma << q``, 0 without
   noise: a noise-free quantised reading of a steady value is a bias, the same for every seed). A
   steady window's mean over ``n`` samples has ``1/n`` of it; a grid sample interpolated between two
   readings at fraction ``a`` has ``a^2 + (1-a)^2`` of it.
4. The residual of each row is linearised in the channels it is made of (errors in the dependent and
   the independent variables, e.g. the shaft torque in both ``eta`` and ``C`` of a coast point), which
   gives a per-row variance ``s_i^2``; the estimator's covariance is the sandwich
   ``(A'WA)^-1 A'W diag(s^2) W A (A'WA)^-1`` (``sigma^2 (A'A)^-1`` for equal rows and no weights).

The prediction is the spread of the estimates over seeds of the sensor noise on one plant run, the
figure a sweep over seeds measures; it holds no bias (gain and offset errors, model error) and no
lack of fit (the identification's own standard errors carry the residual scatter, which includes it).

Parameters whose fit will not get the points it needs are flagged *not identifiable*, with the reason
and the test to add in the campaign's TOML terms. Families without a predicted standard error yet
(motor, engine, road load, brakes, torque converter, shift lines) are checked for excitation only.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from benchtwin.chain.batch import run_batch
from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.setup import ChannelErrors, SetupConfig
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.emulator.cache import cached_campaign
from benchtwin.errors import BenchtwinError
from benchtwin.identification.battery import (
    BATTERY_SEGMENT_KINDS,
    battery_samples,
    eq30_design,
    load_literature_maps,
    refine_soc,
)
from benchtwin.identification.keys import FitKey
from benchtwin.identification.shifts import find_shift_events
from benchtwin.identification.transmission import (
    RPM,
    direction_points,
    efficiency_design,
    transmission_points,
)
from benchtwin.recording import Channel, Recording
from benchtwin.segments import Segment
from benchtwin.sensors.imperfections import hold_sample
from benchtwin.sensors.registry import devices
from benchtwin.trace import Trace
from benchtwin.validation.families import family_spans, merge_recordings, span_seed

__all__ = ["Plan", "PlannedParameter", "plan_campaign", "reading_variance", "truth_recording"]

#: segment kinds whose chain the planner runs (every test an identification family reads)
_KINDS = ("ramp_up", "constant_drive", "acceleration", "deceleration", "ramp_down", "neutral_braking", "coastdown",
          "cycle")


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


@dataclass
class Plan:
    """The predicted standard errors and excitation flags of a campaign on a setup."""

    parameters: list[PlannedParameter] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)

    def get(self, name: str) -> PlannedParameter:
        """The plan of one parameter by name."""
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"meta": self.meta, "parameters": [p.to_dict() for p in self.parameters]}

    def to_json(self) -> str:
        """JSON text."""
        return json.dumps(self.to_dict(), indent=1)

    def format_table(self) -> str:
        """One line per parameter: value, predicted SE, relative SE, identifiable, reason and the test to add."""
        head = f"{'parameter':40s} {'value':>11s} {'pred. SE':>10s} {'rel. SE':>9s}  ident.  reason / test to add"
        lines = [f"plan of campaign {self.meta.get('campaign')!r} on setup {self.meta.get('setup')!r} "
                 f"(vehicle {self.meta.get('vehicle')!r})", head, "-" * len(head)]
        for p in self.parameters:
            note = p.reason + (f" -> {p.suggestion}" if p.suggestion else "")
            lines.append(f"{p.name:40s} {_fmt(p.value):>11s} {_fmt(p.se):>10s} "
                         f"{(f'{p.rel_se:.2%}' if math.isfinite(p.rel_se) else '-'):>9s}  "
                         f"{'yes' if p.identifiable else 'NO':6s}  {note}")
        n_no = sum(not p.identifiable for p in self.parameters)
        lines.append(f"{len(self.parameters)} parameters, {n_no} not identifiable with the planned tests")
        return "\n".join(lines)


def _fmt(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x:.4g}"


# ---------------------------------------------------------------------------------------------------- noise


def reading_variance(sigma: float, q: float, y: np.ndarray | float | None = None) -> np.ndarray | float:
    """Variance of the random part of a reading: white noise ``sigma`` quantised to steps ``q``.

    The reading is ``q rint((y + n) / q)`` with ``n ~ N(0, sigma^2)`` and ``y`` the sensor's noise-free
    output (truth with its gain and offset errors). With ``y`` given, the exact variance over ``n`` at
    each ``y``; without, its average over the position of ``y`` within a step. ``q = 0``: ``sigma^2``;
    ``sigma = 0``: 0 (the quantisation error of a fixed value is the same for every seed);
    ``sigma >= q``: ``sigma^2 + q^2/12`` (Sheppard's correction, exact to a few parts in a thousand there).
    """
    if y is None:
        pos = (np.arange(64) + 0.5) / 64.0 * q if q > 0 else np.zeros(1)
        return float(np.mean(reading_variance(sigma, q, pos)))
    y = np.asarray(y, dtype=float)
    if sigma <= 0.0:
        return np.zeros(y.shape)
    if q <= 0.0:
        return np.full(y.shape, float(sigma**2))
    if sigma >= q:
        return np.full(y.shape, float(sigma**2 + q**2 / 12.0))
    k = np.arange(-int(6 * sigma / q) - 2, int(6 * sigma / q) + 3)
    centre = np.rint(y / q)
    d = (y / q - centre)[..., None]  # position within the step, in steps
    # P(reading = (centre + k) q): the noise moves y into the step around (centre + k) q
    p = stats.norm.cdf((k + 0.5 - d) * q / sigma) - stats.norm.cdf((k - 0.5 - d) * q / sigma)
    m1 = p @ (k * q)
    m2 = p @ (k * q) ** 2
    return np.clip(m2 - m1**2, 0.0, None)


@dataclass(frozen=True)
class _ChannelNoise:
    """The random error of one role's readings: noise, quantisation, and the gain and offset before them."""

    sigma: float
    q: float
    gain: float = 0.0
    offset: float = 0.0

    def variances(self, truth_values: np.ndarray) -> np.ndarray:
        """Variance of each reading whose noise-free truth is ``truth_values``."""
        return np.asarray(reading_variance(self.sigma, self.q, (1.0 + self.gain) * truth_values + self.offset))


def _budget(setup: SetupConfig) -> tuple[dict[str, Any], dict[str, _ChannelNoise]]:
    """Role -> TruthChannel, and role -> the random error of its readings, from every device of the setup."""
    truth: dict[str, Any] = {}
    noise: dict[str, _ChannelNoise] = {}
    for d in devices(setup):
        tcs = d.truth_channels()
        truth.update(tcs)
        for role, (err, _link, _extra) in d.error_budget().items():
            tc = tcs.get(role)
            res = tc.resolution if tc is not None else 0.0
            if isinstance(err, ChannelErrors) and err.noise_std > 0:
                noise[role] = _ChannelNoise(err.noise_std, max(res, err.quantisation_step), err.gain_error_frac,
                                            err.offset)
    return truth, noise


def _sample_variances(rec: Recording, noise: Mapping[str, _ChannelNoise], name: str) -> np.ndarray | None:
    """Per-reading variance of channel ``name`` of the truth Recording (None: noise-free)."""
    if name not in rec or name not in noise:
        return None
    return noise[name].variances(rec[name].values)


def truth_recording(rec: Recording, trace: Trace, truth: Mapping[str, Any]) -> Recording:
    """The Recording with every channel that measures a Trace channel replaced by that truth.

    The timestamps, flags and segments stay those of the bench; channels without a truth stay as recorded.
    """
    out = Recording(segments=list(rec.segments), meta=dict(rec.meta))
    for name, ch in rec.channels.items():
        tc = truth.get(name)
        if tc is None or tc.trace not in trace:
            out.add(ch)
            continue
        x = trace[tc.trace] * tc.factor
        v = hold_sample(trace.time_s, x, ch.timestamps) if tc.hold else np.interp(ch.timestamps, trace.time_s, x)
        out.add(Channel(name, ch.unit, ch.timestamps, v, ch.flags, ch.source))
    return out


def _window_mean_variance(rec: Recording, name: str, var: np.ndarray, starts: np.ndarray, ends: np.ndarray
                          ) -> np.ndarray:
    """Variance of the mean of channel ``name``'s good readings inside each window ``[start, end)``."""
    ch = rec[name]
    order = np.argsort(ch.timestamps, kind="stable")
    ts = ch.timestamps[order]
    good = ch.good[order]
    cn = np.cumsum(np.concatenate(([0], good.astype(int))))
    cv = np.cumsum(np.concatenate(([0.0], np.where(good, var[order], 0.0))))
    lo = np.searchsorted(ts, starts, side="left")
    hi = np.searchsorted(ts, ends, side="left")
    n = np.maximum(cn[hi] - cn[lo], 1)
    return (cv[hi] - cv[lo]) / n**2


def _sandwich(A: np.ndarray, w: np.ndarray | None, s2: np.ndarray) -> np.ndarray:
    """Covariance of weighted least squares with row weights ``w`` when row ``i`` has variance ``s2[i]``."""
    w = np.ones(A.shape[0]) if w is None else w
    Aw = A * w[:, None]
    B = np.linalg.inv(A.T @ Aw)
    return B @ (Aw.T @ (Aw * s2[:, None])) @ B


# ---------------------------------------------------------------------------------------------------- families


def _plan_transmission(rec: Recording, vehicle: VehicleConfig, noise: Mapping[str, _ChannelNoise],
                       segments: list[Segment]) -> list[PlannedParameter]:
    specs = vehicle.specs
    ratios = np.asarray(specs.gear_ratios, dtype=float)
    out: list[PlannedParameter] = []
    try:
        pts = transmission_points(rec, specs)
    except BenchtwinError as exc:  # a campaign without any steady transmission point
        pts, why = None, f"no steady point: {exc}"
    k_w = specs.final_drive_ratio / 3.6 / specs.wheel_radius_m
    ramp_gears = {int(s.settings.get("gear", 0)) for s in segments if s.kind == "ramp_up"}
    for g in range(1, ratios.size + 1):
        for direction in ("drive", "coast"):
            key = str(FitKey.transmission(g, direction))
            test = (f"add a [[tests]] kind = \"ramp_up\" with gear = {g}"
                    + (" and brake_steps_pct = [5.0, 10.0, 20.0] (regenerative coast points)" if direction == "coast"
                       else " and pedal_steps_pct over at least three levels, lockup = \"closed\""))
            if g in ramp_gears and direction == "coast":
                test = f"add brake_steps_pct = [5.0, 10.0, 20.0] to the ramp_up test in gear {g}"
            names = [(f"{key}.eta_m", "-"), (f"{key}.C0", "Nm")]
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
                sv = _sample_variances(rec, noise, name)
                return np.zeros(st.size) if sv is None else _window_mean_variance(rec, name, sv, st, en)

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
            cov = _sandwich(A, w, s2)
            grad_c0 = np.array([-k / eta_m**2, 1.0 / eta_m])
            se_eta = math.sqrt(max(cov[0, 0], 0.0))
            se_c0 = math.sqrt(max(float(grad_c0 @ cov @ grad_c0), 0.0))
            why = f"{c.size} steady windows, C {c.min():.0f}..{c.max():.0f} Nm"
            out.append(PlannedParameter(names[0][0], "-", eta_m, se_eta, True, why, "", int(c.size)))
            out.append(PlannedParameter(names[1][0], "Nm", k / eta_m, se_c0, True, why, "", int(c.size)))
    return out


def _plan_battery(rec: Recording, vehicle: VehicleConfig, noise: Mapping[str, _ChannelNoise],
                  segments: list[Segment]) -> list[PlannedParameter]:
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
        sv = _sample_variances(rec, noise, role)
        if sv is None:
            continue
        ts = rec[role].timestamps
        k = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, ts.size - 2)
        a = np.clip((t - ts[k]) / np.maximum(ts[k + 1] - ts[k], 1e-12), 0.0, 1.0)
        s2 += sens**2 * ((1.0 - a) ** 2 * sv[k] + a**2 * sv[k + 1])
    cov = _sandwich(A, None, s2)
    why = f"{t.size} samples of the constant drives"
    for j, name in enumerate(fitted):
        out.append(PlannedParameter(f"battery.{name}", "-", float(x0[j]), math.sqrt(max(cov[j, j], 0.0)), True,
                                    why, "", int(t.size)))
    order = {n: k for k, (n, _u) in enumerate(names)}
    return sorted(out, key=lambda p: order.get(p.name, 99))


def _plan_shifts(rec: Recording, n_gears: int, segments: list[Segment]) -> list[PlannedParameter]:
    """Excitation of the shift lines: every pair and direction needs 3 events spread over 10 % of pedal."""
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
            out.append(PlannedParameter(name, "km/h", float("nan"), float("nan"), ok, why + "; SE not predicted",
                                        "" if ok else hint, n))
    return out


def _plan_presence(segments: list[Segment]) -> list[PlannedParameter]:
    """Families whose standard errors are not predicted: whether their tests are planned."""
    kinds = {s.kind for s in segments}
    ramp = [s for s in segments if s.kind == "ramp_up"]
    rows = (
        ("road_load.*", "coastdown" in kinds, "a coastdown", "add [[tests]] kind = \"coastdown\" from start_speed_kmh "
                                                              "= 130"),
        ("brakes.*", "neutral_braking" in kinds, "a neutral_braking test",
         "add [[tests]] kind = \"neutral_braking\" with brake_steps_pct = [5.0, 10.0, 20.0, 30.0]"),
        ("engine.*", any(s.settings.get("engine") in ("on", "auto") and s.settings.get("mode") != "electric"
                         for s in ramp), "a ramp_up with the engine on",
         "add [[tests]] kind = \"ramp_up\" with mode = \"hybrid\", engine = \"on\", k0 = \"closed\""),
        ("motor.* (drive)", any(s.settings.get("pedal_steps_pct") for s in ramp), "ramp_up pedal steps",
         "add [[tests]] kind = \"ramp_up\" with pedal_steps_pct"),
        ("motor.* (regeneration)", any(s.settings.get("brake_steps_pct") for s in ramp), "ramp_up brake steps",
         "add brake_steps_pct to a ramp_up test"),
        ("torque_converter.*", bool(kinds & {"acceleration", "deceleration"}), "accelerations or decelerations "
                                                                                "(lock-up open)",
         "add [[tests]] kind = \"acceleration\" (converter mode at the launch)"),
    )
    return [PlannedParameter(name, "", float("nan"), float("nan"), ok,
                             f"{'has' if ok else 'no'} {what}; SE not predicted", "" if ok else hint)
            for name, ok, what, hint in rows]


# ---------------------------------------------------------------------------------------------------- entry


def plan_campaign(vehicle: VehicleConfig, setup: SetupConfig, campaign: CampaignConfig, *,
                  trace: Trace | None = None, cache: bool | str = True,
                  families: Iterable[str] = ("transmission", "battery", "shifts", "other")) -> Plan:
    """Predict the standard error of every parameter and flag those no planned test excites.

    Parameters
    ----------
    vehicle, setup, campaign:
        The scenario (the campaign's seed gives the plant run and the chain's timestamps).
    trace:
        The campaign's Trace, if already simulated.
    cache:
        Take the Trace from the disk cache (True: default directory; a path; False: simulate).
    families:
        Which parts to plan: ``transmission`` and ``battery`` (predicted standard errors), ``shifts``
        and ``other`` (excitation only).

    Returns
    -------
    Plan
    """
    fams = set(families)
    if trace is None:
        if cache is False:
            from benchtwin.emulator import simulate_campaign
            trace = simulate_campaign(vehicle, campaign)
        else:
            trace, _hit = cached_campaign(vehicle, campaign, directory=None if cache is True else cache)
    truth, noise = _budget(setup)
    kinds: set[str] = set()
    if "transmission" in fams:
        kinds |= {"ramp_up"}
    if "battery" in fams:
        kinds |= {"constant_drive"}
    if "shifts" in fams:
        kinds |= {"acceleration", "deceleration", "ramp_down", "cycle"}
    spans = family_spans(trace.segments, kinds)
    plan = Plan(meta={"vehicle": vehicle.name, "setup": setup.name, "campaign": campaign.name,
                      "seed": campaign.seed, "families": sorted(fams),
                      "noise": {k: {"noise_std": v.sigma, "step": v.q} for k, v in sorted(noise.items())}})
    rec = None
    if spans:
        recs = [run_batch(trace.slice_time(a, b), setup, seed=span_seed(campaign.seed, k))
                for k, (a, b) in enumerate(spans)]
        rec = truth_recording(merge_recordings(recs), trace, truth)
    segments = list(trace.segments)
    empty = Recording(segments=segments)
    if "transmission" in fams:
        plan.parameters += _plan_transmission(rec if rec is not None else empty, vehicle, noise, segments)
    if "battery" in fams:
        plan.parameters += _plan_battery(rec if rec is not None else empty, vehicle, noise, segments)
    if "shifts" in fams:
        plan.parameters += _plan_shifts(rec if rec is not None else empty, len(vehicle.specs.gear_ratios), segments)
    if "other" in fams:
        plan.parameters += _plan_presence(segments)
    return plan
