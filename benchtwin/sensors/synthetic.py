"""A synthetic Trace with every TRACE_CHANNELS channel: smooth signals sweeping each sensor's range.

For testing and benchmarking the sensor chain without the plant: every channel is a sum of slow
sines with plausible magnitudes and signs (currents charge and discharge, torques drive and brake,
temperatures sweep their ranges, states step). It is not a physically consistent vehicle; the
chain does not need one. ``excursion=True`` pushes some channels beyond their sensors' ranges
(for saturation tests).
"""

from __future__ import annotations

import numpy as np

from benchtwin.segments import Segment
from benchtwin.trace import TRACE_CHANNELS, Trace

__all__ = ["synthetic_trace"]


def synthetic_trace(duration_s: float = 60.0, rate_hz: float = 100.0, seed: int = 0, *,
                    excursion: bool = False) -> Trace:
    """Build the synthetic trace (see the module docstring).

    Parameters
    ----------
    duration_s:
        Length, seconds.
    rate_hz:
        Sample rate (the plant's is 100 Hz).
    seed:
        Phases of the sines.
    excursion:
        Drive the battery current, shaft torque and one brake pressure past their ranges.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    w = 2 * np.pi / max(duration_s, 1.0)

    def wave(mean: float, amp: float, periods: float = 1.0) -> np.ndarray:
        ph = rng.uniform(0, 2 * np.pi, 3)
        return mean + amp * (0.6 * np.sin(periods * w * t + ph[0]) + 0.3 * np.sin(3.7 * periods * w * t + ph[1])
                             + 0.1 * np.sin(11.3 * periods * w * t + ph[2]))

    def steps(levels: list[int], periods: float = 4.0) -> np.ndarray:
        idx = np.floor((t / max(duration_s, 1e-9)) * periods * len(levels)).astype(int) % len(levels)
        return np.asarray(levels, dtype=np.float64)[idx]

    c: dict[str, np.ndarray] = {}
    v = np.clip(wave(15.0, 20.0), 0.0, None)
    c["vehicle_speed_mps"] = v
    c["vehicle_accel_mps2"] = np.gradient(v, t)
    c["distance_m"] = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    c["dyno_set_speed_mps"] = np.where(steps([1, 0], 2.0) > 0, v, np.nan)
    c["dyno_speed_mps"] = v
    c["dyno_force_front_n"] = wave(0.0, 300.0)
    c["dyno_force_rear_n"] = wave(500.0, 4000.0)
    c["road_load_force_n"] = 171.5 + 0.833 * v * 3.6 + 0.028 * (v * 3.6) ** 2
    c["pedal_pct"] = np.clip(wave(40.0, 70.0), 0, 100)
    c["brake_pedal_pct"] = np.clip(wave(-10.0, 60.0), 0, 100)
    c["hybrid_mode"] = steps([0, 1, 2, 3])
    c["engine_speed_radps"] = np.clip(wave(200.0, 250.0), 0, None)
    c["engine_torque_nm"] = wave(150.0, 280.0)
    c["engine_on"] = (c["engine_speed_radps"] > 60).astype(float)
    c["fuel_mass_flow_kgps"] = np.clip(wave(2e-3, 4e-3), 0, None)
    c["k0_closed"] = steps([0, 1, 1], 5.0)
    c["em_speed_radps"] = np.clip(wave(250.0, 300.0), -20, None)
    c["em_torque_nm"] = wave(50.0, 400.0)
    c["em_elec_power_w"] = c["em_torque_nm"] * c["em_speed_radps"] / 0.92
    c["battery_voltage_v"] = wave(360.0, 30.0)
    c["battery_current_a"] = wave(20.0, 1300.0 if excursion else 250.0)
    c["battery_ocv_v"] = c["battery_voltage_v"] + 0.1 * c["battery_current_a"]
    c["hpcu_hv_voltage_v"] = c["battery_voltage_v"] - 0.2
    c["hpcu_hv_current_a"] = c["em_elec_power_w"] / c["hpcu_hv_voltage_v"]
    c["tc_pump_torque_nm"] = c["em_torque_nm"] + c["engine_torque_nm"]
    c["tc_turbine_speed_radps"] = np.clip(c["em_speed_radps"] * 0.95, 0, None)
    c["tc_turbine_torque_nm"] = c["tc_pump_torque_nm"] * 1.1
    c["lockup_closed"] = steps([0, 1], 6.0)
    c["gear_target"] = steps([1, 2, 3, 4, 5, 6, 7, 8, 9, 0], 3.0)
    c["gear_actual"] = np.roll(c["gear_target"], int(0.5 * rate_hz))
    c["trans_input_torque_nm"] = c["tc_turbine_torque_nm"]
    c["shaft_torque_nm"] = wave(300.0, 5500.0 if excursion else 1700.0)
    c["shaft_speed_radps"] = v / 0.35 * 2.65
    c["wheel_speed_radps"] = v / 0.35
    for corner, gain in (("fl", 1.0), ("fr", 1.0), ("rl", 0.6), ("rr", 0.6)):
        p = np.clip(wave(20.0 * gain, 60.0 * gain), 0, None) * 1e5
        c[f"brake_pressure_{corner}_pa"] = p
    if excursion:
        c["brake_pressure_fl_pa"] = np.clip(wave(60.0, 90.0), 0, None) * 1e5
    c["master_cylinder_pa"] = np.clip(wave(25.0, 70.0), 0, None) * 1e5
    c["brake_torque_front_nm"] = c["brake_pressure_fl_pa"] * 1e-3
    c["brake_torque_rear_nm"] = c["brake_pressure_rl_pa"] * 1e-3
    c["battery_soc_frac"] = np.clip(wave(0.5, 0.4), 0, 1)
    c["displayed_soc_pct"] = np.clip(wave(50.0, 60.0), 0, 100)
    for name, (mean, amp) in {
        "engine_coolant_in_degc": (60.0, 50.0), "engine_coolant_out_degc": (70.0, 50.0),
        "battery_temp_degc": (25.0, 30.0), "battery_coolant_in_degc": (20.0, 35.0),
        "battery_coolant_out_degc": (24.0, 35.0), "hpcu_coolant_in_degc": (40.0, 40.0),
        "hpcu_coolant_out_degc": (45.0, 40.0), "motor_coolant_in_degc": (45.0, 45.0),
        "motor_coolant_out_degc": (50.0, 45.0), "gearbox_oil_degc": (60.0, 50.0),
    }.items():
        c[name] = wave(mean, amp)
    c["dcdc_lv_voltage_v"] = wave(14.0, 0.5)
    c["dcdc_lv_current_a"] = wave(60.0, 120.0)
    c["lv_battery_voltage_v"] = wave(13.0, 0.8)
    c["lv_battery_current_a"] = wave(0.0, 100.0)
    missing = set(TRACE_CHANNELS) - set(c)
    if missing:  # pragma: no cover - guards the contract if TRACE_CHANNELS grows
        for name in missing:
            c[name] = wave(0.0, 1.0)
    half = duration_s / 2
    segs = [Segment(0.0, half, "wltc", "synthetic_a", {"gear": 3}),
            Segment(half, duration_s, "ramp_up", "synthetic_b", {"gear": 5})]
    return Trace(t, {k: c[k] for k in TRACE_CHANNELS}, segs, {"source": "synthetic", "seed": seed})
