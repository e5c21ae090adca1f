"""Synthetic Recordings built from the model forms of docs/models.md, with known parameters.

Used by the battery, torque-converter, shift, CLI and figure tests (identification part B). Each
builder returns ``(recording, truth)``; nothing here imports the emulator.
"""

from __future__ import annotations

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.identification.battery import load_literature_maps
from benchtwin.identification.torque_converter import tc_torques
from benchtwin.recording import Channel, Recording
from benchtwin.segments import Segment

SPECS = VehicleSpecs(
    gear_ratios=[5.35, 3.24, 2.25, 1.64, 1.21, 1.0, 0.86, 0.72, 0.6],
    final_drive_ratio=2.47,
    wheel_radius_m=0.334,
    engine_displacement_m3=1.95e-3,
    n_cells_series=96,
    em_rotor_radius_m=0.1,
    em_rotor_volume_m3=0.004,
    test_mass_kg=2162.0,
)

BATTERY_TRUTH = {"alpha": 1.021, "beta_discharge": 1.37, "beta_charge": 1.18}


#: displayed SOC per Ah of charge (100 / usable capacity of 25 Ah)
SOC_PER_AH = 4.0


def battery_recording(truth: dict[str, float] | None = None, *, rate_hz: float = 10.0, noise_v: float = 0.0,
                      seed: int = 0, with_charge: bool = True, soc_step_pct: float = 0.0
                      ) -> tuple[Recording, dict[str, float]]:
    """A depletion test (SOC 95 -> 15 %) and a charge test (20 -> 35 %) on the eq. 30 pack model.

    SOC follows the current by coulomb counting (:data:`SOC_PER_AH`); with ``soc_step_pct`` the
    displayed SOC on the CAN is rounded to that step, as a real car's is.
    """
    truth = dict(truth or BATTERY_TRUTH)
    maps = load_literature_maps()
    n = SPECS.n_cells_series
    rng = np.random.default_rng(seed)
    parts_t, parts_i, parts_s, segs = [], [], [], []
    t0 = 0.0
    # (kind, name, start SOC, duration, mean |I|, sign): 40 A for 1800 s = 20 Ah = 80 %; 15 A for 900 s = 15 %
    tests = [("constant_drive", "deplete_90kmh", 95.0, 1800.0, 40.0, 1)]
    if with_charge:
        tests.append(("constant_drive", "charge_50kmh", 20.0, 900.0, 15.0, -1))
    for kind, name, s0, dur, i_mean, sign in tests:
        t = t0 + np.arange(0.0, dur, 1.0 / rate_hz)
        tau = (t - t0) / dur
        # current varies around its mean (driver corrections, auxiliaries) and keeps its sign
        i = sign * i_mean * (1.0 + 0.6 * np.sin(2 * np.pi * tau * 37) + 0.25 * np.sin(2 * np.pi * tau * 211))
        q = np.r_[0.0, np.cumsum(-0.5 * (i[1:] + i[:-1]) * np.diff(t))] / 3600.0
        s = s0 + SOC_PER_AH * q
        parts_t.append(t)
        parts_i.append(i)
        parts_s.append(s)
        segs.append(Segment(float(t[0]), float(t[-1] + 1.0 / rate_hz), kind, name, {}))
        t0 = t[-1] + 60.0
    t = np.concatenate(parts_t)
    i = np.concatenate(parts_i)
    s = np.concatenate(parts_s)
    r = np.where(i > 0, truth["beta_discharge"] * maps.r_discharge(s), truth["beta_charge"] * maps.r_charge(s))
    v = (truth["alpha"] * maps.ocv(s) - i * r) * n + noise_v * rng.standard_normal(t.size)
    shown = np.round(s / soc_step_pct) * soc_step_pct if soc_step_pct > 0 else s
    rec = Recording(segments=segs)
    rec.add(Channel("battery_voltage_v", "V", t, v, source="ivt_battery"))
    rec.add(Channel("battery_current_a", "A", t, i, source="ivt_battery"))
    rec.add(Channel("displayed_soc_pct", "%", t, shown, source="vehicle_can"))
    return rec, truth


# converter: T_p/w_p^2 = a0 + a1 SR + a2 SR^2 (K about 150 rpm/sqrt(Nm) at stall), TR(0) = 2, TR(0.85) = 1;
# coupling: continuous at 0.85 and zero torque at SR = 1
TC_TRUTH = {
    "a0": 4.0e-3, "a1": 0.5e-3, "a2": -2.5e-3,
    "a3": 8.0e-3, "a4": -3.0e-3, "a5": 0.0,
    "a6": 0.0, "a7": 0.0, "a8": -5.0e-3,
    "gamma": 0.85,
}
# close the system exactly: TR = 1 at 0.85 fixes a5; continuity and T(SR=1) = 0 fix a6, a7
TC_TRUTH["a5"] = -((TC_TRUTH["a3"] - TC_TRUTH["a0"]) + (TC_TRUTH["a4"] - TC_TRUTH["a1"]) * 0.85) / 0.85**2 \
    + TC_TRUTH["a2"]
_tp_g = TC_TRUTH["a0"] + TC_TRUTH["a1"] * 0.85 + TC_TRUTH["a2"] * 0.85**2
TC_TRUTH["a7"] = (_tp_g - TC_TRUTH["a8"] * (0.85**2 - 1.0) - 0.0) / (0.85 - 1.0)
TC_TRUTH["a6"] = -TC_TRUTH["a7"] - TC_TRUTH["a8"]
TRANSMISSION_TRUTH = {g: (0.97 - 0.002 * g, 2.0 + 0.3 * g) for g in range(1, 10)}


def tc_truth_vector() -> np.ndarray:
    """a0..a8 of :data:`TC_TRUTH`."""
    return np.array([TC_TRUTH[f"a{k}"] for k in range(9)])


def tc_recording(*, duration_s: float = 600.0, rate_hz: float = 10.0, gear: int = 1, noise_nm: float = 0.0,
                 seed: int = 1, transmission: dict[int, tuple[float, float]] | None = None,
                 pump_inertia_kgm2: float = 0.0, speed_reading_bias: float = 0.0,
                 lockup_closed_s: float = 0.0, em_torque_gain: float = 1.0) -> tuple[Recording, dict[str, float]]:
    """Slow, quasi-steady electric take-offs with the lock-up open, K0 open, in one gear.

    With ``pump_inertia_kgm2`` the motor torque also accelerates the rotor and pump: T_em = T_p + J dw_p/dt.
    ``lockup_closed_s`` appends a cruise with the lock-up closed (turbine = pump); ``speed_reading_bias``
    makes the vehicle CAN speed read that fraction high (a speedometer-like error); ``em_torque_gain``
    multiplies the motor torque reading (a gain error of the motor's torque signal).
    """
    transmission = transmission or TRANSMISSION_TRUTH
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    w_p = 160.0 + 90.0 * np.sin(2 * np.pi * t / 300.0) + 8.0 * np.sin(2 * np.pi * t / 7.0)  # |dw/dt| <= 9 rad/s^2
    sr = 0.5 + 0.49 * np.sin(2 * np.pi * t / 97.0)
    w_t = sr * w_p
    tp, tt = tc_torques(tc_truth_vector(), TC_TRUTH["gamma"], w_p, w_t)
    ig = SPECS.gear_ratios[gear - 1]
    eta_m, c0 = transmission[gear]
    t_out = ig * eta_m * (tt - c0)
    v_kmh = w_t / (ig * SPECS.final_drive_ratio) * SPECS.wheel_radius_m * 3.6
    dw = 2 * np.pi / 300.0 * 90.0 * np.cos(2 * np.pi * t / 300.0) + 2 * np.pi / 7.0 * 8.0 * np.cos(2 * np.pi * t / 7.0)
    t_em = tp + pump_inertia_kgm2 * dw
    lock = np.zeros(t.size)
    if lockup_closed_s > 0:
        t2 = duration_s + np.arange(0.0, lockup_closed_s, 1.0 / rate_hz)
        w2 = 150.0 + 20.0 * np.sin(2 * np.pi * (t2 - duration_s) / 60.0)
        tq2 = np.full(t2.size, 80.0)
        t = np.r_[t, t2]
        w_p, t_em = np.r_[w_p, w2], np.r_[t_em, tq2]
        t_out = np.r_[t_out, ig * eta_m * (tq2 - c0)]
        v_kmh = np.r_[v_kmh, w2 / (ig * SPECS.final_drive_ratio) * SPECS.wheel_radius_m * 3.6]
        lock = np.r_[lock, np.ones(t2.size)]
    v_kmh = v_kmh * (1.0 + speed_reading_bias)
    rec = Recording(segments=[Segment(0.0, float(duration_s), "acceleration", f"tc_takeoff_g{gear}", {})])
    can = "vehicle_can"
    rec.add(Channel("em_speed_rpm", "rpm", t, w_p * 60 / (2 * np.pi), source=can))
    rec.add(Channel("em_torque_nm", "Nm", t, em_torque_gain * t_em + noise_nm * rng.standard_normal(t.size),
                    source=can))
    rec.add(Channel("vehicle_speed_kmh", "km/h", t, v_kmh, source=can))
    rec.add(Channel("shaft_torque_nm", "Nm", t, t_out + noise_nm * ig * rng.standard_normal(t.size),
                    source="telemetry"))
    rec.add(Channel("lockup_closed", "", t, lock, source=can))
    for name, val in (("gear_actual", gear), ("gear_target", gear), ("k0_closed", 0)):
        rec.add(Channel(name, "", t, np.full(t.size, float(val)), source=can))
    return rec, dict(TC_TRUTH)


N_GEARS = 9
SHIFT_TRUTH = {
    "up": {g: (8.0 + 11.0 * g, 0.15 + 0.06 * g) for g in range(1, N_GEARS)},
    "down": {g: (3.0 + 10.0 * g, 0.08 + 0.04 * g) for g in range(1, N_GEARS)},
}


def shift_recording(*, up_pedals: tuple[float, ...] = (20, 35, 50, 65, 80, 95),
                    down_pedals: tuple[float, ...] = (0, 10, 20, 30, 40, 50), accel_kmh_s: float = 4.0,
                    rate_hz: float = 10.0) -> tuple[Recording, dict]:
    """Accelerations at constant pedal 0 -> top gear and decelerations back to rest.

    The gear-target channel is event-driven (a sample at each exact threshold crossing); speed and
    pedal are sampled at ``rate_hz`` and piecewise linear, so interpolation at an event is exact.
    """
    up, down = SHIFT_TRUTH["up"], SHIFT_TRUTH["down"]
    g_t, g_v = [0.0], [1.0]
    knots_t, knots_v, knots_p = [], [], []
    t0 = 0.0
    segs = []
    for k, p in enumerate(up_pedals):
        thr = [up[g][0] + up[g][1] * p for g in range(1, N_GEARS)]
        v_end = thr[-1] + 10.0
        dur = v_end / accel_kmh_s
        knots_t += [t0, t0 + dur]
        knots_v += [0.0, v_end]
        knots_p += [p, p]
        for g, th in enumerate(thr, start=1):
            g_t.append(t0 + th / accel_kmh_s)
            g_v.append(g + 1.0)
        segs.append(Segment(t0, t0 + dur, "acceleration", f"acc_pedal{int(p)}", {"pedal_pct": p}))
        # decelerate at the paired pedal level from v_end to 0
        pd = down_pedals[k % len(down_pedals)]
        t1 = t0 + dur + 1.0
        dthr = {g: down[g][0] + down[g][1] * pd for g in range(1, N_GEARS)}
        knots_t += [t1, t1 + v_end / accel_kmh_s]
        knots_v += [v_end, 0.0]
        knots_p += [pd, pd]
        for g in range(N_GEARS - 1, 0, -1):
            g_t.append(t1 + (v_end - dthr[g]) / accel_kmh_s)
            g_v.append(float(g))
        segs.append(Segment(t1, t1 + v_end / accel_kmh_s, "deceleration", f"dec_pedal{int(pd)}", {"pedal_pct": pd}))
        t0 = t1 + v_end / accel_kmh_s + 1.0
    kt = np.array(knots_t)
    t = np.arange(0.0, kt[-1], 1.0 / rate_hz)
    t = np.union1d(t, kt)
    v = np.interp(t, kt, knots_v)
    # pedal steps between runs: hold each run's pedal over the run (piecewise constant)
    idx = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, kt.size - 1)
    p = np.array(knots_p)[idx]
    rec = Recording(segments=segs)
    rec.add(Channel("vehicle_speed_kmh", "km/h", t, v, source="vehicle_can"))
    rec.add(Channel("pedal_pct", "%", t, p, source="vehicle_can"))
    order = np.argsort(g_t, kind="stable")
    rec.add(Channel("gear_target", "", np.array(g_t)[order], np.array(g_v)[order], source="vehicle_can"))
    return rec, {"up": up, "down": down, "up_pedals": up_pedals, "down_pedals": down_pedals}
