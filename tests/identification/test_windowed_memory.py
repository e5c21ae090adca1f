"""Steady windows are found piece by piece: memory bounded by one piece of segments, not by the Recording's length.

The same synthetic ramp-up test laid end to end once and three times: the piece-by-piece search finds the same
windows in each copy, and its peak traced allocation beyond the windows it returns grows by less than one piece's
grid (one segment's points over every channel: what a piece can hold; the whole-grid search grows by two more copies'
grids and its temporaries, about 20 such pieces here). About 3 s.
"""

from __future__ import annotations

import dataclasses
import tracemalloc

import numpy as np
import pytest
from _synth_a import to_recording

import benchtwin.identification.steady as steady
from benchtwin.identification.steady import find_steady_windows
from benchtwin.recording import Recording

NAMES = ["vehicle_speed_kmh", "em_speed_rpm", "em_torque_nm"]
RATE_HZ = 10.0


def _repeated(ramp_plant, n: int) -> Recording:
    t, sig, segs = ramp_plant
    period = float(t[-1] - t[0]) + 1.0 / RATE_HZ * 50  # a 5-s pause between copies: one piece per copy
    tt = np.concatenate([t + k * period for k in range(n)])
    ss = {k: np.concatenate([v] * n) for k, v in sig.items()}
    seg = [dataclasses.replace(s, start_s=s.start_s + k * period, end_s=s.end_s + k * period, name=f"{s.name}_{k}")
           for k in range(n) for s in segs]
    return to_recording(tt, ss, segments=seg)


def _peak(rec: Recording) -> tuple[int, list]:
    """Peak traced bytes of the search beyond the windows it returns (which grow with the windows found, as they
    must), and the windows."""
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        sw = find_steady_windows(rec, NAMES, kinds=["ramp_up"], rate_hz=RATE_HZ)
        peak = tracemalloc.get_traced_memory()[1] - base
        windows = sw.windows
        del sw  # the grid goes, the windows stay
        return peak - (tracemalloc.get_traced_memory()[0] - base), windows
    finally:
        tracemalloc.stop()


def _piece_bytes(rec: Recording) -> int:
    """Bytes of one ramp-up segment's grid over every channel gathered (float64 each, plus the masks)."""
    seg = max((s for s in rec.segments if s.kind == "ramp_up"), key=lambda s: s.end_s - s.start_s)
    points = int((seg.end_s - seg.start_s) * RATE_HZ) + 1
    return points * (8 * len(rec.channels) + 2)


def _check(ramp_plant) -> None:
    one, three = _repeated(ramp_plant, 1), _repeated(ramp_plant, 3)
    p1, w1 = _peak(one)
    p3, w3 = _peak(three)
    # the same windows in every copy (the copies are the same test)
    assert len(w3) == 3 * len(w1) > 0
    assert [round(w.end_s - w.start_s, 6) for w in w3[: len(w1)]] == [round(w.end_s - w.start_s, 6) for w in w1]
    assert p3 - p1 < _piece_bytes(one), (p1, p3, _piece_bytes(one))


def test_the_piece_by_piece_search_does_not_grow_with_the_recording(ramp_plant) -> None:
    _check(ramp_plant)


def test_the_whole_grid_search_fails_the_same_bound(ramp_plant, monkeypatch: pytest.MonkeyPatch) -> None:
    """The bound is tight enough to catch the whole-grid path (what the search did before)."""
    monkeypatch.setattr(steady, "find_steady_windows_by_piece", lambda *a, **k: None)
    with pytest.raises(AssertionError, match=r"\(\d+, \d+, \d+\)"):
        _check(ramp_plant)
