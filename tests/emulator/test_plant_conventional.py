"""The conventional-layout plant (vehicles/conventional_9at.toml): the P2 record with the motor's terms zeroed.

What a conventional car is, checked against numbers taken from the vehicle file, not from the plant: the engine
runs throughout, nothing of the motor or the pack reaches the Trace (NaN, named in the meta), the 12 V loads are
driven by the engine through the alternator (the ledger's ``alternator_drive`` is the alternator's electrical
output over its efficiency, summed from the Trace), the energy ledger closes, and in overrun the fuel is cut and
the engine drags its friction torque. The campaign rule and the setup rule are checked on the shipped files.
About 6 s (one ramp-up with brake steps, 80 s simulated).
"""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.config._base import scenario_path, validate_data
from benchtwin.config.campaign import CampaignConfig, load_campaign
from benchtwin.config.setup import load_setup
from benchtwin.config.vehicle import VehicleConfig, load_vehicle
from benchtwin.emulator import (
    ABSENT_CONVENTIONAL,
    check_campaign,
    conventional_tests,
    energy_balance,
    simulate_campaign,
)
from benchtwin.errors import ConfigError
from benchtwin.sensors import setup_for_trace

CONV = scenario_path("vehicles", "conventional_9at.toml")


@pytest.fixture(scope="module")
def conv_trace():
    vehicle = load_vehicle(CONV)
    ramp = {"kind": "ramp_up", "name": "g5_85", "gear": 5, "speed_kmh": 85.0, "pedal_steps_pct": [10.0, 30.0],
            "brake_steps_pct": [5.0, 10.0], "step_hold_s": 6.0, "engine": "on", "k0": "closed", "lockup": "closed"}
    campaign = validate_data(CampaignConfig, {"name": "conv", "seed": 3, "tests": [ramp]})
    return vehicle, simulate_campaign(vehicle, campaign)


def test_the_vehicle_file_says_its_layout_and_refuses_what_it_cannot_have():
    v = load_vehicle(CONV)
    assert v.layout == "conventional" and not v.has_motor
    assert v.motor is None and v.battery is None and v.hybrid is None
    p2 = load_vehicle(scenario_path("vehicles", "p2_phev_9at.toml"))
    data = v.model_dump(exclude_none=True)
    with pytest.raises(ValueError, match=r"layout 'conventional' has no motor or HV pack: remove the table\(s\) "
                                         r"\[motor\]"):
        VehicleConfig.model_validate({**data, "motor": p2.motor.model_dump()})
    with pytest.raises(ValueError, match="coast_regen_torque_nm must be 0"):
        VehicleConfig.model_validate({**data, "brakes": {**data["brakes"], "coast_regen_torque_nm": 15.0}})
    p2_data = p2.model_dump(exclude_none=True)
    del p2_data["battery"]
    with pytest.raises(ValueError, match=r"layout 'p2_phev' needs the table\(s\) \[battery\]"):
        VehicleConfig.model_validate(p2_data)


def test_tests_that_need_the_motor_are_refused_or_dropped_by_the_stated_rule():
    v = load_vehicle(CONV)
    quick = load_campaign(scenario_path("campaigns", "quick.toml"))
    with pytest.raises(ConfigError) as exc:
        check_campaign(v, quick)
    lines = str(exc.value).splitlines()
    assert len(lines) == 3
    assert "ramp_up_g4_60kmh_electric" in lines[0] and 'engine = "off"' in lines[0] and "no motor" in lines[0]
    kept, dropped = conventional_tests(quick)
    assert set(dropped) == {"ramp_up_g4_60kmh_electric", "constant_drive_deplete_90kmh",
                            "acceleration_pedal50_electric"}
    # the coastdown and neutral braking keep their "electric" label: in neutral it asks nothing of a motor
    assert [t.name for t in kept.tests] == ["ramp_up_g5_85kmh_hybrid", "ramp_down_pedal20", "deceleration_1p5",
                                            "neutral_braking_40kmh", "coastdown_130"]
    check_campaign(v, kept)
    for name in ("conventional.toml", "conventional_quick.toml"):
        check_campaign(v, load_campaign(scenario_path("campaigns", name)))


def test_the_trace_has_no_motor_or_pack_and_the_engine_always_runs(conv_trace):
    vehicle, trace = conv_trace
    c = trace.channels
    assert trace.meta["layout"] == "conventional" and set(trace.meta["absent_channels"]) == set(ABSENT_CONVENTIONAL)
    for name in ABSENT_CONVENTIONAL:
        assert np.all(np.isnan(c[name])), name
    assert np.all(c["engine_on"] == 1.0)
    assert np.min(c["engine_speed_radps"]) * 30 / np.pi > 0.75 * vehicle.engine.idle_speed_rpm  # never stalls
    led = trace.meta["energy_ledger_j"]
    for k in ("hv_battery_chemical", "hv_battery_resistive", "motor_loss", "k0_slip"):
        assert led[k] == 0.0, k


def test_the_alternator_drive_closes_the_ledger(conv_trace):
    vehicle, trace = conv_trace
    c = trace.channels
    dt = 1.0 / trace.meta["plant_rate_hz"]
    assert trace.meta["output_rate_hz"] == trace.meta["plant_rate_hz"]  # one output per plant step
    # the alternator delivers the 12 V side's power; it takes that over its efficiency from the engine
    electrical_j = float(np.sum(c["dcdc_lv_current_a"] * c["dcdc_lv_voltage_v"])) * dt
    led = trace.meta["energy_ledger_j"]
    assert led["alternator_drive"] == pytest.approx(electrical_j / vehicle.low_voltage.dcdc_efficiency, rel=1e-9)
    assert led["dcdc_loss"] == pytest.approx(led["alternator_drive"] - electrical_j, rel=1e-9)
    assert led["alternator_drive"] > 200.0 * trace.duration_s  # the 280 W base load at least, over its efficiency
    assert abs(energy_balance(led)["residual_frac"]) < 1e-9


def test_overrun_cuts_the_fuel_and_the_engine_drags_its_friction(conv_trace):
    vehicle, trace = conv_trace
    c = trace.channels
    rpm = c["engine_speed_radps"] * 30 / np.pi
    # the lock-up closed since the step before (the step it engages in still had the pump side free)
    closed = (c["lockup_closed"] > 0.5) & np.r_[False, c["lockup_closed"][:-1] > 0.5]
    overrun = (c["pedal_pct"] == 0) & closed & (c["gear_actual"] > 0) & (rpm > 1.3 * vehicle.engine.idle_speed_rpm)
    assert overrun.sum() > 500  # the brake steps at 85 km/h
    e = vehicle.engine
    np.testing.assert_allclose(c["engine_torque_nm"][overrun],
                               -(e.friction_torque_nm + e.friction_torque_nm_per_krpm * rpm[overrun] / 1000.0),
                               rtol=1e-12)
    assert np.all(c["fuel_mass_flow_kgps"][overrun] == 0.0)
    driving = (c["pedal_pct"] > 0) & closed
    assert np.all(c["fuel_mass_flow_kgps"][driving] > 0.0)


def test_the_setup_keeps_what_a_conventional_car_can_feed():
    paper = load_setup(scenario_path("setups", "paper.toml"))
    bench, dropped = setup_for_trace(paper, ABSENT_CONVENTIONAL)
    assert set(paper.ivt) - set(bench.ivt) == {"battery", "hpcu"}
    assert set(bench.ivt) == set(paper.ivt) - {"battery", "hpcu"}
    assert set(bench.thermo.places) == {"engine_coolant_in_degc", "engine_coolant_out_degc", "gearbox_oil_degc"}
    assert set(bench.vehicle_can.not_sent) == {"k0_closed", "em_speed_rpm", "em_torque_nm", "displayed_soc_pct"}
    assert any(d.startswith("ivt.battery") for d in dropped) and any("em_torque_nm" in d for d in dropped)
    assert setup_for_trace(paper, ()) == (paper, [])
    with pytest.raises(ConfigError, match=r"telemetry.*shaft_torque_nm.*remove it from the setup"):
        setup_for_trace(paper, [*ABSENT_CONVENTIONAL, "shaft_torque_nm"])
    with pytest.raises(ConfigError, match=r"ivt\.battery reads battery_current_a and battery_voltage_v"):
        setup_for_trace(paper, ["battery_current_a"])
