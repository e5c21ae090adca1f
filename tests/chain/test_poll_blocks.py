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
