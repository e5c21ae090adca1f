"""Identification of a battery-electric and of a conventional car, on logs of those layouts built from the
emulator's output (the emulator is a P2 PHEV; each log keeps only the channels and tests that layout has).

BEV log: the electric-only tests of the quick campaign (engine off, K0 open), written as an MF4 with a BEV
logger's channel names and read back through ``scenarios/signal_maps/bev_mf4.toml``: pack voltage and current,
displayed SOC, motor speed and torque, the DC/DC's 12 V side, vehicle speed, dyno and brake pressures; no
gear, no engine, no HPCU sensor, no segment table. Specs without engine keys or a gear list.

Conventional log: the tests with the engine running plus the coastdown and neutral braking (no traction from
the motor), written as a 20 Hz CSV with the column names of ``scenarios/signal_maps/conventional_csv.toml``:
engine speed, torque and fuel, gears, pedal, lock-up, shaft torque, dyno and brakes; no pack, no motor.
Specs without pack or rotor keys.

Conventional log with converter driving: the P2 plant run as a conventional car (hybrid mode, engine forced on,
K0 closed: the engine alone drives the pump, the motor's torque is zero and its rotor is part of the pump-side
inertia), ramp-ups with the lock-up closed (transmission) and open (converter), written as the same CSV from
where the engine first runs in each test.

Tolerances are those the P2 path's tests derive for the same tests through the same ideal chain (each wire's
resolution is what is left): battery 0.1 % (IVT-S and displayed SOC at their CAN resolution), motor 0.1 % on
the Willans efficiencies and 1 % or 3 standard errors on the losses, road load 1 % (0.01 km/h speed
resolution), brake gains 0.1 %, transmission eta_m 0.5 % and C0 15 % (2.1 Nm shaft-torque resolution at the
lowest step), shift lines 1 km/h (10 Hz target gear). What a layout's log lacks must not cost more than that.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchtwin.cli import main
from benchtwin.config._base import scenario_path, validate_data
from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.specs import VehicleSpecs
from benchtwin.identification.importers import import_log
from benchtwin.identification.run import identify_all
from benchtwin.identification.signal_map import load_signal_map
from benchtwin.recording import Recording

BEV_MAP = scenario_path("signal_maps", "bev_mf4.toml")
CONV_MAP = scenario_path("signal_maps", "conventional_csv.toml")
_STATES = {"gear_actual", "gear_target", "lockup_closed"}


def _inverse_map(path) -> dict[str, tuple[str, str]]:
    """role -> (the log's column name, its unit) of a shipped signal map."""
    smap = load_signal_map(path)
    return {role: (cm.column, cm.unit or "") for role, cm in smap.channels.items()}


def _kept(rec: Recording, keep) -> list:
    return [s for s in rec.segments if keep(s)]


def _write_bev_mf4(rec: Recording, path) -> None:
    from asammdf import MDF, Signal

    segs = _kept(rec, lambda s: s.settings.get("mode") == "electric")
    mdf = MDF(version="4.10")
    for role, (column, unit) in _inverse_map(BEV_MAP).items():
        ch = rec[role]
        m = np.zeros(len(ch), dtype=bool)
        for s in segs:
            m |= s.contains(ch.timestamps)
        mdf.append([Signal(samples=ch.values[m], timestamps=ch.timestamps[m], name=column, unit=unit)])
    mdf.save(path, overwrite=True)


def _write_conventional_csv(rec: Recording, path) -> None:
    segs = _kept(rec, lambda s: s.settings.get("mode") == "hybrid" or s.kind in ("coastdown", "neutral_braking"))
    t = np.concatenate([np.arange(np.ceil(s.start_s * 20), np.floor(s.end_s * 20)) / 20 for s in segs])
    cols, names = [t], ["time_s"]
    for role, (column, _unit) in _inverse_map(CONV_MAP).items():
        cols.append(rec[role].at(t, hold=role in _STATES))
        names.append(column)
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=",".join(names), comments="", fmt="%.6g")


def _bev_specs(vehicle) -> VehicleSpecs:
    s = vehicle.specs
    # one fixed ratio: the 4th gear of the electric ramp-up times the axle (no method of this layout uses it)
    return VehicleSpecs(final_drive_ratio=s.final_drive_ratio * s.gear_ratios[3], wheel_radius_m=s.wheel_radius_m,
                        test_mass_kg=s.test_mass_kg, n_cells_series=s.n_cells_series,
                        em_rotor_radius_m=s.em_rotor_radius_m, em_rotor_volume_m3=s.em_rotor_volume_m3)


def _conventional_specs(vehicle) -> VehicleSpecs:
    s = vehicle.specs
    return VehicleSpecs(gear_ratios=s.gear_ratios, final_drive_ratio=s.final_drive_ratio,
                        wheel_radius_m=s.wheel_radius_m, test_mass_kg=s.test_mass_kg,
                        engine_displacement_m3=s.engine_displacement_m3, fuel_lhv_j_per_kg=s.fuel_lhv_j_per_kg)


def _check_road_load_and_brakes(res, vehicle) -> None:
    rl, b = vehicle.road_load, vehicle.brakes
    fit = res.fits["road_load"]
    np.testing.assert_allclose([fit.value("F0"), fit.value("F1"), fit.value("F2")],
                               [rl.f0_n, rl.f1_n_per_kmh, rl.f2_n_per_kmh2], rtol=0.01)
    np.testing.assert_allclose(res.fits["brakes.front"].value("m_f"), b.gain_front_nm_per_bar, rtol=1e-3)
    np.testing.assert_allclose(res.fits["brakes.rear"].value("m_r"), b.gain_rear_nm_per_bar, rtol=1e-3)


def test_specs_of_each_layout():
    bev = VehicleSpecs(final_drive_ratio=8.2, wheel_radius_m=0.31, test_mass_kg=1700, n_cells_series=96,
                       em_rotor_radius_m=0.06, em_rotor_volume_m3=2e-3)
    assert bev.layout == "bev" and bev.gear_ratios is None and bev.engine_displacement_m3 is None
    conv = VehicleSpecs(gear_ratios=[3.0, 1.0], final_drive_ratio=3.2, wheel_radius_m=0.31, test_mass_kg=1500,
                        engine_displacement_m3=1.6e-3)
    assert conv.layout == "conventional" and conv.n_cells_series is None
    with pytest.raises(ValueError, match=r"layout 'bev' has no use for key\(s\) engine_displacement_m3"):
        VehicleSpecs(layout="bev", **bev.model_dump(exclude={"layout"}, exclude_none=True),
                     engine_displacement_m3=1.6e-3)
    with pytest.raises(ValueError, match=r"needs key\(s\) n_cells_series, em_rotor_radius_m, em_rotor_volume_m3"):
        VehicleSpecs(layout="p2_phev", **conv.model_dump(exclude={"layout"}, exclude_none=True))
    with pytest.raises(ValueError, match="one fixed ratio"):
        VehicleSpecs(gear_ratios=[3.0, 1.0], **bev.model_dump(exclude={"layout"}, exclude_none=True))
    with pytest.raises(ValueError, match="neither an engine"):
        VehicleSpecs(final_drive_ratio=3.0, wheel_radius_m=0.3)


def test_a_bev_log_identifies_battery_motor_road_load_and_brakes(quick_ideal, tmp_path, capsys):
    vehicle, rec = quick_ideal
    log = tmp_path / "bev.mf4"
    _write_bev_mf4(rec, log)
    specs = _bev_specs(vehicle)
    spec_file = tmp_path / "bev_specs.toml"
    spec_file.write_text("\n".join(f"{k} = {json.dumps(v)}" for k, v in specs.model_dump(exclude_none=True).items()),
                         encoding="utf-8")
    out = tmp_path / "out"
    assert main(["identify", str(log), "--signal-map", str(BEV_MAP), "--specs", str(spec_file), "--out", str(out),
                 "--no-figures"]) == 0
    params = json.loads((out / "params.json").read_text(encoding="utf-8"))
    skipped = params["meta"]["skipped"]
    assert set(skipped) == {"transmission", "engine", "torque_converter", "shifts"}
    assert "engine_speed_rpm" in skipped["engine"] and "gear_actual" in skipped["transmission"]
    res = identify_all(import_log(log, BEV_MAP), specs)
    assert not res.errors
    tb, tm = vehicle.battery, vehicle.motor
    for name, true in (("alpha", tb.alpha), ("beta_discharge", tb.beta_discharge), ("beta_charge", tb.beta_charge)):
        assert res.fits["battery"].value(name) == pytest.approx(true, rel=1e-3), name
    for side, e_name, e_true, w_name, w_true in (
            ("motor.motoring", "e", tm.willans_e, "W_loss", tm.willans_w_loss_w),
            ("motor.generating", "e_gen", tm.willans_e_gen, "W_loss_gen", tm.willans_w_loss_gen_w)):
        fit = res.fits[side]
        assert fit.value(e_name) == pytest.approx(e_true, rel=1e-3), side
        w = fit[w_name]
        assert abs(w.value - w_true) < max(0.01 * w_true, 3 * w.std_error), side
        assert any("pack's power" in r for r in fit.reasons)
    _check_road_load_and_brakes(res, vehicle)


def test_a_conventional_log_identifies_transmission_engine_and_shifts(quick_ideal, tmp_path):
    vehicle, rec = quick_ideal
    log = tmp_path / "conventional.csv"
    _write_conventional_csv(rec, log)
    imported = import_log(log, CONV_MAP)
    assert not any(r.startswith(("battery", "em_", "hpcu")) for r in imported.channels)
    res = identify_all(imported, _conventional_specs(vehicle))
    # the converter method runs on the engine's channels (this log has no converter-mode driving worth fitting:
    # see test_a_conventional_log_identifies_its_converter)
    assert set(res.meta["skipped"]) == {"motor", "battery"} and "torque_converter" in res.meta["ran"]
    fit = res.fits["transmission.gear5"]
    assert any("engine drives the gearbox input alone" in r for r in fit.reasons)
    np.testing.assert_allclose(fit.value("eta_m"), vehicle.transmission.eta_m[4], rtol=5e-3)
    np.testing.assert_allclose(fit.value("C0"), vehicle.transmission.c0_nm[4], rtol=0.15)
    assert any(k.startswith("engine.willans") and f.status == "ok" for k, f in res.fits.items())
    _check_road_load_and_brakes(res, vehicle)
    sh = vehicle.shift_schedule
    n_ok = 0
    for g in range(1, len(sh.up_v0_kmh) + 1):
        for key, v0, s1 in ((f"shifts.up_{g}_{g + 1}", sh.up_v0_kmh, sh.up_slope_kmh_per_pct),
                            (f"shifts.down_{g + 1}_{g}", sh.down_v0_kmh, sh.down_slope_kmh_per_pct)):
            f = res.fits.get(key)
            if f is None or f.status != "ok":
                continue
            n_ok += 1
            # at the pedal positions of the events (this log lacks the electric tests' pedal levels, so the
            # line is not extrapolated to pedal positions it never saw)
            p = np.unique(f.data["pedal"])
            np.testing.assert_allclose(f.value("c0_kmh") + f.value("c1_kmh_per_pct") * p,
                                       v0[g - 1] + s1[g - 1] * p, atol=1.0, err_msg=key)
    assert n_ok >= 8


def _conventional_campaign() -> CampaignConfig:
    """Ramp-ups driven by the engine alone: lock-up closed for the gearbox, open for the converter (0.4 < SR < 1)."""
    def ramp(name: str, gear: int, kmh: float, pedals: list[float], lockup: str) -> dict:
        return {"kind": "ramp_up", "name": name, "mode": "hybrid", "gear": gear, "speed_kmh": kmh,
                "pedal_steps_pct": pedals, "step_hold_s": 6.0, "lead_in_s": 8.0, "engine": "on", "k0": "closed",
                "lockup": lockup}

    tests = [ramp("tx_g1_20", 1, 20.0, [10, 20, 30, 40], "closed"),
             ramp("tx_g2_35", 2, 35.0, [10, 20, 30, 40], "closed"),
             ramp("tx_g3_50", 3, 50.0, [10, 20, 30, 40], "closed"),
             ramp("tc_g1_6", 1, 6.0, [15, 25, 35, 45, 55], "open"),
             ramp("tc_g1_12", 1, 12.0, [10, 20, 30, 40, 50], "open"),
             ramp("tc_g2_20", 2, 20.0, [5, 10, 20, 30, 40], "open"),
             ramp("tc_g2_35", 2, 35.0, [3, 6, 10, 15], "open")]
    return validate_data(CampaignConfig, {"name": "conventional_converter", "seed": 5,
                                          "initial_displayed_soc_pct": 80.0, "tests": tests})


def test_a_conventional_log_identifies_its_converter(tmp_path):
    """Pump torque = engine torque, pump speed = engine speed: the converter curves come back within the P2
    vehicle's own converter checks (validation.parameters, ideal profile: 0.5 % on the converter-mode TR and
    CF curves, 2 % on the coupling CF), and params.json says the method ran on the engine's channels.
    About 8 s (362 s simulated)."""
    from benchtwin.chain.batch import run_batch
    from benchtwin.config.setup import load_setup
    from benchtwin.config.vehicle import load_vehicle
    from benchtwin.emulator import simulate_campaign
    from benchtwin.validation.parameters import _tc_checks

    vehicle = load_vehicle(scenario_path("vehicles", "p2_phev_9at.toml"))
    trace = simulate_campaign(vehicle, _conventional_campaign())
    c = trace.channels
    on = (c["engine_on"] > 0.5) & (c["k0_closed"] > 0.5)
    open_drive = on & (c["lockup_closed"] < 0.5) & (c["gear_actual"] > 0) & (c["pedal_pct"] > 0)
    assert open_drive.sum() > 5000 and np.all(c["em_torque_nm"][open_drive] == 0.0)  # the engine alone drives
    rec = run_batch(trace, load_setup(scenario_path("setups", "ideal.toml")), seed=1)
    ts = []
    for s in rec.segments:  # from where the engine first runs with K0 closed (the lead-in is electric)
        t = np.arange(np.ceil(s.start_s * 20), np.floor(s.end_s * 20)) / 20
        k = np.flatnonzero((rec["engine_on"].at(t, hold=True) > 0.5) & (rec["k0_closed"].at(t, hold=True) > 0.5))
        ts.append(t[k[0]:])
    t = np.concatenate(ts)
    cols, names = [t], ["time_s"]
    for role, (column, _unit) in _inverse_map(CONV_MAP).items():
        cols.append(rec[role].at(t, hold=role in _STATES))
        names.append(column)
    log = tmp_path / "conventional_tc.csv"
    np.savetxt(log, np.column_stack(cols), delimiter=",", header=",".join(names), comments="", fmt="%.6g")
    specs = _conventional_specs(vehicle)
    spec_file = tmp_path / "specs.toml"
    spec_file.write_text("\n".join(f"{k} = {json.dumps(v)}" for k, v in specs.model_dump(exclude_none=True).items()),
                         encoding="utf-8")
    out = tmp_path / "out"
    main(["identify", str(log), "--signal-map", str(CONV_MAP), "--specs", str(spec_file), "--out", str(out),
          "--no-figures", "--methods", "transmission,torque_converter"])
    params = json.loads((out / "params.json").read_text(encoding="utf-8"))
    assert "torque_converter" in params["meta"]["ran"] and "torque_converter" not in params["meta"]["skipped"]
    assert "torque_converter.converter" in params["fits"]
    res = identify_all(import_log(log, CONV_MAP), specs, methods=["transmission", "torque_converter"])
    assert "torque_converter" not in res.errors
    assert any("engine drives the pump alone" in r for r in res.fits["torque_converter.converter"].reasons)
    checks = _tc_checks(res, vehicle, "ideal")
    assert {ch.name for ch in checks} == {"torque_converter.torque_ratio_curve",
                                          "torque_converter.capacity_factor_curve",
                                          "torque_converter.coupling_cf_curve"}
    for ch in checks:
        assert ch.passed and ch.tolerance in (5e-3, 2e-2), ch


def test_contradictory_specs_are_a_one_line_error(tmp_path, capsys):
    log = tmp_path / "log.csv"
    log.write_text("time_s,volts,amps\n0,350,1\n1,349,2\n2,348,3\n", encoding="utf-8")
    smap = tmp_path / "map.toml"
    smap.write_text('[source]\ntime_column = "time_s"\n[channels.battery_voltage_v]\ncolumn = "volts"\n'
                    '[channels.battery_current_a]\ncolumn = "amps"\n'
                    '[specs]\nlayout = "conventional"\ngear_ratios = [3.0, 1.0]\nfinal_drive_ratio = 3.2\n'
                    "wheel_radius_m = 0.31\ntest_mass_kg = 1500\nengine_displacement_m3 = 1.6e-3\n"
                    "n_cells_series = 96\n", encoding="utf-8")
    assert main(["identify", str(log), "--signal-map", str(smap), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "layout 'conventional' has no use for key(s) n_cells_series" in err


def test_methods_whose_spec_keys_the_layout_lacks_are_skipped_with_the_reason(quick_ideal):
    """The P2 log with BEV specs: the engine and driveline channels are there, the keys are not."""
    vehicle, rec = quick_ideal
    res = identify_all(rec, _bev_specs(vehicle), methods=["transmission", "engine", "torque_converter", "road_load"])
    assert set(res.meta["skipped"]) == {"transmission", "engine", "torque_converter"}
    assert "needs spec key(s) gear_ratios, which the bev layout" in res.meta["skipped"]["transmission"]
    assert "engine_displacement_m3" in res.meta["skipped"]["engine"]
    assert "road_load" in res.fits and not res.errors


def test_a_bev_log_without_an_soc_channel_counts_from_the_declared_start(quick_ideal, tmp_path):
    """Without the car's SOC signal, the pack is coulomb-counted from [battery] capacity_ah; a start SOC given
    on the command line anchors the count, and params.json says so."""
    import tomllib

    vehicle, rec = quick_ideal
    log = tmp_path / "bev.mf4"
    _write_bev_mf4(rec, log)
    data = tomllib.loads(BEV_MAP.read_text(encoding="utf-8"))
    del data["channels"]["displayed_soc_pct"]
    data["specs"] = _bev_specs(vehicle).model_dump(exclude_none=True)
    data["battery"] = {"capacity_ah": vehicle.battery.capacity_ah}
    smap = tmp_path / "bev_no_soc.toml"
    smap.write_text(_toml(data), encoding="utf-8")
    out = tmp_path / "out"
    assert main(["identify", str(log), "--signal-map", str(smap), "--out", str(out), "--no-figures",
                 "--methods", "battery,battery_map_free", "--start-soc", "70"]) == 0
    params = json.loads((out / "params.json").read_text(encoding="utf-8"))
    assert params["meta"]["soc_reference"]["rule"] == "declared_start"
    assert "displayed_soc_pct" in params["meta"]["skipped"]["battery"]
    assert "battery_map_free" in params["fits"]


def _toml(data: dict) -> str:
    """A two-level TOML text (tables of scalars and lists) for the test's signal map."""
    lines = []
    for table, body in data.items():
        if table == "channels":
            for role, cm in body.items():
                lines.append(f"[channels.{role}]")
                lines += [f"{k} = {json.dumps(v)}" for k, v in cm.items()]
            continue
        lines.append(f"[{table}]")
        lines += [f"{k} = {json.dumps(v)}" for k, v in body.items()]
    return "\n".join(lines) + "\n"


def test_a_bev_log_identifies_its_reduction_gear_efficiency(quick_ideal, tmp_path):
    """The BEV log's one ratio is the electric ramp-up's 4th gear times the axle: at its steady motoring windows
    (the dyno holding 60 km/h) the roller force times the wheel radius against the motor torque times the ratio
    gives the gear's eta, the truth being eta_m of 4th gear (eq. 14; the axle is lossless in the plant), within
    the 0.5 % the transmission method's test allows for eta_m on the same chain (the roller forces' resolution is
    finer than the shaft torque's). The electric tests in other gears (the 90 km/h constant drive, the
    acceleration's upshifts) turn at another ratio and are left out, and counted."""
    vehicle, rec = quick_ideal
    log = tmp_path / "bev.mf4"
    _write_bev_mf4(rec, log)
    res = identify_all(import_log(log, BEV_MAP), _bev_specs(vehicle))
    assert "reduction_gear" in res.meta["ran"]
    fit = res.fits["reduction_gear"]
    assert fit.status == "ok", fit.reasons
    np.testing.assert_allclose(fit.value("eta"), vehicle.transmission.eta_m[3], rtol=5e-3)
    lo, hi = fit["eta"].ci95
    assert lo < fit.value("eta") < hi and hi - lo < 0.01
    # a wrong ratio in the specs leaves no window at it: said, not a silently wrong efficiency
    wrong = _bev_specs(vehicle).model_copy(update={"final_drive_ratio": 1.1 * _bev_specs(vehicle).final_drive_ratio})
    res2 = identify_all(import_log(log, BEV_MAP), wrong)
    assert "at the specified ratio" in res2.errors["reduction_gear"]
