"""The torque converter's points read the 10 Hz grid a block at a time: the same points, memory bounded by a block.

:func:`converter_points` takes its masks (shift hold, pump speed derivative, the settle rule after a pump speed step)
on blocks of grid points with margins, the settle rule's state carried from block to block, and gathers only the
candidate points and the calibration ratios. Checked here: the block's grid times are ``np.arange``'s; the settle
rule by blocks is :func:`unsettled` on the whole record; the points of a Recording with gear changes, K0 and lock-up
stretches, pump speed steps (one never settling) and bad samples are the same bit for bit by blocks of 37 and 500
grid points, read from lazy channels, as in one block from memory; and the peak traced allocation beyond the points
returned grows from a campaign to three times it by less than one block's grid (the whole-grid path, one block as
long as the grid, grows by some ten times that and fails the bound). About 4 s.
"""

from __future__ import annotations

import dataclasses
import inspect
import tracemalloc
import types

import numpy as np
import pytest
from _synth_b import SPECS, TRANSMISSION_TRUTH, tc_recording

import benchtwin.identification.torque_converter_points as tcp
from benchtwin.identification._resample_blocks import grid_times
from benchtwin.identification.torque_converter import identify_torque_converter
from benchtwin.identification.torque_converter_points import ConverterPoints, converter_points, unsettled
from benchtwin.recording import Channel, LazyChannel, Recording

#: converter_points' keyword arguments as identify_torque_converter passes them by default
KW = {k: p.default for k, p in inspect.signature(identify_torque_converter).parameters.items()
      if k in inspect.signature(converter_points).parameters and k not in ("rec", "specs")}
KW["transmission"] = TRANSMISSION_TRUTH
#: the grid points of a block
BLOCK = tcp.POINTS_BLOCK


def test_grid_times_are_numpys_arange() -> None:
    rng = np.random.default_rng(5)
    for _ in range(300):
        lo = float(rng.uniform(-50.0, 5e4))
        step = 1.0 / float(rng.choice([10.0, 3.0, 7.0, 100.0]))
        whole = np.arange(lo, lo + float(rng.uniform(0.0, 3000.0)), step)
        a = int(rng.integers(0, whole.size + 1))
        b = int(rng.integers(a, whole.size + 1))
        np.testing.assert_array_equal(grid_times(lo, step, a, b), whole[a:b])


def test_the_median_step_by_blocks_is_the_whole_grids(monkeypatch: pytest.MonkeyPatch) -> None:
    """The derivative's half window comes from the whole grid's median step, counted block by block."""
    rng = np.random.default_rng(2)
    for _ in range(40):
        lo, step = float(rng.uniform(0.0, 1e5)), 1.0 / float(rng.choice([10.0, 3.0, 7.0]))
        n = int(rng.integers(2, 5000))
        monkeypatch.setattr(tcp, "POINTS_BLOCK", int(rng.choice([37, 97, 8192])))
        grid = types.SimpleNamespace(size=n, times=lambda a, b, lo=lo, step=step: grid_times(lo, step, a, b))
        assert tcp._median_step(grid) == float(np.median(np.diff(grid_times(lo, step, 0, n))))


def _unsettled_by_blocks(n_p: np.ndarray, t: np.ndarray, max_rate: float, window_s: float, block: int
                         ) -> np.ndarray:
    """The settle rule a block at a time, with the margins and the carry :func:`converter_points` uses."""
    n, h = n_p.size, tcp._half_window(t, window_s)
    margin = 2 * h + 2
    out, carry = np.zeros(n, dtype=bool), (-1, -1)
    for a in range(0, n, block):
        b = min(a + block, n)
        e0, e1 = max(0, a - margin), min(n, b + margin)
        out[a:b], carry = tcp._unsettled_block(n_p[e0:e1], t[e0:e1], max_rate, window_s, h, e0, a, b, carry)
    return out


@pytest.mark.parametrize("window_s", [0.1, 0.4, 1.0])
def test_the_settle_rule_by_blocks_is_the_whole_records(window_s: float) -> None:
    rng = np.random.default_rng(11)
    t = np.arange(3000) * 0.1
    # a slow drift with steps now and then, each followed by a ringing of random length (some long)
    n_p = 1000.0 + np.cumsum(rng.normal(0.0, 2.0, t.size))
    for j in rng.choice(t.size - 10, 25, replace=False):
        n_p[j:] += rng.choice([-1.0, 1.0]) * 300.0
        ring = int(rng.integers(0, 80))
        n_p[j:j + ring] += 60.0 * np.sin(np.arange(min(ring, t.size - j)) * 2.5)
    n_p[-40:] += 400.0 * np.sin(np.arange(40) * 2.5)  # no settling before the end
    whole = unsettled(n_p, t, 400.0, window_s)
    assert 0.05 < whole.mean() < 0.8 and whole[-1]  # the rule has both outcomes, and an unsettled end
    for block in (1, 7, 37, 500, 5000):
        np.testing.assert_array_equal(_unsettled_by_blocks(n_p, t, 400.0, window_s, block), whole)


def _arrays(idle_s: float, events: bool) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One copy: electric take-offs, a cruise with the lock-up closed, then ``idle_s`` at rest in neutral."""
    rec, _ = tc_recording(duration_s=60.0 if events else 10.0, lockup_closed_s=40.0 if events else 0.0, seed=3)
    t = rec["em_speed_rpm"].timestamps
    sig = {n: c.values.copy() for n, c in rec.channels.items()}
    if events:
        s = sig["em_speed_rpm"]
        s[(t >= 20.0) & (t < 25.0)] += 400.0  # two pump speed steps
        s[(t >= 30.0) & (t < 31.0)] += 150.0 * np.sin(np.arange(10) * 2.5)  # ringing after the next one
        s[t >= 30.0] += 250.0
        sig["gear_actual"][(t >= 40.0) & (t < 50.0)] = 2.0
        sig["gear_target"][(t >= 39.5) & (t < 50.0)] = 2.0  # the target leads the shift
        sig["k0_closed"][(t >= 52.0) & (t < 56.0)] = 1.0
        sig["em_torque_nm"][(t >= 57.0) & (t < 57.3)] = np.nan  # bad samples
        # a step, then one-sample changes too large to be calm, too small to be steps: unsettled, no derivative
        s[t >= t[-1] - 12.0] += 300.0 + 30.0 * (-1.0) ** np.arange(np.sum(t >= t[-1] - 12.0))
    dt = float(t[1] - t[0])
    ti = t[-1] + dt + np.arange(0.0, idle_s, dt)
    rest = {"gear_actual": 0.0, "gear_target": 0.0, "k0_closed": 0.0, "lockup_closed": 0.0}
    return np.r_[t, ti], {n: np.r_[v, np.full(ti.size, rest.get(n, 0.0))] for n, v in sig.items()}


def _recording(copies: int, idle_s: float, *, events: bool, lazy: bool) -> Recording:
    t, sig = _arrays(idle_s, events)
    period = float(t[-1] - t[0]) + 2 * float(t[1] - t[0])
    tt = np.concatenate([t + k * period for k in range(copies)])
    out = Recording()
    for name, v in sig.items():
        src = "telemetry" if name == "shaft_torque_nm" else "vehicle_can"
        ch = Channel(name, "", tt, np.concatenate([v] * copies), source=src)
        if lazy:
            def whole(ch: Channel = ch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
                raise AssertionError(f"{ch.name} read whole")

            def part(a: int, b: int, ch: Channel = ch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
                return ch.timestamps[a:b].copy(), ch.values[a:b].copy(), ch.flags[a:b].copy()

            ch = LazyChannel(name, "", src, len(ch), whole, block_loader=part)
        out.add(ch)
    return out


def _assert_same(a: ConverterPoints, b: ConverterPoints) -> None:
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), f.name
        elif f.name == "torque_calibration" and x is not None:
            for g in dataclasses.fields(x):
                assert np.array_equal(getattr(x, g.name), getattr(y, g.name)), g.name
        else:
            assert repr(x) == repr(y), f.name


def test_the_points_by_blocks_are_the_whole_grids(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(tcp, "POINTS_BLOCK", 10**9)
    whole = converter_points(_recording(1, 30.0, events=True, lazy=False), SPECS, **KW)
    # every kind of point is there, and some left out for each reason the events give
    assert whole.t.size > 300 and whole.n_cal > 300 and whole.n_tcal > 50 and set(whole.gear) == {1, 2}
    assert whole.n_excluded > 600
    for block in (37, 500):
        monkeypatch.setattr(tcp, "POINTS_BLOCK", block)
        _assert_same(converter_points(_recording(1, 30.0, events=True, lazy=True), SPECS, **KW), whole)


def _peak(rec: Recording) -> tuple[int, ConverterPoints]:
    """Peak traced bytes of converter_points beyond the points it returns, and the points."""
    tracemalloc.start()
    try:
        pts = converter_points(rec, SPECS, **KW)
        current, peak = tracemalloc.get_traced_memory()
        return peak - current, pts
    finally:
        tracemalloc.stop()


def _check() -> None:
    one, three = _recording(1, 1500.0, events=False, lazy=True), _recording(3, 1500.0, events=False, lazy=True)
    p1, pts1 = _peak(one)
    p3, pts3 = _peak(three)
    assert pts3.t.size > 2 * pts1.t.size > 100  # the take-off of every copy (the later ones start on a step)
    # one block of the grid: every channel's values (float64) and the bad mask, for POINTS_BLOCK points
    block_bytes = BLOCK * (8 * len(one.channels) + 1)
    assert p3 - p1 < block_bytes, (p1, p3, block_bytes)


def test_the_peak_does_not_grow_with_the_campaign() -> None:
    _check()


def test_the_whole_grid_fails_the_same_bound(monkeypatch: pytest.MonkeyPatch) -> None:
    """The bound is tight enough to catch the whole-grid path (one block as long as the grid)."""
    monkeypatch.setattr(tcp, "POINTS_BLOCK", 10**9)
    with pytest.raises(AssertionError, match=r"\(\d+, \d+, \d+\)"):
        _check()
