"""The high-fidelity plant (fidelity = "high"): each new physics term against a hand computation from the
vehicle file's values (docs/fidelity.md), and the whole plant's energy ledger on a short campaign."""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.config import scenario_path, validate_data
from benchtwin.config.campaign import CampaignConfig, load_campaign
from benchtwin.config.vehicle import VehicleConfig, load_vehicle
from benchtwin.emulator import energy_balance, simulate_campaign
from benchtwin.emulator.models import cold_start_factor, motor_loss_hifi_w, tabulated_converter_torques_nm, tyre_slip
from benchtwin.emulator.params import (
    P_AMBIENT_DEGC,
    P_DT_S,
    P_HF_OIL_REF_DEGC,
    P_HF_OIL_VISC_PER_K,
    P_HF_SLIP_STIFFNESS_N,
    P_HF_SPIN_PER_RADPS,
    P_HIFI,
    build_tables,
)
from benchtwin.emulator.steps_energy import (
    engine_fuel,
    hifi_thermal_step,
    hv_battery,
    hv_battery_dynamics,
    hv_battery_hifi,
)
from benchtwin.emulator.steps_powertrain import driveline_step

RPM = np.pi / 30.0


@pytest.fixture(scope="module")
def hifi() -> VehicleConfig:
    return load_vehicle(scenario_path("vehicles", "p2_phev_9at_hifi.toml"))


@pytest.fixture(scope="module")
def tab(hifi: VehicleConfig):
    return build_tables(hifi, load_campaign("quick.toml"))


def test_paper_vehicle_has_no_high_fidelity_tables() -> None:
    t = build_tables(load_vehicle(), load_campaign("quick.toml"))
    assert t.p[P_HIFI] == 0.0 and t.tc_sr.size == 0 and t.motor_loss.size == 0


def test_fidelity_key_and_table_go_together(hifi: VehicleConfig) -> None:
    data = hifi.model_dump()
    data["fidelity"] = "paper"
    with pytest.raises(Exception, match="high_fidelity"):
        validate_data(VehicleConfig, data)


def test_motor_loss_by_hand(hifi: VehicleConfig, tab) -> None:
    m = hifi.high_fidelity.motor
    wb = m.base_speed_rpm * RPM
    for t, n in ((200.0, 4000.0), (-120.0, 1200.0), (400.0, 500.0)):
        w = n * RPM
        phi = min(1.0, wb / w)
        fw = max(0.0, 1.0 - wb / w)
        want = (m.copper_w_per_nm2 * t**2 + m.d_axis_w * fw**2
                + (m.hysteresis_w_per_radps * w + m.eddy_w_per_radps2 * w**2) * phi**2
                + m.friction_w_per_radps * w + m.windage_w_per_radps3 * w**3 + m.inverter_standby_w
                + m.inverter_switching_w_per_nm * abs(t))
        assert motor_loss_hifi_w(tab.motor_loss, t, w) == pytest.approx(want, rel=1e-12)


def test_motor_map_is_not_a_willans_line_and_peaks_in_the_centre_right(hifi: VehicleConfig, tab) -> None:
    # efficiency over the full-load envelope: peak 94-95 % (Figure 11) above 2500 rpm and below 300 Nm,
    # and the loss at fixed speed is not affine in torque (a Willans line's is)
    best = (0.0, 0.0, 0.0)
    for n in np.arange(500.0, 6001.0, 250.0):
        tmax = np.interp(n, hifi.motor.full_load_speed_rpm, hifi.motor.full_load_torque_nm)
        for t in np.arange(10.0, tmax + 1e-9, 10.0):
            w = n * RPM
            eff = t * w / (t * w + motor_loss_hifi_w(tab.motor_loss, t, w))
            best = max(best, (eff, n, t))
    assert 0.94 <= best[0] <= 0.95 and best[1] >= 2500.0 and best[2] <= 300.0, best
    w = 2000 * RPM
    loss = [motor_loss_hifi_w(tab.motor_loss, t, w) for t in (0.0, 150.0, 300.0)]
    assert loss[2] - loss[1] > 1.5 * (loss[1] - loss[0])  # copper T^2: convex, not affine


def test_tabulated_converter_by_hand(hifi: VehicleConfig, tab) -> None:
    c = hifi.high_fidelity.torque_converter
    wp, sr = 200.0, 0.45  # between the 0.4 and 0.5 rows
    k = np.interp(sr, c.speed_ratio, c.k_factor_rpm_per_sqrt_nm)  # not the plant's: K, not 1/K^2, interpolated
    tr = np.interp(sr, c.speed_ratio, c.torque_ratio)
    tp, tt, dtp = tabulated_converter_torques_nm(tab.tc_sr, tab.tc_cap, tab.tc_tr, wp, sr * wp)
    # the plant interpolates the capacity 1/K^2 linearly: within 0.5 % of (n/K)^2 at a mid-point of a
    # 0.1-wide row where K changes by 4 %
    assert tp == pytest.approx((wp / RPM / k) ** 2, rel=5e-3)
    assert tt / tp == pytest.approx(tr, rel=1e-12)
    # at a table point exactly
    tp1, _tt1, _d1 = tabulated_converter_torques_nm(tab.tc_sr, tab.tc_cap, tab.tc_tr, wp, 0.5 * wp)
    assert tp1 == pytest.approx((wp / RPM / c.k_factor_rpm_per_sqrt_nm[5]) ** 2, rel=1e-12)
    # the derivative at fixed turbine speed against a central difference
    h = 1e-3
    tpp, _a, _b = tabulated_converter_torques_nm(tab.tc_sr, tab.tc_cap, tab.tc_tr, wp + h, sr * wp)
    tpm, _a, _b = tabulated_converter_torques_nm(tab.tc_sr, tab.tc_cap, tab.tc_tr, wp - h, sr * wp)
    assert dtp == pytest.approx((tpp - tpm) / (2 * h), rel=1e-4)
    # overrun: the wheels drive the pump (negative pump torque) beyond SR 1
    tpo, tto, _d = tabulated_converter_torques_nm(tab.tc_sr, tab.tc_cap, tab.tc_tr, 100.0, 120.0)
    assert tpo < 0.0 and tto == tpo


def test_spin_loss_drag_in_the_driveline(hifi: VehicleConfig, tab) -> None:
    tr = hifi.high_fidelity.transmission
    g, w_in, oil = 3, 250.0, 40.0
    c = hifi.transmission.c0_nm[g - 1] * (1.0 + tr.spin_per_radps * w_in) * np.exp(
        -tr.oil_viscosity_per_k * (oil - tr.oil_reference_degc))
    assert c > 2.0 * hifi.transmission.c0_nm[g - 1]  # cold oil and speed: well above the constant C0
    from benchtwin.emulator.models import spin_loss_torque_nm

    p = tab.p
    drag = spin_loss_torque_nm(tab.c0[g], p[P_HF_SPIN_PER_RADPS], p[P_HF_OIL_VISC_PER_K], p[P_HF_OIL_REF_DEGC],
                               w_in, oil)
    assert drag == pytest.approx(c, rel=1e-12)
    # lock-up closed, drive: T_out = i_g eta_m (T_in - C(w, T_oil))
    kg = hifi.specs.gear_ratios[g - 1] * hifi.specs.final_drive_ratio / hifi.specs.wheel_radius_m
    v = w_in / kg
    out = driveline_step(tab, g, True, v, w_in, w_in, 150.0, 0.36, kg, hifi.specs.gear_ratios[g - 1], 0.0, 0.0,
                         0.0, 0.0, 2162.0, -300.0, 0.0, drag)
    tin, tout = out[4], out[5]
    assert tout == pytest.approx(hifi.specs.gear_ratios[g - 1] * hifi.transmission.eta_m[g - 1] * (tin - c),
                                 rel=1e-12)


def test_pack_with_rc_branches_hysteresis_and_cold_resistance(hifi: VehicleConfig, tab) -> None:
    b = hifi.high_fidelity.battery
    n = hifi.specs.n_cells_series
    soc, power, u1, u2, h, temp = 0.5, 40e3, 1.5, 0.8, -0.5, 5.0
    uoc, r_paper, _i, _v = hv_battery(tab, soc, power)
    r0 = r_paper * np.exp(b.r0_temp_coeff_per_k * (25.0 - temp))
    src = uoc + h * n * b.hysteresis_v_per_cell - u1 - u2
    i_hand = (src - np.sqrt(src**2 - 4 * r0 * power)) / (2 * r0)
    uoc2, r_loss, ib, vb = hv_battery_hifi(tab, soc, power, u1, u2, h, temp)
    assert uoc2 == uoc and ib == pytest.approx(i_hand, rel=1e-12)
    assert vb * ib == pytest.approx(power, rel=1e-9)  # the terminal power drawn
    assert r_loss * ib**2 == pytest.approx((uoc - vb) * ib, rel=1e-12)  # every pack loss in the ledger's R I^2
    assert r0 > 1.6 * r_paper  # 20 K colder: exp(0.025 x 20) = 1.65
    # RC branches: exact step against a fine explicit Euler integration of du/dt = (R I - u) / tau
    dt = tab.p[P_DT_S]
    u1n, u2n, hn = hv_battery_dynamics(tab.p, ib, u1, u2, h)
    r1, tau1 = n * b.r1_ohm_per_cell, b.tau1_s
    u = u1
    for _k in range(1000):
        u += dt / 1000 * (r1 * ib - u) / tau1
    assert u1n == pytest.approx(u, rel=1e-5)
    # hysteresis moves towards -1 while discharging, by 1 - exp(-I dt / Q_h) of the way
    frac = 1.0 - np.exp(-ib * dt / (b.hysteresis_charge_ah * 3600.0))
    assert hn == pytest.approx(h + (-1.0 - h) * frac, rel=1e-12) and hn < h
    _a, _b, hc = hv_battery_dynamics(tab.p, -50.0, u1, u2, h)
    assert hc > h and u2n != u2


def test_cold_start_fuel_and_thermal_states(hifi: VehicleConfig, tab) -> None:
    e = hifi.high_fidelity.engine
    assert cold_start_factor(e.cold_penalty_frac, e.warm_degc, 20.0) == pytest.approx(1.0 + e.cold_penalty_frac)
    assert cold_start_factor(e.cold_penalty_frac, e.warm_degc, 90.0) == 1.0
    warm, _ = engine_fuel(tab, True, True, 150.0, 200.0, 200.0, 0.0, 90.0)
    cold, _ = engine_fuel(tab, True, True, 150.0, 200.0, 200.0, 0.0, 50.0)
    assert cold == pytest.approx(warm * (1.0 + e.cold_penalty_frac * 30.0 / 60.0), rel=1e-12)
    # one explicit Euler step of each lump, by hand from the vehicle file's thermal section
    th, tr = hifi.thermal, hifi.high_fidelity.transmission
    dt, amb = tab.p[P_DT_S], tab.p[P_AMBIENT_DEGC]
    tb, tc, to = hifi_thermal_step(tab.p, 30e3, 2e3, 1.5e3, 30.0, 50.0, 40.0)
    assert tb == pytest.approx(30.0 + dt * (2e3 - th.battery_ua_w_per_k * (30.0 - amb - 1.5))
                               / th.battery_heat_capacity_j_per_k, rel=1e-12)
    q_rad = th.engine_radiator_ua_w_per_k * 0.03 * (50.0 - amb)  # thermostat closed (3 % bypass)
    assert tc == pytest.approx(50.0 + dt * (th.engine_heat_to_coolant_frac * 30e3 - q_rad)
                               / th.engine_heat_capacity_j_per_k, rel=1e-12)
    assert to == pytest.approx(40.0 + dt * (1.5e3 - tr.oil_ua_w_per_k * (40.0 - 50.0))
                               / tr.oil_heat_capacity_j_per_k, rel=1e-12)


@pytest.fixture(scope="module")
def short_trace(hifi: VehicleConfig):
    camp = validate_data(CampaignConfig, {
        "name": "hifi_short", "seed": 3, "initial_displayed_soc_pct": 60.0, "tests": [
            {"kind": "ramp_up", "name": "g4_hybrid", "mode": "hybrid", "gear": 4, "speed_kmh": 60.0,
             "pedal_steps_pct": [10.0, 40.0], "step_hold_s": 5.0, "engine": "on", "k0": "closed",
             "lockup": "closed"},
            {"kind": "acceleration", "name": "acc", "mode": "electric", "pedal_pct": 40.0,
             "end_speed_kmh": 80.0, "max_duration_s": 40.0}]})
    return simulate_campaign(hifi, camp)


def test_hifi_plant_ledger_closes_and_states_feed_back(hifi: VehicleConfig, short_trace) -> None:
    tr = short_trace
    bal = energy_balance(tr.meta["energy_ledger_j"])
    assert abs(bal["residual_frac"]) < 0.005, bal
    c = tr.channels
    # motor DC power is T w + loss(T, w) of the loss model, by hand, not a Willans line
    m = hifi.high_fidelity.motor
    t, w = c["em_torque_nm"], c["em_speed_radps"]
    k = np.flatnonzero((np.abs(t) > 20.0) & (w > 50.0))
    assert k.size > 100
    tk, wk = t[k], w[k]
    wb = m.base_speed_rpm * RPM
    phi = np.minimum(1.0, wb / wk)
    fw = np.maximum(0.0, 1.0 - wb / wk)
    loss = (m.copper_w_per_nm2 * tk**2 + m.d_axis_w * fw**2 + (m.hysteresis_w_per_radps * wk
            + m.eddy_w_per_radps2 * wk**2) * phi**2 + m.friction_w_per_radps * wk + m.windage_w_per_radps3 * wk**3
            + m.inverter_standby_w + m.inverter_switching_w_per_nm * np.abs(tk))
    np.testing.assert_allclose(c["em_elec_power_w"][k], tk * wk + loss, rtol=1e-9)
    # the cell temperature is a state of the loop that rises with the pack's losses
    assert c["battery_temp_degc"][-1] > c["battery_temp_degc"][0] + 0.05


def test_tyre_slip_by_hand(hifi: VehicleConfig, tab) -> None:
    ty = hifi.high_fidelity.tyre
    # C_k = (C_k / F_z) x m g x axle share: 18 x 2162 kg x 9.81 m/s^2 x 0.5 = 190,883 N per unit slip
    c_k = 18.0 * 2162.0 * 9.81 * 0.5
    assert (ty.slip_stiffness_per_load, ty.driven_axle_load_share) == (18.0, 0.5)
    assert tab.p[P_HF_SLIP_STIFFNESS_N] == pytest.approx(c_k, rel=1e-12)
    assert tyre_slip(1000.0, c_k) == pytest.approx(1000.0 / 190882.98, rel=1e-6)  # 0.524 %
    assert tyre_slip(-3000.0, c_k) == pytest.approx(-0.015716, rel=1e-4)  # braking: the wheel turns slower
    assert tyre_slip(30000.0, c_k) == 0.1  # beyond the linear range the model stops at 10 %
    assert tyre_slip(1000.0, 0.0) == 0.0  # paper form: no slip
    paper = build_tables(load_vehicle(), load_campaign("quick.toml"))
    assert paper.p[P_HF_SLIP_STIFFNESS_N] == 0.0


def test_tyre_slip_in_the_plant(hifi: VehicleConfig, short_trace) -> None:
    """Wheel speed over roller speed on the steady holds is 1 + F_x / C_k, F_x the driven axle's force."""
    c, sp = short_trace.channels, hifi.specs
    rl = hifi.road_load
    v, vd = c["vehicle_speed_mps"], c["dyno_speed_mps"]
    kmh = 3.6 * vd
    parasitic = rl.parasitic_f0_n + rl.parasitic_f1_n_per_kmh * kmh + rl.parasitic_f2_n_per_kmh2 * kmh**2
    f_x = c["dyno_force_rear_n"] + 0.5 * parasitic  # the rear channel carries half the parasitic loss
    c_k = 18.0 * sp.test_mass_kg * 9.81 * 0.5
    # steady samples: the force moved by less than 0.5 % of itself from the previous output (the slip is that of
    # the previous plant step's force, which lies between the two), moving at more than 5 m/s, in drive
    df = np.abs(np.diff(f_x, prepend=np.nan))
    k = np.flatnonzero((vd > 5.0) & (df < 0.005 * np.abs(f_x)) & (np.abs(f_x) > 200.0))
    assert k.size > 200
    slip = v[k] / vd[k] - 1.0
    np.testing.assert_allclose(slip, f_x[k] / c_k, rtol=0.01)
    assert slip.max() > 0.003  # the holds at 40 % pedal slip measurably
    # the wheel and shaft speeds follow the wheels, the dyno measures the roller
    np.testing.assert_allclose(c["wheel_speed_radps"] * sp.wheel_radius_m, v, rtol=1e-12)
    np.testing.assert_allclose(c["shaft_speed_radps"] * sp.wheel_radius_m / sp.final_drive_ratio, v, rtol=1e-12)
    # the slip loss is booked: F_x v s summed over the test, within the ledger's own closure
    led = short_trace.meta["energy_ledger_j"]
    assert led["tyre_slip"] > 0.0


@pytest.mark.parametrize(("key", "value"), [("slip_stiffness_per_load", 0.0), ("driven_axle_load_share", 1.5)])
def test_bad_tyre_table_is_a_clear_error(hifi: VehicleConfig, key: str, value: float) -> None:
    data = hifi.model_dump()
    data["high_fidelity"]["tyre"][key] = value
    with pytest.raises(Exception, match=rf"high_fidelity\.tyre\.{key}"):
        validate_data(VehicleConfig, data)
