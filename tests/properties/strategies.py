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
SUVs), validated by :class:`~benchtwin.config.vehicle.VehicleConfig` like a user's file. Campaigns are the
paper campaign's tests of a family's kinds, with the ramp-ups moved to the drawn vehicle's gears and speeds.
"""

from __future__ import annotations

import copy
import json
import math
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
def _ratio_set(draw: st.DrawFn, n: int) -> list[float]:
    first = draw(_u(4.4, 5.5))
    top = draw(_u(0.55, 0.70))
    # progressive steps (larger between the low gears), as real ratio sets: geometric in a warped index
    warp = draw(_u(0.75, 0.95))
    x = (np.arange(n) / (n - 1)) ** warp
    r = np.exp(np.log(first) + x * (np.log(top) - np.log(first)))
    return [round(float(v), 3) for v in r]


def _torque_converter(draw: st.DrawFn) -> dict[str, Any]:
    """a0..a8 from a stall torque ratio (1.7-2.5) and a coupling point (0.80-0.92), continuous at the point."""
    for _ in range(50):
        a0 = draw(_u(5.5e-3, 1.0e-2))
        a1 = draw(_u(0.0, 8e-4))
        a2 = draw(_u(-4.5e-3, -2.0e-3))
        stall = draw(_u(1.7, 2.5))
        gamma = draw(_u(0.80, 0.92))
        a3 = stall * a0
        a4 = draw(_u(-8e-3, -3e-3))
        pump_g = a0 + a1 * gamma + a2 * gamma**2
        a5 = (pump_g - a3 - a4 * gamma) / gamma**2
        a8 = draw(_u(-4e-3, 4e-3))
        a6 = pump_g / (1.0 - gamma) + a8 * gamma
        a7 = -a6 - a8
        sr = np.linspace(0.0, gamma, 60)
        tp = a0 + a1 * sr + a2 * sr**2
        tt = a3 + a4 * sr + a5 * sr**2
        tr = tt / tp
        src = np.linspace(gamma, 0.999, 30)
        coup = a6 + a7 * src + a8 * src**2
        if pump_g > 0 and np.all(tp > 0) and np.all(np.diff(tr) < 0) and tr[-1] > 0.99 and np.all(coup > 0):
            return {"a_nm_per_radps2": [a0, a1, a2, a3, a4, a5, a6, a7, a8], "coupling_speed_ratio": gamma}
    raise AssertionError("no plausible torque converter in 50 draws")  # pragma: no cover


def bsfc_map(kind: str, speed_rpm: list[float], bmep_bar: list[float], *, bsfc_min: float, n_opt: float,
             b_opt: float, fmep_bar: float, k_speed: float, k_high: float,
             enrich_bar: float | None = None, enrich_per_bar: float = 0.0) -> list[list[float]]:
    """A BSFC map (g/kWh, speed rows x BMEP columns) of a stated shape.

    Low load follows a Willans line, ``(BMEP + FMEP) / BMEP``; the speed term is parabolic around ``n_opt``;
    above ``b_opt`` it rises quadratically; a petrol engine adds full-load enrichment above ``enrich_bar``
    at high speed (a steep corner of the map).
    """
    n = np.asarray(speed_rpm, float)[:, None]
    b = np.asarray(bmep_bar, float)[None, :]
    low = (b + fmep_bar) / b / ((b_opt + fmep_bar) / b_opt)
    spd = 1.0 + k_speed * ((n - n_opt) / 1000.0) ** 2
    high = 1.0 + k_high * np.maximum(b - b_opt, 0.0) ** 2
    m = bsfc_min * low * spd * high
    if kind == "petrol" and enrich_bar is not None:
        corner = np.clip((n - 3000.0) / 1000.0, 0.0, 1.5)
        m = m * (1.0 + enrich_per_bar * np.maximum(b - enrich_bar, 0.0) * corner)
    return [[round(float(v), 1) for v in row] for row in m]


@st.composite
def vehicles(draw: st.DrawFn, *, gears: st.SearchStrategy[int] | None = None,
             fuel: st.SearchStrategy[str] | None = None) -> VehicleConfig:
    """A physically plausible P2 PHEV, validated as a vehicle file would be."""
    d = copy.deepcopy(PAPER_VEHICLE.model_dump())
    n = draw(gears if gears is not None else st.sampled_from([8, 9]))
    kind = draw(fuel if fuel is not None else st.sampled_from(["diesel", "petrol"]))
    sp = d["specs"]
    sp["gear_ratios"] = _ratio_set(draw, n)
    sp["wheel_radius_m"] = draw(_u(0.31, 0.37))
    # the final drive puts 120 km/h in top gear near 1700-2300 rpm
    n_top = draw(_u(1700.0, 2300.0))
    v = 120.0 / 3.6
    sp["final_drive_ratio"] = round(n_top * math.pi / 30.0 * sp["wheel_radius_m"] / (v * sp["gear_ratios"][-1]), 3)
    sp["test_mass_kg"] = draw(_u(1300.0, 2600.0))
    sp["n_cells_series"] = draw(st.integers(80, 110))
    if kind == "petrol":
        sp["fuel_lhv_j_per_kg"] = 43.0e6
    d["name"] = f"drawn {n}-speed {kind}"

    tx = d["transmission"]
    tx["eta_m"] = [draw(_u(0.90, 0.99)) for _ in range(n)]
    tx["c0_nm"] = [draw(_u(2.0, 12.0)) for _ in range(n)]

    m = d["motor"]
    m["willans_e"] = draw(_u(0.92, 0.97))
    m["willans_w_loss_w"] = draw(_u(400.0, 1000.0))
    m["willans_e_gen"] = draw(_u(0.92, 0.97))
    m["willans_w_loss_gen_w"] = draw(_u(300.0, 800.0))

    b = d["battery"]
    b["alpha"] = draw(_u(0.95, 1.05))
    b["beta_discharge"] = draw(_u(0.9, 1.5))
    b["beta_charge"] = draw(_u(0.9, 1.5))

    d["torque_converter"].update(_torque_converter(draw))

    en = d["engine"]
    if kind == "diesel":
        en["bsfc_g_per_kwh"] = bsfc_map("diesel", en["bsfc_speed_rpm"], en["bsfc_bmep_bar"],
                                        bsfc_min=draw(_u(200.0, 222.0)), n_opt=draw(_u(1600.0, 2400.0)),
                                        b_opt=draw(_u(13.0, 19.0)), fmep_bar=draw(_u(1.2, 2.0)),
                                        k_speed=draw(_u(0.01, 0.04)), k_high=draw(_u(5e-4, 2e-3)))
    else:
        en["bsfc_g_per_kwh"] = bsfc_map("petrol", en["bsfc_speed_rpm"], en["bsfc_bmep_bar"],
                                        bsfc_min=draw(_u(228.0, 255.0)), n_opt=draw(_u(2000.0, 3000.0)),
                                        b_opt=draw(_u(9.0, 14.0)), fmep_bar=draw(_u(1.6, 2.6)),
                                        k_speed=draw(_u(0.02, 0.06)), k_high=draw(_u(5e-4, 2e-3)),
                                        enrich_bar=draw(_u(15.0, 20.0)), enrich_per_bar=draw(_u(0.03, 0.08)))

    # shift lines that follow the ratios: an upshift g -> g+1 at an engine speed rising with the pedal
    ratios, fd, r = sp["gear_ratios"], sp["final_drive_ratio"], sp["wheel_radius_m"]

    def kmh(rpm: float, g: int) -> float:
        return rpm * math.pi / 30.0 / (ratios[g] * fd) * r * 3.6

    n_low, n_high = draw(_u(1500.0, 1900.0)), draw(_u(3200.0, 4000.0))
    down_frac, down_slope_frac = draw(_u(0.55, 0.75)), draw(_u(0.6, 0.8))
    sh = d["shift_schedule"]
    sh["up_v0_kmh"] = [round(kmh(n_low, g), 2) for g in range(n - 1)]
    sh["up_slope_kmh_per_pct"] = [round((kmh(n_high, g) - kmh(n_low, g)) / 100.0, 4) for g in range(n - 1)]
    sh["down_v0_kmh"] = [round(v * down_frac, 2) for v in sh["up_v0_kmh"]]
    sh["down_slope_kmh_per_pct"] = [round(s * down_slope_frac, 4) for s in sh["up_slope_kmh_per_pct"]]

    br = d["brakes"]
    kf = draw(_u(0.55, 0.75))
    total = draw(_u(60.0, 90.0))
    br["gain_front_nm_per_bar"] = kf * total
    br["gain_rear_nm_per_bar"] = (1.0 - kf) * total

    rl = d["road_load"]
    size = draw(_u(0.0, 1.0))  # small car .. SUV
    rl["f0_n"] = 90.0 + 170.0 * size + draw(_u(-15.0, 15.0))
    rl["f1_n_per_kmh"] = draw(_u(0.2, 1.0))
    rl["f2_n_per_kmh2"] = 0.020 + 0.022 * size + draw(_u(-0.002, 0.002))
    rl["parasitic_f0_n"] = rl["f0_n"] * draw(_u(0.2, 0.4))
    rl["parasitic_f1_n_per_kmh"] = rl["f1_n_per_kmh"] * draw(_u(0.1, 0.4))
    return VehicleConfig.model_validate(d)


# --------------------------------------------------------------------------------------------- campaigns
def vehicle_gear(paper_gear: int, n_gears: int) -> int:
    """The gear of an n-speed vehicle that takes the place of a paper (9-speed) ramp-up's gear."""
    return max(1, min(n_gears, round(paper_gear * n_gears / 9)))


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
    pv = PAPER_VEHICLE.specs
    sp = vehicle.specs
    n = vehicle.n_gears
    ramps = {}
    for i, t in enumerate(PAPER_CAMPAIGN.tests):
        if t.kind != "ramp_up" or "ramp_up" not in kinds:
            continue
        g = vehicle_gear(t.gear, n)
        if (gears is not None and g not in gears) or (modes is not None and t.mode not in modes):
            continue
        em_radps = t.speed_kmh / 3.6 / pv.wheel_radius_m * pv.final_drive_ratio * pv.gear_ratios[t.gear - 1]
        v = em_radps * sp.wheel_radius_m / (sp.final_drive_ratio * sp.gear_ratios[g - 1]) * 3.6
        ramps[i] = t.model_copy(update={"gear": g, "speed_kmh": round(min(v, 180.0), 1), "name": f"{t.name}_as_g{g}"})
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
