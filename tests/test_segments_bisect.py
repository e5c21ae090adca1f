"""The segment masks by bisection (``segments.inside_any``, ``segments.touched``) equal the pass per segment they
replace (``mask |= s.contains(t)``), on grids with many tests, times on the segments' edges, overlaps, NaN."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest

from benchtwin.segments import Segment, SegmentIndex, inside_any, touched


def _loop(segs: list[Segment], t: np.ndarray) -> np.ndarray:
    mask = np.zeros(np.shape(t), dtype=bool)
    for s in segs:
        mask |= s.contains(t)
    return mask


def _campaign(rng: np.random.Generator, n: int) -> list[Segment]:
    """``n`` tests on a 100 Hz grid's points and between them, some overlapping, some empty or reversed."""
    starts = np.sort(rng.choice(np.arange(0, 20_000) / 100.0, n, replace=False))
    segs = []
    for k, a in enumerate(starts):
        d = float(rng.choice([0.0, -1.0, 0.005, 3.0, 37.21, 400.0]))
        segs.append(Segment(float(a), float(a) + d, "ramp_up", f"t{k}"))
    return segs


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_inside_any_equals_the_pass_per_segment(seed: int) -> None:
    rng = np.random.default_rng(seed)
    segs = _campaign(rng, 150)
    grid = 5.0 + np.arange(0, 2_000_000) / 100.0  # a shifted grid: segment edges fall on and between points
    assert np.array_equal(inside_any(segs, grid), _loop(segs, grid))
    rng.shuffle(segs)  # order of the table does not matter
    sub = grid[123_456:345_678]
    assert np.array_equal(inside_any(segs, sub), _loop(segs, sub))
    on_edges = np.sort(np.array([s.start_s for s in segs] + [s.end_s for s in segs]))
    assert np.array_equal(inside_any(segs, on_edges), _loop(segs, on_edges))
    assert inside_any(segs, on_edges).any() and not inside_any(segs, on_edges).all()


def test_inside_any_other_times_take_the_pass() -> None:
    rng = np.random.default_rng(5)
    segs = [*_campaign(rng, 40), Segment(float("nan"), 10.0, "x", "n1"), Segment(10.0, float("nan"), "x", "n2"),
            Segment(-np.inf, 1.0, "x", "i1")]
    t = rng.uniform(-10, 21_000, 50_000)
    for case in (t, np.sort(t), np.where(rng.random(t.size) < 0.01, np.nan, np.sort(t)), np.sort(t).astype(np.float32),
                 t.reshape(100, 500), np.array([np.nan]), np.zeros(0), np.float64(12.0)):
        assert np.array_equal(inside_any(segs, case), _loop(segs, case))
    assert inside_any([], t).shape == t.shape and not inside_any([], t).any()


def test_touched_equals_any_of_contains() -> None:
    rng = np.random.default_rng(7)
    segs = [*_campaign(rng, 200), Segment(float("nan"), 10.0, "x", "n1"), Segment(10.0, float("nan"), "x", "n2")]
    for t in (rng.uniform(0, 21_000, 300), np.round(rng.uniform(0, 21_000, 3000), 2),
              np.array([s.start_s for s in segs[:50]] + [s.end_s for s in segs[50:100]] + [np.nan]),
              rng.uniform(0, 21_000, 300).astype(np.float32), np.zeros(0)):
        want = [bool(np.any(s.contains(t))) for s in segs]
        assert touched(segs, t) == want
    assert any(touched(segs, rng.uniform(0, 21_000, 300))) and touched([], np.zeros(3)) == []


def _first_name(segs: list[Segment], times: np.ndarray) -> list[str]:
    return [next((s.name for s in segs if s.start_s <= t < s.end_s), "") for t in times]


def test_segment_index_equals_the_first_match_in_order() -> None:
    rng = np.random.default_rng(11)
    a = np.cumsum(rng.choice([0.0, 0.01, 5.0, 61.3], 300))  # a campaign's table: in order, touching, some empty
    segs = [Segment(float(x), float(y), "k", f"t{k}") for k, (x, y) in enumerate(pairwise(a))]
    gaps = [s for k, s in enumerate(segs) if k % 3]  # with gaps between tests
    times = np.concatenate([a, a - 1e-9, rng.uniform(-5, a[-1] + 5, 2000), [np.nan, np.inf, -np.inf]])
    # a campaign's: a test ending a rounding past the next one's start (5041.320000000001 then 5041.32)
    ulp = [Segment(s.start_s, float(np.nextafter(s.end_s, np.inf)), s.kind, s.name) for s in segs]
    times = np.concatenate([times, [s.end_s for s in ulp]])
    wide = Segment(segs[50].start_s, segs[60].end_s, "k", "wide")  # in start order, over the next ten
    assert wide.end_s > segs[55].start_s
    rev = [Segment(s.end_s, s.start_s, s.kind, s.name) if k % 7 == 0 else s for k, s in enumerate(segs)]
    for table in (segs, gaps, ulp, [*segs[:50], wide, *segs[51:]], sorted([*gaps, wide], key=lambda s: s.start_s),
                  rev):
        idx = SegmentIndex(table)
        assert idx._sorted
        assert idx.names_at(times) == _first_name(table, times)
    names = SegmentIndex(gaps).names_at(times)
    assert "" in names and len(set(names)) > 100
    # overlapping, out of order or NaN tables are searched in order: the same first match
    for table in ([*segs[:50], Segment(3.0, 500.0, "k", "wide"), *segs[50:]], segs[::-1],
                  [*gaps[:10], Segment(float("nan"), 1.0, "k", "nan"), *gaps[10:]],
                  [*gaps[:10], Segment(gaps[9].end_s, float("nan"), "k", "nan_end"), *gaps[10:]], []):
        idx = SegmentIndex(table)
        assert idx.names_at(times) == _first_name(table, times)
    assert not SegmentIndex(segs[::-1])._sorted or len(segs) < 2
