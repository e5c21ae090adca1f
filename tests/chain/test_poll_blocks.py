"""The Modbus poll logs decoded block by block equal the whole-log decoding bit for bit, and hold a block, not the log.

:func:`~benchtwin.sensors.pressure_decode.decode_pressure_polls` (the whole log: the module's clock judged over all of
it) is the reference; :func:`~benchtwin.sensors.pressure_polls.decode_pressure_poll_blocks` must give the same
channels (timestamps, values, flags), counts, clock offset and fault evidence for any block size, and the acquisition
(which spools the poll logs beside its chunk files and decodes them by blocks) the same Recording as with the
whole-log decoder. About 25 s on a loaded 2-core machine (the quick campaign's acquisitions; the session fixture's
simulation is shared with the other chain tests).
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from benchtwin.chain.acquisition import Acquisition
from benchtwin.chain.decoding import events_for
from benchtwin.config import load_setup
from benchtwin.sensors.base import Device
from benchtwin.sensors.pressure import PressureModule
from benchtwin.sensors.pressure_decode import decode_pressure_polls
from benchtwin.sensors.pressure_polls import decode_pressure_poll_blocks, select_ranks
from benchtwin.wire.frames import POLL_TIMEOUT, PollLog
from benchtwin.wire.quality import DecodeSink


def _blocks(plog, cfg, drops, block: int) -> tuple[DecodeSink, dict[str, tuple[np.ndarray, ...]]]:
    sink, parts = DecodeSink(), {}
    decode_pressure_poll_blocks(plog, cfg, sink, drops,
                                lambda n, u, t, v, f, s: parts.setdefault(n, []).append((t, v, f, u, s)), block)
    return sink, {n: tuple(np.concatenate([p[k] for p in ps]) for k in range(3)) + ps[0][3:] for n, ps in parts.items()}


def _same_evidence(a: DecodeSink, b: DecodeSink) -> bool:
    return len(a.evidence) == len(b.evidence) and all(
        x[:3] == y[:3] and np.array_equal(x[3], y[3]) and np.array_equal(x[4], y[4])
        for x, y in zip(a.evidence, b.evidence))


@pytest.mark.parametrize("setup_name", ["paper", "faults"])
@pytest.mark.parametrize("block", [997, 4096, 1 << 18])
def test_block_decoding_equals_the_whole_log(quick_inputs, setup_name: str, block: int) -> None:
    """The quick campaign's poll log (the faults setup: a clock step, drift, a restart, slow answers, drops)."""
    setup = load_setup(setup_name)
    inp = quick_inputs[setup_name]
    (device, plog), = inp.polls.items()
    drops = events_for(inp.events, {device})
    whole = DecodeSink()
    decode_pressure_polls(plog, setup.pressure, whole, drops)
    sink, got = _blocks(plog, setup.pressure, drops, block)
    assert list(got) == list(whole.rec.channels)
    for name, ch in whole.rec.channels.items():
        t, v, f, unit, source = got[name]
        assert t.tobytes() == ch.timestamps.tobytes() and v.tobytes() == ch.values.tobytes(), name
        assert np.array_equal(f, ch.flags) and (unit, source) == (ch.unit, ch.source), name
    assert sink.counts == whole.counts  # polls, timeouts, exceptions, the clock offset
    assert _same_evidence(sink, whole)
    if setup_name == "faults":  # the log's faults were found (what the carried state must keep across blocks)
        assert {e[0] for e in whole.evidence} >= {"clock_step", "modbus_slow", "modbus_restart"}


def test_the_acquisition_by_blocks_equals_the_whole_log_decoding(quick_inputs, tmp_path, monkeypatch) -> None:
    """The faults setup's quick campaign fed in chunks, on disk: every channel and the meta data as when the poll log
    is decoded whole (the device's default ``decode_poll_blocks``: the whole log into ``decode_polls``)."""
    setup = load_setup("faults")

    def run(block: int):
        acq = Acquisition(setup, tmp_path / f"b{block}" / "recording.mf4", keep_chunks=True, block_samples=block)
        for chunk in quick_inputs["faults"].split_by_time([200.0, 450.0, 700.05]):
            acq.feed(chunk)
        return acq.finish()

    got = {block: run(block) for block in (997, 65537)}
    monkeypatch.setattr(PressureModule, "decode_poll_blocks", Device.decode_poll_blocks)
    whole = run(1 << 20)
    for rec in got.values():
        assert list(rec.channels) == list(whole.channels)
        for name in whole.channels:
            a, b = rec[name], whole[name]
            assert a.timestamps.tobytes() == b.timestamps.tobytes(), name
            assert a.values.tobytes() == b.values.tobytes() and np.array_equal(a.flags, b.flags), name
            rec[name].drop(), whole[name].drop()
        assert rec.meta == whole.meta
    for rec in (*got.values(), whole):
        rec.close()


def test_select_ranks_is_numpys_sort() -> None:
    rng = np.random.default_rng(4)
    x = np.concatenate([rng.normal(size=5000), [0.0, -0.0, 1e-300, -1e300, 7.0, 7.0], rng.integers(-3, 3, 999)])
    ranks = [0, 1, 2500, 2501, x.size - 1]
    got = select_ranks(lambda: ([x[a:a + 777]] for a in range(0, x.size, 777)), [ranks])[0]
    assert got == [float(v) for v in np.sort(x)[ranks]]


@pytest.mark.parametrize("hold", [0, 100, 6000, 10**6])
def test_select_ranks_held_whole_or_counted_gives_the_same_values(hold: int) -> None:
    """Sets held whole (a partial sort of their keys) and counted (the radix passes), alone or mixed in one call
    (a set of 6,005 values and one of 300, under and over ``hold``): the values of np.sort, bit for bit (the signed
    zeros told apart: -0.0 sorts before 0.0 as their keys do), and the blocks read once when every set is held."""
    rng = np.random.default_rng(5)
    x = np.concatenate([rng.normal(size=5000), [0.0, -0.0, -0.0, 0.0, 1e-300], rng.integers(-3, 3, 1000)])
    y = np.concatenate([[0.0, -0.0] * 100, rng.normal(size=100)])
    rx = [0, 1, 2500, 2502, 2502, x.size - 1]
    ry = [99, 99, 100, 150]
    passes = []

    def blocks():
        passes.append(1)
        return ([x[a:a + 777], y[a // 20:(a + 777) // 20]] for a in range(0, x.size, 777))

    got = select_ranks(blocks, [rx, ry], hold)
    want = [z[np.lexsort((~np.signbit(z), z))][r] for z, r in ((x, rx), (y, ry))]  # -0.0 before 0.0
    assert [np.array(g).tobytes() for g in got] == [w.tobytes() for w in want]
    assert len(passes) == (1 if hold >= x.size else 4)


def _synthetic_log(seconds: float) -> PollLog:
    """A 100 Hz poll log of a module whose 200 Hz registers run 30 ppm fast, 1 timeout in 500."""
    rng = np.random.default_rng(7)
    t_req = np.arange(0.0, seconds, 0.01)
    t = t_req + 0.002 + 0.0005 * rng.random(t_req.size)
    up_ms = np.floor((t_req * (1 + 30e-6) + 3.0) * 200.0) * 5.0
    values = rng.integers(0, 30000, (t.size, 14)).astype(np.uint16)
    values[:, 10] = 0
    values[:, 12] = (up_ms.astype(np.int64) >> 16).astype(np.uint16)
    values[:, 13] = (up_ms.astype(np.int64) & 0xFFFF).astype(np.uint16)
    status = np.where(rng.random(t.size) < 0.002, POLL_TIMEOUT, 0).astype(np.int16)
    values[status != 0] = 0
    return PollLog("brake_pressure", 1, 4, 0, t, values, status)


def _peak(fn) -> float:
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        fn()
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def test_the_block_decoding_holds_a_block_not_the_log() -> None:
    """A log 3x as long (600 s -> 1,800 s at 100 Hz): the block decoding's traced peak grows by less than one block's
    arrays (4,096 polls x ~130 B: the registers, times and status read, the time base, flags, hold indices and the
    five channels' values and flags made), the per-second medians and the judgement made of them included; the
    whole-log decoding's grows by every poll's arrays (~0.1 kB a poll: ~14 MB)."""
    cfg = load_setup("paper").pressure
    block = 4096
    drops = np.zeros(0)
    warm = _synthetic_log(100.0)  # imports and caches out of the measurement
    decode_pressure_poll_blocks(warm, cfg, DecodeSink(), drops, lambda *a: None, block)
    decode_pressure_polls(warm, cfg, DecodeSink(), drops)
    peaks = {}
    for n in (1, 3):
        plog = _synthetic_log(600.0 * n)
        peaks["blocks", n] = _peak(lambda plog=plog: decode_pressure_poll_blocks(
            plog, cfg, DecodeSink(), drops, lambda *a: None, block))
        peaks["whole", n] = _peak(lambda plog=plog: decode_pressure_polls(plog, cfg, DecodeSink(), drops))
    bound = block * 130
    assert peaks["blocks", 3] - peaks["blocks", 1] <= bound, peaks
    assert peaks["whole", 3] - peaks["whole", 1] > bound, peaks  # the bound tells the two apart


def _faulty_log() -> tuple[PollLog, np.ndarray]:
    """120 s of polls with something at many block edges: failed polls before the first answer, the uptime passing
    2^31 ms at 8 s (a first answer below it: read unsigned to the end), timeouts alone and in runs (a restart),
    exception answers, clock steps of +60 ms at 62 s and -80 ms at 100 s, a second of answers 40 ms late, 400 ppm
    of drift, jittered latencies; and transport drops, some at poll times."""
    rng = np.random.default_rng(11)
    t_req = np.arange(0.0, 120.0, 0.01)
    t = t_req + 0.002 + 0.001 * rng.random(t_req.size)
    dev_s = t_req * (1 + 400e-6) + (2**31 / 1000.0 - 8.0) + np.where(t_req >= 62.0, 0.06, 0.0)
    dev_s = dev_s - np.where(t_req >= 100.0, 0.08, 0.0)  # a step back: held times must not go back
    dev_s = dev_s - np.where((t_req > 90.0) & (t_req < 91.0), 0.04, 0.0)  # late answers: an older update
    up_ms = (np.floor(dev_s * 200.0) * 5.0).astype(np.int64) & 0xFFFFFFFF
    values = rng.integers(0, 40000, (t.size, 14)).astype(np.uint16)
    values[:, 10] = rng.choice([0, 0, 0, 1, 256], t.size)
    values[:, 12] = (up_ms >> 16).astype(np.uint16)
    values[:, 13] = (up_ms & 0xFFFF).astype(np.uint16)
    status = np.zeros(t.size, np.int16)
    status[:5] = POLL_TIMEOUT
    status[rng.random(t.size) < 0.03] = POLL_TIMEOUT
    status[rng.random(t.size) < 0.02] = 4
    status[1500:1511] = POLL_TIMEOUT
    status[11990:11996] = POLL_TIMEOUT
    values[status != 0] = 0
    drops = np.sort(np.concatenate([rng.uniform(0.0, 120.0, 40), t[rng.integers(0, t.size, 40)]]))
    return PollLog("brake_pressure", 1, 4, 0, t, values, status), drops


@pytest.mark.parametrize("block", [13, 61, 1000])
def test_what_spans_block_edges_is_carried(block: int) -> None:
    """Blocks far shorter than a second, a run of timeouts or the wrap: every carried state is exercised."""
    cfg = load_setup("paper").pressure
    plog, drops = _faulty_log()
    whole = DecodeSink()
    decode_pressure_polls(plog, cfg, whole, drops)
    assert {e[0] for e in whole.evidence} >= {"clock_step", "modbus_restart", "modbus_slow", "clock_drift"}
    sink, got = _blocks(plog, cfg, drops, block)
    for name, ch in whole.rec.channels.items():
        t, v, f, _unit, _source = got[name]
        assert t.tobytes() == ch.timestamps.tobytes() and v.tobytes() == ch.values.tobytes(), name
        assert np.array_equal(f, ch.flags), name
    assert sink.counts == whole.counts
    assert _same_evidence(sink, whole)
