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
   :func:`~benchtwin.identification.battery.eq30_design`,
   :func:`~benchtwin.identification.brakes.brake_gain_windows`,
   :func:`~benchtwin.identification.motor.motor_points`, :func:`~benchtwin.identification.motor.side_points`):
   the design matrix ``A`` at the points a fit will use, with its row weights ``W``.
3. Each recorded channel's random error per reading is taken from the setup's error budget
   (:mod:`benchtwin.studies.plan_noise`): white noise and quantisation, as the exact variance of the
   quantised noisy reading at its own noise-free value (0 without noise: the quantisation error of a
   noise-free reading is a bias, the same for every seed). A steady window's mean of ``n`` readings has
   the mean of their variances over ``n``; a grid sample interpolated between two readings at fraction
   ``a`` has ``(1-a)^2`` and ``a^2`` of theirs.
4. The residual of each row is linearised in the channels it is made of (errors in the dependent and
   the independent variables, e.g. the shaft torque in both ``eta`` and ``C`` of a coast point, the
   caliper pressure in a brake gain), which gives a per-row variance ``s_i^2``; the estimator's
   covariance is the sandwich ``(A'WA)^-1 A'W diag(s^2) W A (A'WA)^-1`` (``sigma^2 (A'A)^-1`` for equal
   rows and no weights). The motor's Willans fits (noisy power products inside a normalised design, and
   derived parameters) are linearised by differentiating the identification's own fit at the planned
   points instead (the delta method on the same estimator).

5. Where the rows of a fit themselves change with the seed, the plan models that from the setup: a bench
   whose pressure polls can fail (declared timeout and exception rates) splits steady braking windows at
   random, so the brake gains add the variance of the noise-free estimate over draws of those faults
   (:mod:`benchtwin.studies.plan_brakes`). The torque converter's two linear fits are propagated at the
   identification's own points and kept rows (:mod:`benchtwin.studies.plan_converter`).
6. The extension fits (``battery.rc``, ``soc_per_ah``, ``motor.loss``, ``engine.can_torque``) are planned in
   :mod:`benchtwin.studies.plan_extensions`: linearised where the estimator is linear or smooth, by draws of the
   readings through the identification's own fit where it searches (the RC time constants, the drag's terms).

The prediction is the spread of the estimates over seeds of the sensor noise on one plant run, the
figure a sweep over seeds measures; it holds no bias (gain and offset errors, model error) and no
lack of fit (the identification's own standard errors carry the residual scatter, which includes it).

Parameters whose fit will not get the points it needs are flagged *not identifiable*, with the reason
and the test to add in the campaign's TOML terms; so is each region of the motor map (side, speed band,
torque level: :mod:`benchtwin.studies.plan_motor_regions`) no planned steady point visits. A family that
reads no channel with a random error on the setup (engine, road load and shift lines on the paper bench) gets
a standard error of 0: the same estimate for every seed.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from benchtwin.chain.batch import run_batch
from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.setup import SetupConfig
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.emulator.cache import cached_campaign
from benchtwin.recording import Channel, Recording
from benchtwin.studies.plan_brakes import BRAKES_SEARCHED, plan_brakes
from benchtwin.studies.plan_converter import CONVERTER_RECORDED, plan_converter
from benchtwin.studies.plan_drag import plan_drag
from benchtwin.studies.plan_extensions import plan_battery_rc, plan_can_torque, plan_motor_loss, plan_soc_slope
from benchtwin.studies.plan_fits import (
    PlannedParameter,
    plan_battery,
    plan_motor,
    plan_presence,
    plan_shifts,
    plan_transmission,
)
from benchtwin.studies.plan_motor_regions import plan_motor_regions
from benchtwin.studies.plan_noise import (
    noise_budget,
    poll_fault_model,
    reading_variance,
    sensor_response,
    truth_recording,
)
from benchtwin.studies.plan_windows import SEARCHED
from benchtwin.trace import Trace
from benchtwin.validation.families import (
    FAMILIES,
    FAMILY_CHUNK_S,
    family_spans,
    merge_recordings,
    resolve_families,
    span_seed,
)

__all__ = ["Plan", "PlannedParameter", "plan_campaign", "planned_recording", "reading_variance", "truth_recording"]

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
        w = max([40, *(len(p.name) for p in self.parameters)])  # the name column as wide as the longest name
        head = f"{'parameter':{w}s} {'value':>11s} {'pred. SE':>10s} {'rel. SE':>9s}  ident.  reason / test to add"
        lines = [f"plan of campaign {self.meta.get('campaign')!r} on setup {self.meta.get('setup')!r} "
                 f"(vehicle {self.meta.get('vehicle')!r})", head, "-" * len(head)]
        for p in self.parameters:
            note = p.reason + (f" -> {p.suggestion}" if p.suggestion else "")
            lines.append(f"{p.name:{w}s} {_fmt(p.value):>11s} {_fmt(p.se):>10s} "
                         f"{(f'{p.rel_se:.2%}' if math.isfinite(p.rel_se) else '-'):>9s}  "
                         f"{'yes' if p.identifiable else 'NO':6s}  {note}")
        n_no = sum(not p.identifiable for p in self.parameters)
        lines.append(f"{len(self.parameters)} parameters, {n_no} not identifiable with the planned tests")
        return "\n".join(lines)


def _fmt(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x:.4g}"



def planned_recording(setup: SetupConfig, campaign: CampaignConfig, trace: Trace,
                      families: Iterable[str] | None = None, *, recorded: Iterable[str] = ()
                      ) -> tuple[Recording, dict[str, Channel]]:
    """The noise-free Recording a plan works on: the bench's timestamps and flags, every channel its truth.

    The batch chain runs over the tests of the kinds the families need (with every family, None, also over
    the cycles), each contiguous run of tests with the seed a family run of the validation gives it. The
    channels named in ``recorded`` are also returned as the bench recorded them (role -> Channel).
    """
    fams = resolve_families(families) or list(FAMILIES.values())
    truth, _noise = noise_budget(setup)
    kinds = {k for f in fams for k in f.kinds}
    if families is None:
        kinds.add("cycle")  # the whole identification also reads a campaign's cycles (shift events, steady points)
    spans = family_spans(trace.segments, kinds)
    if not spans:
        return Recording(segments=list(trace.segments)), {}
    # in chunks of FAMILY_CHUNK_S, not one per test: the same Recording (any cut gives it), less per-chunk cost
    recs = [run_batch(trace.slice_time(a, b), setup, seed=span_seed(campaign.seed, k), chunk_s=FAMILY_CHUNK_S)
            for k, (a, b) in enumerate(spans)]
    merged = merge_recordings(recs)
    return truth_recording(merged, trace, truth), {n: merged[n] for n in recorded if n in merged}


def plan_campaign(vehicle: VehicleConfig, setup: SetupConfig, campaign: CampaignConfig, *,
                  trace: Trace | None = None, cache: bool | str = True,
                  families: Iterable[str] | None = None) -> Plan:
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
        Identification families to plan (:data:`~benchtwin.validation.families.FAMILIES`; default all).
        The chain runs over the tests of the kinds they need, as a family run of the validation does;
        with every family (None) over those and the cycles, as the whole identification reads them.

    Returns
    -------
    Plan

    Raises
    ------
    ConfigError
        An unknown family.
    """
    fams = resolve_families(families) or list(FAMILIES.values())
    # a conventional car: no motor or pack to plan for, and no coast line (its only negative gearbox input is
    # the engine's overrun drag, one torque per speed; validation expects none either)
    unplanned = [f.name for f in fams if not vehicle.has_motor and f.name in ("motor", "battery")]
    fams = [f for f in fams if f.name not in unplanned]
    names = [f.name for f in fams]
    if trace is None:
        if cache is False:
            from benchtwin.emulator import simulate_campaign
            trace = simulate_campaign(vehicle, campaign)
        else:
            trace, _hit = cached_campaign(vehicle, campaign, directory=None if cache is True else cache)
    _truth, noise = noise_budget(setup)
    plan = Plan(meta={"vehicle": vehicle.name, "setup": setup.name, "campaign": campaign.name,
                      "seed": campaign.seed, "families": names,
                      "noise": {k: {"noise_std": v.sigma, "step": v.q} for k, v in sorted(noise.items())}})
    if unplanned:
        plan.meta["not_planned"] = {n: "a conventional car has no motor or HV pack" for n in unplanned}
    segments = list(trace.segments)
    conv = any(f.name == "torque_converter" for f in fams)
    tx = any(f.name in ("transmission", "torque_converter") for f in fams)
    rec, raw = planned_recording(setup, campaign, trace, families,
                                 recorded=(CONVERTER_RECORDED if conv else ()) + (SEARCHED if tx else ())
                                 + (BRAKES_SEARCHED if any(f.name == "brakes" for f in fams) else ()))
    # what each noisy reading the window search and the converter read measures (filter, clock, latency)
    sensed = sensor_response(rec, trace, setup, [n for n in (*SEARCHED, *CONVERTER_RECORDED) if n in noise]) \
        if tx else {}
    for fam in fams:
        if fam.name == "transmission":
            kept: dict[str, Any] = {}
            plan.parameters += plan_transmission(rec, vehicle, noise, segments, recorded=raw, sensed=sensed,
                                                 keep=kept)
            plan.parameters += plan_can_torque(rec, vehicle, noise)
            if kept.get("points") is not None:
                plan.parameters += plan_drag(rec, vehicle.specs, noise, kept["points"], kept["drawn"],
                                             recorded=raw, sensed=sensed)
        elif fam.name == "battery":
            plan.parameters += plan_battery(rec, vehicle, noise, segments)
            plan.parameters += [plan_soc_slope(rec, noise, segments), *plan_battery_rc(rec, vehicle, noise, segments)]
        elif fam.name == "brakes":
            # the searched readings as the bench reads them: the sensor's response where noisy, else the bench's
            # own readings (free of random error: the same on every seed)
            seen = sensor_response(rec, trace, setup, [n for n in BRAKES_SEARCHED if n in noise])
            seen.update({n: ch for n, ch in raw.items() if n in BRAKES_SEARCHED and n not in noise})
            plan.parameters += plan_brakes(rec, vehicle, noise, segments, poll_fault_model(setup), sensed=seen)
        elif fam.name == "motor":
            plan.parameters += plan_motor(rec, vehicle, noise, segments)
            plan.parameters += plan_motor_loss(rec, vehicle, noise)
            regions, plan.meta["motor_regions"] = plan_motor_regions(rec, vehicle.specs)
            plan.parameters += regions
        elif fam.name == "torque_converter":
            planned = [p for p in plan.parameters if p.name.startswith("transmission.")] or \
                plan_transmission(rec, vehicle, noise, segments, recorded=raw, sensed=sensed)
            plan.parameters += plan_converter(rec, vehicle, noise, segments, planned,
                                              recorded=raw, sensed=sensed)
        elif fam.name == "shifts":
            plan.parameters += plan_shifts(rec, len(vehicle.specs.gear_ratios), noise, fam.roles())
        else:
            plan.parameters += plan_presence(fam.name, segments, noise, fam.roles())
    if not vehicle.has_motor:
        plan.parameters = [p for p in plan.parameters if "_coast." not in p.name]
    return plan
