"""Campaign-level behaviour: depletion like Figure 14, determinism from the seed, the paper campaign's coverage."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from benchtwin.config._base import validate_data
from benchtwin.config.campaign import CampaignConfig
from benchtwin.emulator import simulate_campaign


def _campaign(tests: list[dict], **kw) -> CampaignConfig:
    data = {"name": "t", "seed": 1, "tests": tests, **kw}
    return validate_data(CampaignConfig, data, "<test>")


def test_depletion_like_figure_14(vehicle) -> None:
    camp = _campaign([{"kind": "constant_drive", "name": "deplete", "mode": "electric", "speed_kmh": 85.0,
                       "max_duration_s": 3000.0, "end_displayed_soc_pct": 13.0}], initial_displayed_soc_pct=45.0)
    tr = simulate_campaign(vehicle, camp)
    (seg,) = tr.segments
    assert seg.duration_s < 3000.0  # ended on the SOC condition, not on time
    hold = tr.slice_time(seg.settings["hold_start_s"] + 20.0, seg.end_s)
    cruising = (hold["vehicle_speed_mps"] > 84.0 / 3.6) & (hold["brake_pedal_pct"] == 0)
    cruising &= np.cumsum(hold["brake_pedal_pct"] > 0) == 0  # until the driver stops at 13 %
    soc = hold["displayed_soc_pct"][cruising]
    p_kw = (hold["battery_current_a"] * hold["battery_voltage_v"])[cruising] / 1e3
    assert 11.0 < np.mean(p_kw) < 15.0  # about 13 kW
    assert np.std(p_kw) / np.mean(p_kw) < 0.05  # roughly constant
    assert soc[-1] == pytest.approx(13.0, abs=0.2)
    assert soc[0] > 40.0
    assert np.all(np.diff(soc) <= 1e-12)  # monotonic discharge
    assert np.all(hold["engine_on"] == 0)
    v = hold["battery_voltage_v"][cruising]
    assert v[0] - v[-1] > 10.0  # the terminal voltage falls with SOC, as in Figure 14


def test_same_seed_identical_different_seed_different_12v_loads(vehicle) -> None:
    tests = [{"kind": "deceleration", "name": "d", "start_speed_kmh": 60.0, "decel_mps2": 1.0}]
    a = simulate_campaign(vehicle, _campaign(tests, seed=11))
    b = simulate_campaign(vehicle, _campaign(tests, seed=11))
    c = simulate_campaign(vehicle, _campaign(tests, seed=12))
    for name in a.channels:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert a.meta == b.meta
    assert not np.array_equal(a["dcdc_lv_current_a"], c["dcdc_lv_current_a"])

    # the 12 V loads draw from the seed; the drive itself follows the same protocol
    n = min(len(a), len(c))
    assert np.max(np.abs(a["vehicle_speed_mps"][:n] - c["vehicle_speed_mps"][:n])) < 0.5


def test_output_rate_decimates_the_plant(vehicle) -> None:
    tests = [{"kind": "deceleration", "name": "d", "start_speed_kmh": 50.0, "decel_mps2": 1.0}]
    full = simulate_campaign(vehicle, _campaign(tests, plant_rate_hz=100.0))
    slow = simulate_campaign(vehicle, _campaign(tests, plant_rate_hz=100.0, output_rate_hz=10.0))
    np.testing.assert_allclose(slow.dt_s, 0.1)
    np.testing.assert_array_equal(slow["vehicle_speed_mps"], full["vehicle_speed_mps"][::10][: len(slow)])


def test_every_test_kind_makes_one_segment_with_its_settings(quick_trace, quick_campaign) -> None:
    segs = quick_trace.segments
    assert [s.name for s in segs] == [t.name for t in quick_campaign.tests]
    assert {s.kind for s in segs} == {"ramp_up", "constant_drive", "acceleration", "deceleration",
                                      "neutral_braking", "coastdown"}
    for a, b in itertools.pairwise(segs):
        assert a.end_s == pytest.approx(b.start_s)
    ramp = segs[0]
    assert ramp.settings["gear"] == 5 and ramp.settings["speed_kmh"] == 85.0 and ramp.settings["mode"] == "hybrid"
    part = quick_trace.slice_time(ramp.settings["steps_start_s"], ramp.settings["steps_end_s"])
    assert np.all(part["gear_actual"] == 5)
    assert np.all(part["lockup_closed"] == 1) and np.all(part["k0_closed"] == 1) and np.all(part["engine_on"] == 1)
    np.testing.assert_allclose(part["vehicle_speed_mps"], 85 / 3.6, atol=0.3 / 3.6)  # the dyno holds the speed
    nb = next(s for s in segs if s.kind == "neutral_braking")
    part = quick_trace.slice_time(nb.settings["steps_start_s"], nb.settings["steps_end_s"])
    assert np.all(part["gear_actual"] == 0) and np.all(part["shaft_torque_nm"] == 0)
    braking = part["brake_torque_front_nm"] > 0
    # braking torque shows on the rollers: front roller force = -T_front / r - half the parasitic loss
    assert braking.sum() > 100
    assert np.all(part["dyno_force_front_n"][braking] < -100)


def test_paper_campaign_excites_every_gear_pair_at_three_pedals(paper_trace, vehicle) -> None:
    tr = paper_trace
    gt = tr["gear_target"].astype(int)
    ped = np.round(tr["pedal_pct"], 1)
    idx = np.nonzero(np.diff(gt) != 0)[0] + 1
    kinds = {"acceleration", "deceleration"}
    up: dict[int, set] = {g: set() for g in range(1, vehicle.n_gears)}
    down: dict[int, set] = {g: set() for g in range(1, vehicle.n_gears)}
    for k in idx:
        if not any(s.kind in kinds and s.contains(tr.time_s[k]) for s in tr.segments):
            continue
        g0, g1 = gt[k - 1], gt[k]
        if g0 > 0 and g1 == g0 + 1:
            up[g0].add(ped[k])
        elif g1 > 0 and g1 == g0 - 1:
            down[g1].add(ped[k])
    for g in range(1, vehicle.n_gears):
        assert len(up[g]) >= 3, (g, up[g])
        assert len(down[g]) >= 3, (g, down[g])
    names = {s.name: s for s in tr.segments}
    dep = tr.segment("constant_drive_deplete_85kmh")
    assert dep["displayed_soc_pct"].min() <= 13.2
    chg = tr.segment("constant_drive_charge_50kmh")
    assert chg["displayed_soc_pct"].max() >= 35.0 and np.mean(chg["engine_on"]) > 0.9
    assert {s.kind for s in names.values()} == {"ramp_up", "constant_drive", "acceleration", "deceleration",
                                                "neutral_braking", "cycle", "coastdown"}
    assert all(tr.segment(f"ramp_up_hybrid_g{g}_{v}kmh")["gear_actual"].max() >= g for g, v in
               [(1, 15), (9, 130)])
    # electric take-offs run through the open torque converter with K0 open
    acc = tr.segment("acceleration_electric_pedal35")
    slip = (acc["lockup_closed"] == 0) & (acc["vehicle_speed_mps"] > 1) & (acc["gear_actual"] == 1)
    assert slip.sum() > 100 and np.all(acc["k0_closed"][slip] == 0)


@pytest.fixture(scope="module")
def wltc_by_mode(vehicle) -> dict:
    out = {}
    for mode in ("hybrid", "electric", "e_save", "charge"):
        camp = _campaign([{"kind": "cycle", "mode": mode}], initial_displayed_soc_pct=50.0)
        out[mode] = simulate_campaign(vehicle, camp)
    return out


def test_the_four_hybrid_modes_behave_as_the_paper_describes(wltc_by_mode) -> None:
    soc = {m: (tr["displayed_soc_pct"][0], tr["displayed_soc_pct"][-1]) for m, tr in wltc_by_mode.items()}
    eon = {m: float(np.mean(tr["engine_on"])) for m, tr in wltc_by_mode.items()}
    for m, tr in wltc_by_mode.items():
        np.testing.assert_array_equal(tr["hybrid_mode"], {"hybrid": 0, "electric": 1, "e_save": 2, "charge": 3}[m])
    # Electric: the engine never runs below the kick-down point; the battery alone drives the cycle
    assert eon["electric"] == 0.0 and np.all(wltc_by_mode["electric"]["fuel_mass_flow_kgps"] == 0)
    assert soc["electric"][1] < soc["electric"][0] - 20
    # Hybrid: electric driving with the engine for high power (it does start on the extra-high phase)
    assert 0.0 < eon["hybrid"] < 0.3 and soc["hybrid"][1] < soc["hybrid"][0]
    # E-Save: the SOC is held
    assert abs(soc["e_save"][1] - soc["e_save"][0]) < 3.0 and eon["e_save"] > eon["hybrid"]
    # Charge: the engine charges the battery, the motor never propels the car while the engine runs
    ch = wltc_by_mode["charge"]
    assert soc["charge"][1] > soc["charge"][0] + 10
    both = (ch["engine_on"] > 0.5) & (ch["k0_closed"] > 0.5)
    assert both.mean() > 0.5 and np.all(ch["em_torque_nm"][both] <= 1e-9)


def test_part_of_a_cycle_then_the_driver_stops(vehicle) -> None:
    camp = _campaign([{"kind": "cycle", "name": "part", "from_s": 100.0, "to_s": 200.0}])
    tr = simulate_campaign(vehicle, camp)
    (seg,) = tr.segments
    assert seg.settings["from_s"] == 100.0 and seg.settings["to_s"] == 200.0
    from benchtwin.emulator.protocols import load_cycle

    tc, vc = load_cycle("wltc_class3b.csv")
    m = tr.time_s <= 100.0
    err = 3.6 * (tr["vehicle_speed_mps"][m] - np.interp(tr.time_s[m] + 100.0, tc, vc))
    assert np.sqrt(np.mean(err**2)) < 1.0
    assert tr["vehicle_speed_mps"][-1] == 0.0
    with pytest.raises(Exception, match="to_s must be after from_s"):
        _campaign([{"kind": "cycle", "from_s": 100.0, "to_s": 50.0}])


def test_campaign_that_does_not_fit_the_vehicle_is_refused(vehicle) -> None:
    from benchtwin.errors import ConfigError

    camp = _campaign([{"kind": "ramp_up", "name": "g12", "gear": 12, "speed_kmh": 50.0, "pedal_steps_pct": [5.0]},
                      {"kind": "ramp_up", "name": "fast", "gear": 1, "speed_kmh": 120.0, "pedal_steps_pct": [5.0]}])
    with pytest.raises(ConfigError) as exc:
        simulate_campaign(vehicle, camp)
    lines = str(exc.value).splitlines()
    assert len(lines) == 2
    assert "tests[0] (g12): key 'gear' = 12: the vehicle has 9 gears" in lines[0]
    assert "tests[1] (fast): key 'speed_kmh' = 120.0" in lines[1] and "exceeds" in lines[1]


def test_electric_test_may_run_to_the_motor_top_speed_not_the_engine_s(vehicle) -> None:
    from benchtwin.emulator import check_campaign
    from benchtwin.errors import ConfigError

    # gear 2 at 85 km/h: 85 / 3.6 / 0.352 * 2.65 * 3.25 rad/s = 5,516 rpm, above the engine's 4,600 rpm and
    # below the motor's 6,000 rpm
    rpm = 85 / 3.6 / vehicle.specs.wheel_radius_m * vehicle.specs.final_drive_ratio * 3.25 * 30 / np.pi
    assert vehicle.engine.max_speed_rpm < rpm < vehicle.motor.max_speed_rpm
    test = {"kind": "ramp_up", "name": "e", "gear": 2, "speed_kmh": 85.0, "pedal_steps_pct": [5.0]}
    check_campaign(vehicle, _campaign([{**test, "engine": "off", "k0": "open"}]))
    with pytest.raises(ConfigError, match="4600 rpm"):
        check_campaign(vehicle, _campaign([test]))


def test_controller_coefficients_are_the_tustin_discretisation_of_the_designed_pi() -> None:
    from benchtwin.emulator.params import _pi_coefficients

    mass, bw, zeta, dt = 2162.0, 1.5, 1.0, 0.01
    b0, b1 = _pi_coefficients(mass, bw, zeta, dt)
    kp, ki = 2 * zeta * bw * mass, bw**2 * mass
    np.testing.assert_allclose([b0, b1], [kp + ki * dt / 2, -kp + ki * dt / 2], rtol=1e-12)


def test_12v_loads_vary_over_time_and_the_12v_battery_buffers_them(quick_trace) -> None:
    i_dcdc = quick_trace["dcdc_lv_current_a"]
    assert len(np.unique(np.round(i_dcdc, 0))) >= 5  # fan duty levels and pump on/off
    i_lv = quick_trace["lv_battery_current_a"]
    assert i_lv.min() < 0 < i_lv.max()  # charged at light load, discharging at heavy load (DC/DC droop)
    v_lv = quick_trace["dcdc_lv_voltage_v"]
    assert v_lv.min() > 13.5 and v_lv.max() < 14.5
    np.testing.assert_array_equal(v_lv, quick_trace["lv_battery_voltage_v"])
