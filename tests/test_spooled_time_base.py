"""The spooled Trace's time base is spooled too: not held in memory between uses, whatever the campaign's length."""

from __future__ import annotations

import gc
import tracemalloc

import numpy as np
import pytest

from benchtwin.errors import DataError
from benchtwin.segments import Segment
from benchtwin.trace import SpooledTrace, Trace


def _pieces(n_pieces: int, n: int) -> list[Trace]:
    out = []
    for k in range(n_pieces):
        t = (k * n + np.arange(n)) * 0.01
        segs = [Segment(f"s{k}", "ramp_up", float(t[0]), float(t[-1]) + 0.01)]
        out.append(Trace(t, {"vehicle_speed_mps": np.sqrt(t)}, segs, {"k": k}))
    return out


@pytest.mark.parametrize("n_pieces", [2, 20])
def test_time_base_is_not_held_between_uses(n_pieces: int) -> None:
    """Appending 20,000-sample pieces (160 kB of times each) leaves less than 64 kB traced in the SpooledTrace,
    at 2 and at 20 pieces (the time base an array: 320 kB and 3.2 MB); the times read back equal."""
    pieces = _pieces(n_pieces, 20_000)
    with SpooledTrace() as spooled:
        gc.collect()
        tracemalloc.start()
        try:
            before = tracemalloc.get_traced_memory()[0]
            for p in pieces:
                spooled.append(p)
            _ = spooled.duration_s, len(spooled), spooled.time_s[-1]  # used, then dropped
            gc.collect()
            held = tracemalloc.get_traced_memory()[0] - before
        finally:
            tracemalloc.stop()
        assert held < 64_000
        want = np.concatenate([p.time_s for p in pieces])
        assert len(spooled) == want.size
        np.testing.assert_array_equal(spooled.time_s, want)
        assert spooled.duration_s == want[-1] - want[0]
        np.testing.assert_array_equal(spooled.read("vehicle_speed_mps", 5, 9), np.sqrt(want[5:9]))
        assert not spooled.time_s.flags.writeable  # a read-only map: the file cannot be changed through it


def test_length_and_duration_known_after_close_times_are_not() -> None:
    """After close the length and duration stay (the report uses them), the time base is a clear error."""
    spooled = SpooledTrace()
    assert len(spooled) == 0 and spooled.duration_s == 0.0 and spooled.time_s.size == 0
    for p in _pieces(3, 100):
        spooled.append(p)
    spooled.close()
    assert len(spooled) == 300
    assert spooled.duration_s == pytest.approx(2.99)
    with pytest.raises(DataError, match="closed"):
        _ = spooled.time_s
    with pytest.raises(DataError, match="closed"):
        spooled.append(_pieces(4, 100)[3])


def test_piece_out_of_order_still_refused() -> None:
    """A piece that does not start after the last time is refused (the last time kept as a number)."""
    with SpooledTrace() as spooled:
        a, b = _pieces(2, 100)
        spooled.append(b)
        with pytest.raises(DataError, match="not after the last one"):
            spooled.append(a)
