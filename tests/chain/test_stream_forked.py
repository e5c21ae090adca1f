"""The chain's whole producer (pieces -> encode -> deliver) in a forked child (``run_chunked(producer_mode="fork")``):
the same Recording, meta, bus logs and notes as on the prefetch thread, the producer's failures raised here and an
early stop leaving no child behind."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

import benchtwin.chain.stream as stream
import benchtwin.validation.run as vrun
from benchtwin.chain.buslog import read_mf4
from benchtwin.chain.forked_iter import ForkedIter
from benchtwin.chain.stream import run_chunked, time_slices
from benchtwin.config import load_campaign, load_setup, load_vehicle
from benchtwin.emulator import iter_campaign
from benchtwin.errors import SimulationError
from benchtwin.trace import Trace
from tests.chain.test_stream import _with_faults, assert_same_recording

PAPER = load_setup("paper")
#: faults that end in the run's meta (a bus log cut short: ``damaged_logs``) and in its events
FAULTS = [{"kind": "log_truncation", "bus": "dyno", "start_s": 600.0},
          {"kind": "transport_disconnect", "bus": "vehicle", "start_s": 299.0, "duration_s": 2.0}]


class _Seen(ForkedIter):
    """A ForkedIter that keeps its instances: the producer's child of a run can be looked for after it."""

    made: ClassVar[list[ForkedIter]] = []

    def __enter__(self) -> ForkedIter:
        out = super().__enter__()
        _Seen.made.append(self)
        self.forked_pid = self.pid
        return out


@pytest.fixture()
def seen(monkeypatch: pytest.MonkeyPatch) -> list[ForkedIter]:
    _Seen.made = []
    monkeypatch.setattr(stream, "ForkedIter", _Seen)
    return _Seen.made


def _gone(pid: int) -> bool:
    try:
        os.waitpid(pid, os.WNOHANG)
    except ChildProcessError:
        return True
    return False


def _noted(vehicle, campaign, notes: list) -> Iterator[Trace]:
    """The campaign's tests cut in slices, each test noted (its number, its last sample, the process) as it is made."""
    for k, piece in enumerate(iter_campaign(vehicle, campaign)):
        notes.append((k, float(piece.time_s[-1]), os.getpid()))
        yield from time_slices([piece], 200.0)


def _run(mode: str, out: Path) -> tuple:
    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    setup = _with_faults(PAPER, FAULTS)
    notes: list = []
    got: list[list] = []
    rec = run_chunked(_noted(vehicle, campaign, notes), setup, campaign.seed, out, meta={"x": 1},
                      producer_mode=mode, notes=notes, on_notes=got.append)
    return rec, got


def test_the_forked_producer_gives_the_threads_recording_meta_logs_and_notes(tmp_path: Path, seen) -> None:
    rec, got = _run("fork", tmp_path / "fork")
    assert len(seen) == 1 and seen[0].mode == "fork" and _gone(seen[0].forked_pid)
    want, want_got = _run("thread", tmp_path / "thread")
    assert_same_recording(rec, want)
    assert rec.meta["trace"] == want.meta["trace"] and rec.meta["trace"]  # the last piece's meta, from the child
    assert [d["bus"] for d in rec.meta["damaged_logs"]] == ["dyno"]
    # the notes: every test's once, in order, made in the child, handed over once per chunk and at the end
    flat = [n for batch in got for n in batch]
    assert [n[:2] for n in flat] == [n[:2] for batch in want_got for n in batch]
    assert [n[0] for n in flat] == list(range(len(flat))) and len(flat) > 1
    assert {n[2] for n in flat} == {seen[0].forked_pid}
    assert len(got) == len(want_got) > len(flat)
    files = sorted(p.name for p in (tmp_path / "thread").iterdir() if not p.name.startswith("."))
    assert files == sorted(p.name for p in (tmp_path / "fork").iterdir() if not p.name.startswith("."))
    assert any(f.endswith(".mf4") and f != "recording.mf4" for f in files)
    for name in files:  # an MF4 file's header holds the time it was written: the frames compared there
        a, b = tmp_path / "fork" / name, tmp_path / "thread" / name
        if name.endswith(".mf4") and name != "recording.mf4":
            x, y = read_mf4(a, a.stem).frames, read_mf4(b, b.stem).frames
            assert x.dtype == y.dtype and len(x) and x.tobytes() == y.tobytes(), name
        elif name != "recording.mf4":  # recording.mf4: the Recording compared above
            assert a.read_bytes() == b.read_bytes(), name


def _fails_after_one(vehicle, campaign) -> Iterator[Trace]:
    it = iter_campaign(vehicle, campaign)
    yield next(it)
    yield next(it)
    raise SimulationError(f"the plant left its physical domain in process {os.getpid()}")


def test_the_producers_exception_is_raised_here_and_its_child_reaped(tmp_path: Path, seen) -> None:
    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    with pytest.raises(SimulationError, match="left its physical domain") as info:
        run_chunked(_fails_after_one(vehicle, campaign), PAPER, campaign.seed, tmp_path, producer_mode="fork")
    assert f"in process {os.getpid()}" not in str(info.value)  # raised in the child
    assert _gone(seen[0].forked_pid)
    assert not list(tmp_path.glob(".acquisition-*"))  # the chunk files went


def test_a_consumer_that_stops_early_ends_the_child(tmp_path: Path, seen) -> None:
    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    calls: list[int] = []

    def stop(notes: list) -> None:
        calls.append(len(notes))
        if len(calls) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_chunked(time_slices(iter_campaign(vehicle, campaign), 100.0), PAPER, campaign.seed, tmp_path,
                    producer_mode="fork", notes=[], on_notes=stop)
    assert len(calls) == 2 and _gone(seen[0].forked_pid)
    assert not list(tmp_path.glob(".acquisition-*"))


def test_a_bad_mode_is_refused() -> None:
    with pytest.raises(ValueError, match="producer_mode 'process'"):
        run_chunked([], PAPER, producer_mode="process")


def test_validate_stream_forked_counts_the_childs_truth_and_plant_seconds(seen) -> None:
    vehicle, setup, campaign = load_vehicle(), PAPER, load_campaign("quick.toml")
    want = list(iter_campaign(vehicle, campaign))
    with ExitStack() as stack:
        truth, rec, plant_s = vrun._simulated_and_measured(vehicle, setup, campaign, None, stack, progress=True,
                                                           producer_mode="fork")
        assert len(seen) == 1 and seen[0].mode == "fork"
        assert plant_s > 0.0
        assert len(truth) == sum(len(w) for w in want) and truth.duration_s == want[-1].time_s[-1] - want[0].time_s[0]
        assert truth.segments == [s for w in want for s in w.segments] and truth.meta == want[-1].meta
        assert truth.time_s.tobytes() == np.concatenate([w.time_s for w in want]).tobytes()
        for name in want[0].channels:
            assert truth[name].tobytes() == np.concatenate([w.channels[name] for w in want]).tobytes(), name
        with ExitStack() as again:
            _, rec2, _ = vrun._simulated_and_measured(vehicle, setup, campaign, None, again)
            assert_same_recording(rec, rec2)


def _one_test_then_fails(vehicle, campaign) -> Iterator[Trace]:
    it = iter_campaign(vehicle, campaign)
    yield next(it)
    raise SimulationError(f"campaign {campaign.name!r}: the plant left its physical domain in process {os.getpid()}")


def test_validate_forks_the_chains_producer_and_raises_its_error(monkeypatch: pytest.MonkeyPatch, seen) -> None:
    import benchtwin.validation.forked_chain as fchain

    assert vrun.CHAIN_PRODUCER_MODE == "fork"  # the default where os.fork is
    monkeypatch.setattr(fchain, "iter_campaign", _one_test_then_fails)
    with pytest.raises(SimulationError, match="'quick': the plant left its physical domain") as info:
        vrun.validate(load_vehicle(), PAPER, load_campaign("quick.toml"), figures=False)
    assert f"in process {os.getpid()}" not in str(info.value)  # raised in the child, re-raised here
    assert len(seen) == 1 and _gone(seen[0].forked_pid)


def test_validate_beside_a_running_thread_keeps_the_producer_in_this_process(monkeypatch: pytest.MonkeyPatch,
                                                                               seen) -> None:
    """A program with a thread of its own: forking beside it could leave the child a lock that thread holds, so the
    chain's producer runs here (the plant's error is raised in this process) and no child is made."""
    import threading

    import benchtwin.validation.forked_chain as fchain

    monkeypatch.setattr(fchain, "iter_campaign", _one_test_then_fails)
    monkeypatch.setattr(vrun, "iter_campaign", _one_test_then_fails)
    done = threading.Event()
    other = threading.Thread(target=done.wait, name="the program's own thread", daemon=True)
    other.start()
    try:
        assert fchain.fork_if_alone("fork") == "thread" and fchain.fork_if_alone("thread") == "thread"
        with pytest.raises(SimulationError, match="'quick': the plant left its physical domain") as info:
            vrun.validate(load_vehicle(), PAPER, load_campaign("quick.toml"), figures=False)
    finally:
        done.set()
        other.join()
    assert f"in process {os.getpid()}" in str(info.value)  # made in this process: nothing forked
    assert all(it.forked_pid is None for it in seen)
    assert fchain.fork_if_alone("fork") == "fork"  # the thread gone (tqdm's monitor, left by a bar, not counted)
