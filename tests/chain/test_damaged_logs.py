"""Truncated or damaged bus logs: detected per bus and time span, the frames before the cut kept, the cut
flagged in the Recording, and ``benchtwin acquire`` warns on stderr and exits 1 (never a traceback)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from benchtwin.chain.acquisition import acquire
from benchtwin.chain.batch import deliver, read_logs, write_logs
from benchtwin.cli import main
from benchtwin.config.setup import load_setup
from benchtwin.recording import Flag
from benchtwin.sensors import encode
from benchtwin.sensors.synthetic import synthetic_trace

DURATION_S = 4.0
BUS = "instrument"


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    setup = load_setup("ideal")
    trace = synthetic_trace(DURATION_S)
    received = deliver(encode(trace, setup, 0), setup, seed=0, span_s=(0.0, DURATION_S))
    received.segments = list(trace.segments)
    d = tmp_path_factory.mktemp("logs")
    write_logs(received, setup, d, blf=True)
    return d, received


def _cut_copy(src, dst, kind: str, keep: float | int):
    shutil.copytree(src, dst)
    if kind == "blf":  # a BLF-only logger: the MF4 copies are not there
        for p in dst.glob("*.mf4"):
            p.unlink()
    f = dst / f"{BUS}.{kind}"
    n = f.stat().st_size
    with f.open("r+b") as fh:
        fh.truncate(keep if isinstance(keep, int) else int(n * keep))
    return f


def test_whole_logs_are_not_flagged(logs, capsys, tmp_path):
    d, _ = logs
    received, _ = read_logs(d)
    assert "damaged_logs" not in received.meta
    assert not [e for e in received.events if e.kind == "truncated"]
    assert main(["acquire", str(d), "--out", str(tmp_path / "rec.mf4")]) == 0
    assert "damaged" not in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["blf", "mf4"])
@pytest.mark.parametrize("keep", [0.01, 0.5, 0.99, 40])
def test_a_truncated_log_is_detected_and_the_data_before_the_cut_kept(logs, kind, keep, tmp_path, capsys):
    src, original = logs
    d = tmp_path / "cut"
    _cut_copy(src, d, kind, keep)
    received, setup = read_logs(d)
    damaged = received.meta["damaged_logs"]
    assert [x["bus"] for x in damaged] == [BUS]
    dmg = damaged[0]
    assert dmg["file"] == f"{BUS}.{kind}" and dmg["reason"]
    assert dmg["expected_s"][1] == pytest.approx(DURATION_S, abs=0.05)
    # the frames kept are exactly the first ones written
    got = received.can[BUS].frames
    want = original.can[BUS].frames
    assert dmg["frames_read"] == len(got) < len(want) or (kind == "mf4" and keep == 0.99)
    np.testing.assert_array_equal(got["arbitration_id"], want["arbitration_id"][:len(got)])
    np.testing.assert_array_equal(got["data"], want["data"][:len(got)])
    np.testing.assert_allclose(got["timestamp"], want["timestamp"][:len(got)], atol=1e-5)
    if len(got):
        assert dmg["covered_s"][1] == pytest.approx(float(got["timestamp"][-1]))
    # the other buses are whole and decoded as before
    for bus in ("vehicle", "dyno"):
        assert len(received.can[bus]) == len(original.can[bus])
    ev = [e for e in received.events if e.kind == "truncated"]
    assert len(ev) == 1 and ev[0].source == BUS and ev[0].end_s == pytest.approx(DURATION_S, abs=0.05)
    rec = acquire(received, setup)
    assert rec.meta["damaged_logs"] == damaged
    if "battery_current_a" in rec and len(rec["battery_current_a"]):
        cur = rec["battery_current_a"]
        assert cur.timestamps[-1] <= dmg["covered_s"][1] + 1e-9
        assert cur.flags[-1] & Flag.TRANSPORT_DROP and cur.flags[-1] & Flag.LOST_FRAME
    # the command says so, per bus and span, exits 1 and still writes the Recording
    out = tmp_path / "rec.mf4"
    assert main(["acquire", str(d), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert f"warning: damaged log {BUS}.{kind} (bus {BUS})" in err and "Traceback" not in err
    assert out.exists()
