"""Hypothesis strategies for the property tests: setups, vehicles and the campaigns that follow them.

Setups are the paper bench with its imperfections redrawn: per-sensor noise 0-3x the paper's, offsets and
gain errors within and beyond the data sheets, the telemetry AD converter's bits (10-12; the IVT-S shunts stay at
their 16 bits: at 14 bits and no noise the HPCU shunt's step biases the DC/DC efficiency by 5 %, which the
validation's tolerance for it does not yet state), the K_TEL
position, rates,
frame-drop and poll-fault rates, clock drift up to +-100 ppm. Vehicles are the paper vehicle's file with
its identified parameters redrawn inside physically plausible ranges (8- and 9-speed ratio sets, per-gear
eta_m and C0, Willans lines, battery alpha/beta, torque converters by stall torque ratio and coupling point,
diesel and petrol BSFC shapes, shift lines that follow the ratios, brake shares, road loads of small cars to
SUVs), validated by :class:`~benchtwin.config.vehicle.VehicleConfig` like a user's file: the ranges and the
drawing procedure are the package's (:mod:`benchtwin.studies.vehicle_family`, also behind a sweep file's random
vehicle family), fed here by hypothesis's ``draw`` (same ranges, same order of draws as before the move).
Campaigns are the paper campaign's tests of a family's kinds, with the ramp-ups moved to the drawn vehicle's gears
and speeds.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import strategies as st

from benchtwin.config import load_campaign, load_vehicle, scenario_path
from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.setup import K_TEL_STEPS, SetupConfig, load_setup
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.sensors.telemetry import torque_step_nm
from benchtwin.studies.vehicle_family import (  # noqa: F401  (bsfc_map, vehicle_gear: re-exported)
    FUELS,
    GEAR_COUNTS,
    bsfc_map,
    build_vehicle,
    move_ramp_up,
    vehicle_gear,
)

PAPER_VEHICLE: VehicleConfig = load_vehicle()
PAPER_SETUP: SetupConfig = load_setup(scenario_path("setups", "paper.toml"))
IDEAL_SETUP: SetupConfig = load_setup(scenario_path("setups", "ideal.toml"))
PAPER_CAMPAIGN: CampaignConfig = load_campaign(scenario_path("campaigns", "paper.toml"))


def _u(lo: float, hi: float) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


# ------------------------------------------------------------------------------------------------ setups
@dataclass(frozen=True)
class DrawnSetup:
    """A drawn setup and the figures it was drawn from (for the tolerance of a property).

    Attributes
    ----------
    setup:
        The validated setup.
    noise:
        Multiplier of every sensor's noise standard deviation against the paper setup (0-3).
    beyond_sheet:
        Whether the gain and offset errors were drawn beyond the data sheets (up to 3x).
    """

    setup: SetupConfig
    noise: float
    beyond_sheet: bool


def _scale_errors(errors: dict[str, Any], noise: float, sys_scale: float, sign: float) -> None:
    if "noise_std" in errors:
        errors["noise_std"] = errors["noise_std"] * noise
    for k in ("offset", "gain_error_frac"):
        if k in errors:
            errors[k] = errors[k] * sys_scale * sign


@st.composite
def setups(draw: st.DrawFn, *, max_noise: float = 3.0, faults: bool = True) -> DrawnSetup:
    """A realistic bench: the paper setup with noise, systematic errors, converter, rates and link faults redrawn.

    Parameters
    ----------
    max_noise:
        Upper bound of the noise multiplier.
    faults:
        Draw frame-drop and poll-fault rates (else none).
    """
    d = PAPER_SETUP.model_dump()
    noise = draw(_u(0.0, max_noise))
    beyond = draw(st.booleans())
    sys_scale = draw(_u(1.0, 3.0)) if beyond else draw(_u(0.0, 1.0))

    def link(lk: dict[str, Any] | None) -> dict[str, Any]:
        lk = dict(lk or {})
        lk["clock_drift_ppm"] = draw(_u(-100.0, 100.0))
        if faults and "drop_prob" in lk:
            lk["drop_prob"] = draw(_u(0.0, 2e-3))
        elif "drop_prob" in lk:
            lk["drop_prob"] = 0.0
        return lk

    for ivt in d["ivt"].values():
        sign = draw(st.sampled_from([-1.0, 1.0]))
        _scale_errors(ivt["current_errors"], noise, sys_scale, sign)
        _scale_errors(ivt["voltage_errors"], noise, sys_scale, sign)
        ivt["link"] = link(ivt.get("link"))
    p = d["pressure"]
    _scale_errors(p["errors"], noise, sys_scale, draw(st.sampled_from([-1.0, 1.0])))
    p["link"] = link(p.get("link"))
    p["poll_hz"] = draw(st.sampled_from([50.0, 100.0]))
    p["timeout_prob"] = draw(_u(0.0, 2e-3)) if faults else 0.0
    p["exception_prob"] = draw(_u(0.0, 1e-3)) if faults else 0.0
    t = d["telemetry"]
    _scale_errors(t["errors"], noise, sys_scale, draw(st.sampled_from([-1.0, 1.0])))
    t["link"] = link(t.get("link"))
    t["k_tel"] = draw(st.sampled_from(K_TEL_STEPS))
    t["rate_hz"] = draw(st.sampled_from([250.0, 500.0, 1000.0]))
    # the telemetry AD module is 12-bit on the wire; a coarser converter (10 or 11 bits) is declared as an extra
    # quantisation step of 4 or 2 wire steps
    bits = draw(st.sampled_from([10, 11, 12]))
    if bits < 12:
        t["errors"]["quantisation_step"] = torque_step_nm(PAPER_SETUP.telemetry.shaft, t["k_tel"]) * 2 ** (12 - bits)
    d["thermo"]["link"] = link(d["thermo"].get("link"))
    _scale_errors(d["thermo"]["errors"], noise, sys_scale, 1.0)
    for e in d["vehicle_can"]["errors"].values():
        _scale_errors(e, noise, sys_scale, draw(st.sampled_from([-1.0, 1.0])))
    d["name"] = "drawn"
    return DrawnSetup(SetupConfig.model_validate(d), noise, beyond)


# ---------------------------------------------------------------------------------------------- vehicles
class _HypothesisDrawer:
    """The package's :class:`~benchtwin.studies.vehicle_family.Drawer` on a hypothesis ``draw``: the vehicle
    family's ranges and drawing order, shrinkable by hypothesis."""

    def __init__(self, draw: st.DrawFn) -> None:
        self.draw = draw

    def uniform(self, lo: float, hi: float) -> float:
        return self.draw(_u(lo, hi))

    def choice(self, options: Any) -> Any:
        return self.draw(st.sampled_from(options))

    def integer(self, lo: int, hi: int) -> int:
        return self.draw(st.integers(lo, hi))


@st.composite
def vehicles(draw: st.DrawFn, *, gears: st.SearchStrategy[int] | None = None,
             fuel: st.SearchStrategy[str] | None = None) -> VehicleConfig:
    """A physically plausible P2 PHEV (:func:`benchtwin.studies.vehicle_family.build_vehicle`), validated as a
    vehicle file would be."""
    n = draw(gears if gears is not None else st.sampled_from(list(GEAR_COUNTS)))
    kind = draw(fuel if fuel is not None else st.sampled_from(list(FUELS)))
    return build_vehicle(_HypothesisDrawer(draw), n, kind, PAPER_VEHICLE)


# --------------------------------------------------------------------------------------------- campaigns
def campaign_for(vehicle: VehicleConfig, kinds: tuple[str, ...], *, seed: int, gears: set[int] | None = None,
                 modes: set[str] | None = None, max_ramp_ups: int | None = None,
                 max_drive_s: float | None = None,
                 caps: dict[str, dict[str, float]] | None = None) -> CampaignConfig:
    """The paper campaign's tests of ``kinds``, moved to ``vehicle``: ramp-ups follow its gears and ratios.

    A paper ramp-up in gear g becomes one in gear :func:`vehicle_gear` of the vehicle, at the speed where the
    motor turns as fast as on the paper vehicle (capped at 180 km/h), so the campaign follows the gear count.
    ``gears`` (the vehicle's) and ``modes`` keep only those ramp-ups; ``max_ramp_ups`` then keeps that many,
    spread over the list. ``max_drive_s`` caps the duration of each constant drive (the paper's run until a
    displayed SOC, 40-60 minutes). ``caps`` shortens the tests of a kind: kind -> {field: upper bound} (e.g.
    ``{"coastdown": {"max_duration_s": 10.0}}``), each field set to the lower of its value and the bound.
    """
    n = vehicle.n_gears
    ramps = {}
    for i, t in enumerate(PAPER_CAMPAIGN.tests):
        if t.kind != "ramp_up" or "ramp_up" not in kinds:
            continue
        g = vehicle_gear(t.gear, n)
        if (gears is not None and g not in gears) or (modes is not None and t.mode not in modes):
            continue
        ramps[i] = move_ramp_up(t, PAPER_VEHICLE, vehicle)
    if max_ramp_ups is not None and len(ramps) > max_ramp_ups:
        keys = sorted(ramps)
        idx = sorted(set(np.linspace(0, len(keys) - 1, max_ramp_ups).round().astype(int).tolist()))
        ramps = {keys[i]: ramps[keys[i]] for i in idx}
    tests = []  # in the paper campaign's order (each test starts from the state the previous one left)
    for i, t in enumerate(PAPER_CAMPAIGN.tests):
        if t.kind == "ramp_up":
            if i in ramps:
                tests.append(ramps[i])
        elif t.kind in kinds:
            if t.kind == "constant_drive" and max_drive_s is not None:
                t = t.model_copy(update={"max_duration_s": min(t.max_duration_s, max_drive_s)})
            if caps and t.kind in caps:
                # validated again (a cap below a field's bound is an error, not a silently odd test)
                t = type(t).model_validate({**t.model_dump(), **{k: min(getattr(t, k), v)
                                                                 for k, v in caps[t.kind].items()}})
            tests.append(t)
    return PAPER_CAMPAIGN.model_copy(update={"tests": tests, "seed": int(seed),
                                             "name": f"paper {'+'.join(kinds)}"})


seeds = st.integers(0, 2**31 - 1)


#: what each family's property example runs of the paper campaign (the keywords of :func:`campaign_for`),
#: chosen to keep one example near a second: the transmission draws two gears instead
FAMILY_PICKS: dict[str, dict[str, Any]] = {
    "transmission": {"gears": {2, 5}},
    "motor": {"modes": {"electric", "charge"}, "max_ramp_ups": 4},
    "engine": {"modes": {"hybrid"}, "max_ramp_ups": 6},
    "battery": {"max_drive_s": 400.0},
    # the converter's own tests (FAMILIES["torque_converter"].kinds, about 5,800 s of plant) cut to where its
    # points are: ramp-ups of gears 1-3 only (the gears whose transmission models eq. 32 reads: the lock-up is
    # open in 1st and below ~18 km/h in 2nd, where the converter-mode points lie; gear 3 for the low-speed
    # shifts), the accelerations to 40 km/h and the ramp-downs from 40 km/h (the lock-up is closed above), the
    # coastdown's coast in neutral cut to 10 s (its run-up to 135 km/h, where coupling mode is reached, is
    # kept): about 1,700 s of plant. Cut further (one ramp-up per gear, or the decelerations from 50 km/h
    # as well) the loose 10-bit converter's coupling curve fails (6.9 % > 6 %, or not identified)
    "torque_converter": {"gears": {1, 2, 3}, "caps": {"acceleration": {"end_speed_kmh": 40.0},
                                                      "ramp_down": {"start_speed_kmh": 40.0},
                                                      "coastdown": {"max_duration_s": 10.0}}},
}

#: every test of the paper campaign but the cycle and the constant drives (about 6,000 s of plant): what the
#: converter's property example ran while the family's own tests were not enough (now FAMILY_PICKS); the pinned
#: converter findings of test_recovery still run it, as when they were found
TC_KINDS: tuple[str, ...] = ("ramp_up", "acceleration", "ramp_down", "deceleration", "neutral_braking",
                             "coastdown")


def pinned(name: str) -> tuple[VehicleConfig, DrawnSetup, int]:
    """A vehicle, setup and seed a property once failed on (``examples/<name>.json``), for its ``@example``."""
    d = json.loads((Path(__file__).parent / "examples" / f"{name}.json").read_text(encoding="utf-8"))
    return (VehicleConfig.model_validate(d["vehicle"]),
            DrawnSetup(SetupConfig.model_validate(d["setup"]), float(d["noise"]), bool(d["beyond_sheet"])),
            int(d["seed"]))


def pinned_gears(name: str) -> list[int]:
    """The gears a pinned transmission finding ran (``gears`` of ``examples/<name>.json``)."""
    d = json.loads((Path(__file__).parent / "examples" / f"{name}.json").read_text(encoding="utf-8"))
    return [int(g) for g in d["gears"]]
