"""validate streams the campaign: neither the whole Trace nor the whole Recording is held in memory.

The pieces: the truth spooled to raw files (:class:`~benchtwin.trace.SpooledTrace`), the chain fed in time slices
(:func:`~benchtwin.chain.stream.time_slices`), the Recording read from the acquisition's raw chunk files
(``keep_chunks``), the held-out Recording cut lazily (:func:`~benchtwin.validation.holdout.without_window`).
Each is compared with the in-memory result it replaces; the validate test checks what is in memory when
identification and the chain checks run. About 10 s in all.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import benchtwin.validation.run as vrun
from benchtwin.chain.stream import run_chunked, time_slices
from benchtwin.config import load_campaign, load_setup, load_vehicle
from benchtwin.recording import LazyChannel, Recording
from benchtwin.sensors import devices
from benchtwin.sensors.synthetic import synthetic_trace
from benchtwin.trace import SpooledTrace, Trace
from benchtwin.validation.holdout import without_window

PAPER = load_setup("paper")


def assert_same_recording(a: Recording, b: Recording, *, meta: bool = True) -> None:
    """Every channel equal bit for bit (times, values, flags, unit, source), the same segments (and meta)."""
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
    assert a.meta == b.meta or not meta


def test_spooled_trace_reads_what_was_appended() -> None:
    trace = synthetic_trace(30.0, 100.0, seed=3)
    with SpooledTrace() as spooled:
        for piece in time_slices([trace], 7.0):
            spooled.append(piece)
        folder = spooled._dir
        assert folder is not None and folder.is_dir()
        np.testing.assert_array_equal(spooled.time_s, trace.time_s)
        assert list(spooled) == list(trace.channels) and "no_such" not in spooled
        for name, values in trace.channels.items():
            got = spooled[name]
            assert got.dtype == values.dtype
            np.testing.assert_array_equal(got, values)
        for a, b in ((0.0, 30.0), (3.33, 12.5), (29.99, 40.0), (12.0, 12.0)):
            want, got = trace.slice_time(a, b), spooled.slice_time(a, b)
            np.testing.assert_array_equal(got.time_s, want.time_s)
            for name in trace.channels:
                np.testing.assert_array_equal(got[name], want[name])
            assert got.segments == want.segments
    assert not folder.exists()


def test_time_slices_cut_by_duration_and_keep_segments_once() -> None:
    trace = synthetic_trace(25.0, 100.0, seed=1)
    slices = list(time_slices([trace], 10.0))
    assert [len(s) for s in slices] == [1000, 1000, len(trace) - 2000]
    np.testing.assert_array_equal(np.concatenate([s.time_s for s in slices]), trace.time_s)
    assert slices[0].segments == trace.segments and all(not s.segments for s in slices[1:])
    with pytest.raises(ValueError, match="positive"):
        list(time_slices([trace], 0.0))


def test_recording_read_from_the_chunk_files_equals_the_in_memory_one(tmp_path: Path) -> None:
    trace = synthetic_trace(60.0, 100.0, seed=5)
    whole = run_chunked([trace], PAPER, seed=2)
    rec = run_chunked(time_slices([trace], 13.0), PAPER, seed=2, out_dir=tmp_path, keep_chunks=True)
    try:
        lazy = [n for n, c in rec.channels.items() if isinstance(c, LazyChannel)]
        assert len(lazy) > len(rec.channels) // 2 and not rec.loaded() & set(lazy)
        assert_same_recording(rec, whole)
        rec.drop()
        assert not rec.loaded() & set(lazy)
        # the file's meta went through JSON (integer keys became text)
        assert_same_recording(Recording.load(tmp_path / "recording.mf4"), whole, meta=False)
        cut = without_window(rec, 20.0, 35.0)
        assert not rec.loaded() & set(lazy) and not cut.loaded() & set(lazy)
        eager = without_window(whole, 20.0, 35.0)
        assert_same_recording(cut, eager)
    finally:
        rec.close()
    assert not list(tmp_path.glob(".acquisition-*"))  # the chunk files go with the Recording


def test_validate_holds_neither_the_trace_nor_the_recording(monkeypatch: pytest.MonkeyPatch) -> None:
    campaign = load_campaign("quick.toml")
    campaign = campaign.model_copy(update={"tests": campaign.tests[:2]})
    setup = load_setup("paper")
    polled = {d.poll_device for d in devices(setup) if d.poll_device is not None}  # decoded at the end
    seen: dict[str, object] = {}
    real_identify, real_checks = vrun.identify_all, vrun.chain_checks

    def identify(rec: Recording, *args: object, **kwargs: object) -> object:
        if "rec" not in seen:
            seen["rec"] = rec
            seen["in_memory"] = {n for n, c in rec.channels.items() if not isinstance(c, LazyChannel)}
            seen["loaded_before"] = rec.loaded()
        return real_identify(rec, *args, **kwargs)

    def checks(trace: Trace, rec: Recording, *args: object, **kwargs: object) -> object:
        seen["trace"] = trace
        before = rec.loaded()
        out = real_checks(trace, rec, *args, **kwargs)
        seen["loaded_by_checks"] = rec.loaded() - before
        return out

    monkeypatch.setattr(vrun, "identify_all", identify)
    monkeypatch.setattr(vrun, "chain_checks", checks)
    # the chain checks in this process, in line (beside, in a forked child, what they saw would stay the child's)
    monkeypatch.setattr(vrun, "SIDE_MODE", "off")
    report = vrun.validate(load_vehicle(), setup, campaign, type_b=False)
    rec = seen["rec"]
    assert isinstance(rec, Recording)
    # every channel read from its file, the poll logs' (decoded at the end) too: none held in memory
    assert seen["in_memory"] == set()
    assert seen["loaded_before"] == set()
    assert {c.source for c in rec.channels.values()} & polled  # the polled channels are there
    assert seen["loaded_by_checks"] == set()  # each channel checked goes again
    assert isinstance(seen["trace"], SpooledTrace)
    assert seen["trace"]._dir is None  # the truth's files are gone after the run
    assert any(c.group == "chain" and c.passed for c in report.checks)


def test_the_further_drives_run_after_the_held_out_identification_one_at_a_time(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Both at once were the run's peak: the held-out identification sees no other thread simulating a further
    drive; the further drives (the WLTC from a low SOC, then the NEDC) run once it is done, each closed before the
    next starts."""
    import threading

    from benchtwin.errors import DataError
    from benchtwin.segments import Segment
    from benchtwin.validation.report import ValidationReport

    events: list[str] = []

    class Closable:
        def __init__(self, name: str) -> None:
            self.name = name
            self.segments = (Segment(0.0, 10.0, "cycle", name),)

        def close(self) -> None:
            events.append(f"{self.name} closed")

    def identify(rec: object, *args: object, **kwargs: object) -> object:
        others = [t.name for t in threading.enumerate() if t is not threading.current_thread()]
        events.append("identify beside " + ",".join(sorted(n for n in others if "drive" in n)))
        return object()

    def drive(vehicle: object, setup: object, campaign: object, name: str, cycle: str, soc_pct: float,
              seed: int) -> tuple[Closable, Closable]:
        events.append(f"{name} from {cycle} at {soc_pct:g} %")
        return Closable(name), Closable(name)

    def predict(*args: object, **kwargs: object) -> object:
        raise DataError("not predicted here")

    monkeypatch.setattr(vrun, "identify_all", identify)
    monkeypatch.setattr(vrun, "_held_out_drive", drive)
    monkeypatch.setattr(vrun, "MapVehicle", lambda result, specs: type("M", (), {"notes": []})())
    monkeypatch.setattr(vrun, "predict_drive", predict)
    monkeypatch.setattr(vrun, "without_window", lambda rec, a, b: rec)
    trace = Trace(np.arange(0.0, 30.0, 0.5), {"x": np.zeros(60)},
                  [Segment(0.0, 10.0, "ramp_up", "r"), Segment(10.0, 30.0, "cycle", "wltc")], {})
    vehicle = load_vehicle()
    assert vehicle.hybrid is not None and vehicle.hybrid.sustain_soc_pct == 15.0
    report = ValidationReport()
    checks = vrun._prediction(report, vehicle, PAPER, load_campaign("quick.toml"), trace, Recording(), "realistic")
    assert checks == []
    assert events == ["identify beside ",
                      "wltc_low_soc from wltc_class3b.csv at 14 %", "wltc_low_soc closed", "wltc_low_soc closed",
                      "nedc from nedc.csv at 22 %", "nedc closed", "nedc closed"]
    # a drive that could not be predicted is said so, by name
    assert [n for n in report.prediction["notes"] if n.startswith("held-out drive")] == [
        "held-out drive wltc_low_soc: not predicted here", "held-out drive nedc: not predicted here"]


def test_recording_mf4_written_from_the_chunk_files_in_small_blocks_reads_back_equal(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """recording.mf4 is written from the acquisition's chunk files block by block (here 1000 samples, so every
    group of this minute is several blocks): read back with Recording.load it is the in-memory Recording."""
    import benchtwin.mdf

    trace = synthetic_trace(30.0, 100.0, seed=8)
    whole = run_chunked([trace], PAPER, seed=3)
    monkeypatch.setattr(benchtwin.mdf, "WRITE_BLOCK_SAMPLES", 1000)
    rec = run_chunked(time_slices([trace], 11.0), PAPER, seed=3, out_dir=tmp_path, keep_chunks=True)
    rec.close()
    assert max(len(c) for c in whole.channels.values()) > 5 * 1000
    assert_same_recording(Recording.load(tmp_path / "recording.mf4"), whole, meta=False)
