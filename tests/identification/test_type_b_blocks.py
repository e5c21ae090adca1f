"""The resolution component's Monte Carlo draws on a channel read by blocks (the chunk files ``validate --out``
identifies from): the same numbers as on the channel in memory, and memory bounded by a block, not by the channel.

A synthetic 200 k-sample reading (a slow random walk with noise, some samples flagged or NaN) wrapped in a lazy
channel whose whole read fails. The draws equal the in-memory draws bit for bit, block by block, with the random
stream left where the in-memory draws leave it; drawing and reading a channel three times as long, window by window,
peaks less than one rounding block's arrays higher (the in-memory draw holds the whole channel and its scaled levels:
that path fails the same bound). About 2 s.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import benchtwin.identification.uncertainty as unc
from benchtwin.identification.uncertainty import ROUNDING_BLOCK, Component, dithered
from benchtwin.recording import Channel, Flag, LazyChannel, Recording

Q = 0.5
N = 200_000
WINDOW = 10_000


def _channel(n: int, seed: int = 1) -> Channel:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    v = 100.0 + np.cumsum(rng.normal(0.0, 0.05, n)) + rng.normal(0.0, 0.3, n)
    flags = np.zeros(n, dtype=np.uint16)
    flags[rng.integers(0, n, n // 500)] = int(Flag.TIMEOUT)
    v[rng.integers(0, n, n // 1000)] = np.nan
    v[rng.integers(0, n, 20)] = 1e6  # flagged outliers: they must not move the grid of the others
    flags[v == 1e6] = int(Flag.SATURATED)
    return Channel("y", "u", t, v, flags)


def _lazy(ch: Channel) -> LazyChannel:
    def whole() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise AssertionError("read whole")

    def part(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return ch.timestamps[a:b].copy(), ch.values[a:b].copy(), ch.flags[a:b].copy()

    return LazyChannel(ch.name, ch.unit, ch.source, len(ch), whole, block_loader=part)


def _rec(ch: Channel) -> Recording:
    rec = Recording()
    rec.add(ch)
    return rec


COMP = Component("resolution", ("y",), "resolution", 0.0, (Q,))


def test_block_draws_equal_the_in_memory_draws_bit_for_bit() -> None:
    ch = _channel(N)
    mem, blk = _rec(ch), _rec(_lazy(ch))
    rng_m, rng_b = np.random.default_rng(7), np.random.default_rng(7)
    shared_m: dict = {}
    shared_b: dict = {}
    for _ in range(3):
        want = dithered(mem, COMP, rng_m, shared_m)["y"]
        got = dithered(blk, COMP, rng_b, shared_b)["y"]
        assert isinstance(got, LazyChannel) and not got.loaded
        assert not np.array_equal(want.values, ch.values, equal_nan=True)  # the draw moved something
        for a, b in [(0, N), (0, 1), (12_345, 80_001), (N - 7, N + 5), (ROUNDING_BLOCK, 2 * ROUNDING_BLOCK + 3)]:
            for k in range(3):
                np.testing.assert_array_equal(got.block(a, b)[k], want.block(a, b)[k])
    assert rng_m.bit_generator.state == rng_b.bit_generator.state  # the same stream for the next component


def _peak(n: int) -> int:
    """Peak traced bytes of one draw on a channel of ``n`` samples read by blocks, read window by window."""
    rec = _rec(_lazy(_channel(n)))
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        ch = dithered(rec, COMP, np.random.default_rng(3))["y"]
        total = 0.0
        for a in range(0, n, WINDOW):
            total += float(np.nansum(ch.block(a, a + WINDOW)[1]))
        assert np.isfinite(total)
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def _check() -> None:
    _peak(1_000)  # the first draw loads the compiled kernel: not the channel's memory
    p1, p3 = _peak(N), _peak(3 * N)
    block = ROUNDING_BLOCK * (8 + 8 + 2)  # one block's timestamps, values and flags
    assert p3 - p1 < block, (p1, p3, block)


def test_a_draw_on_a_channel_read_by_blocks_does_not_grow_with_the_channel() -> None:
    _check()


def test_the_in_memory_draw_fails_the_same_bound(monkeypatch: pytest.MonkeyPatch) -> None:
    """The bound catches the whole-channel draw (what ``dithered`` did before on every channel)."""
    monkeypatch.setattr(unc, "reads_by_block", lambda ch: False)
    monkeypatch.setattr(LazyChannel, "_load", lambda self: list(self._block_loader(0, self._n)))
    with pytest.raises(AssertionError, match=r"\(\d+, \d+, \d+\)"):
        _check()
