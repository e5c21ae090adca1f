"""The strict grid's typical step of a channel read by blocks, from the strided timestamps kept with its time index:
the very step of the block-by-block pass on any clock map, and a moved copy (a new clock map per draw) reads no
block."""

from __future__ import annotations

import numpy as np
import pytest

import benchtwin.identification._resample_blocks as rb
from benchtwin.identification._clock import ClockShift
from benchtwin.identification._windows import share_time_index
from benchtwin.recording import LazyChannel

SHIFTS = [0.0, 0.0123, -2.5, ClockShift(0.0123, -3e-5), ClockShift(-0.31, 4.7e-6)]


def _lazy(ts: np.ndarray, reads: list[tuple[int, int]]) -> LazyChannel:
    vs = np.zeros(ts.size)
    fl = np.zeros(ts.size, dtype=np.uint16)

    def whole() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise AssertionError("read whole")

    def part(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        reads.append((a, b))
        return ts[a:b].copy(), vs[a:b].copy(), fl[a:b].copy()

    return LazyChannel("shaft_torque_nm", "Nm", "telemetry", ts.size, whole, None, block_loader=part)


@pytest.mark.parametrize("n", [1000, 1001, 50001, 70003])
def test_the_kept_pairs_give_the_block_pass_step(n: int, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(rb, "_STEP_BLOCK", 64 if n < 2000 else 4096)
    rng = np.random.default_rng(n)
    steps = rng.choice([0.00099, 0.001, 0.00101, 0.00102, 0.002], n - 1, p=[.2, .3, .15, .3, .05])
    steps[::3] += rng.uniform(-2e-6, 2e-6, steps[::3].size)  # steps that a clock map rounds apart
    ts = np.concatenate(([1234.5], 1234.5 + np.cumsum(steps)))
    reads: list[tuple[int, int]] = []
    ch = _lazy(ts, reads)
    for s in SHIFTS:
        want = rb._typical_step_of(ch, s)
        assert rb._typical_step(ch, s) == want
    # a moved copy on the same timestamps: new clock maps read no block
    copy = _lazy(ts, reads)
    share_time_index(copy, ch)
    reads.clear()
    for k in range(4):
        s = ClockShift(0.01 * k, 1e-6 * (k + 1))
        step = rb._typical_step(copy, s)
        assert not reads
        assert step == rb._typical_step_of(_lazy(ts, []), s)
