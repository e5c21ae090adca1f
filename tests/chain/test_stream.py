"""The batch chain with outputs decodes what it writes without reading the files back: the Recording of
``run_batch(..., out_dir)`` is the one decoded from its written logs, bit for bit (times, values, flags, meta)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchtwin.chain.acquisition import acquire
from benchtwin.chain.batch import read_logs, run_batch
from benchtwin.config import load_setup
from benchtwin.config._base import validate_data
from benchtwin.config.setup import SetupConfig
from benchtwin.recording import Recording
from benchtwin.sensors.synthetic import synthetic_trace

PAPER = load_setup("paper")
T_S = 120.0

#: faults that change what the files hold: a bus log cut short, a disconnect, frame faults on the bus logs
FAULTS = [
    {"kind": "log_truncation", "bus": "dyno", "start_s": T_S - 20.0},
    {"kind": "transport_disconnect", "bus": "vehicle", "start_s": 30.0, "duration_s": 2.0},
    {"kind": "duplicate", "device": "vehicle_can", "start_s": 50.0, "duration_s": 5.0},
    {"kind": "frame_loss", "device": "ivt_battery", "start_s": 10.0, "duration_s": 5.0, "prob": 0.2},
    {"kind": "modbus_restart", "device": "brake_pressure", "start_s": 60.0, "duration_s": 3.0},
]


def _with_faults(setup: SetupConfig, faults: list[dict]) -> SetupConfig:
    data = setup.model_dump()
    data["faults"] = faults
    return validate_data(SetupConfig, data, "test")


def assert_same_recording(a: Recording, b: Recording) -> None:
    """Every channel equal bit for bit (times, values, flags, unit, source) and the same meta and segments."""
    assert list(a.channels) == list(b.channels)
    for name in a.channels:
        ca, cb = a[name], b[name]
        for field in ("timestamps", "values", "flags"):
            x, y = getattr(ca, field), getattr(cb, field)
            assert x.dtype == y.dtype, (name, field)
            np.testing.assert_array_equal(x, y, err_msg=f"{name}.{field}")
        assert (ca.unit, ca.source) == (cb.unit, cb.source), name
    assert a.segments == b.segments
    assert a.start_time == b.start_time
    skip = {"skipped_files"}  # read back after the run, the folder also holds recording.mf4 (not a bus log)
    assert {k: v for k, v in a.meta.items() if k not in skip} == {k: v for k, v in b.meta.items() if k not in skip}


@pytest.mark.parametrize("faults", [[], FAULTS], ids=["paper", "paper+faults"])
def test_outputs_path_equals_decoding_the_written_logs(faults: list[dict], tmp_path: Path) -> None:
    setup = _with_faults(PAPER, faults)
    trace = synthetic_trace(T_S, 100.0, seed=11)
    rec = run_batch(trace, setup, seed=4, out_dir=tmp_path)
    again, _ = read_logs(tmp_path, setup)
    assert_same_recording(rec, acquire(again, setup))
    if faults:  # the cut is seen without reading the files: the dyno log ends early
        assert [d["bus"] for d in rec.meta["damaged_logs"]] == ["dyno"]
        assert any(e["kind"] == "truncated" for e in rec.meta["transport_events"])
    assert rec.meta["frames"] and set(rec.meta["frames"]) <= {p.stem for p in tmp_path.glob("*.mf4")}


def test_mf4_bus_log_written_in_blocks_reads_back_whole(tmp_path: Path) -> None:
    """A bus log appended in several blocks (the last one short) is the same log: frames, python-can's view."""
    import can

    from benchtwin.chain.buslog import DEFAULT_START, read_mf4, write_mf4
    from benchtwin.wire.frames import FRAME_DTYPE, FrameTable

    n = 2_500
    f = np.zeros(n, FRAME_DTYPE)
    f["timestamp"] = np.arange(n) * 1e-3
    f["arbitration_id"] = 0x100 + np.arange(n) % 7
    f["is_extended"] = np.arange(n) % 11 == 0
    f["dlc"] = 1 + np.arange(n) % 8
    f["data"] = np.random.default_rng(1).integers(0, 256, (n, 8), dtype=np.uint8)
    one = write_mf4(FrameTable("x", f, 500_000), tmp_path / "one.mf4", block_frames=n)
    blocks = write_mf4(FrameTable("x", f, 500_000), tmp_path / "blocks.mf4", block_frames=1_000)
    for p in (one, blocks):
        np.testing.assert_array_equal(read_mf4(p).frames, f)
    msgs = list(can.MF4Reader(str(blocks)))
    assert len(msgs) == n
    k = n - 1
    assert msgs[k].arbitration_id == f["arbitration_id"][k] and msgs[k].is_extended_id == f["is_extended"][k]
    assert msgs[k].timestamp - DEFAULT_START.timestamp() == pytest.approx(f["timestamp"][k], abs=1e-6)


def test_a_campaign_streamed_from_the_plant_test_by_test_is_the_whole_run(tmp_path: Path) -> None:
    """The plant's tests straight into the chain (one test's Trace and frames in memory at a time, the logs and
    recording.mf4 written as they come) give the Recording of the whole Trace run at once, and its logs."""
    from benchtwin.chain.stream import run_chunked
    from benchtwin.config import load_campaign, load_vehicle
    from benchtwin.emulator import iter_campaign, simulate_campaign

    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    setup = _with_faults(PAPER, [{"kind": "log_truncation", "bus": "dyno", "start_s": 600.0},
                                 {"kind": "transport_disconnect", "bus": "vehicle", "start_s": 299.0,
                                  "duration_s": 2.0}])
    streamed = run_chunked(iter_campaign(vehicle, campaign), setup, campaign.seed, tmp_path / "streamed")
    whole = run_batch(simulate_campaign(vehicle, campaign), setup, seed=campaign.seed)
    assert_same_recording(streamed, whole)
    assert [d["bus"] for d in streamed.meta["damaged_logs"]] == ["dyno"]
    again, _ = read_logs(tmp_path / "streamed", setup)
    assert_same_recording(streamed, acquire(again, setup))
    assert (tmp_path / "streamed" / "recording.mf4").exists()
    assert not list((tmp_path / "streamed").glob(".acquisition-*"))  # the chunks' files are gone
