"""Kinematic and model-form consistency of every driveline sample: the forms identification recovers."""

from __future__ import annotations

import numpy as np

from benchtwin.emulator.params import cell_maps


def _ratios(vehicle):
    return np.concatenate([[0.0], vehicle.specs.gear_ratios])


def _settled(trace, vehicle):
    """Samples at least one inertia phase after the last change of the actual gear."""
    g = trace["gear_actual"]
    n_hold = int(np.ceil(vehicle.transmission.shift_inertia_phase_s / trace.dt_s)) + 1
    changed = np.concatenate([[True], g[1:] != g[:-1]])
    since = np.arange(len(g)) - np.maximum.accumulate(np.where(changed, np.arange(len(g)), 0))
    return since >= n_hold


def test_gear_speed_ratio_consistency(quick_trace, vehicle) -> None:
    tr = quick_trace
    g = tr["gear_actual"].astype(int)
    ing = (g > 0) & _settled(tr, vehicle)
    assert ing.mean() > 0.5
    fd = vehicle.specs.final_drive_ratio
    wheel = tr["wheel_speed_radps"]
    np.testing.assert_allclose(wheel * vehicle.specs.wheel_radius_m, tr["vehicle_speed_mps"], rtol=1e-12)
    np.testing.assert_allclose(tr["shaft_speed_radps"], wheel * fd, rtol=1e-12)
    np.testing.assert_allclose(tr["tc_turbine_speed_radps"][ing], wheel[ing] * fd * _ratios(vehicle)[g[ing]],
                               rtol=1e-12, atol=1e-9)
    lu = tr["lockup_closed"] > 0.5
    assert lu.sum() > 1000
    np.testing.assert_allclose(tr["em_speed_radps"][lu], tr["tc_turbine_speed_radps"][lu], rtol=1e-9, atol=1e-9)
    k0 = tr["k0_closed"] > 0.5
    assert k0.sum() > 100
    np.testing.assert_allclose(tr["engine_speed_radps"][k0], tr["em_speed_radps"][k0], rtol=1e-12)
    # an open K0 with the engine off: engine at rest, the motor alone turns the pump
    off = (~k0) & (tr["engine_on"] < 0.5) & (tr["em_speed_radps"] > 50)
    assert off.sum() > 1000
    assert np.mean(tr["engine_speed_radps"][off] == 0.0) > 0.95  # only the run-down after a stop is not at rest


def test_torque_converter_obeys_eq_35_36_exactly_when_unlocked(quick_trace, vehicle) -> None:
    tr = quick_trace
    a = np.asarray(vehicle.torque_converter.a_nm_per_radps2)
    gamma = vehicle.torque_converter.coupling_speed_ratio
    m = (tr["lockup_closed"] < 0.5) & (tr["gear_actual"] > 0) & (tr["em_speed_radps"] > 5.0)
    assert m.sum() > 2000
    wp, wt = tr["em_speed_radps"][m], tr["tc_turbine_speed_radps"][m]
    sr = wt / wp
    conv = sr < gamma
    assert conv.sum() > 200 and (~conv).sum() > 200  # both regimes are exercised
    tp = np.where(conv, a[0] * wp**2 + a[1] * wp * wt + a[2] * wt**2, a[6] * wp**2 + a[7] * wp * wt + a[8] * wt**2)
    tt = np.where(conv, a[3] * wp**2 + a[4] * wp * wt + a[5] * wt**2, tp)
    np.testing.assert_allclose(tr["tc_pump_torque_nm"][m], tp, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(tr["tc_turbine_torque_nm"][m], tt, rtol=1e-12, atol=1e-9)
    # torque multiplication at low speed ratio (converter mode), as a converter must
    stall = conv & (sr < 0.3) & (tp > 10)
    assert stall.sum() > 10 and np.all(tt[stall] / tp[stall] > 1.5)


def test_transmission_follows_eq_14_in_drive_and_coast(quick_trace, vehicle) -> None:
    tr = quick_trace
    g = tr["gear_actual"].astype(int)
    ing = (g > 0) & _settled(tr, vehicle)
    eta = np.concatenate([[1.0], vehicle.transmission.eta_m])[g]
    c0 = np.concatenate([[0.0], vehicle.transmission.c0_nm])[g]
    ratio = _ratios(vehicle)[g]
    tin, tout = tr["trans_input_torque_nm"], tr["shaft_torque_nm"]
    drive = ing & (tin >= c0)
    coast = ing & (tin <= eta * c0)
    assert drive.sum() > 1000 and coast.sum() > 1000
    np.testing.assert_allclose(tout[drive], ratio[drive] * eta[drive] * (tin[drive] - c0[drive]), rtol=1e-12)
    np.testing.assert_allclose(tout[coast], ratio[coast] * (tin[coast] / eta[coast] - c0[coast]), rtol=1e-12)
    band = ing & ~drive & ~coast
    assert np.all(tout[band] == 0.0)
    assert np.all(tout[g == 0] == 0.0)
    # during the inertia phase of a shift the turbine speed moves between the two ratios
    moving = (g > 0) & ~_settled(tr, vehicle) & (tr["lockup_closed"] == 0) & (tr["vehicle_speed_mps"] > 3)
    ratio_seen = tr["tc_turbine_speed_radps"][moving] / tr["shaft_speed_radps"][moving]
    assert moving.sum() > 50
    assert np.all(ratio_seen <= _ratios(vehicle)[1] + 1e-9) and np.all(ratio_seen >= _ratios(vehicle)[-1] - 1e-9)


def test_motor_willans_line_and_hpcu_power(quick_trace, vehicle) -> None:
    tr = quick_trace
    mo = vehicle.motor
    t, w, p = tr["em_torque_nm"], tr["em_speed_radps"], tr["em_elec_power_w"]
    mot = (t > 0) & (w > 10)
    gen = (t < 0) & (w > 10)
    assert mot.sum() > 1000 and gen.sum() > 500
    np.testing.assert_allclose(p[mot], (t[mot] * w[mot] + mo.willans_w_loss_w) / mo.willans_e, rtol=1e-12)
    np.testing.assert_allclose(p[gen], mo.willans_e_gen * t[gen] * w[gen] + mo.willans_w_loss_gen_w, rtol=1e-12)
    # HPCU HV power = motor DC power + DC/DC input (P_lv / eta_dcdc)
    p_hv = tr["hpcu_hv_current_a"] * tr["hpcu_hv_voltage_v"]
    p_lv = tr["dcdc_lv_current_a"] * tr["dcdc_lv_voltage_v"]
    np.testing.assert_allclose(p_hv, p + p_lv / vehicle.low_voltage.dcdc_efficiency, rtol=1e-9, atol=1e-6)


def test_battery_follows_eq_29_30(quick_trace, vehicle) -> None:
    tr = quick_trace
    b = vehicle.battery
    n = vehicle.specs.n_cells_series
    cells = cell_maps()
    s = tr["displayed_soc_pct"]
    np.testing.assert_allclose(s, 100 * (tr["battery_soc_frac"] - b.soc_min_frac) / (b.soc_max_frac - b.soc_min_frac),
                               rtol=1e-12)
    ocv = n * b.alpha * np.interp(s, cells[:, 0], cells[:, 1])
    np.testing.assert_allclose(tr["battery_ocv_v"], ocv, rtol=1e-12)
    i = tr["battery_current_a"]
    r = np.where(i >= 0, b.beta_discharge * np.interp(s, cells[:, 0], cells[:, 2]),
                 b.beta_charge * np.interp(s, cells[:, 0], cells[:, 3])) * n
    np.testing.assert_allclose(tr["battery_voltage_v"], ocv - i * r, rtol=1e-9)
    assert (i > 50).sum() > 100 and (i < -50).sum() > 100  # both directions exercised


def test_brake_torque_is_gain_times_pressure_and_shares(quick_trace, vehicle) -> None:
    tr = quick_trace
    br = vehicle.brakes
    pf, pr = tr["brake_pressure_fl_pa"] / 1e5, tr["brake_pressure_rl_pa"] / 1e5
    np.testing.assert_allclose(tr["brake_torque_front_nm"], br.gain_front_nm_per_bar * pf, rtol=1e-12)
    np.testing.assert_allclose(tr["brake_torque_rear_nm"], br.gain_rear_nm_per_bar * pr, rtol=1e-12)
    np.testing.assert_array_equal(tr["brake_pressure_fl_pa"], tr["brake_pressure_fr_pa"])
    assert np.all(tr["master_cylinder_pa"] >= np.maximum(tr["brake_pressure_fl_pa"], tr["brake_pressure_rl_pa"]))
    # front share of the hydraulic torque rises with the brake demand
    tot = tr["brake_torque_front_nm"] + tr["brake_torque_rear_nm"]
    m = tot > 200
    share = tr["brake_torque_front_nm"][m] / tot[m]
    dem = tr["brake_pedal_pct"][m]
    assert np.corrcoef(dem, share)[0, 1] > 0.5
    # hydraulic only below the regen cut-off speed; above it, regeneration takes part when in gear
    slow = (3.6 * tr["vehicle_speed_mps"] < br.regen_cutoff_speed_kmh) & (tr["brake_pedal_pct"] > 0)
    assert np.all(tr["em_torque_nm"][slow] >= -br.coast_regen_torque_nm - 1e-9)


def test_shift_schedule_events_lie_on_the_lines_and_actual_gear_lags(quick_trace, vehicle) -> None:
    tr = quick_trace
    sh = vehicle.shift_schedule
    gt = tr["gear_target"].astype(int)
    v = 3.6 * tr["vehicle_speed_mps"]
    ped = tr["pedal_pct"]
    idx = np.nonzero(np.diff(gt) != 0)[0] + 1
    # events of the automatic schedule: tests in which no gear is held
    auto_kinds = {"acceleration", "deceleration", "cycle", "coastdown"}
    auto = [k for k in idx if gt[k] > 0 and gt[k - 1] > 0
            and any(s.kind in auto_kinds and s.contains(tr.time_s[k]) for s in tr.segments)]
    n_up = n_down = 0
    for k in auto:
        g0, g1 = gt[k - 1], gt[k]
        assert abs(g1 - g0) == 1
        if g1 > g0:
            line = sh.up_v0_kmh[g0 - 1] + sh.up_slope_kmh_per_pct[g0 - 1] * ped[k]
            assert v[k] >= line - 1e-9, (k, v[k], line)
            n_up += 1
        else:
            line = sh.down_v0_kmh[g1 - 1] + sh.down_slope_kmh_per_pct[g1 - 1] * ped[k]
            assert v[k] <= line + 1e-9, (k, v[k], line)
            n_down += 1
    assert n_up >= 16 and n_down >= 16
    # the actual gear follows the target after the actuation delay
    ga = tr["gear_actual"].astype(int)
    delay = vehicle.transmission.shift_delay_s
    for k in auto[:50]:
        lag = np.argmax(ga[k:] == gt[k]) * tr.dt_s
        assert lag >= delay - 1.5 * tr.dt_s


def test_regenerative_braking_comes_first_up_to_the_motor_limit(quick_trace, vehicle) -> None:
    tr = quick_trace
    seg = next(s for s in tr.segments if s.kind == "deceleration" and s.settings["protocol"] == "deceleration")
    part = tr.slice_time(seg.settings["decel_start_s"], seg.end_s)
    settled = _settled(part, vehicle)
    # above the fade-out zone (cut-off + 8 km/h) the motor takes all it can, except where the controller ramps
    # regeneration around a shift: out while a shift is pending, back in over the lock-up's engagement time
    braking = (part["brake_pedal_pct"] > 0) & (3.6 * part["vehicle_speed_mps"] > 18.5) & settled
    lu = part["lockup_closed"] == 1
    n_ramp = int(np.ceil(vehicle.torque_converter.lockup_engage_time_s / part.dt_s)) + 1
    closed_at = np.maximum.accumulate(np.where(np.concatenate([[True], lu[1:] & ~lu[:-1]]), np.arange(lu.size), 0))
    braking &= lu & (np.arange(lu.size) - closed_at >= n_ramp) & (part["gear_target"] == part["gear_actual"])
    assert braking.sum() > 100
    w = part["em_speed_radps"][braking]
    limit = np.interp(w * 30 / np.pi, vehicle.motor.full_load_speed_rpm, vehicle.motor.full_load_torque_nm)
    limit = np.minimum(limit, (vehicle.battery.max_charge_power_w + vehicle.motor.willans_w_loss_gen_w)
                       / (vehicle.motor.willans_e_gen * w))
    hyd = part["brake_torque_front_nm"][braking] + part["brake_torque_rear_nm"][braking]
    tm = part["em_torque_nm"][braking]
    below = tm > -limit + 1.0
    assert below.sum() > 50 and np.all(hyd[below] < 1e-6)  # below the motor's limit: all regenerative
    assert (tm < 0).all()
    # in the fade-out zone the regenerative share falls towards the cut-off speed, then braking is hydraulic only
    fade = (part["brake_pedal_pct"] > 5) & (part["gear_actual"] > 0)
    vk = 3.6 * part["vehicle_speed_mps"]
    hi = fade & (vk > 16.5) & (vk < 18.0)
    lo = fade & (vk > 10.5) & (vk < 13.0)
    regen = np.maximum(-part["shaft_torque_nm"] * vehicle.specs.final_drive_ratio, 0.0)
    share = regen / (regen + part["brake_torque_front_nm"] + part["brake_torque_rear_nm"] + 1e-9)
    assert hi.sum() > 5 and lo.sum() > 5 and np.mean(share[hi]) > np.mean(share[lo])
    slow = (part["brake_pedal_pct"] > 0) & (3.6 * part["vehicle_speed_mps"] < vehicle.brakes.regen_cutoff_speed_kmh)
    assert slow.sum() > 20 and np.all(part["em_torque_nm"][slow] >= 0)
