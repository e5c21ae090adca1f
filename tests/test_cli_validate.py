"""The ``validate`` and ``gain`` commands as a user runs them."""

from __future__ import annotations

import json

import pytest

from benchtwin.cli import main


def test_validate_quick_campaign_says_what_it_cannot_identify(tmp_path, capsys) -> None:
    # the quick campaign is too short for some parameters: the command must say which and why, and fail
    out = tmp_path / "v"
    status = main(["validate", "--campaign", "quick", "--setup", "ideal", "--out", str(out)])
    text = capsys.readouterr().out
    assert status == 1
    assert "profile ideal" in text and "bus load:" in text
    assert "road_load.F0" in text  # the short table of main parameters
    assert "need at least" in text or "need 3" in text  # the reason under a failed check
    report = json.loads((out / "validation.json").read_text())
    assert report["n_failed"] > 0 and not report["passed"]
    assert any(c["name"] == "road_load.F2" and c["passed"] for c in report["checks"])
    assert (out / "params.json").exists() and (out / "recording.mf4").exists()


def test_validate_bad_setup_is_one_line(tmp_path, capsys) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n[telemetry]\nk_tel = 300\n')
    status = main(["validate", "--campaign", "quick", "--setup", str(bad)])
    err = capsys.readouterr().err
    assert status == 2
    assert err.startswith("benchtwin: error: ") and "k_tel" in err and "Traceback" not in err


def test_gain_recommends_a_switch_position(capsys) -> None:
    assert main(["gain", "--campaign", "quick", "--setup", "paper"]) == 0
    text = capsys.readouterr().out
    rows = [ln for ln in text.splitlines() if ln.strip()[:4].strip().isdigit()]
    assert len(rows) == 6 and sum("<- recommended" in r for r in rows) == 1
    assert "clips in" in rows[-1]  # K_TEL 8000 (+-273 Nm) cannot carry the launches


def test_validate_families_runs_only_those_families(tmp_path, capsys) -> None:
    out = tmp_path / "f"
    status = main(["validate", "--campaign", "quick", "--setup", "ideal", "--families", "battery,road_load",
                   "--out", str(out)])
    text = capsys.readouterr().out
    report = json.loads((out / "validation.json").read_text())
    assert report["meta"]["families"] == ["battery", "road_load"]
    groups = {c["group"] for c in report["checks"]}
    assert {"battery", "road_load"} <= groups
    assert not groups & {"transmission", "motor", "engine", "torque_converter", "shifts", "brakes", "prediction"}
    assert status == (0 if report["passed"] else 1)
    assert "predicted" not in text  # a family run has no held-out prediction


def test_validate_unknown_family_is_a_usage_error(capsys) -> None:
    # rejected while parsing (exit status 2, argparse's usage line), before anything is simulated
    with pytest.raises(SystemExit) as exc:
        main(["validate", "--campaign", "quick", "--families", "transmission,gearbox"])
    err = capsys.readouterr().err
    assert exc.value.code == 2
    assert "'gearbox'" in err and "unknown family" in err and "road_load" in err and "Traceback" not in err
    with pytest.raises(SystemExit) as exc:
        main(["validate", "--campaign", "quick", "--families", ","])
    assert exc.value.code == 2 and "no family named" in capsys.readouterr().err


def test_family_names_of_the_command_are_the_library_families() -> None:
    from benchtwin.commands.validate import FAMILY_NAMES
    from benchtwin.validation.families import FAMILIES

    assert tuple(FAMILIES) == FAMILY_NAMES


def test_the_command_line_imports_no_heavy_library_before_a_command_runs() -> None:
    """``benchtwin --help`` and ``benchtwin validate --help`` answer without the plotting, MDF, fitting, bus and data
    frame libraries (each command imports what it uses when it runs): the parser alone, in a fresh interpreter."""
    import subprocess
    import sys

    heavy = ("matplotlib", "asammdf", "scipy", "numba", "pandas", "pymodbus", "canopen", "cantools", "dask",
             "benchtwin.validation", "benchtwin.identification", "benchtwin.emulator")
    code = ("import sys; from benchtwin.cli import build_parser; build_parser(); "
            f"print(sorted(m for m in {heavy!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
