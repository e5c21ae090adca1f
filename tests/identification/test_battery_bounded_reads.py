"""The battery fits read a channel read by blocks around the times they use, never whole.

``battery.rc`` interpolates the pack temperature's good samples at the eq. 30 fit's times; on the acquisition's
chunk files (a lazy channel that reads blocks) that read is :func:`interp_good`, in parts of at most ``READ_SPAN_S``
of the times, each widened to the good samples bracketing it. The numbers are ``np.interp`` on the whole channel's
good samples, bit for bit (the interpolation uses only the two good samples around a time), and the bytes of block
reads alive at once are at most one part's: a part of ``S`` s read with the margin ``MARGIN_S`` each side, widened to
the time index's marks (one in ``INDEX_STRIDE`` samples, at most one stride each side, plus the sample at or after
the end), at ``RATE`` Hz, whatever the length of the channel.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _alive_reads import AliveReads, tracked_lazy
from test_battery_rc import SPECS, TRUTH, rc_recording

import benchtwin.identification._battery_used as battery_used
import benchtwin.identification._good_interp as good_interp
import benchtwin.identification._windows as windows
from benchtwin.identification._good_interp import count_good, interp_good
from benchtwin.identification._resample_blocks import StrictGrid
from benchtwin.identification._windows import MARGIN_S
from benchtwin.identification.battery import BATTERY_SEGMENT_KINDS, battery_samples, identify_battery, refine_soc
from benchtwin.identification.battery_rc import identify_battery_rc
from benchtwin.recording import Channel, Flag, LazyChannel, Recording

RATE = 10.0  #: samples per second of the synthetic temperature channel
STRIDE = 64  #: the time index's stride in these tests
SPAN = 20.0  #: the read span in these tests
SAMPLE_BYTES = 8 + 8 + 2  #: timestamp, value, flags
READ_SAMPLES = int((SPAN + 2 * MARGIN_S) * RATE) + 2 * STRIDE + 2  #: most samples one part's read spans


_Reads = AliveReads


def _lazy(ch: Channel, reads: _Reads) -> LazyChannel:
    """``ch`` as a lazy channel whose whole read fails and whose block reads are tracked copies."""
    lazy = tracked_lazy(ch, reads)
    windows.time_index(lazy)  # built here, by its own blocks: not counted below
    reads.most = reads.alive
    return lazy


@pytest.fixture
def small_reads(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(windows, "INDEX_STRIDE", STRIDE)
    monkeypatch.setattr(windows, "READ_SPAN_S", SPAN)
    monkeypatch.setattr(good_interp, "COUNT_BLOCK", STRIDE)  # the count's blocks within the bound too


def _temperature(duration_s: float, *, bad_ends: bool = False, bad_run_s: float = 0.0) -> Channel:
    """A warming pack temperature at RATE Hz with scattered NaN and flagged samples; with ``bad_ends`` its first and
    last 3 s are flagged, with ``bad_run_s`` a run that long in the middle is NaN."""
    rng = np.random.default_rng(3)
    t = 0.05 + np.arange(int(duration_s * RATE)) / RATE
    v = 23.0 + 15.0 * t / duration_s + rng.normal(0.0, 0.05, t.size)
    fl = np.zeros(t.size, dtype=np.uint16)
    v[rng.integers(0, t.size, 30)] = np.nan
    fl[rng.integers(0, t.size, 30)] = int(Flag.SATURATED)
    if bad_ends:
        fl[t < t[0] + 3.0] = int(Flag.LOST_FRAME)
        fl[t > t[-1] - 3.0] = int(Flag.LOST_FRAME)
    if bad_run_s:
        mid = 0.5 * duration_s
        v[(t > mid) & (t < mid + bad_run_s)] = np.nan
    return Channel("battery_temp_degc", "degC", t, v, fl, "thermo")


def _whole(ch: Channel, t: np.ndarray) -> np.ndarray:
    ok = np.isfinite(ch.values) & (ch.flags == 0)
    return np.interp(t, ch.timestamps[ok], ch.values[ok])


def test_interp_good_is_np_interp_on_the_good_samples(small_reads) -> None:
    """Bad ends (clamped values), a NaN run five spans long (the part widened across it), times on samples, between
    them, before the first and after the last: the same numbers as on the whole channel, bit for bit."""
    ch = _temperature(600.0, bad_ends=True, bad_run_s=5 * SPAN)
    reads = _Reads()
    lazy = _lazy(ch, reads)
    t = np.sort(np.r_[np.arange(-2.0, 603.0, 0.5), ch.timestamps[::7], ch.timestamps[:40], ch.timestamps[-40:]])
    got = interp_good(lazy, t)
    np.testing.assert_array_equal(got, _whole(ch, t))
    assert np.isfinite(got).all()
    assert count_good(lazy, 2) == 2
    assert count_good(ch, 10**9) == int((np.isfinite(ch.values) & (ch.flags == 0)).sum())


@pytest.mark.parametrize("duration_s", [300.0, 900.0])
def test_interp_good_reads_in_bounded_parts(small_reads, duration_s: float) -> None:
    """The 2 Hz times of a whole channel: one part read at a time, the same bound for a channel three times longer
    (mutant: interpolating on the whole channel fails on its whole read)."""
    ch = _temperature(duration_s)
    reads = _Reads()
    lazy = _lazy(ch, reads)
    t = np.arange(0.0, duration_s, 0.5)
    np.testing.assert_array_equal(interp_good(lazy, t), _whole(ch, t))
    assert 0 < reads.most <= READ_SAMPLES * SAMPLE_BYTES


def test_interp_good_without_a_good_sample_says_so(small_reads) -> None:
    ch = _temperature(100.0)
    ch.flags[:] = int(Flag.LOST_FRAME)
    lazy = _lazy(ch, _Reads())
    assert count_good(lazy, 2) == 0
    with pytest.raises(ValueError, match="no good sample"):
        interp_good(lazy, np.arange(0.0, 50.0, 0.5))


def test_battery_rc_reads_the_pack_temperature_by_blocks(small_reads) -> None:
    """identify_battery_rc on a Recording whose pack temperature reads blocks gives the fit of the channel in memory,
    field by field (mutant: the whole-channel interpolation of before fails on the lazy channel's whole read)."""
    truth = dict(TRUTH, beta_temp_per_k=0.025 * TRUTH["beta_discharge"])
    rec, _arr = rc_recording(truth, noise_v=0.2, seed=11, temp_rise_k=15.0)
    mem = identify_battery_rc(rec, SPECS, rate_hz=2.0)
    reads = _Reads()
    blocked = Recording(segments=rec.segments)
    for name, ch in rec.channels.items():
        blocked.add(_lazy(ch, reads) if name == "battery_temp_degc" else ch)
    got = identify_battery_rc(blocked, SPECS, rate_hz=2.0)
    assert "beta_temp_per_k" in mem.params
    assert set(got.params) == set(mem.params)
    for name, p in mem.params.items():
        q = got.params[name]
        assert (q.value, q.std_error, q.ci95) == (p.value, p.std_error, p.ci95), name
    assert 0 < reads.most <= READ_SAMPLES * SAMPLE_BYTES  # rc_recording samples at RATE too


@pytest.mark.parametrize("lazy", [False, True])
def test_eq30_keeps_only_its_samples_walking_the_grid_by_blocks(small_reads, monkeypatch: pytest.MonkeyPatch,
                                                                 lazy: bool) -> None:
    """identify_battery walks the common grid 97 points at a time and keeps the constant drives' points: its samples,
    refined SOC (the charge counted over every grid point, carried from block to block) and fit are those of
    battery_samples + refine_soc on the whole grid, bit for bit (mutants: the grid in one piece fails the block
    size; the charge's running sum restarted or added after the block's own sum fails the refined SOC)."""
    monkeypatch.setattr(battery_used, "BLOCK", 97)
    sizes: list[int] = []
    block = StrictGrid.block

    def spy(self, i0: int, i1: int):  # type: ignore[no-untyped-def]
        sizes.append(i1 - i0)
        return block(self, i0, i1)

    monkeypatch.setattr(StrictGrid, "block", spy)
    rec, _arr = rc_recording(TRUTH, noise_v=0.2, seed=5)
    rec.segments[1] = dataclasses.replace(rec.segments[1], kind="hold")  # the charge drive's points not used
    d, use, segs, _n_bad = battery_samples(rec, soc=True, rate_hz=None, kinds=BATTERY_SEGMENT_KINDS)
    soc, k, k_se, n_blocks = refine_soc(d["t"], d["battery_current_a"], d["displayed_soc_pct"], use)
    assert 0 < use.sum() < 0.8 * use.size and np.isfinite(k)
    src = rec
    if lazy:
        reads = _Reads()
        src = Recording(segments=rec.segments)
        for ch in rec.channels.values():
            src.add(_lazy(ch, reads))
    fit = identify_battery(src, SPECS)
    assert sizes and max(sizes) <= 97
    np.testing.assert_array_equal(fit.data["t"], d["t"][use])
    np.testing.assert_array_equal(fit.data["soc"], soc[use])
    np.testing.assert_array_equal(fit.data["current"], d["battery_current_a"][use])
    np.testing.assert_array_equal(fit.data["soc_displayed"], d["displayed_soc_pct"][use])
    est = fit.params["soc_per_ah"]
    assert (est.value, est.std_error, est.n_points, est.segments) == (k, k_se, n_blocks, segs)
