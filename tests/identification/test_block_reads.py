"""Identification on a Recording whose channels are read by blocks from their store (as ``validate --out`` identifies
from the acquisition's chunk files): the same numbers as on the Recording in memory, never a whole channel read.

The ramp-up test laid end to end three times, each channel wrapped in a lazy channel whose whole read fails. The
steady windows' raw averages are grouped (one read per group of windows): with groups of 30 s here (a dozen groups)
they equal the in-memory averages bit for bit, which holds only if the running sums carry from group to group; a type
B re-run's moved channel stays lazy and reads moved blocks; the strict resample of the converter and battery fits,
by blocks of 37 grid points, equals the whole one. About 3 s.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _synth_a import to_recording

import benchtwin.identification.steady as steady
from benchtwin.identification._window_sums import window_groups
from benchtwin.identification._windows import time_index
from benchtwin.identification.steady import find_steady_windows
from benchtwin.identification.uncertainty import Component, perturbed
from benchtwin.recording import Channel, LazyChannel, Recording

NAMES = ["vehicle_speed_kmh", "em_speed_rpm", "em_torque_nm"]


def _repeated(ramp_plant, n: int) -> Recording:
    t, sig, segs = ramp_plant
    period = float(t[-1] - t[0]) + 5.0
    tt = np.concatenate([t + k * period for k in range(n)])
    ss = {k: np.concatenate([v] * n) for k, v in sig.items()}
    seg = [dataclasses.replace(s, start_s=s.start_s + k * period, end_s=s.end_s + k * period, name=f"{s.name}_{k}")
           for k in range(n) for s in segs]
    return to_recording(tt, ss, segments=seg, noise=1.0, seed=3)


def _blocked(rec: Recording) -> Recording:
    """The Recording with every channel lazy: whole reads fail, block reads are copies of the slices."""
    def lazy(ch: Channel) -> LazyChannel:
        def whole() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            raise AssertionError(f"{ch.name} read whole")

        def part(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            return ch.timestamps[a:b].copy(), ch.values[a:b].copy(), ch.flags[a:b].copy()

        return LazyChannel(ch.name, ch.unit, ch.source, len(ch), whole, ch.value_texts, block_loader=part)

    out = Recording(segments=rec.segments, meta=rec.meta)
    for ch in rec.channels.values():
        out.add(lazy(ch))
    return out


@pytest.fixture(scope="module")
def recs(ramp_plant) -> tuple[Recording, Recording]:
    rec = _repeated(ramp_plant, 3)
    return rec, _blocked(rec)


def test_raw_averages_by_groups_equal_the_whole_pass(recs, monkeypatch: pytest.MonkeyPatch) -> None:
    mem, blocked = recs
    monkeypatch.setattr(steady, "window_groups", lambda s, e: window_groups(s, e, 30.0))
    sw_mem = find_steady_windows(mem, NAMES, kinds=["ramp_up"], rate_hz=10.0)
    sw_blk = find_steady_windows(blocked, NAMES, kinds=["ramp_up"], rate_hz=10.0)
    starts = np.array([w.start_s for w in sw_blk.windows])
    ends = np.array([w.end_s for w in sw_blk.windows])
    assert len(window_groups(starts, ends, 30.0)) >= 6  # several groups, so the carry is exercised
    assert [(w.i0, w.i1) for w in sw_blk.windows] == [(w.i0, w.i1) for w in sw_mem.windows]
    for name, other in (("em_torque_nm", None), ("em_torque_nm", "em_speed_rpm"), ("vehicle_speed_kmh", None)):
        np.testing.assert_array_equal(sw_blk.raw_average(blocked, name, other), sw_mem.raw_average(mem, name, other))
    assert not any(c.loaded for c in blocked.channels.values())


def test_a_moved_channel_stays_lazy_and_moves_what_it_reads(recs) -> None:
    mem, blocked = recs
    comp = Component("em_torque_nm.gain", ("em_torque_nm",), "gain", 0.01)
    moved_mem, moved_blk = perturbed(mem, comp)["em_torque_nm"], perturbed(blocked, comp)["em_torque_nm"]
    assert isinstance(moved_blk, LazyChannel) and not moved_blk.loaded
    assert time_index(moved_blk) is time_index(blocked["em_torque_nm"])  # the same times: indexed once
    n = len(moved_mem)
    for a, b in ((0, 7), (n // 3, n // 3 + 1000), (n - 5, n)):
        got = moved_blk.block(a, b)
        for k in range(3):
            np.testing.assert_array_equal(got[k], moved_mem.block(a, b)[k])
    # the piece-by-piece search on the moved Recording reads blocks only (a whole read fails)
    sw = find_steady_windows(perturbed(blocked, comp), NAMES, kinds=["ramp_up"], rate_hz=10.0)
    assert len(sw) > 0


def test_the_strict_resample_by_blocks_equals_the_whole_one(ramp_plant, monkeypatch: pytest.MonkeyPatch) -> None:
    """Flagged and non-finite samples, a pause in one channel and a held state: the same grid, values and bad
    points with blocks of 37 grid points as ``strict_resample`` on the channels in memory."""
    import benchtwin.identification._resample_blocks as rb
    from benchtwin.identification._signals import strict_resample
    from benchtwin.recording import Flag

    rec = _repeated(ramp_plant, 2)
    torque = rec["em_torque_nm"]
    torque.flags[100:200:7] = int(Flag.SATURATED)  # single samples: some only next to a grid point
    torque.values[300] = np.nan
    speed = rec["em_speed_rpm"]
    keep = np.ones(len(speed), dtype=bool)
    keep[500:560] = False  # a pause in the log
    rec.add(Channel(speed.name, speed.unit, speed.timestamps[keep], speed.values[keep], None, speed.source))
    names = [*NAMES, "gear_actual"] if "gear_actual" in rec else NAMES
    hold = ("gear_actual",) if "gear_actual" in rec else ()
    monkeypatch.setattr(rb, "GRID_BLOCK", 37)
    t0, v0, bad0 = strict_resample(rec, names, 10.0, hold=hold)
    t1, v1, bad1 = rb.resample_strict(_blocked(rec), names, 10.0, hold=hold)
    np.testing.assert_array_equal(t1, t0)
    np.testing.assert_array_equal(bad1, bad0)
    assert bad0.sum() > 0
    for n in names:
        np.testing.assert_array_equal(v1[n], v0[n])


def test_values_at_times_read_by_runs_equal_the_whole_channel(recs, monkeypatch: pytest.MonkeyPatch) -> None:
    """Shift events' speed and pedal: unsorted times (outside the span too), read in runs of 20 s."""
    import benchtwin.identification._windows as win

    mem, blocked = recs
    monkeypatch.setattr(win, "AT_SPAN_S", 20.0)
    lo, hi = mem["em_torque_nm"].timestamps[[0, -1]]
    t = np.random.default_rng(5).uniform(lo - 3.0, hi + 3.0, 400)
    t[:5] = mem["em_torque_nm"].timestamps[[0, 1, 17, -2, -1]]  # on samples, at both ends
    for hold in (False, True):
        v, f = win.at_times(blocked["em_torque_nm"], t, hold=hold)
        np.testing.assert_array_equal(v, mem["em_torque_nm"].at(t, hold=hold))
        np.testing.assert_array_equal(f, mem["em_torque_nm"].flags_at(t))
    assert not blocked["em_torque_nm"].loaded


@pytest.mark.parametrize("ties", [True, False])
@pytest.mark.parametrize("n", [1001, 1000])
def test_the_native_rate_by_blocks_is_the_whole_median(n: int, ties: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """Jittered steps with and without ties, an even and an odd count of steps (the two middle ones averaged),
    blocks of 64 steps."""
    import benchtwin.identification._resample_blocks as rb
    from benchtwin.identification._signals import native_rate

    monkeypatch.setattr(rb, "_STEP_BLOCK", 64)
    rng = np.random.default_rng(n)
    steps = (rng.choice([0.0099, 0.01, 0.0101, 0.0102, 0.02], n - 1, p=[.2, .3, .15, .3, .05]) if ties
             else rng.uniform(0.009, 0.011, n - 1))
    ts = np.concatenate(([3.0], 3.0 + np.cumsum(steps)))
    ch = Channel("vehicle_speed_kmh", "km/h", ts, np.zeros(n), None, "vehicle_can")
    blocked = _blocked(Recording(channels={ch.name: ch}))[ch.name]
    assert rb.rate_of(blocked, max_hz=1e6) == native_rate(ch, max_hz=1e6)
    assert not blocked.loaded


@pytest.mark.parametrize("shift", [0.0123, "drift"])
def test_the_strict_resample_by_blocks_with_clock_shifts_equals_the_whole_one(ramp_plant, shift,
                                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """With the sources' clock shifts (a constant, and an offset with a drift as the converter's shaft clock gives):
    the same grid, values and bad points by blocks of 37 grid points as the whole path on the shifted channels, bit
    for bit (the grid times put on a channel's own clock instead interpolate with other weights in the last bits)."""
    import benchtwin.identification._resample_blocks as rb
    from benchtwin.identification._clock import ClockShift
    from benchtwin.recording import Flag

    rec = _repeated(ramp_plant, 2)
    rec["em_torque_nm"].flags[100:200:7] = int(Flag.SATURATED)
    speed = rec["em_speed_rpm"]
    keep = np.ones(len(speed), dtype=bool)
    keep[500:560] = False  # a pause in the log
    rec.add(Channel(speed.name, speed.unit, speed.timestamps[keep], speed.values[keep], None, speed.source))
    s = ClockShift(0.0123, -3e-5) if shift == "drift" else shift
    shifts = {c.source: s for c in rec.channels.values()}
    names = [*NAMES, "gear_actual"] if "gear_actual" in rec else NAMES
    hold = ("gear_actual",) if "gear_actual" in rec else ()
    monkeypatch.setattr(rb, "GRID_BLOCK", 37)
    t0, v0, bad0 = rb.resample_strict(rec, names, 10.0, hold=hold, shifts=shifts)  # in memory: the whole path
    blocked = _blocked(rec)
    t1, v1, bad1 = rb.resample_strict(blocked, names, 10.0, hold=hold, shifts=shifts)
    grid = rb.StrictGrid(blocked, names, 10.0, hold=hold, shifts=shifts)
    t2, v2, bad2 = grid.block(0, grid.size)
    assert bad0.sum() > 0
    for t, v, bad in ((t1, v1, bad1), (t2, v2, bad2)):
        np.testing.assert_array_equal(t, t0)
        np.testing.assert_array_equal(bad, bad0)
        for n in names:
            np.testing.assert_array_equal(v[n], v0[n])
