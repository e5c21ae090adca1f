"""A chunked acquisition equals the one-shot ``acquire()`` bit for bit.

Today's AcquisitionInput of the quick campaign (sensors.encode + chain.batch.deliver, as the logs hold it) is
cut by time into chunks and fed to :class:`~benchtwin.chain.acquisition.Acquisition`; every channel's
timestamps, values and flags and the meta data must equal ``acquire()`` of the whole. The cuts go through
each injected fault burst of ``scenarios/setups/faults.toml``, the transport drop and the cut-short dyno log.
About 18 s of CPU (6 s of it the quick campaign's plant), 40 s wall on a busy 2-core machine, 0.9 GB peak.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import benchtwin.chain.acquisition as acquisition
from benchtwin.chain.acquisition import Acquisition, AcquisitionInput, acquire
from benchtwin.config import load_setup
from benchtwin.errors import DataError
from benchtwin.recording import Recording

#: inside every fault span of faults.toml (plant time: frame loss 20-25 s, burst 60-62, duplicates 100-105,
#: reorder 140-145, corrupt payload 180-185, wrong DLC 220-225, IVT error 260-, silent 300-303 and 340-345,
#: Modbus restart 380-383, slow 420-425, transport drop 460-462, stuck 680-690, clock step 700, clip 720-723,
#: open circuit 760-770, stuck 800-840, the dyno log cut at 905 s)
THROUGH_FAULTS = [22.5, 61.0, 102.0, 142.0, 182.0, 222.0, 261.0, 301.5, 342.0, 382.0, 422.0, 461.0, 685.0,
                  700.05, 721.5, 765.0, 820.0, 910.0]


@pytest.fixture(scope="module")
def one_shot(quick_inputs: dict[str, AcquisitionInput]) -> dict[str, Recording]:
    return {name: acquire(data, load_setup(name)) for name, data in quick_inputs.items()}


def _json(x: object) -> object:
    return json.loads(json.dumps(x, default=str))


def differences(a: Recording, b: Recording) -> list[str]:
    """What differs between two Recordings: channel order, any timestamp, value (NaN = NaN) or flag, unit, source,
    segments, start time, meta data."""
    out = []
    if list(a.channels) != list(b.channels):
        out.append(f"channels {list(a.channels)} != {list(b.channels)}")
    for name in a.channels:
        if name not in b:
            continue
        ca, cb = a[name], b[name]
        for field in ("timestamps", "values", "flags"):
            x, y = getattr(ca, field), getattr(cb, field)
            if x.dtype != y.dtype or not np.array_equal(x, y, equal_nan=field == "values"):
                out.append(f"{name}.{field}")
        if (ca.unit, ca.source, ca.value_texts) != (cb.unit, cb.source, cb.value_texts):
            out.append(f"{name}: unit/source/value texts")
    if a.segments != b.segments or a.start_time != b.start_time:
        out.append("segments or start time")
    ma, mb = _json(a.meta), _json(b.meta)
    out += [f"meta[{k!r}]" for k in sorted(set(ma) | set(mb)) if ma.get(k) != mb.get(k)]
    return out


def chunked(data: AcquisitionInput, setup_name: str, edges: list[float], path: Path | None = None) -> Recording:
    acq = Acquisition(load_setup(setup_name), path)
    for chunk in data.split_by_time(edges):
        acq.feed(chunk)
    return acq.finish()


@pytest.mark.parametrize(("setup_name", "edges"), [
    ("paper", [461.0]),
    ("paper", list(np.arange(37.3, 921.0, 61.7))),  # 15 cuts at odd times
    ("faults", THROUGH_FAULTS),
    ("faults", list(np.arange(459.5, 462.5, 0.037))),  # shorter than the thermo's 100 ms cycle, 8 IVT-S frames
], ids=["paper-2", "paper-16", "faults-through-every-burst", "faults-short-chunks-over-the-drop"])
def test_chunked_equals_one_shot(quick_inputs, one_shot, setup_name: str, edges: list[float]) -> None:
    data = quick_inputs[setup_name]
    assert any(len(c.can["vehicle"]) for c in data.split_by_time(edges)[1:])  # the cuts are inside the run
    assert differences(one_shot[setup_name], chunked(data, setup_name, edges)) == []


def test_the_faults_are_seen(one_shot) -> None:
    """The comparison above is not between two empty lists: the faults setup's one-shot Recording shows them."""
    kinds = {f["kind"] for f in one_shot["faults"].meta["faults_detected"]}
    assert {"frame_loss_burst", "duplicate", "reorder", "corrupt_payload", "wrong_dlc", "silent",
            "transport_disconnect", "log_truncation", "stuck"} <= kinds
    assert one_shot["faults"].meta["protocol_errors"]


def test_without_the_carried_context_a_chunked_run_differs(quick_inputs, one_shot, monkeypatch) -> None:
    """The mutant: no frame carried before a chunk's first new one (counter and timing state reset per chunk)."""
    monkeypatch.setattr(acquisition, "CONTEXT_FRAMES", acquisition.HOLD_FRAMES)
    diff = differences(one_shot["faults"], chunked(quick_inputs["faults"], "faults", THROUGH_FAULTS))
    assert any(d.endswith(".flags") for d in diff)


def test_chunks_appended_on_disk_give_the_saved_recording(quick_inputs, one_shot, tmp_path: Path) -> None:
    """With a path, the chunks go to files beside it and finish() returns the MF4 opened lazily: the same content
    as Recording.save of the one-shot Recording, and no file of the chunks is left."""
    rec = chunked(quick_inputs["faults"], "faults", THROUGH_FAULTS[::3], tmp_path / "chunked.mf4")
    assert not rec.loaded()  # opened lazily
    rec.close()
    one_shot["faults"].save(tmp_path / "one.mf4")
    assert differences(Recording.load(tmp_path / "one.mf4"), Recording.load(tmp_path / "chunked.mf4")) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["chunked.mf4", "chunked.segments.json", "one.mf4",
                                                          "one.segments.json"]


def test_bad_chunks_give_one_line_errors(quick_inputs) -> None:
    data = quick_inputs["paper"]
    first, second = data.split_by_time([300.0])
    acq = Acquisition(load_setup("paper")).feed(second)
    with pytest.raises(DataError, match="feed the chunks in time order") as err:
        acq.feed(first)
    assert "\n" not in str(err.value)
    done = Acquisition(load_setup("paper"))
    done.finish()
    with pytest.raises(DataError, match="after finish"):
        done.feed(first)
    with pytest.raises(DataError, match="increasing"):
        data.split_by_time([5.0, 1.0])
    with pytest.raises(DataError, match="takes an AcquisitionInput"):
        Acquisition(load_setup("paper")).feed({"can": {}})  # type: ignore[arg-type]


def test_an_acquisition_given_up_leaves_no_file(quick_inputs, tmp_path: Path) -> None:
    first, second = quick_inputs["paper"].split_by_time([300.0])
    with pytest.raises(DataError, match="time order"), Acquisition(load_setup("paper"), tmp_path / "r.mf4") as acq:
        acq.feed(second)
        assert list(tmp_path.iterdir())  # the chunk's samples are on disk
        acq.feed(first)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("block", [997, 65_536])
def test_the_whole_recording_passes_do_not_depend_on_the_block(quick_inputs, one_shot, tmp_path: Path,
                                                               block: int) -> None:
    """finish()'s passes (truncation, saturation, gaps, stuck runs, flag counts) read a block of a channel at a
    time: blocks of 997 samples (every fault span and stuck run crosses block edges) and of 64 Ki give the one-shot
    Recording, on disk (the validate path: chunk files kept, the poll channels stored too) and in memory."""
    data = quick_inputs["faults"]
    acq = Acquisition(load_setup("faults"), tmp_path / "r.mf4", keep_chunks=True, block_samples=block)
    for chunk in data.split_by_time(THROUGH_FAULTS):
        acq.feed(chunk)
    rec = acq.finish()
    assert not rec.loaded()  # every channel, the poll logs' too, read from the chunk files
    assert differences(one_shot["faults"], rec) == []
    rec.close()
    mem = Acquisition(load_setup("faults"), block_samples=block).feed(data, last=True).finish()
    assert differences(one_shot["faults"], mem) == []


def _repeated(data: AcquisitionInput, k: int) -> list[AcquisitionInput]:
    """``data`` k times in a row (each copy's times shifted by the span of the one before, plus 10 s)."""
    import dataclasses

    span = 10.0 + max(float(t.frames["timestamp"][-1]) for t in data.can.values() if len(t))
    out = []
    for j in range(k):
        part = AcquisitionInput(segments=list(data.segments) if j == 0 else [], meta=dict(data.meta))
        for bus, table in data.can.items():
            frames = table.frames.copy()
            frames["timestamp"] += j * span
            part.can[bus] = type(table)(bus, frames, table.bitrate)
        for dev, p in data.polls.items():
            part.polls[dev] = dataclasses.replace(p, times=p.times + j * span)
        part.events = [dataclasses.replace(e, time_s=e.time_s + j * span, end_s=e.end_s + j * span)
                       for e in data.events]
        out.append(part)
    return out


def _pass_peaks(parts: list[AcquisitionInput], block: int, monkeypatch) -> dict[str, int]:
    """Traced peak (bytes above what was held at the call) of each whole-recording pass of finish()."""
    import tracemalloc

    peaks: dict[str, int] = {}

    def traced(name: str, fn):
        def run(*args, **kwargs):
            base = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            try:
                return fn(*args, **kwargs)
            finally:
                peaks[name] = max(peaks.get(name, 0), tracemalloc.get_traced_memory()[1] - base)
        return run

    for name in ("flag_truncations", "flag_saturation", "detect_faults", "_flag_counts"):
        monkeypatch.setattr(acquisition, name, traced(name, getattr(acquisition, name)))
    acq = Acquisition(load_setup("paper"), keep_chunks=True, align=False, block_samples=block)
    for part in parts:
        acq.feed(part)
    tracemalloc.start()
    try:
        acq.finish().close()
    finally:
        tracemalloc.stop()
    monkeypatch.undo()
    return peaks


def test_the_whole_recording_passes_hold_one_block(quick_inputs, monkeypatch) -> None:
    """Memory of finish()'s passes does not grow with the recording: the quick campaign three times over (the
    500 Hz shaft torque 1.4 M samples instead of 0.46 M) raises no pass's traced peak by more than one block
    (18 bytes a sample) plus the sample of steps the median period is taken from (at most 200,000 steps of
    8 bytes, whatever the length). The same recording read a channel at a time (one block as long as the
    longest channel: the old whole-channel passes) grows by far more: the bound tells the two apart."""
    block = 20_000
    bound = 18 * block + 8 * 200_001
    one, three = _repeated(quick_inputs["paper"], 1), _repeated(quick_inputs["paper"], 3)
    small = {k: _pass_peaks(parts, block, monkeypatch) for k, parts in ((1, one), (3, three))}
    assert set(small[1]) == {"flag_truncations", "flag_saturation", "detect_faults", "_flag_counts"}
    growth = {name: small[3][name] - small[1][name] for name in small[1]}
    assert max(growth.values()) < bound, growth
    whole = {k: _pass_peaks(parts, 1 << 40, monkeypatch) for k, parts in ((1, one), (3, three))}
    assert whole[3]["detect_faults"] - whole[1]["detect_faults"] > 4 * bound
