"""The fault campaign: every injected fault kind is detected (kind, device, span), a clean run raises nothing,
steady holds are not called stuck, and ``benchtwin faults`` writes faults.json end to end."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchtwin.chain.batch import run_batch
from benchtwin.cli import main
from benchtwin.config import load_setup
from benchtwin.config._base import validate_data
from benchtwin.config.setup import FAULT_KINDS, SetupConfig
from benchtwin.errors import ConfigError
from benchtwin.recording import Flag
from benchtwin.sensors.synthetic import synthetic_trace
from benchtwin.trace import Trace
from benchtwin.validation.faults import fault_campaign

PAPER = load_setup("paper")
T_S = 400.0

#: every kind once (silent twice: a shunt with a counter and the CANopen node without one)
FAULTS = [
    {"kind": "frame_loss", "device": "ivt_battery", "start_s": 10.0, "duration_s": 5.0, "prob": 0.2},
    {"kind": "frame_loss_burst", "device": "ivt_hpcu", "start_s": 30.0, "duration_s": 2.0},
    {"kind": "duplicate", "device": "vehicle_can", "start_s": 50.0, "duration_s": 5.0},
    {"kind": "reorder", "device": "telemetry", "start_s": 70.0, "duration_s": 5.0},
    {"kind": "corrupt_payload", "device": "ivt_dcdc", "start_s": 90.0, "duration_s": 5.0},
    {"kind": "wrong_dlc", "device": "dyno", "start_s": 110.0, "duration_s": 5.0},
    {"kind": "ivt_error", "device": "ivt_lv_battery", "start_s": 130.0, "duration_s": 3.0},
    {"kind": "silent", "device": "ivt_battery", "start_s": 150.0, "duration_s": 3.0},
    {"kind": "silent", "device": "thermo", "start_s": 170.0, "duration_s": 3.0},
    {"kind": "modbus_restart", "device": "brake_pressure", "start_s": 190.0, "duration_s": 3.0},
    {"kind": "modbus_slow", "device": "brake_pressure", "start_s": 210.0, "duration_s": 5.0},
    {"kind": "transport_disconnect", "bus": "vehicle", "start_s": 230.0, "duration_s": 2.0},
    {"kind": "clock_drift", "device": "brake_pressure", "start_s": 250.0, "duration_s": 100.0, "drift_ppm": 100.0},
    {"kind": "stuck", "device": "ivt_hpcu", "channel": "hpcu_current_a", "start_s": 360.0, "duration_s": 5.0},
    {"kind": "clip", "device": "telemetry", "start_s": 370.0, "duration_s": 3.0},
    {"kind": "open_circuit", "device": "thermo", "channel": "battery_temp_degc", "start_s": 375.0, "duration_s": 5.0},
    {"kind": "clock_step", "device": "brake_pressure", "start_s": 385.0, "duration_s": 1.0, "offset_s": 0.1},
    {"kind": "log_truncation", "bus": "dyno", "start_s": T_S - 5.0},
]


def _with_faults(setup: SetupConfig, faults: list[dict]) -> SetupConfig:
    data = setup.model_dump()
    data["faults"] = faults
    return validate_data(SetupConfig, data, "test")


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> dict:
    trace = synthetic_trace(T_S, 100.0, seed=5)
    return fault_campaign(trace, _with_faults(PAPER, FAULTS), seed=3, out_dir=tmp_path_factory.mktemp("faults"),
                          identify=False)


def test_every_kind_is_in_the_synthetic_campaign() -> None:
    assert {f["kind"] for f in FAULTS} == set(FAULT_KINDS)


def test_every_injected_fault_detected_with_its_kind_and_span(campaign: dict) -> None:
    for f, entry in zip(FAULTS, campaign["faults"]):
        assert entry["detected"], f"{f['kind']} on {f.get('device') or f.get('bus')} at {f['start_s']} s missed"
        end = f["start_s"] + f.get("duration_s", 1e9)
        assert any(a <= end + 1.0 and b >= f["start_s"] - 1.0 for a, b in entry["spans"])
    assert all(row["injected"] == row["detected"] for row in campaign["kinds"].values())


def test_no_false_alarm_and_a_clean_run_detects_nothing(campaign: dict) -> None:
    assert campaign["false_alarms"] == []
    assert campaign["clean_detections"] == []
    assert all(row["false_alarms"] == 0 for row in campaign["kinds"].values())


def test_faults_with_wrong_values_are_kept_out_of_identification(campaign: dict) -> None:
    # each fault that leaves wrong values (or times) in the Recording has them flagged with a bad flag
    assert all(entry["identification_safe"] for entry in campaign["faults"])
    flags = {e["kind"]: set(e["flags"]) for e in campaign["faults"]}
    assert "STALE" in flags["stuck"] and "STATUS_ERROR" in flags["ivt_error"]
    assert "LATE" in flags["modbus_slow"] and "CLOCK" in flags["clock_step"] and "TIMEOUT" in flags["modbus_restart"]


def test_fault_list_errors_are_one_line() -> None:
    for bad, words in (({"kind": "reorder", "device": "thermo", "start_s": 1, "duration_s": 2}, "frame counter"),
                       ({"kind": "stuck", "device": "ivt_battery", "start_s": 1, "duration_s": 2}, "needs channel"),
                       ({"kind": "silent", "device": "nope", "start_s": 1, "duration_s": 2}, "not in this setup"),
                       ({"kind": "frame_loss", "bus": "vehicle", "start_s": 1}, "needs device"),
                       ({"kind": "jam", "device": "thermo", "start_s": 1, "duration_s": 2}, "faults[0].kind")):
        with pytest.raises(ConfigError) as exc:
            _with_faults(PAPER, [bad])
        msg = str(exc.value)
        assert "\n" not in msg and words in msg, msg


def _steady_trace(duration_s: float = 240.0) -> Trace:
    """Every channel held at its value for 20-s plateaus: a trace of steady holds."""
    tr = synthetic_trace(duration_s, 100.0, seed=11)
    hold = np.floor(tr.time_s / 20.0).astype(np.int64) * 2000
    return Trace(tr.time_s, {k: v[np.minimum(hold, len(v) - 1)] for k, v in tr.channels.items()}, tr.segments,
                 tr.meta)


def test_steady_holds_are_not_stale_on_the_paper_setup() -> None:
    rec = run_batch(_steady_trace(), PAPER, seed=1)
    stale = {name: int(np.count_nonzero(ch.flags & int(Flag.STALE))) for name, ch in rec.channels.items()}
    assert not any(stale.values()), stale
    assert rec.meta["faults_detected"] == []


def test_faults_cli_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # the shipped faults setup (timed for the quick campaign's 922 s) on a synthetic trace of that length
    trace_dir = tmp_path / "trace"
    synthetic_trace(925.0, 100.0, seed=2).save(trace_dir)
    out = tmp_path / "out"
    assert main(["faults", "--setup", "faults", "--trace", str(trace_dir), "--seed", "7", "--no-identify",
                 "--out", str(out)]) == 0
    result = json.loads((out / "faults.json").read_text())
    kinds = result["kinds"]
    assert sum(r["injected"] for r in kinds.values()) == len(load_setup("faults").faults)
    assert all(r["injected"] == r["detected"] and r["false_alarms"] == 0 for r in kinds.values())
    assert (out / "faulty" / "recording.mf4").exists() and (out / "clean" / "recording.mf4").exists()
    assert "| **all** |" in capsys.readouterr().out
