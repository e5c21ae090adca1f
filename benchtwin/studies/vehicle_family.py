"""A family of random, physically plausible P2 PHEVs: the ranges, one drawing procedure, and the campaigns
that follow a drawn vehicle's gear count.

The paper vehicle's file with its identified parameters redrawn inside :data:`RANGES` (8- and 9-speed ratio
sets, per-gear eta_m and C0, Willans lines, battery alpha/beta, torque converters by stall torque ratio and
coupling point, diesel and petrol BSFC shapes, shift lines that follow the ratios, brake shares, road loads of
small cars to SUVs), validated by :class:`~benchtwin.config.vehicle.VehicleConfig` like a user's file.

One procedure, :func:`build_vehicle`, draws every value through a :class:`Drawer` (``uniform``, ``choice``,
``integer``): :func:`random_vehicle` gives it a seeded numpy generator (the sweep file's
``[axes.vehicle] random = {count, seed}``); the hypothesis strategies of the property tests give it their
``draw`` (tests/properties/strategies.py), so both draw from the same ranges in the same order.

A paper campaign's ramp-ups name the paper (9-speed) vehicle's gears; :func:`follow_gears` moves each to the
drawn vehicle's gear :func:`vehicle_gear` at the speed where the motor turns as fast as on the reference vehicle.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from typing import Any, Protocol, TypeVar

import numpy as np

from benchtwin.config import load_vehicle
from benchtwin.config.campaign import CampaignConfig, RampUpTest
from benchtwin.config.vehicle import VehicleConfig

__all__ = ["FUELS", "GEAR_COUNTS", "RANGES", "Drawer", "NumpyDrawer", "bsfc_map", "build_vehicle", "follow_gears",
           "move_ramp_up", "random_family", "random_vehicle", "vehicle_gear"]

T = TypeVar("T")

#: the gear counts and fuels a drawn vehicle takes
GEAR_COUNTS: tuple[int, ...] = (8, 9)
FUELS: tuple[str, ...] = ("diesel", "petrol")

#: every drawn value's range (low, high), uniform; the names are those of :func:`build_vehicle`'s steps
RANGES: dict[str, tuple[float, float]] = {
    # ratio set: first and top gear, and the warp of the geometric progression (larger steps in low gears)
    "first_ratio": (4.4, 5.5), "top_ratio": (0.55, 0.70), "ratio_warp": (0.75, 0.95),
    "wheel_radius_m": (0.31, 0.37),
    # the final drive puts 120 km/h in top gear at this engine speed
    "top_gear_rpm_at_120": (1700.0, 2300.0),
    "test_mass_kg": (1300.0, 2600.0), "n_cells_series": (80, 110),
    # transmission, per gear
    "eta_m": (0.90, 0.99), "c0_nm": (2.0, 12.0),
    # motor Willans lines
    "willans_e": (0.92, 0.97), "willans_w_loss_w": (400.0, 1000.0),
    "willans_e_gen": (0.92, 0.97), "willans_w_loss_gen_w": (300.0, 800.0),
    # battery
    "alpha": (0.95, 1.05), "beta_discharge": (0.9, 1.5), "beta_charge": (0.9, 1.5),
    # torque converter: pump capacity a0..a2, stall torque ratio, coupling point, turbine a4, coupling a8
    "tc_a0": (5.5e-3, 1.0e-2), "tc_a1": (0.0, 8e-4), "tc_a2": (-4.5e-3, -2.0e-3), "tc_stall_ratio": (1.7, 2.5),
    "tc_coupling_point": (0.80, 0.92), "tc_a4": (-8e-3, -3e-3), "tc_a8": (-4e-3, 4e-3),
    # BSFC shapes (g/kWh, rpm, bar)
    "diesel_bsfc_min": (200.0, 222.0), "diesel_n_opt": (1600.0, 2400.0), "diesel_b_opt": (13.0, 19.0),
    "diesel_fmep": (1.2, 2.0), "diesel_k_speed": (0.01, 0.04), "diesel_k_high": (5e-4, 2e-3),
    "petrol_bsfc_min": (228.0, 255.0), "petrol_n_opt": (2000.0, 3000.0), "petrol_b_opt": (9.0, 14.0),
    "petrol_fmep": (1.6, 2.6), "petrol_k_speed": (0.02, 0.06), "petrol_k_high": (5e-4, 2e-3),
    "petrol_enrich_bar": (15.0, 20.0), "petrol_enrich_per_bar": (0.03, 0.08),
    # shift lines: upshift engine speeds at 0 and 100 % pedal, downshift lines as fractions of the upshift's
    "shift_rpm_low": (1500.0, 1900.0), "shift_rpm_high": (3200.0, 4000.0),
    "down_frac": (0.55, 0.75), "down_slope_frac": (0.6, 0.8),
    # brakes: front share of the total gain (Nm/bar)
    "brake_front_share": (0.55, 0.75), "brake_total_nm_per_bar": (60.0, 90.0),
    # road load: size 0 (small car) .. 1 (SUV), with scatter around the size's line
    "size": (0.0, 1.0), "f0_scatter_n": (-15.0, 15.0), "f1_n_per_kmh": (0.2, 1.0), "f2_scatter": (-0.002, 0.002),
    "parasitic_f0_frac": (0.2, 0.4), "parasitic_f1_frac": (0.1, 0.4),
}


class Drawer(Protocol):
    """Where the values come from: a seeded generator, or a hypothesis ``draw``."""

    def uniform(self, lo: float, hi: float) -> float:
        """A float in [lo, hi]."""
        ...  # pragma: no cover

    def choice(self, options: Sequence[T]) -> T:
        """One of ``options``."""
        ...  # pragma: no cover

    def integer(self, lo: int, hi: int) -> int:
        """An integer in [lo, hi] (both included)."""
        ...  # pragma: no cover


class NumpyDrawer:
    """A :class:`Drawer` on a numpy generator."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def uniform(self, lo: float, hi: float) -> float:
        """A float in [lo, hi)."""
        return float(self.rng.uniform(lo, hi))

    def choice(self, options: Sequence[T]) -> T:
        """One of ``options``, equally likely."""
        return options[int(self.rng.integers(len(options)))]

    def integer(self, lo: int, hi: int) -> int:
        """An integer in [lo, hi]."""
        return int(self.rng.integers(lo, hi + 1))


def _r(d: Drawer, name: str) -> float:
    return d.uniform(*RANGES[name])


def _ratio_set(d: Drawer, n: int) -> list[float]:
    first = _r(d, "first_ratio")
    top = _r(d, "top_ratio")
    warp = _r(d, "ratio_warp")
    x = (np.arange(n) / (n - 1)) ** warp
    r = np.exp(np.log(first) + x * (np.log(top) - np.log(first)))
    return [round(float(v), 3) for v in r]


def _torque_converter(d: Drawer) -> dict[str, Any]:
    """a0..a8 from a stall torque ratio and a coupling point, continuous at the point (redrawn until plausible)."""
    for _ in range(50):
        a0 = _r(d, "tc_a0")
        a1 = _r(d, "tc_a1")
        a2 = _r(d, "tc_a2")
        stall = _r(d, "tc_stall_ratio")
        gamma = _r(d, "tc_coupling_point")
        a3 = stall * a0
        a4 = _r(d, "tc_a4")
        pump_g = a0 + a1 * gamma + a2 * gamma**2
        a5 = (pump_g - a3 - a4 * gamma) / gamma**2
        a8 = _r(d, "tc_a8")
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


def build_vehicle(d: Drawer, n: int, kind: str, base: VehicleConfig | None = None) -> VehicleConfig:
    """A physically plausible P2 PHEV of ``n`` gears and fuel ``kind``: ``base`` (default: the paper vehicle)
    with every value of :data:`RANGES` drawn from ``d``, in a fixed order.

    Raises
    ------
    ValueError
        ``n`` not in :data:`GEAR_COUNTS` or ``kind`` not in :data:`FUELS`.
    """
    if n not in GEAR_COUNTS or kind not in FUELS:
        raise ValueError(f"a drawn vehicle has {' or '.join(map(str, GEAR_COUNTS))} gears and burns "
                         f"{' or '.join(FUELS)}, not {n} gears / {kind!r}")
    d0 = copy.deepcopy((base if base is not None else load_vehicle()).model_dump())
    sp = d0["specs"]
    sp["gear_ratios"] = _ratio_set(d, n)
    sp["wheel_radius_m"] = _r(d, "wheel_radius_m")
    n_top = _r(d, "top_gear_rpm_at_120")
    v = 120.0 / 3.6
    sp["final_drive_ratio"] = round(n_top * math.pi / 30.0 * sp["wheel_radius_m"] / (v * sp["gear_ratios"][-1]), 3)
    sp["test_mass_kg"] = _r(d, "test_mass_kg")
    sp["n_cells_series"] = d.integer(*(int(x) for x in RANGES["n_cells_series"]))
    if kind == "petrol":
        sp["fuel_lhv_j_per_kg"] = 43.0e6
    d0["name"] = f"drawn {n}-speed {kind}"

    tx = d0["transmission"]
    tx["eta_m"] = [_r(d, "eta_m") for _ in range(n)]
    tx["c0_nm"] = [_r(d, "c0_nm") for _ in range(n)]

    m = d0["motor"]
    for k in ("willans_e", "willans_w_loss_w", "willans_e_gen", "willans_w_loss_gen_w"):
        m[k] = _r(d, k)

    b = d0["battery"]
    for k in ("alpha", "beta_discharge", "beta_charge"):
        b[k] = _r(d, k)

    d0["torque_converter"].update(_torque_converter(d))

    en = d0["engine"]
    p = kind
    shape = {"bsfc_min": _r(d, f"{p}_bsfc_min"), "n_opt": _r(d, f"{p}_n_opt"), "b_opt": _r(d, f"{p}_b_opt"),
             "fmep_bar": _r(d, f"{p}_fmep"), "k_speed": _r(d, f"{p}_k_speed"), "k_high": _r(d, f"{p}_k_high")}
    if kind == "petrol":
        shape.update(enrich_bar=_r(d, "petrol_enrich_bar"), enrich_per_bar=_r(d, "petrol_enrich_per_bar"))
    en["bsfc_g_per_kwh"] = bsfc_map(kind, en["bsfc_speed_rpm"], en["bsfc_bmep_bar"], **shape)

    # shift lines that follow the ratios: an upshift g -> g+1 at an engine speed rising with the pedal
    ratios, fd, r = sp["gear_ratios"], sp["final_drive_ratio"], sp["wheel_radius_m"]

    def kmh(rpm: float, g: int) -> float:
        return rpm * math.pi / 30.0 / (ratios[g] * fd) * r * 3.6

    n_low, n_high = _r(d, "shift_rpm_low"), _r(d, "shift_rpm_high")
    down_frac, down_slope_frac = _r(d, "down_frac"), _r(d, "down_slope_frac")
    sh = d0["shift_schedule"]
    sh["up_v0_kmh"] = [round(kmh(n_low, g), 2) for g in range(n - 1)]
    sh["up_slope_kmh_per_pct"] = [round((kmh(n_high, g) - kmh(n_low, g)) / 100.0, 4) for g in range(n - 1)]
    sh["down_v0_kmh"] = [round(v * down_frac, 2) for v in sh["up_v0_kmh"]]
    sh["down_slope_kmh_per_pct"] = [round(s * down_slope_frac, 4) for s in sh["up_slope_kmh_per_pct"]]

    br = d0["brakes"]
    kf = _r(d, "brake_front_share")
    total = _r(d, "brake_total_nm_per_bar")
    br["gain_front_nm_per_bar"] = kf * total
    br["gain_rear_nm_per_bar"] = (1.0 - kf) * total

    rl = d0["road_load"]
    size = _r(d, "size")
    rl["f0_n"] = 90.0 + 170.0 * size + _r(d, "f0_scatter_n")
    rl["f1_n_per_kmh"] = _r(d, "f1_n_per_kmh")
    rl["f2_n_per_kmh2"] = 0.020 + 0.022 * size + _r(d, "f2_scatter")
    rl["parasitic_f0_n"] = rl["f0_n"] * _r(d, "parasitic_f0_frac")
    rl["parasitic_f1_n_per_kmh"] = rl["f1_n_per_kmh"] * _r(d, "parasitic_f1_frac")
    return VehicleConfig.model_validate(d0)


def random_vehicle(seed: int | Sequence[int], *, gears: Sequence[int] = GEAR_COUNTS,
                   fuels: Sequence[str] = FUELS, base: VehicleConfig | None = None) -> VehicleConfig:
    """One vehicle drawn by a numpy generator seeded with ``seed``: its gear count from ``gears``, its fuel
    from ``fuels``, then :func:`build_vehicle`. The same seed gives the same vehicle."""
    d = NumpyDrawer(np.random.default_rng(seed))
    n = d.choice(list(gears))
    kind = d.choice(list(fuels))
    return build_vehicle(d, int(n), str(kind), base)


def random_family(count: int, seed: int, *, gears: Sequence[int] = GEAR_COUNTS, fuels: Sequence[str] = FUELS,
                  base: VehicleConfig | None = None) -> list[VehicleConfig]:
    """``count`` vehicles; vehicle i is :func:`random_vehicle` of the seed ``(seed, i)``, so a larger count
    keeps the smaller family's vehicles. Each is named ``random-i (drawn N-speed FUEL, seed S)``."""
    out = []
    for i in range(count):
        v = random_vehicle([int(seed), i], gears=gears, fuels=fuels, base=base)
        out.append(v.model_copy(update={"name": f"random-{i} ({v.name}, seed {seed})"}))
    return out


def vehicle_gear(paper_gear: int, n_gears: int) -> int:
    """The gear of an n-speed vehicle that takes the place of a paper (9-speed) ramp-up's gear."""
    return max(1, min(n_gears, round(paper_gear * n_gears / 9)))


def move_ramp_up(test: RampUpTest, reference: VehicleConfig, vehicle: VehicleConfig) -> RampUpTest:
    """A ramp-up of ``reference``'s gear g moved to ``vehicle``'s gear :func:`vehicle_gear`, at the speed where
    the motor turns as fast as on ``reference`` (capped at 180 km/h)."""
    pv, sp = reference.specs, vehicle.specs
    g = vehicle_gear(test.gear, vehicle.n_gears)
    em_radps = test.speed_kmh / 3.6 / pv.wheel_radius_m * pv.final_drive_ratio * pv.gear_ratios[test.gear - 1]
    v = em_radps * sp.wheel_radius_m / (sp.final_drive_ratio * sp.gear_ratios[g - 1]) * 3.6
    return test.model_copy(update={"gear": g, "speed_kmh": round(min(v, 180.0), 1), "name": f"{test.name}_as_g{g}"})


def follow_gears(campaign: CampaignConfig, vehicle: VehicleConfig,
                 reference: VehicleConfig | None = None) -> CampaignConfig:
    """``campaign`` (written for ``reference``, default the paper vehicle) with every ramp-up moved to
    ``vehicle`` by :func:`move_ramp_up`; the other tests unchanged, in their order."""
    ref = reference if reference is not None else load_vehicle()
    tests = [move_ramp_up(t, ref, vehicle) if isinstance(t, RampUpTest) else t for t in campaign.tests]
    return campaign.model_copy(update={"tests": tests})
