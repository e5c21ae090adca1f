"""The live scheduler on its own: pacing, batching, statistics, failures and stop."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from live_synth import synthetic_frames

from benchtwin.chain.live.scheduler import (
    LiveScheduler,
    Stream,
    bus_load_fraction,
    restore_policy,
    use_realtime_priority,
)
from benchtwin.errors import ConfigError, DataError
from benchtwin.wire.frames import FrameTable


def _recording_stream(name: str, times: np.ndarray, log: list) -> Stream:
    def deliver(i0: int, i1: int) -> int:
        now = time.perf_counter()
        log.extend((now, i) for i in range(i0, i1))
        return i1 - i0

    return Stream(name, times, deliver)


def test_items_delivered_once_in_order_and_on_time():
    t_a = np.arange(0, 1.0, 0.001)
    t_b = np.arange(0.0005, 1.0, 0.01)
    got_a: list = []
    got_b: list = []
    sch = LiveScheduler([_recording_stream("a", t_a, got_a), _recording_stream("b", t_b, got_b)], speedup=4.0)
    previous = use_realtime_priority(10)
    try:
        wall0 = time.perf_counter()
        rep = sch.run()
    finally:
        restore_policy(previous)
    assert rep.completed and rep.lost == 0
    assert [i for _, i in got_a] == list(range(len(t_a)))
    assert [i for _, i in got_b] == list(range(len(t_b)))
    # no item leaves before its deadline (how late they leave depends on the machine's load: a benchmark)
    deadline = wall0 + (t_a - t_a[0]) / 4.0
    err = np.array([w for w, _ in got_a]) - deadline
    assert np.all(err >= -2e-3)
    assert rep.streams["a"].sent == len(t_a)
    assert rep.streams["a"].pacing_p99_ms >= rep.streams["a"].pacing_p50_ms >= 0
    assert rep.achieved_speedup <= 4.0 * 1.02


def test_batching_groups_items_within_the_window():
    t = np.repeat(np.arange(10) * 0.01, 5)  # bursts of 5 frames at the same time
    calls: list = []
    sch = LiveScheduler([Stream("burst", t, lambda i0, i1: calls.append((i0, i1)) or (i1 - i0))], speedup=10.0)
    rep = sch.run()
    assert calls == [(5 * k, 5 * k + 5) for k in range(10)]
    assert rep.streams["burst"].deliveries == 10


def test_failing_delivery_is_counted_and_does_not_stop_the_run():
    t = np.arange(0, 0.1, 0.01)
    seen = []

    def flaky(i0: int, i1: int) -> int:
        seen.append(i0)
        if i0 == 3:
            raise OSError("socket went away")
        return i1 - i0

    rep = LiveScheduler([Stream("flaky", t, flaky)], speedup=20.0).run()
    assert rep.completed
    assert rep.streams["flaky"].lost == 1 and rep.streams["flaky"].sent == len(t) - 1
    assert seen == list(range(len(t)))


def test_stop_returns_a_partial_report():
    t = np.arange(0, 10.0, 0.01)
    sch = LiveScheduler([Stream("long", t, lambda i0, i1: i1 - i0)], speedup=1.0)
    threading.Timer(0.2, sch.stop).start()
    rep = sch.run()
    assert not rep.completed
    assert 0 < rep.streams["long"].sent < len(t)
    assert rep.plant_end_s < 1.0


def test_slice_and_bus_load():
    f = synthetic_frames(2.0, 2000.0, [0x100])
    table = FrameTable("pt", f)
    sch = LiveScheduler([Stream("can:pt", f["timestamp"], lambda i0, i1: i1 - i0, frames=f)], speedup=50.0,
                        start_s=0.5, end_s=1.5)
    rep = sch.run()
    assert rep.streams["can:pt"].items == 2001  # both ends included
    # 8-byte standard frames: 135 bits worst case -> 2000/s * 135 / 500k = 54 %
    assert rep.streams["can:pt"].bus_load == pytest.approx(table.bus_load(), rel=0.01)
    assert bus_load_fraction(f[:2000], 500_000, 1.0) == pytest.approx(2000 * 135 / 500_000, rel=1e-9)
    assert "can:pt" in rep.format()


def test_bad_arguments():
    with pytest.raises(ConfigError):
        LiveScheduler([], speedup=0)
    with pytest.raises(DataError):
        Stream("x", np.array([1.0, 0.5]), lambda a, b: 0)
    with pytest.raises(ConfigError):
        LiveScheduler([Stream("x", [0.0], lambda a, b: 1), Stream("x", [0.0], lambda a, b: 1)])


@pytest.mark.timeout(600)
def test_as_fast_as_possible():
    """Unpaced: 10,000 s of plant time (100,000 items) delivered whole. Paced, it would take hours and hit the
    timeout; how fast it goes is a benchmark, not asserted here."""
    t = np.arange(0, 10_000.0, 0.1)
    n = []
    rep = LiveScheduler([Stream("fast", t, lambda i0, i1: n.append(i1 - i0) or (i1 - i0))], speedup=np.inf).run()
    assert sum(n) == len(t) and rep.completed and rep.lost == 0


def test_realtime_priority_is_validated_and_restored():
    import os

    with pytest.raises(ConfigError):
        use_realtime_priority(0)
    before = os.sched_getscheduler(0)
    previous = use_realtime_priority(5)  # None (and a warning) without the privilege
    if previous is not None:
        assert os.sched_getscheduler(0) == os.SCHED_FIFO
    restore_policy(previous)
    assert os.sched_getscheduler(0) == before


def test_pacing_table_columns_are_aligned_for_long_names_big_counts_and_missing_figures():
    from benchtwin.chain.live.scheduler import PacingReport, StreamStats

    streams = {
        "can:instrument": StreamStats("can:instrument", "can", 123456789, 123456789, 0, 5000, 0.012, 0.5, 12.25,
                                      -0.1, 81234.0, 0.4321),
        "canopen:a_very_long_thermo_module_name": StreamStats("canopen:a_very_long_thermo_module_name", "canopen",
                                                              30, 29, 1, 30, 0.1, 0.2, 0.3, 0.0, float("nan")),
        "modbus:pressure": StreamStats("modbus:pressure", "modbus", 400, 400, 0, 400, float("nan"), float("nan"),
                                       float("nan"), float("nan"), 200.0),
    }
    rep = PacingReport(speedup=4.0, plant_start_s=0.0, plant_end_s=2.0, wall_s=0.5, completed=True, streams=streams,
                       pacing_p50_ms=0.05, pacing_p99_ms=0.4, pacing_max_ms=12.25)
    lines = rep.format().splitlines()
    table = lines[1:]
    assert len(table) == 1 + len(streams) + 1  # header, one row per stream, the total
    assert len({len(line) for line in table}) == 1  # fixed width: every line as long as the header
    header = table[0]
    # each right-aligned column ends where its title ends, on every row
    for title in ("items", "sent", "lost", "p50 ms", "p99 ms", "max ms", "rate/s", "bus load"):
        end = header.index(title) + len(title)
        for line in table[1:]:
            assert line[end - 1] != " ", (title, line)
            assert end == len(line) or line[end] == " ", (title, line)
    assert table[-1].startswith("all ")
    assert "nan" not in rep.format()
    assert "43.2 %" in table[1] and "123456789" in table[1]
    assert table[2].startswith("canopen:a_very_long_thermo_module_name ")
