"""recording.mf4 written later (benchtwin.chain.deferred_save): the file finish() would have written, whatever the
caller does to its Recording meanwhile, written once, at the latest when the Recording is closed."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchtwin.chain.deferred_save import pending_save
from benchtwin.chain.stream import run_chunked, trace_pieces
from benchtwin.config import load_setup
from benchtwin.recording import Recording
from benchtwin.sensors.synthetic import synthetic_trace

PAPER = load_setup("paper")


def _run(out: Path, defer: bool) -> Recording:
    trace = synthetic_trace(60.0, 100.0, seed=3)
    return run_chunked(trace_pieces(trace), PAPER, 5, out, keep_chunks=True, defer_save=defer)


def _same_file(a: Path, b: Path) -> None:
    ra, rb = Recording.load(a), Recording.load(b)
    assert list(ra.channels) == list(rb.channels) and ra.channels
    for name in ra.channels:
        for field in ("timestamps", "values", "flags"):
            np.testing.assert_array_equal(getattr(ra[name], field), getattr(rb[name], field), err_msg=name)
    assert ra.meta == rb.meta and ra.segments == rb.segments
    # the bytes too, but for the file history block's creation time (asammdf stamps the save's clock)
    assert a.stat().st_size == b.stat().st_size


def test_a_deferred_save_writes_the_file_finish_would_have(tmp_path: Path) -> None:
    now = _run(tmp_path / "now", defer=False)
    assert pending_save(now) is None and (tmp_path / "now" / "recording.mf4").exists()
    later = _run(tmp_path / "later", defer=True)
    path = tmp_path / "later" / "recording.mf4"
    deferred = pending_save(later)
    assert deferred is not None and not path.exists()
    # what the caller does to its Recording before the save does not reach the file
    later.meta["clock_offsets_s"] = {"changed": 1.0}
    later.meta["added_later"] = True
    later.segments.clear()
    assert deferred.run() == path and deferred.done
    assert deferred.run() == path  # once
    _same_file(tmp_path / "now" / "recording.mf4", path)
    # and the Recording returned still reads the chunk files (the save dropped only its own copy's channels)
    name = next(iter(now.channels))
    np.testing.assert_array_equal(later[name].values, now[name].values)
    now.close()
    later.close()


def test_closing_the_recording_writes_a_save_nobody_ran(tmp_path: Path) -> None:
    _run(tmp_path / "now", defer=False).close()
    rec = _run(tmp_path / "later", defer=True)
    assert not (tmp_path / "later" / "recording.mf4").exists()
    rec.close()
    _same_file(tmp_path / "now" / "recording.mf4", tmp_path / "later" / "recording.mf4")


def test_a_save_done_elsewhere_is_not_written_again(tmp_path: Path) -> None:
    rec = _run(tmp_path, defer=True)
    deferred = pending_save(rec)
    assert deferred is not None
    deferred.done_elsewhere(str(tmp_path / "recording.mf4"))
    assert deferred.done
    rec.close()
    assert not (tmp_path / "recording.mf4").exists()  # another process's to write


def _bytes_but_creation_time(path: Path) -> bytes:
    """The file's bytes with the file history block's creation time (ns, after its header and two links) zeroed."""
    raw = bytearray(path.read_bytes())
    at = raw.find(b"##FH")
    assert at >= 0
    raw[at + 40:at + 48] = bytes(8)
    return bytes(raw)


def test_one_worker_writes_the_same_bytes(tmp_path: Path) -> None:
    _run(tmp_path / "now", defer=False).close()  # finish's save: two workers
    rec = _run(tmp_path / "later", defer=True)
    deferred = pending_save(rec)
    assert deferred is not None
    deferred.run(workers=1)  # the side stages' child: one core
    rec.close()
    a, b = (_bytes_but_creation_time(p / "recording.mf4") for p in (tmp_path / "now", tmp_path / "later"))
    assert a == b
