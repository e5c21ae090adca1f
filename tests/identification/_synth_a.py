"""Synthetic Recordings for identification tests, built directly from the model forms of docs/models.md.

Every Recording here is made the way an acquisition would deliver it: channels named by role, each
source on its own clock and rate (vehicle CAN 50 Hz, CAN states 10 Hz, IVT-S 50 Hz, shaft telemetry
and Modbus pressures 100 Hz, dyno 100 Hz), with a phase offset per source, optional Gaussian noise
per channel and quality flags. The plant behind them is evaluated at 100 Hz from the exact model
forms with the parameters in :class:`Truth`, so identification must give those back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import RegularGridInterpolator

from benchtwin.config.specs import VehicleSpecs
from benchtwin.recording import Channel, Recording
from benchtwin.roles import unit_of_role
from benchtwin.segments import Segment

RPM = 2 * math.pi / 60
PLANT_HZ = 100.0
#: the reference data shipped with the tests, each licence beside its data (tests/data/reference/README.md)
REFERENCE_DATA = Path(__file__).resolve().parents[1] / "data" / "reference"
MERCEDES = REFERENCE_DATA / "engine_mercedes_1p7" / "Mercedes1pt7_engine_steady_state_points.txt"

#: role -> (source, rate Hz)
SOURCES: dict[str, tuple[str, float]] = {
    **{r: ("vehicle_can", 50.0) for r in ("vehicle_speed_kmh", "engine_speed_rpm", "engine_torque_nm", "em_speed_rpm",
                                          "em_torque_nm", "fuel_mass_flow_gps", "pedal_pct", "brake_pedal_pct")},
    **{r: ("vehicle_can_states", 10.0) for r in ("gear_actual", "gear_target", "k0_closed", "lockup_closed",
                                                 "engine_on", "hybrid_mode")},
    "hpcu_current_a": ("ivt_hpcu", 50.0),
    "hpcu_voltage_v": ("ivt_hpcu", 50.0),
    "dcdc_lv_current_a": ("ivt_dcdc", 50.0),
    "dcdc_lv_voltage_v": ("ivt_dcdc", 50.0),
    "shaft_torque_nm": ("telemetry", 100.0),
    "dyno_speed_kmh": ("dyno", 100.0),
    "dyno_force_front_n": ("dyno", 100.0),
    "dyno_force_rear_n": ("dyno", 100.0),
    **{r: ("modbus_pressure", 100.0) for r in ("brake_pressure_fl_bar", "brake_pressure_fr_bar",
                                               "brake_pressure_rl_bar", "brake_pressure_rr_bar",
                                               "master_cylinder_bar")},
}
PHASE = {"vehicle_can": 0.0031, "vehicle_can_states": 0.017, "ivt_hpcu": 0.0072, "ivt_dcdc": 0.0113,
         "telemetry": 0.0009, "dyno": 0.0047, "modbus_pressure": 0.0023}
STATES = {"gear_actual", "gear_target", "k0_closed", "lockup_closed", "engine_on", "hybrid_mode"}

#: noise standard deviations of the noisy variants (per source sample)
NOISE = {"vehicle_speed_kmh": 0.05, "engine_speed_rpm": 2.0, "engine_torque_nm": 1.5, "em_speed_rpm": 2.0,
         "em_torque_nm": 1.0, "fuel_mass_flow_gps": 0.003, "hpcu_current_a": 0.3, "hpcu_voltage_v": 0.2,
         "dcdc_lv_current_a": 0.4, "dcdc_lv_voltage_v": 0.01, "shaft_torque_nm": 3.0, "dyno_speed_kmh": 0.02,
         "dyno_force_front_n": 8.0, "dyno_force_rear_n": 8.0, "brake_pressure_fl_bar": 0.1,
         "brake_pressure_fr_bar": 0.1, "brake_pressure_rl_bar": 0.1, "brake_pressure_rr_bar": 0.1}

SPECS = VehicleSpecs(gear_ratios=[5.35, 3.24, 2.25, 1.64, 1.21, 1.0, 0.86, 0.72, 0.60], final_drive_ratio=2.65,
                     wheel_radius_m=0.334, engine_displacement_m3=1.95e-3, n_cells_series=96,
                     em_rotor_radius_m=0.09, em_rotor_volume_m3=2.3e-3, test_mass_kg=2162.0)


def bsfc_truth(n_rpm: np.ndarray, bmep_bar: np.ndarray) -> np.ndarray:
    """A smooth diesel-like BSFC surface, g/kWh (minimum about 206 near 2100 rpm, 14 bar)."""
    return 183.0 + 4e-6 * (n_rpm - 2100.0) ** 2 + 0.25 * (bmep_bar - 14.0) ** 2 + 250.0 / (bmep_bar + 2.0)


@dataclass
class Truth:
    """The parameters the synthetic plant uses."""

    eta_m: dict[int, float] = field(default_factory=lambda: {g: 0.985 - 0.004 * abs(g - 6) for g in range(1, 10)})
    c0: dict[int, float] = field(default_factory=lambda: {g: 3.0 + 0.6 * g for g in range(1, 10)})
    e: float = 0.955
    w_loss: float = 1600.0
    e_gen: float = 0.935
    w_loss_gen: float = 1300.0
    eta_dcdc: float = 0.93
    bsfc_speed: np.ndarray = field(default_factory=lambda: np.arange(800.0, 4601.0, 200.0))
    bsfc_bmep: np.ndarray = field(default_factory=lambda: np.arange(0.5, 24.1, 0.5))
    f0: float = 171.5
    f1: float = 0.833
    f2: float = 0.0280
    m_f: float = 38.8
    m_r: float = 20.0
    c_f: float = 14.0
    c_r: float = 9.0

    @property
    def bsfc_table(self) -> np.ndarray:
        n, b = np.meshgrid(self.bsfc_speed, self.bsfc_bmep, indexing="ij")
        return bsfc_truth(n, b)

    def bsfc(self, n_rpm: np.ndarray, bmep_bar: np.ndarray) -> np.ndarray:
        """Bilinear in the grid, clamped outside (docs/models.md)."""
        f = RegularGridInterpolator((self.bsfc_speed, self.bsfc_bmep), self.bsfc_table)
        pts = np.column_stack([np.clip(n_rpm, self.bsfc_speed[0], self.bsfc_speed[-1]),
                               np.clip(bmep_bar, self.bsfc_bmep[0], self.bsfc_bmep[-1])])
        return f(pts)


def to_recording(t: np.ndarray, sig: dict[str, np.ndarray], *, noise: float = 0.0, seed: int = 0,
                 segments: list[Segment] | None = None) -> Recording:
    """Sample plant signals per source (own clock, rate, phase), add noise, build a Recording."""
    rng = np.random.default_rng(seed)
    rec = Recording(segments=list(segments or []))
    for role, x in sig.items():
        source, rate = SOURCES[role]
        ts = t[0] + PHASE[source] + np.arange(int((t[-1] - t[0] - PHASE[source]) * rate) + 1) / rate
        if role in STATES:
            idx = np.clip(np.searchsorted(t, ts, side="right") - 1, 0, t.size - 1)
            v = x[idx].astype(float)
        else:
            v = np.interp(ts, t, x)
            if noise:
                v = v + rng.normal(0.0, noise * NOISE.get(role, 0.0), v.size)
        rec.add(Channel(role, unit_of_role(role), ts, v, None, source))
    return rec


def _knots(holds: list[dict], hold_s: float, ramp_s: float, t: np.ndarray, key: str) -> np.ndarray:
    """Piecewise-linear plant signal: each hold flat for hold_s, linear ramps of ramp_s between."""
    tk, vk = [], []
    s = 0.0
    for h in holds:
        tk += [s, s + h.get("hold_s", hold_s)]
        vk += [h[key], h[key]]
        s += h.get("hold_s", hold_s) + ramp_s
    return np.interp(t, tk, vk)


def _steps(holds: list[dict], hold_s: float, ramp_s: float, t: np.ndarray, key: str) -> np.ndarray:
    """Discrete state: switches in the middle of each ramp."""
    edges, vals = [], []
    s = 0.0
    for h in holds:
        edges.append(s - ramp_s / 2)
        vals.append(h[key])
        s += h.get("hold_s", hold_s) + ramp_s
    idx = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(vals) - 1)
    return np.asarray(vals, dtype=float)[idx]


def trans_out(t_in: np.ndarray, gear: np.ndarray, truth: Truth, specs: VehicleSpecs = SPECS) -> np.ndarray:
    """Shaft torque from input torque (docs/models.md, drive, coast and dead band)."""
    ig = np.asarray(specs.gear_ratios)[gear.astype(int) - 1]
    em = np.array([truth.eta_m[int(g)] for g in gear])
    c0 = np.array([truth.c0[int(g)] for g in gear])
    drive = ig * em * (t_in - c0)
    coast = ig * (t_in / em - c0)
    return np.where(t_in >= c0, drive, np.where(t_in <= em * c0, coast, 0.0))


def ramp_up_plant(truth: Truth, specs: VehicleSpecs = SPECS, *, seed: int = 1, hold_s: float = 6.0,
                  ramp_s: float = 2.0, settings: list[tuple[int, float]] | None = None,
                  levels: list[float] | None = None) -> tuple[np.ndarray, dict[str, np.ndarray], list[Segment]]:
    """Ramp-up tests: per (gear, speed), steps of input torque (hybrid, electric and coast)."""
    rng = np.random.default_rng(seed)
    settings = settings or [(3, 40.0), (3, 68.0), (4, 50.0), (4, 88.0), (5, 62.0), (5, 85.0), (6, 70.0),
                            (6, 120.0), (7, 90.0), (7, 140.0)]
    levels = levels or [-90.0, -50.0, -25.0, 25.0, 45.0, 70.0, 100.0, 140.0, 180.0, 230.0, 280.0]
    holds: list[dict] = []
    segs: list[Segment] = []
    s = 0.0
    for g, v in settings:
        start = s
        for lv in levels:
            hybrid = lv >= 45.0
            frac = rng.uniform(0.35, 0.9) if hybrid else 0.0
            holds.append({"gear": g, "v": v, "t_eng": lv * frac, "t_em": lv * (1 - frac), "k0": float(hybrid),
                          "lock": 1.0, "p_lv": rng.uniform(250.0, 1400.0)})
            s += hold_s + ramp_s
        segs.append(Segment(start, s - ramp_s, "ramp_up", f"ramp_up_g{g}_{v:.0f}kmh", {"gear": g, "speed_kmh": v}))
    # one hold with the lock-up open (slipping converter): must be excluded by transmission
    holds.append({"gear": 5, "v": 70.0, "t_eng": 0.0, "t_em": 60.0, "k0": 0.0, "lock": 0.0, "p_lv": 500.0})
    s += hold_s + ramp_s
    t = np.arange(0.0, s, 1.0 / PLANT_HZ)
    gear = _steps(holds, hold_s, ramp_s, t, "gear")
    k0 = _steps(holds, hold_s, ramp_s, t, "k0")
    lock = _steps(holds, hold_s, ramp_s, t, "lock")
    v = _knots(holds, hold_s, ramp_s, t, "v")
    t_eng = _knots(holds, hold_s, ramp_s, t, "t_eng") * k0
    t_em = _knots(holds, hold_s, ramp_s, t, "t_em")
    p_lv = _knots(holds, hold_s, ramp_s, t, "p_lv") + 150.0 * np.sin(2 * np.pi * t / 37.0)
    ig = np.asarray(specs.gear_ratios)[gear.astype(int) - 1]
    w_turb = v / 3.6 / specs.wheel_radius_m * specs.final_drive_ratio * ig
    w_em = np.where(lock > 0.5, w_turb, 1.12 * w_turb)
    t_in = t_em + t_eng
    t_out = trans_out(t_in, gear, truth, specs)
    p_mech = t_em * w_em
    p_el = np.where(t_em >= 0, (p_mech + truth.w_loss) / truth.e, truth.e_gen * p_mech + truth.w_loss_gen)
    p_hpcu = p_el + p_lv / truth.eta_dcdc
    u_hv = 358.0 - 0.02 * p_hpcu / 358.0
    u_lv = 14.1 - 0.0002 * p_lv
    bmep = 4 * np.pi * t_eng / specs.engine_displacement_m3 / 1e5
    fuel = np.where(t_eng > 0, truth.bsfc(w_em / RPM, bmep) * t_eng * w_em / 3.6e6, 0.0)
    sig = {"vehicle_speed_kmh": v, "em_speed_rpm": w_em / RPM, "em_torque_nm": t_em,
           "engine_speed_rpm": np.where(k0 > 0.5, w_em / RPM, 0.0), "engine_torque_nm": t_eng,
           "fuel_mass_flow_gps": fuel, "shaft_torque_nm": t_out, "gear_actual": gear, "gear_target": gear,
           "k0_closed": k0, "lockup_closed": lock, "engine_on": k0, "hpcu_current_a": p_hpcu / u_hv,
           "hpcu_voltage_v": u_hv, "dcdc_lv_current_a": p_lv / u_lv, "dcdc_lv_voltage_v": u_lv,
           "pedal_pct": np.clip(t_in / 4.0, 0, 100), "brake_pedal_pct": np.zeros_like(t)}
    return t, sig, segs


def coastdown_plant(truth: Truth, specs: VehicleSpecs = SPECS, *, v0: float = 130.0,
                    v_end: float = 5.0) -> tuple[np.ndarray, dict[str, np.ndarray], list[Segment]]:
    """A run-up in 5th gear (40 s) then a neutral coastdown from v0 with m dv/dt = -(F0 + F1 v + F2 v^2)."""
    m = specs.test_mass_kg

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        vk = y[0]
        return np.array([-(truth.f0 + truth.f1 * vk + truth.f2 * vk**2) / m * 3.6])

    def stop(_t: float, y: np.ndarray) -> float:
        return y[0] - v_end

    stop.terminal = True  # type: ignore[attr-defined]
    sol = solve_ivp(rhs, (0.0, 2000.0), [v0], method="DOP853", rtol=1e-12, atol=1e-10, dense_output=True,
                    events=stop)
    t_run = 40.0
    t_end = t_run + float(sol.t[-1])
    t = np.arange(0.0, t_end, 1.0 / PLANT_HZ)
    tc = np.clip(t - t_run, 0.0, None)
    v = np.where(t < t_run, 60.0 + (v0 - 60.0) * t / t_run, sol.sol(tc)[0])
    driving = t < t_run
    sig = {"dyno_speed_kmh": v, "vehicle_speed_kmh": v, "gear_actual": np.where(driving, 5.0, 0.0),
           "pedal_pct": np.where(driving, 60.0, 0.0), "brake_pedal_pct": np.zeros_like(t)}
    return t, sig, [Segment(t_run, t_end, "coastdown", "coastdown_130", {"from_kmh": v0})]


def neutral_braking_plant(truth: Truth, specs: VehicleSpecs = SPECS, *, hold_s: float = 5.0, ramp_s: float = 1.0,
                          levels: list[float] | None = None) -> tuple[np.ndarray, dict[str, np.ndarray],
                                                                      list[Segment]]:
    """Braking in neutral at a constant 50 km/h with pressure steps; roller forces carry the brake torque."""
    levels = levels or [0.0, 4.0, 8.0, 14.0, 20.0, 28.0, 36.0, 45.0, 55.0, 65.0]
    holds = [{"pf": p, "pr": 0.55 * p + (1.5 if p > 0 else 0.0)} for p in levels]
    t = np.arange(0.0, len(holds) * (hold_s + ramp_s), 1.0 / PLANT_HZ)
    pf = _knots(holds, hold_s, ramp_s, t, "pf")
    pr = _knots(holds, hold_s, ramp_s, t, "pr")
    r = specs.wheel_radius_m
    sig = {"dyno_speed_kmh": np.full_like(t, 50.0), "vehicle_speed_kmh": np.full_like(t, 50.0),
           "gear_actual": np.zeros_like(t), "brake_pressure_fl_bar": pf * 1.01, "brake_pressure_fr_bar": pf * 0.99,
           "brake_pressure_rl_bar": pr, "brake_pressure_rr_bar": pr,
           "dyno_force_front_n": -(truth.m_f * pf + truth.c_f) / r,
           "dyno_force_rear_n": -(truth.m_r * pr + truth.c_r) / r}
    return t, sig, [Segment(0.0, float(t[-1]), "neutral_braking", "neutral_braking_50kmh", {"speed_kmh": 50.0})]


def blending_true_split(v_kmh: np.ndarray, decel: np.ndarray, t_tot: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                          np.ndarray]:
    """Regenerative, front and rear hydraulic torque (wheel side) for a total braking torque."""
    w = np.maximum(v_kmh / 3.6 / SPECS.wheel_radius_m, 1e-3)
    limit = np.minimum(1400.0, 45e3 / w) * (v_kmh > 10.0)
    regen = np.minimum(t_tot, limit)
    hyd = t_tot - regen
    front = np.clip(0.45 + 0.12 * decel, 0.0, 1.0)
    return regen, front * hyd, (1 - front) * hyd


def blending_plant(truth: Truth, specs: VehicleSpecs = SPECS) -> tuple[np.ndarray, dict[str, np.ndarray],
                                                                       list[Segment]]:
    """Decelerations at constant levels (0.4..2.6 m/s^2) from 110 km/h, each followed by a run-up."""
    m, r = specs.test_mass_kg, specs.wheel_radius_m
    pieces_t, pieces_v, pieces_a = [], [], []
    s = 0.0
    for a in (0.4, 0.8, 1.2, 1.6, 2.0, 2.6):
        tb = 110.0 / 3.6 / a
        tt = np.arange(0.0, tb, 1.0 / PLANT_HZ)
        pieces_t.append(s + tt)
        pieces_v.append(110.0 - a * 3.6 * tt)
        pieces_a.append(np.full_like(tt, a))
        s += tb
        tu = np.arange(0.0, 25.0, 1.0 / PLANT_HZ)
        pieces_t.append(s + tu)
        pieces_v.append(110.0 * tu / 25.0)
        pieces_a.append(np.zeros_like(tu))
        s += 25.0
    t = np.concatenate(pieces_t)
    v = np.concatenate(pieces_v)
    decel = np.concatenate(pieces_a)
    braking = decel > 0
    t_tot = np.where(braking, m * decel * r, 0.0)
    regen, hf, hr = blending_true_split(v, decel, t_tot)
    pf, pr = hf / truth.m_f, hr / truth.m_r
    sig = {"dyno_speed_kmh": v, "vehicle_speed_kmh": v, "gear_actual": np.where(braking, 3.0, 4.0),
           "brake_pressure_fl_bar": pf, "brake_pressure_fr_bar": pf, "brake_pressure_rl_bar": pr,
           "brake_pressure_rr_bar": pr, "pedal_pct": np.where(braking, 0.0, 30.0),
           "dyno_force_front_n": np.where(braking, -(hf + truth.c_f) / r, 300.0),
           "dyno_force_rear_n": np.where(braking, -(hr + regen + truth.c_r) / r, 2000.0)}
    return t, sig, [Segment(0.0, float(t[-1]), "deceleration", "decelerations", {})]
