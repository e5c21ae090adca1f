"""Reads of a channel read by blocks stay bounded by a span of time, not by the run or window they serve.

A run of grid points inside touching segments (``gather_at``) and a steady window (``raw_average`` by groups) can
last as long as the campaign; each is read in parts of at most ``READ_SPAN_S`` / ``GROUP_S`` seconds, one part let go
before the next. The numbers are those of one read (bit for bit), and the bytes of block reads alive at once are at
most one part's (two for a product of two channels) whatever the length. The bound is derived from the read's
geometry: a part of ``S`` s read with the margin ``MARGIN_S`` each side, widened to the time index's marks (one in
``INDEX_STRIDE`` samples, at most one stride each side, plus the sample at or after the end), at ``RATE`` Hz.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from _alive_reads import AliveReads, tracked_lazy

import benchtwin.identification._windows as windows
import benchtwin.identification.steady as steady
from benchtwin.identification._signals import Grid
from benchtwin.identification._window_sums import cut_windows, window_groups
from benchtwin.identification._windows import MARGIN_S, gather_at, read_parts
from benchtwin.identification.steady import SteadyWindow, SteadyWindows
from benchtwin.recording import Channel, Flag, Recording

RATE = 100.0  #: samples per second of the synthetic channels "a" and "b"
STRIDE = 64  #: the time index's stride in these tests (the default, 4096, is 41 s at 100 Hz)
SPAN = 20.0  #: the read span in these tests
#: one sample's bytes in a read: timestamp (float64), value (float64), flags (uint16)
SAMPLE_BYTES = 8 + 8 + 2
#: most samples one read of a part spans (see the module docstring)
READ_SAMPLES = int((SPAN + 2 * MARGIN_S) * RATE) + 2 * STRIDE + 2


_Reads = AliveReads


def _recording(duration_s: float) -> Recording:
    """Channels "a", "b" (one source, the same timestamps, some flagged and NaN samples) and "c" (another source,
    37 Hz, phase 3 ms) over ``duration_s``."""
    rng = np.random.default_rng(7)
    t = np.arange(int(duration_s * RATE)) / RATE
    a = np.sin(t / 17.0) * 50.0 + rng.normal(0.0, 1.0, t.size)
    b = 100.0 + np.cos(t / 23.0) * 10.0
    a[rng.integers(0, t.size, 40)] = np.nan
    flags = np.zeros(t.size, dtype=np.uint16)
    flags[rng.integers(0, t.size, 40)] = int(Flag.SATURATED)  # a bad flag
    tc = 0.003 + np.arange(int(duration_s * 37.0)) / 37.0
    rec = Recording()
    rec.add(Channel("a", "Nm", t, a, flags, "s1"))
    rec.add(Channel("b", "rpm", t.copy(), b, None, "s1"))
    rec.add(Channel("c", "Nm", tc, np.sin(tc), None, "s2"))
    return rec


def _blocked(rec: Recording, reads: _Reads) -> Recording:
    """The Recording with every channel lazy: a whole read fails, a block read is a tracked copy."""
    out = Recording()
    for ch in rec.channels.values():
        out.add(tracked_lazy(ch, reads))
        windows.time_index(out[ch.name])  # built here, by its own blocks of INDEX_BLOCK samples: not counted below
    reads.most = reads.alive
    return out


@pytest.fixture
def small_reads(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(windows, "INDEX_STRIDE", STRIDE)
    monkeypatch.setattr(windows, "READ_SPAN_S", SPAN)


def test_read_parts_cover_the_times_in_runs_of_at_most_the_span() -> None:
    t = np.sort(np.random.default_rng(1).uniform(0.0, 1000.0, 5000))
    parts = read_parts(t, 30.0)
    assert parts[0][0] == 0 and parts[-1][1] == t.size
    assert all(p[1] == q[0] for p, q in itertools.pairwise(parts))  # consecutive, no gap, no overlap
    assert all(t[j - 1] - t[i] <= 30.0 for i, j in parts)
    assert len(parts) >= 1000.0 / 30.0 - 1  # not one part for everything
    with pytest.raises(ValueError, match="positive"):
        read_parts(t, 0.0)


@pytest.mark.parametrize("duration_s", [300.0, 900.0])
def test_gather_at_reads_a_long_run_in_bounded_parts(small_reads, duration_s: float) -> None:
    mem = _recording(duration_s)
    reads = _Reads()
    blocked = _blocked(mem, reads)
    t = 0.5 + np.arange(int((duration_s - 1.0) * 10.0)) / 10.0  # one run of 10 Hz points over the whole recording
    shifts = {"s2": 0.002}
    g_mem = gather_at(mem, ["a", "b"], t, 10.0, shifts, optional=["c"])
    g_blk = gather_at(blocked, ["a", "b"], t, 10.0, shifts, optional=["c"])
    for name in ("a", "b", "c"):
        np.testing.assert_array_equal(g_blk[name], g_mem[name])
    np.testing.assert_array_equal(g_blk.bad, g_mem.bad)
    np.testing.assert_array_equal(g_blk.flagged, g_mem.flagged)
    assert g_mem.flagged.any() and np.isnan(g_mem["a"]).any()  # the flags and NaNs were sampled
    # one part read at a time: the same bound for a run three times as long
    assert 0 < reads.most <= READ_SAMPLES * SAMPLE_BYTES


def _windows_over(mem: Recording, spans: list[tuple[float, float]]) -> SteadyWindows:
    ws = [SteadyWindow(s, e, 0, 0, {}, {}, {}) for s, e in spans]
    empty = np.zeros(0)
    grid = Grid(empty, {}, np.zeros(0, dtype=bool), np.zeros(0, dtype=bool), 10.0, set(), {})
    return SteadyWindows(ws, grid, windowed=True)


@pytest.mark.parametrize("scale", [1.0, 3.0])
def test_long_steady_windows_are_averaged_in_bounded_reads(small_reads, monkeypatch: pytest.MonkeyPatch,
                                                           scale: float) -> None:
    monkeypatch.setattr(steady, "cut_windows", lambda s, e: cut_windows(s, e, SPAN))
    monkeypatch.setattr(steady, "window_groups", lambda s, e: window_groups(s, e, SPAN))
    spans = [(5.0, 12.0), (20.0, 20.0 + 75.0 * scale), (21.0, 30.0), (100.0 * scale, 101.0 * scale),
             (150.0 * scale, 150.0 * scale + 250.0), (150.0 * scale + 250.0, 150.0 * scale + 251.5)]
    mem = _recording(450.0 * scale)
    reads = _Reads()
    blocked = _blocked(mem, reads)
    sw = _windows_over(mem, spans)
    for name, other in (("a", None), ("a", "b"), ("b", None)):
        whole = sw.raw_average(mem, name, other)  # the whole pass over the channel in memory
        assert np.isfinite(whole).all()
        np.testing.assert_array_equal(sw.raw_average(blocked, name, other), whole)
    # a group's read of one channel, or of two for a product, alive at a time
    assert 0 < reads.most <= 2 * READ_SAMPLES * SAMPLE_BYTES


def test_cut_windows_lays_each_window_out_in_pieces() -> None:
    starts = np.array([0.0, 10.0, 12.0, 500.0, 800.0])
    ends = np.array([5.0, 70.0, 12.0, 530.0, 1100.0])
    ps, pe, first = cut_windows(starts, ends, 30.0)
    assert first.tolist() == [0, 1, 3, 4, 5]
    bounds = np.append(first, ps.size)
    for w in range(starts.size):
        p = slice(bounds[w], bounds[w + 1])
        assert ps[p][0] == starts[w] and pe[p][-1] == ends[w]
        np.testing.assert_array_equal(ps[p][1:], pe[p][:-1])  # each piece starts where the one before ends
        assert np.all(pe[p] - ps[p] <= 30.0)
