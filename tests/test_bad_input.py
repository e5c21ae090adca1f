"""Bad input gets one clear line naming file, key, value and what is allowed; never a traceback.

Each mutated scenario file goes through its loader, each bad command line through ``benchtwin.cli.main``.
Nothing here simulates a whole campaign: the loaders and the checks before the plant are what is tested.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import pytest

from benchtwin.config import load_campaign, load_setup, load_vehicle, scenario_path
from benchtwin.errors import ConfigError


def _mutated(tmp_path: Path, kind: str, name: str, edit: Callable[[str], str]) -> Path:
    text = scenario_path(kind, f"{name}.toml").read_text(encoding="utf-8")
    new = edit(text)
    assert new != text, "the edit must change the file"
    path = tmp_path / f"{kind}_{name}.toml"
    path.write_text(new, encoding="utf-8")
    return path


def _sub(pattern: str, repl: str) -> Callable[[str], str]:
    return lambda text: re.sub(pattern, repl, text, count=1, flags=re.MULTILINE)


def _one_line_error(loader: Callable[[Path], object], path: Path) -> str:
    with pytest.raises(ConfigError) as exc:
        loader(path)
    msg = str(exc.value)
    assert "\n" not in msg, msg
    assert str(path) in msg
    return msg


# --- vehicle -------------------------------------------------------------------------------------

@pytest.mark.parametrize(("edit", "expected"), [
    (_sub(r"^test_mass_kg = .*$", "test_mass_kg = inf"), "key 'specs.test_mass_kg' = inf: nan and inf"),
    (_sub(r"^capacity_ah = .*$", "capacity_ah = inf"), "key 'battery.capacity_ah' = inf: nan and inf"),
    (_sub(r"^capacity_ah = .*$", "capacity_ah = nan"), "key 'battery.capacity_ah' = nan: nan and inf"),
    (_sub(r"^f0_n = .*$", "f0_n = -inf"), "key 'road_load.f0_n' = -inf: nan and inf"),
    (_sub(r"^eta_m = \[0.955", "eta_m = [nan"), "key 'transmission.eta_m[0]' = nan: nan and inf"),
    (_sub(r"^  \[543.3,", "  [nan,"), "key 'engine.bsfc_g_per_kwh[0][0]' = nan: nan and inf"),
    (_sub(r"^full_load_torque_nm = \[440,", "full_load_torque_nm = [-440,"),
     "key 'motor.full_load_torque_nm[0]' = -440: Input should be greater than 0"),
    (_sub(r"^full_load_torque_nm = \[200,", "full_load_torque_nm = [0,"),
     "key 'engine.full_load_torque_nm[0]' = 0: Input should be greater than 0"),
    (_sub(r"^engine_thermostat_degc = .*$", "engine_thermostat_degc = 1e6"),
     "key 'thermal.engine_thermostat_degc' = 1000000.0: Input should be less than or equal to 130"),
])
def test_bad_vehicle_value_is_one_line(tmp_path: Path, edit: Callable[[str], str], expected: str) -> None:
    path = _mutated(tmp_path, "vehicles", "p2_phev_9at", edit)
    assert expected in _one_line_error(load_vehicle, path)


def test_non_utf8_file_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes('name = "Zündung"\nseed = 1\n'.encode("latin-1"))
    msg = _one_line_error(load_campaign, path)
    assert "not UTF-8" in msg and "0xfc" in msg


# --- campaign ------------------------------------------------------------------------------------

@pytest.mark.parametrize(("edit", "expected"), [
    (_sub(r"^step_hold_s = .*$", "step_hold_s = nan"), "key 'tests[0].step_hold_s' = nan: nan and inf"),
    (_sub(r"^step_hold_s = .*$", "step_hold_s = 1e7"),
     "key 'tests[0].step_hold_s' = 10000000.0: Input should be less than or equal to 86400"),
    (_sub(r"^pedal_steps_pct = \[5.0,", "pedal_steps_pct = [150.0,"),
     "key 'tests[0].pedal_steps_pct[0]' = 150.0: Input should be less than or equal to 100"),
    (_sub(r"^pedal_steps_pct = \[5.0,", "pedal_steps_pct = [-5.0,"),
     "key 'tests[0].pedal_steps_pct[0]' = -5.0: Input should be greater than or equal to 0"),
    (_sub(r"^seed = .*$", "seed = 1\nambient_degc = inf"), "key 'ambient_degc' = inf: nan and inf"),
    (_sub(r"^seed = .*$", "seed = 1\ndriver = { preview_s = inf }"), "key 'driver.preview_s' = inf: nan and inf"),
])
def test_bad_campaign_value_is_one_line(tmp_path: Path, edit: Callable[[str], str], expected: str) -> None:
    path = _mutated(tmp_path, "campaigns", "quick", edit)
    assert expected in _one_line_error(load_campaign, path)


def test_brake_steps_outside_0_100_are_rejected(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text('name = "x"\nseed = 1\n[[tests]]\nkind = "neutral_braking"\nspeed_kmh = 50.0\n'
                    'brake_steps_pct = [10.0, 101.0]\n', encoding="utf-8")
    msg = _one_line_error(load_campaign, path)
    assert "key 'tests[0].brake_steps_pct[1]' = 101.0: Input should be less than or equal to 100" in msg


def test_campaign_longer_than_the_plant_sample_limit_is_refused_before_allocating(tmp_path: Path) -> None:
    from benchtwin.emulator import simulate_campaign
    from benchtwin.emulator.protocols import MAX_PLANT_SAMPLES

    path = tmp_path / "long.toml"
    path.write_text('name = "long"\nseed = 1\n[[tests]]\nkind = "ramp_up"\nname = "slow"\ngear = 4\n'
                    'speed_kmh = 60.0\npedal_steps_pct = [5.0, 10.0, 20.0]\nstep_hold_s = 86400.0\n',
                    encoding="utf-8")
    campaign = load_campaign(path)  # every key is within its own bound ...
    with pytest.raises(ConfigError) as exc:  # ... but the whole campaign is too long
        simulate_campaign(load_vehicle(), campaign)
    msg = str(exc.value)
    assert "\n" not in msg
    assert "campaign 'long'" in msg and "tests[0] (slow" in msg
    assert f"the limit is {MAX_PLANT_SAMPLES:.3g} samples" in msg and "h) of plant time" in msg


def test_ramp_down_must_go_down(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text('name = "x"\nseed = 1\n[[tests]]\nkind = "ramp_down"\npedal_pct = 10.0\n'
                    'start_speed_kmh = 50.0\nend_speed_kmh = 80.0\n', encoding="utf-8")
    assert "end_speed_kmh (80.0) must be below start_speed_kmh" in _one_line_error(load_campaign, path)


# --- setup ---------------------------------------------------------------------------------------

def _setup_file(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "setup.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(("text", "expected"), [
    ('[thermo]\ncold_junction_degc = nan\n', "key 'thermo.cold_junction_degc' = nan: nan and inf"),
    ('[ivt.battery]\ncurrent_errors.noise_std = inf\n', "key 'ivt.battery.current_errors.noise_std' = inf"),
    ('[dyno]\nerrors.dyno_speed_kmh.offset = nan\n', "key 'dyno.errors.dyno_speed_kmh.offset' = nan"),
    ('[telemetry]\nlink.clock_offset_s = inf\n', "key 'telemetry.link.clock_offset_s' = inf"),
    ('[telemetry]\nlink.clock_offset_s = 1e300\n',
     "key 'telemetry.link.clock_offset_s' = 1e+300: Input should be less than or equal to 86400"),
    ('[vehicle_can]\nerrors.vehicle_speed_kph.offset = 0.5\n',
     "'vehicle_speed_kph' is not a role the vehicle CAN carries; did you mean 'vehicle_speed_kmh'?"),
    ('[dyno]\nerrors.shaft_torque_nm.offset = 0.5\n', "'shaft_torque_nm' is not a role the dyno carries"),
    ('[pressure]\nhost = "0.0.0.0"\n',
     "key 'pressure.host' = '0.0.0.0': Value error, the emulated pressure module serves on loopback only"),
    ('name = "empty"\n', "the setup has no sensor"),
])
def test_bad_setup_is_one_line(tmp_path: Path, text: str, expected: str) -> None:
    msg = _one_line_error(load_setup, _setup_file(tmp_path, text))
    assert expected in msg, msg


def test_loopback_pressure_host_is_accepted(tmp_path: Path) -> None:
    for host in ("127.0.0.1", "localhost", "::1"):
        assert load_setup(_setup_file(tmp_path, f'[pressure]\nhost = "{host}"\n')).pressure is not None


def test_the_roles_allowed_under_errors_are_those_the_dbc_signals_carry() -> None:
    from benchtwin.config.setup import DYNO_ROLES, VEHICLE_CAN_ROLES
    from benchtwin.roles import ROLES
    from benchtwin.sensors.vehicle import SIGNAL_MAP

    for stem, allowed in (("vehicle", VEHICLE_CAN_ROLES), ("dyno", DYNO_ROLES)):
        mapped = {src.role for src in SIGNAL_MAP[stem].values() if src.role is not None}
        assert set(allowed) == mapped, stem
        assert set(allowed) <= set(ROLES)
