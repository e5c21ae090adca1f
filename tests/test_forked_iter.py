"""A producer iterated in a forked child (benchtwin.chain.forked_iter): the same items bit for bit as iterated in line,
and every failure of either side raised, never lost, with no child left behind."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from contextlib import ExitStack
from functools import partial

import numpy as np
import pytest

import benchtwin.validation.run as vrun
from benchtwin.chain.forked_iter import ForkedIter, ForkedProducerError
from benchtwin.config import load_campaign, load_setup, load_vehicle, scenario_path
from benchtwin.emulator import iter_campaign
from benchtwin.errors import SimulationError
from benchtwin.trace import Trace

MODES = ("fork", "thread")


def _paper_setup():
    return load_setup(scenario_path("setups", "paper.toml"))


def _gone(pid: int) -> bool:
    """Whether ``pid`` is neither running nor a zombie of this process (it has been waited for)."""
    try:
        os.waitpid(pid, os.WNOHANG)
    except ChildProcessError:
        return True
    return False


def _arrays(n: int) -> Iterator[dict]:
    rng = np.random.default_rng(7)
    for k in range(n):
        block = rng.standard_normal((4, 1000 + k))
        yield {"k": k, "row": block[1], "col": block[:, 3], "ints": np.arange(k, dtype=np.int32),
               "nan": np.full(5, np.nan), "big": rng.standard_normal(300_000)}


@pytest.mark.parametrize(("mode", "depth"), [("fork", 1), ("fork", 3), ("thread", 1)])
def test_the_items_arrive_in_order_bit_for_bit(mode: str, depth: int) -> None:
    want = list(_arrays(5))
    with ForkedIter(partial(_arrays, 5), mode, depth=depth) as it:
        got = list(it)
    assert [g["k"] for g in got] == list(range(5))
    for g, w in zip(got, want, strict=True):
        for name in ("row", "col", "ints", "nan", "big"):
            assert g[name].dtype == w[name].dtype and g[name].tobytes() == w[name].tobytes()
            assert g[name].flags.writeable and g[name].flags.aligned  # as the producer's: may be worked in place


def test_the_plants_tests_arrive_bit_for_bit() -> None:
    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    want = list(iter_campaign(vehicle, campaign))
    with ForkedIter(partial(iter_campaign, vehicle, campaign), "fork") as it:
        got = list(it)
        assert it.made_s > 0.0
    assert len(got) == len(want) > 1
    for g, w in zip(got, want, strict=True):
        assert isinstance(g, Trace) and g.segments == w.segments and g.meta == w.meta
        assert g.time_s.tobytes() == w.time_s.tobytes() and list(g.channels) == list(w.channels)
        for name in w.channels:
            assert g.channels[name].tobytes() == w.channels[name].tobytes(), name


def _fails_after_two() -> Iterator[int]:
    yield 1
    yield 2
    raise SimulationError("campaign 'x': the plant left its physical domain (non-finite states)")


@pytest.mark.parametrize("mode", MODES)
def test_the_producers_exception_is_raised_with_its_type_and_message_after_its_items(mode: str) -> None:
    got = []
    with ForkedIter(_fails_after_two, mode) as it:
        with pytest.raises(SimulationError, match="left its physical domain") as info:
            for x in it:
                got.append(x)
        pid = it.pid
    assert got == [1, 2]
    if mode == "fork":
        assert "_fails_after_two" in "".join(getattr(info.value, "__notes__", []))
        assert pid is None  # waited for


class _UnpicklableError(Exception):
    def __init__(self, a: int, b: int) -> None:  # pickle rebuilds it with one argument: fails
        super().__init__(f"{a} and {b}")


def _raises_unpicklable() -> Iterator[int]:
    raise _UnpicklableError(1, 2)
    yield 0  # pragma: no cover


def test_an_exception_that_does_not_pickle_comes_back_as_its_text() -> None:
    with ForkedIter(_raises_unpicklable, "fork") as it, pytest.raises(ForkedProducerError, match="1 and 2"):
        list(it)


def _dies() -> Iterator[int]:
    yield 1
    os._exit(3)


def test_a_child_that_dies_is_a_clear_error() -> None:
    with ForkedIter(_dies, "fork") as it:
        with pytest.raises(ForkedProducerError, match="exit code 3"):
            for x in it:
                assert x == 1
        assert it.pid is None


def _endless() -> Iterator[np.ndarray]:
    while True:
        yield np.zeros(100_000)


@pytest.mark.parametrize("stop", ["break", "consumer error", "ctrl-c"])
def test_stopping_early_ends_the_child(stop: str) -> None:
    with ExitStack() as stack:
        it = stack.enter_context(ForkedIter(_endless, "fork"))
        pid = it.pid
        assert pid is not None and not _gone(pid)
        if stop == "break":
            for _ in it:
                break
        else:
            exc = KeyboardInterrupt if stop == "ctrl-c" else ValueError
            with pytest.raises(exc):
                for _ in it:
                    raise exc("stop")
        it_iter_closed = it.pid is None  # the iteration's end ends the child, not only the context's
    assert _gone(pid)
    assert it_iter_closed or stop == "break"


def test_leaving_the_context_unused_ends_the_child() -> None:
    with ForkedIter(_endless, "fork") as it:
        pid = it.pid
    assert pid is not None and _gone(pid) and it.pid is None


def _sleeps_forever() -> Iterator[int]:
    yield 1
    while True:
        time.sleep(60)


def _ignored_signals(pid: int) -> int:
    with open(f"/proc/{pid}/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("SigIgn:"):
                return int(line.split()[1], 16)
    raise AssertionError("no SigIgn line")  # pragma: no cover


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="reads /proc")
def test_the_child_ignores_ctrl_c_that_its_parent_handles() -> None:
    """A terminal's Ctrl-C reaches the whole process group: the parent's KeyboardInterrupt ends the child, which
    must not end on its own first (its end would read as a dead child, not as the interrupt)."""
    with ForkedIter(_sleeps_forever, "fork") as it:
        items = iter(it)
        assert next(items) == 1  # the child is past its set-up
        assert it.pid is not None
        pid = it.pid
        assert _ignored_signals(pid) & (1 << (signal.SIGINT - 1))
        assert not _ignored_signals(os.getpid()) & (1 << (signal.SIGINT - 1))  # this process still handles it
        items.close()
    assert _gone(pid)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="mode"):
        ForkedIter(_endless, "process")
    with pytest.raises(ValueError, match="depth"):
        ForkedIter(_endless, "fork", depth=0)
    it = ForkedIter(_endless, "fork")
    with pytest.raises(RuntimeError, match="enter"):
        iter(it)


@pytest.mark.parametrize("mode", MODES)
def test_streamed_truth_recording_and_plant_seconds_the_same_either_way(mode: str) -> None:
    vehicle, setup, campaign = load_vehicle(), _paper_setup(), load_campaign("quick.toml")
    with ExitStack() as stack:
        truth, rec, plant_s = vrun._simulated_and_measured(vehicle, setup, campaign, None, stack, plant_mode=mode)
        want = list(iter_campaign(vehicle, campaign))
        assert plant_s > 0.0
        assert len(truth) == sum(len(w) for w in want)
        assert truth.segments == [s for w in want for s in w.segments] and truth.meta == want[-1].meta
        for name in want[0].channels:
            assert truth[name].tobytes() == np.concatenate([w.channels[name] for w in want]).tobytes(), name
        got = {name: rec[name].values.tobytes() for name in sorted(rec.channels)[:12]}
    with ExitStack() as stack:
        _, rec2, _ = vrun._simulated_and_measured(vehicle, setup, campaign, None, stack, plant_mode="thread")
        assert got == {name: rec2[name].values.tobytes() for name in got}


def _one_test_then_fails(vehicle, campaign) -> Iterator[Trace]:
    it = iter_campaign(vehicle, campaign)
    yield next(it)
    raise SimulationError(f"campaign {campaign.name!r}: the plant left its physical domain (non-finite states) "
                          f"in process {os.getpid()}")


def test_validate_runs_the_plant_in_a_child_and_raises_its_error(monkeypatch) -> None:
    monkeypatch.setattr(vrun, "iter_campaign", _one_test_then_fails)
    monkeypatch.setattr(vrun, "PLANT_MODE", "fork")
    monkeypatch.setattr(vrun, "CHAIN_PRODUCER_MODE", "thread")  # the plant alone forked, not the chain's producer
    with pytest.raises(SimulationError, match="'quick': the plant left its physical domain") as info:
        vrun.validate(load_vehicle(), _paper_setup(), load_campaign("quick.toml"), figures=False)
    assert f"in process {os.getpid()}" not in str(info.value)  # raised in the child, re-raised here


def test_the_objects_are_frozen_while_the_child_lives_and_thawed_after() -> None:
    """Frozen (out of the collector's walk) on both sides while they share pages; the parent's collector gets them
    back once the child is gone, and a freeze the caller made is left to the caller."""
    import gc

    assert gc.get_freeze_count() == 0
    with ForkedIter(partial(_arrays, 2), "fork") as it:
        assert gc.get_freeze_count() > 0
        assert len(list(it)) == 2
    assert gc.get_freeze_count() == 0
    gc.freeze()
    try:
        with ForkedIter(partial(_arrays, 2), "fork") as it:
            list(it)
        assert gc.get_freeze_count() > 0  # still the caller's (a few of its objects may have been freed)
    finally:
        gc.unfreeze()
