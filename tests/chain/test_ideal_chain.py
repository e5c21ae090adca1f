"""With every imperfection off, every Recording channel equals the Trace within its sensor's resolution."""

from __future__ import annotations

import cantools
import numpy as np
import pytest

from benchtwin.chain.batch import run_batch
from benchtwin.config import load_setup, scenario_path
from benchtwin.config.setup import IVT_PLACES
from benchtwin.recording import Flag, Recording
from benchtwin.roles import ROLES
from benchtwin.sensors.imperfections import hold_sample
from benchtwin.sensors.synthetic import synthetic_trace
from benchtwin.trace import Trace
from benchtwin.wire.dbc import DBC_DIR

SETUP = load_setup("ideal")


@pytest.fixture(scope="module")
def trace() -> Trace:
    return synthetic_trace(60.0, 100.0, seed=3)


@pytest.fixture(scope="module")
def recording(trace: Trace, tmp_path_factory: pytest.TempPathFactory) -> Recording:
    # through the files: MF4 bus logs and the poll log are written and read back
    return run_batch(trace, SETUP, seed=11, out_dir=tmp_path_factory.mktemp("ideal"))


RPM = 60.0 / (2.0 * np.pi)
#: role -> (trace channel, factor to the role's unit, zero-order hold, DBC file, signal): written out here from
#: docs/sensor_chain.md, so the test does not borrow the production signal map
CAN_ROLES: dict[str, tuple[str, float, bool, str, str]] = {
    "engine_speed_rpm": ("engine_speed_radps", RPM, False, "vehicle", "EngSpeed"),
    "engine_torque_nm": ("engine_torque_nm", 1.0, False, "vehicle", "EngTorque"),
    "engine_on": ("engine_on", 1.0, True, "vehicle", "EngOn"),
    "em_speed_rpm": ("em_speed_radps", RPM, False, "vehicle", "EmSpeed"),
    "em_torque_nm": ("em_torque_nm", 1.0, False, "vehicle", "EmTorque"),
    "fuel_mass_flow_gps": ("fuel_mass_flow_kgps", 1000.0, False, "vehicle", "FuelMassFlow"),
    "gear_target": ("gear_target", 1.0, True, "vehicle", "GearTarget"),
    "gear_actual": ("gear_actual", 1.0, True, "vehicle", "GearActual"),
    "lockup_closed": ("lockup_closed", 1.0, True, "vehicle", "LockupClosed"),
    "k0_closed": ("k0_closed", 1.0, True, "vehicle", "K0Closed"),
    "pedal_pct": ("pedal_pct", 1.0, False, "vehicle", "AccelPedal"),
    "brake_pedal_pct": ("brake_pedal_pct", 1.0, False, "vehicle", "BrakePedal"),
    "vehicle_speed_kmh": ("vehicle_speed_mps", 3.6, False, "vehicle", "VehicleSpeed"),
    "displayed_soc_pct": ("displayed_soc_pct", 1.0, False, "vehicle", "DisplayedSOC"),
    "hybrid_mode": ("hybrid_mode", 1.0, True, "vehicle", "HybridMode"),
    "dyno_speed_kmh": ("dyno_speed_mps", 3.6, False, "dyno", "RollerSpeed"),
    "dyno_set_speed_kmh": ("dyno_set_speed_mps", 3.6, False, "dyno", "SetSpeed"),
    "dyno_force_front_n": ("dyno_force_front_n", 1.0, False, "dyno", "ForceFront"),
    "dyno_force_rear_n": ("dyno_force_rear_n", 1.0, False, "dyno", "ForceRear"),
}


def _dbc_scale(stem: str, signal: str) -> float:
    db = cantools.database.load_file(str(DBC_DIR / f"{stem}.dbc"))
    return next(float(s.scale) for m in db.messages for s in m.signals if s.name == signal)


def truth_and_tolerance(trace: Trace) -> dict[str, tuple[str, float, bool, float]]:
    """role -> (trace channel, factor to role unit, hold, tolerance in role unit)."""
    out: dict[str, tuple[str, float, bool, float]] = {}
    for role, (name, factor, hold, stem, signal) in CAN_ROLES.items():
        out[role] = (name, factor, hold, 0.5 * _dbc_scale(stem, signal) * (1 + 1e-9) + 1e-9)
    for place, cfg in SETUP.ivt.items():
        ch_i, ch_u, role_i, role_u = IVT_PLACES[place]
        out[role_i] = (ch_i, 1.0, False, cfg.current_range_a / 2**cfg.adc_bits + 0.0005 + 1e-9)
        out[role_u] = (ch_u, 1.0, False, cfg.voltage_range_v / 2**cfg.adc_bits + 0.0005 + 1e-9)
    # eq. 12 with the paper's shaft (facts.md): K_TOT = 218,725 / K_TEL Nm/V; 12 bits over +-10 V
    tel = SETUP.telemetry
    out["shaft_torque_nm"] = ("shaft_torque_nm", 1.0, False, 0.5 * 218_725.0 / tel.k_tel * 20 / 4096 * 1.0001)
    # 16-bit module over 0-10 V, transducer full scale / output voltage
    lsb_bar = 10.0 / 65535 * SETUP.pressure.full_scale_bar / SETUP.pressure.full_scale_v
    for trace_name, role in (("brake_pressure_fl_pa", "brake_pressure_fl_bar"),
                             ("brake_pressure_fr_pa", "brake_pressure_fr_bar"),
                             ("brake_pressure_rl_pa", "brake_pressure_rl_bar"),
                             ("brake_pressure_rr_pa", "brake_pressure_rr_bar"),
                             ("master_cylinder_pa", "master_cylinder_bar")):
        out[role] = (trace_name, 1e-5, False, 0.5 * lsb_bar + 1e-9)
    for place in SETUP.thermo.places:
        # 0.1 degC output step, 0.5 uV input converter (~0.013 degC at 39 uV/degC)
        out[place] = (place, 1.0, False, 0.05 + 0.0065 + 1e-6)
    return out


def test_every_role_is_recorded(recording: Recording) -> None:
    missing = sorted(set(ROLES) - set(recording.channels))
    assert missing == []
    for role, (unit, _) in ROLES.items():
        assert recording[role].unit == unit, role


def test_ideal_chain_equals_trace_within_resolution(trace: Trace, recording: Recording) -> None:
    checked = 0
    for role, (name, factor, hold, tol) in truth_and_tolerance(trace).items():
        ch = recording[role]
        assert len(ch) > 50, role
        x = trace[name] * factor
        truth = hold_sample(trace.time_s, x, ch.timestamps) if hold else np.interp(ch.timestamps, trace.time_s, x)
        finite = np.isfinite(truth)
        np.testing.assert_array_equal(np.isfinite(ch.values), finite, err_msg=role)
        err = np.abs(ch.values[finite] - truth[finite])
        assert err.max() <= tol, f"{role}: max error {err.max():.6g} > resolution/2 {tol:.6g}"
        # nothing flagged on an ideal chain (NaN set speed = road-load mode is not a flag)
        assert not np.any(ch.flags), role
        checked += 1
    assert checked >= 40


def test_ideal_ivt_power_and_charge(trace: Trace, recording: Recording) -> None:
    p = recording["battery_power_w"]
    i = np.interp(p.timestamps, trace.time_s, trace["battery_current_a"])
    u = np.interp(p.timestamps, trace.time_s, trace["battery_voltage_v"])
    tol = np.abs(u) * 1000 / 2**16 + np.abs(i) * 600 / 2**16 + 0.5 + 0.01
    assert np.all(np.abs(p.values - i * u) <= tol)
    q = recording["ivt_battery_charge_as"]
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (trace["battery_current_a"][1:] + trace["battery_current_a"][:-1])
                                           * np.diff(trace.time_s))])
    assert np.all(np.abs(q.values - np.interp(q.timestamps, trace.time_s, cum)) < 1.0 + 1e-9)


def test_ideal_chain_meta(recording: Recording, trace: Trace) -> None:
    m = recording.meta
    assert m["protocol_errors"] == {} and m["unknown_ids"] == {}
    assert m["modbus"]["brake_pressure"]["timeouts"] == 0
    assert abs(m["clock_offsets_s"]["vehicle_can->dyno"]) < 0.002
    assert [s.name for s in recording.segments] == [s.name for s in trace.segments]
    assert 0 < m["bus_load"]["instrument"] < 0.5


# ---------------------------------------------------------------- on the emulator's quick campaign
# every channel equals the Trace within resolution, except samples flagged SATURATED, which read the
# range limit while the truth is beyond it


@pytest.fixture(scope="module")
def quick_trace() -> Trace:
    emulator = pytest.importorskip("benchtwin.emulator")
    from benchtwin.config.campaign import load_campaign
    from benchtwin.config.vehicle import load_vehicle

    simulate_campaign = emulator.simulate_campaign

    return simulate_campaign(load_vehicle(scenario_path("vehicles", "p2_phev_9at.toml")),
                                      load_campaign(scenario_path("campaigns", "quick.toml")))


@pytest.fixture(scope="module")
def quick_recording(quick_trace: Trace) -> Recording:
    return run_batch(quick_trace, SETUP, seed=7)


def test_quick_campaign_ideal_chain(quick_trace: Trace, quick_recording: Recording) -> None:
    assert load_setup("ideal") == SETUP
    for role, (name, factor, hold, tol) in truth_and_tolerance(quick_trace).items():
        ch = quick_recording[role]
        x = quick_trace[name] * factor
        truth = hold_sample(quick_trace.time_s, x, ch.timestamps) if hold else np.interp(
            ch.timestamps, quick_trace.time_s, x)
        sat = (ch.flags & int(Flag.SATURATED)) != 0
        ok = np.isfinite(truth) & ~sat
        err = np.abs(ch.values[ok] - truth[ok])
        assert err.max() <= tol, f"{role}: {err.max():.6g} > {tol:.6g}"
        if sat.any():  # saturated samples read the range limit while the truth is beyond it
            assert np.all(np.abs(truth[sat]) >= np.abs(ch.values[sat]) - tol), role
    assert quick_recording.meta["protocol_errors"] == {}
    assert [s.name for s in quick_recording.segments] == [s.name for s in quick_trace.segments]
    # a pressure beyond the transducer's output limit (105 bar) is flagged, and only then
    p = quick_recording["brake_pressure_fl_bar"]
    limit = SETUP.pressure.output_max_v / SETUP.pressure.full_scale_v * SETUP.pressure.full_scale_bar
    over = np.interp(p.timestamps, quick_trace.time_s, quick_trace["brake_pressure_fl_pa"]) / 1e5 > limit + 0.01
    under = np.interp(p.timestamps, quick_trace.time_s, quick_trace["brake_pressure_fl_pa"]) / 1e5 < limit - 0.01
    sat = (p.flags & Flag.SATURATED) != 0
    assert np.all(sat[over]) and not np.any(sat[under])
