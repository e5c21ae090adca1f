"""Bad input gets one clear line naming file, key, value and what is allowed; never a traceback.

Each mutated scenario file goes through its loader, each bad command line through ``benchtwin.cli.main``.
Nothing here simulates a whole campaign: the loaders and the checks before the plant are what is tested.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import pytest

from benchtwin.cli import main
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


# --- command line --------------------------------------------------------------------------------

def _cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    """Run ``benchtwin ARGV``; return the exit code, stdout and stderr (no traceback allowed in either)."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err and "Exception ignored" not in err
    return code, out, err


def _fails_with(capsys: pytest.CaptureFixture[str], expected: str, *argv: str, code: int = 2) -> str:
    got, _out, err = _cli(capsys, *argv)
    lines = err.strip().splitlines()
    assert got == code, err
    assert len(lines) == 1 and lines[0].startswith("benchtwin: error: "), err
    assert expected in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def bench_logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A saved 3 s synthetic Trace and the raw logs of the paper bench on it."""
    from benchtwin.chain.batch import run_batch
    from benchtwin.sensors.synthetic import synthetic_trace

    root = tmp_path_factory.mktemp("bench")
    trace = synthetic_trace(3.0)
    trace.save(root / "trace")
    run_batch(trace, load_setup("paper"), 1, root / "logs")
    return root / "trace", root / "logs"


def _damaged(src: Path, dst: Path, name: str, data: bytes | None) -> Path:
    import shutil

    shutil.copytree(src, dst)
    if data is None:
        (dst / name).write_bytes((src / name).read_bytes()[:3000])  # truncated
    else:
        (dst / name).write_bytes(data)
    return dst


@pytest.mark.parametrize(("name", "data"), [("vehicle.mf4", None), ("vehicle.blf", b"LOGG\x90\x00\x00\x00junk")])
def test_acquire_damaged_bus_log_keeps_what_it_can_and_says_so(bench_logs: tuple[Path, Path], tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str], name: str,
                                                              data: bytes | None) -> None:
    """A truncated or damaged bus log is decoded up to the damage, named in a warning, and the exit is 1."""
    logs = _damaged(bench_logs[1], tmp_path / "logs", name, data)
    if name.endswith(".blf"):
        (logs / "vehicle.mf4").unlink()
    code, _out, err = _cli(capsys, "acquire", logs, "--out", tmp_path / "rec.mf4")
    assert code == 1, err
    assert f"damaged log {name}" in err
    assert (tmp_path / "rec.mf4").exists()


@pytest.mark.parametrize(("name", "data", "expected"), [
    ("meta.json", b"{bad", "meta.json: damaged, not the logs' meta data"),
    ("setup.json", b"{bad", "setup.json: damaged, not the setup written with the logs"),
    ("segments.json", b"[{", "segments.json: not a valid segment table"),
    ("brake_pressure.polls.npz", b"junk", "brake_pressure.polls.npz: not a poll log (not an .npz archive)"),
    ("brake_pressure.polls.npz", None, "brake_pressure.polls.npz: not a poll log"),
])
def test_acquire_damaged_log_folder_names_the_file(bench_logs: tuple[Path, Path], tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str], name: str,
                                                   data: bytes | None, expected: str) -> None:
    import gc
    import sys

    logs = _damaged(bench_logs[1], tmp_path / "logs", name, data)
    if name.endswith(".blf"):
        (logs / "vehicle.mf4").unlink()
    unraisable: list[object] = []
    previous = sys.unraisablehook
    sys.unraisablehook = unraisable.append
    try:
        _fails_with(capsys, expected, "acquire", logs, "--out", tmp_path / "rec.mf4")
        gc.collect()  # whatever the failed read left behind goes now, under this hook
    finally:
        sys.unraisablehook = previous
    assert not unraisable  # asammdf's __del__ of a half-read file stays quiet
    assert not (tmp_path / "rec.mf4").exists()


def test_acquire_output_paths_are_checked_before_encoding(bench_logs: tuple[Path, Path], tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    trace, logs = bench_logs
    a_file = tmp_path / "a_file"
    a_file.write_text("keep me", encoding="utf-8")
    _fails_with(capsys, f"--logs {a_file}: is a file; a folder is needed here",
                "acquire", "--trace", trace, "--setup", "paper", "--logs", a_file, "--out", tmp_path / "r.mf4")
    assert a_file.read_text(encoding="utf-8") == "keep me"
    _fails_with(capsys, f"--out {a_file}/r.mf4: {a_file} is a file, not a folder",
                "acquire", logs, "--out", a_file / "r.mf4")
    if Path("/proc/self").exists():
        _fails_with(capsys, "--logs /proc/benchtwin_x: cannot write there",
                    "acquire", "--trace", trace, "--setup", "paper", "--logs", "/proc/benchtwin_x",
                    "--out", tmp_path / "r.mf4")
        _fails_with(capsys, "--out /proc/benchtwin_x.mf4: cannot write there", "acquire", logs, "--out",
                    "/proc/benchtwin_x.mf4")


def test_acquire_into_an_existing_folder_name_prints_the_file_it_wrote(bench_logs: tuple[Path, Path], tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "existing"
    target.mkdir()
    code, out, _err = _cli(capsys, "acquire", bench_logs[1], "--out", target)
    assert code == 0
    assert out.strip().splitlines()[-1] == f"wrote {target}.mf4" and Path(f"{target}.mf4").is_file()


def test_acquire_trace_seed_is_recorded(bench_logs: tuple[Path, Path], tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    from benchtwin.recording import Recording

    code, _out, _err = _cli(capsys, "acquire", "--trace", bench_logs[0], "--setup", "ideal", "--seed", "42",
                            "--logs", tmp_path / "logs", "--out", tmp_path / "r.mf4")
    assert code == 0 and Recording.load(tmp_path / "r.mf4").meta["seed"] == 42
    _fails_with(capsys, "--seed is for --trace", "acquire", bench_logs[1], "--seed", "3", "--out", tmp_path / "x.mf4")


@pytest.mark.skipif(not Path("/proc/self").exists(), reason="needs /proc")
@pytest.mark.parametrize("argv", [
    ("simulate", "--campaign", "quick", "--out", "/proc/benchtwin_x"),
    ("validate", "--campaign", "quick", "--setup", "ideal", "--out", "/proc/benchtwin_x"),
    ("record", "--setup", "ideal", "--out", "/proc/benchtwin_x.mf4"),
    ("serve", "--setup", "ideal", "--synthetic", "1", "--report", "/proc/benchtwin_x"),
    ("serve", "--setup", "ideal", "--synthetic", "1", "--record", "/proc/benchtwin_x.mf4"),
])
def test_unwritable_outputs_fail_before_any_work(capsys: pytest.CaptureFixture[str], argv: tuple[str, ...]) -> None:
    # a shipped name (quick) resolves in every command; the output is checked before simulating
    _fails_with(capsys, "/proc/benchtwin_x", *argv)


def test_identify_output_and_options_are_checked(bench_logs: tuple[Path, Path], tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "r.mf4"
    (tmp_path / "a_file").write_text("", encoding="utf-8")
    rec.write_bytes(b"")  # never read: the options and the output come first
    for option, expected in [
        ("shifts.min_events=abc", "shifts.min_events takes a whole number, got 'abc'"),
        ("motor.min_torque_nm=nan", "motor.min_torque_nm takes a finite number, got nan"),
        ("torque_converter.pump_inertia=1", "torque_converter.pump_inertia takes true or false, got 1"),
        ("shifts.nope=1", "shifts has no option 'nope'"),
    ]:
        _fails_with(capsys, f"--option '{option}': {expected}", "identify", rec, "--out", tmp_path / "o", "-O", option)
    _fails_with(capsys, "--out", "identify", rec, "--out", tmp_path / "a_file")


def test_identify_a_foreign_mf4_is_one_line(bench_logs: tuple[Path, Path], tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    bus_log = bench_logs[1] / "vehicle.mf4"
    _fails_with(capsys, f"{bus_log}: channel 'CAN_DataFrame' holds records (e.g. CAN frames), not numbers: this is "
                        "not a benchtwin Recording", "identify", bus_log, "--out", tmp_path / "o", "--no-figures")


def test_gain_without_telemetry_is_one_line_before_simulating(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    setup = _setup_file(tmp_path, "[dyno]\n")
    _fails_with(capsys, "has no [telemetry] section: there is no gain to choose",
                "gain", "--setup", setup, "--campaign", "quick")


def test_cli_bad_vehicle_and_setup_values_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    vehicle = _mutated(tmp_path, "vehicles", "p2_phev_9at", _sub(r"^test_mass_kg = .*$", "test_mass_kg = inf"))
    _fails_with(capsys, "key 'specs.test_mass_kg' = inf: nan and inf are not allowed",
                "simulate", "--vehicle", vehicle, "--campaign", "quick", "--out", tmp_path / "o")
    setup = _setup_file(tmp_path, "[thermo]\ncold_junction_degc = nan\n")
    _fails_with(capsys, "key 'thermo.cold_junction_degc' = nan", "serve", "--setup", setup, "--synthetic", "1")
    _fails_with(capsys, "--synthetic inf: give a duration in seconds",
                "serve", "--setup", "ideal", "--synthetic", "inf")
    _fails_with(capsys,
                "no such file, and no shipped campaign of that name (shipped: conventional, conventional_quick, "
                "paper, paper_motor_map, paper_x10, paper_x3, quick, wltc)",
                "simulate", "--campaign", "quik", "--out", tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_every_command_resolves_shipped_names_alike() -> None:
    from benchtwin.commands._common import resolve_scenario

    for value in ("quick", "quick.toml"):
        assert resolve_scenario("campaigns", value) == scenario_path("campaigns", "quick.toml")
    assert resolve_scenario("setups", "ideal") == scenario_path("setups", "ideal.toml")
    assert resolve_scenario("vehicles", "p2_phev_alt") == scenario_path("vehicles", "p2_phev_alt.toml")


@pytest.mark.parametrize("command", ["simulate", "validate", "gain", "serve", "acquire"])
def test_seed_option_everywhere_randomness_is_drawn(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    from benchtwin.cli import build_parser

    parser = build_parser()
    base = {"simulate": ["--campaign", "quick", "--out", "o"], "serve": ["--setup", "ideal"],
            "acquire": ["--out", "o.mf4"]}.get(command, [])
    assert parser.parse_args([command, *base, "--seed", "11"]).seed == 11
    with pytest.raises(SystemExit):
        parser.parse_args([command, *base, "--seed", "-1"])
    assert "a seed is >= 0" in capsys.readouterr().err


def test_seed_overrides_the_campaign_and_is_recorded(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    import json

    import tqdm

    totals: list[float] = []

    class Bar(tqdm.tqdm):  # records every total the bar is given
        def __setattr__(self, name: str, value: object) -> None:
            if name == "total":
                totals.append(value)
            super().__setattr__(name, value)

    monkeypatch.setattr(tqdm, "tqdm", Bar)
    camp = tmp_path / "c.toml"
    camp.write_text('name = "tiny"\nseed = 3\n[[tests]]\nkind = "acceleration"\npedal_pct = 40.0\n'
                    'end_speed_kmh = 20.0\nmax_duration_s = 100.0\n[[tests]]\nkind = "deceleration"\n'
                    'start_speed_kmh = 20.0\ndecel_mps2 = 3.0\napproach_s = 10.0\n', encoding="utf-8")
    code, _out, _err = _cli(capsys, "simulate", "--campaign", camp, "--out", tmp_path / "o", "--seed", "99")
    assert code == 0
    assert json.loads((tmp_path / "o" / "meta.json").read_text(encoding="utf-8"))["seed"] == 99
    # the acceleration test ends long before its 100 s block: the bar's total still never moves
    assert totals and len(set(totals)) == 1, totals


def test_seed_reaches_the_scenario_of_validate_and_gain() -> None:
    import argparse

    from benchtwin.commands._common import load_scenario

    args = argparse.Namespace(vehicle="p2_phev_9at", setup="ideal", campaign="quick", seed=5)
    assert load_scenario(args)[2].seed == 5  # validation.json meta and the recording take campaign.seed
    args.seed = None
    assert load_scenario(args)[2].seed == load_campaign("quick.toml").seed
