"""The chain checks compare a block of a channel at a time: no whole channel of the campaign (Recording or Trace) is
read, and the verdicts and values equal those of the same checks made on whole channels (the oracle below is the
whole-channel comparison as the checks were written before; the quick and paper campaigns were compared with it
too, see benchmarks/RESULTS.md). About 3 s."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import maximum_filter1d

import benchtwin.validation.chain as vchain
from benchtwin.chain.stream import run_chunked, time_slices
from benchtwin.config import load_setup
from benchtwin.recording import Flag, LazyChannel, Recording
from benchtwin.sensors.imperfections import hold_sample
from benchtwin.sensors.synthetic import synthetic_trace
from benchtwin.trace import SpooledTrace, Trace
from benchtwin.validation.chain import _chain_truth, _error_budget, _kth, _median_step, _plant_step, chain_checks

PAPER = load_setup("paper")
IDEAL = load_setup("ideal")


def whole_channel_checks(trace: Trace, rec: Recording, setup, profile: str) -> dict[str, tuple]:
    """Each role's (value, truth, error, tolerance, passed) computed on whole channels."""
    budget = _error_budget(setup)
    out = {}
    for role, tc in sorted(_chain_truth(setup).items()):
        if role not in rec or tc.trace not in trace:
            continue
        ch = rec[role]
        x = trace[tc.trace] * tc.factor
        truth = hold_sample(trace.time_s, x, ch.timestamps) if tc.hold else np.interp(ch.timestamps, trace.time_s, x)
        ok = np.isfinite(truth) & np.isfinite(ch.values) & (ch.flags & int(Flag.bad()) == 0)
        n_flag = int(np.count_nonzero(ch.flags))
        err = ch.values[ok] - truth[ok]
        degc = 0.0065 * (ch.unit == "degC")
        if profile == "ideal":
            k = int(np.argmax(np.abs(err)))
            tol = 0.5 * tc.resolution + degc + 1e-9
            out[role] = (ch.values[ok][k], truth[ok][k], err[k], tol, bool(abs(err[k]) <= tol and n_flag == 0))
            continue
        errs, link, extra = budget.get(role, (None, None, 0.0))
        t, xv = ch.timestamps[ok], truth[ok]
        bound = np.full(xv.shape, 0.5 * tc.resolution * (1 + 1e-6) + 1e-9 + extra + degc)
        lag = 0.0
        if errs is not None:
            bound += abs(errs.offset) + abs(errs.gain_error_frac) * np.abs(xv) + 4.0 * errs.noise_std
            bound += errs.quantisation_step
            lag += 3.0 / (2 * np.pi * errs.bandwidth_hz) if errs.bandwidth_hz > 0 else 0.0
        lag += float(np.median(np.diff(ch.timestamps)))
        lag_t = np.full(t.shape, lag)
        if link is not None:
            lag += link.latency_s + abs(link.clock_offset_s)
            lag_t = lag + abs(link.clock_drift_ppm) * 1e-6 * np.abs(t)
        w = max(int(np.ceil(float(np.max(lag_t, initial=lag)) / trace.dt_s)) + 1, 1)
        slope = maximum_filter1d(np.abs(np.gradient(x, trace.time_s)), size=2 * w + 1, mode="nearest")
        bound += np.interp(t, trace.time_s, slope) * lag_t
        inside = float(np.mean(np.abs(err) <= bound))
        out[role] = (inside, 0.99, inside, 0.99, inside >= 0.99)
    return out


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory):
    """A minute of synthetic truth spooled to files, measured by the paper and ideal benches (Recordings read from
    the acquisition's chunk files)."""
    trace = synthetic_trace(60.0, 100.0, seed=7)
    spooled = SpooledTrace()
    for piece in time_slices([trace], 20.0):
        spooled.append(piece)
    recs = {s.name: run_chunked(time_slices([trace], 20.0), s, seed=4, out_dir=tmp_path_factory.mktemp(s.name),
                                keep_chunks=True) for s in (PAPER, IDEAL)}
    yield trace, spooled, recs
    for r in recs.values():
        r.close()
    spooled.close()


@pytest.mark.parametrize(("setup", "profile"), [(PAPER, "realistic"), (IDEAL, "ideal"), (PAPER, "ideal")])
@pytest.mark.parametrize(("block", "cap"), [(1 << 20, 1 << 21), (997, 1 << 21), (4000, 1500)])
def test_windowed_checks_equal_the_whole_channel_ones(bench, setup, profile: str, block: int, cap: int,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    trace, spooled, recs = bench
    monkeypatch.setattr(vchain, "CHECK_BLOCK_SAMPLES", block)
    monkeypatch.setattr(vchain, "MEDIAN_CAP", cap)
    rec = recs[setup.name]
    want = whole_channel_checks(trace, rec, setup, profile)
    got = {c.name.removeprefix("chain."): c for c in chain_checks(spooled, rec, setup, profile=profile)}
    assert len(want) > 10 and set(want) <= set(got)
    assert any(not w[4] for w in want.values()) or profile != "ideal" or setup is IDEAL  # the paper bench is not ideal
    for role, (value, truth, err, tol, passed) in want.items():
        c = got[role]
        assert (c.identified, c.truth, c.error, c.tolerance, c.passed) == (value, truth, err, tol, passed), role


def test_checks_read_no_whole_channel(bench, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every Recording channel is read through blocks of at most CHECK_BLOCK_SAMPLES, every Trace channel through
    windows about that long: a whole-channel read fails the test."""
    _trace, spooled, recs = bench
    rec = recs["paper"]
    block = 1000
    monkeypatch.setattr(vchain, "CHECK_BLOCK_SAMPLES", block)
    monkeypatch.setattr(vchain, "MEDIAN_CAP", 500)
    widest = {"rec": 0, "trace": 0}
    lazy = [c for c in rec.channels.values() if isinstance(c, LazyChannel)]
    assert len(lazy) > 10

    def whole(self: LazyChannel) -> list[np.ndarray]:
        if self._arrays is None:
            raise AssertionError(f"{self.name} read whole")
        return self._arrays

    real_block, real_read = LazyChannel.block, SpooledTrace.read

    def block_of(self: LazyChannel, a: int, b: int):
        widest["rec"] = max(widest["rec"], min(b, len(self)) - a)
        return real_block(self, a, b)

    def read(self: SpooledTrace, name: str, a: int = 0, b: int | None = None) -> np.ndarray:
        out = real_read(self, name, a, b)
        widest["trace"] = max(widest["trace"], out.size)
        return out

    monkeypatch.setattr(LazyChannel, "_load", whole)
    monkeypatch.setattr(LazyChannel, "block", block_of)
    monkeypatch.setattr(SpooledTrace, "read", read)
    checks = chain_checks(spooled, rec, PAPER, profile="realistic")
    assert sum(c.passed for c in checks) > 10
    assert widest["rec"] == block
    # a block spans at most 1000 plant samples (10 s): the Trace window is that and the lags' margin each side (the
    # slowest declared response of the paper bench, 3 / (2 pi f) of a ~0.5 Hz sensor, is about 1 s: 100 samples)
    assert 0 < widest["trace"] < 2 * block <= len(spooled) // 3


@pytest.mark.parametrize("n", [1, 2, 3, 10, 1001, 4000])
@pytest.mark.parametrize("kind", ["distinct", "ties", "two_values", "neighbours"])
def test_selected_order_statistics_and_median_equal_numpy(n: int, kind: str, monkeypatch) -> None:
    rng = np.random.default_rng(n)
    x = {"distinct": rng.normal(0.01, 1e-4, n), "ties": rng.integers(0, 5, n) * 0.25,
         "two_values": np.where(rng.random(n) < 0.3, 1.0, 2.0),
         "neighbours": np.where(rng.random(n) < 0.5, 1.0, np.nextafter(1.0, 2.0))}[kind]
    monkeypatch.setattr(vchain, "MEDIAN_CAP", 7)  # gathered only once few are left: several passes

    def parts():
        return iter(np.array_split(x, 5))

    srt = np.sort(x)
    for k in sorted({0, n // 2, n - 1}):
        assert _kth(parts, k, bins=16) == srt[k]
    monkeypatch.setattr(vchain, "CHECK_BLOCK_SAMPLES", 3)
    t = np.cumsum(np.concatenate([[0.0], x]))
    ch = Recording()
    from benchtwin.recording import Channel

    ch.add(Channel("c", "", t, np.zeros_like(t)))
    assert _median_step(ch["c"]) == float(np.median(np.diff(t)))
    assert _plant_step(Trace(t, {})) == Trace(t, {}).dt_s  # the Trace's plant step by blocks: the same


def test_the_paper_estimation_window_is_cut_without_reading_a_channel_whole(bench, monkeypatch) -> None:
    """The transmission fit on one ramp-up (paper_r2) takes its window of every channel a block at a time."""
    from benchtwin.validation.paper_r2 import _slice_recording

    _trace, _spooled, recs = bench
    rec = recs["paper"]
    want = {}
    for name, ch in rec.channels.items():
        m = (ch.timestamps >= 21.5) & (ch.timestamps < 33.25)
        want[name] = (ch.timestamps[m], ch.values[m], ch.flags[m])
    rec.drop()

    def whole(self: LazyChannel) -> list[np.ndarray]:
        if self._arrays is None:
            raise AssertionError(f"{self.name} read whole")
        return self._arrays

    monkeypatch.setattr(LazyChannel, "_load", whole)
    monkeypatch.setattr("benchtwin.validation.paper_r2._BLOCK", 777)
    cut = _slice_recording(rec, 21.5, 33.25)
    assert list(cut.channels) == list(want)
    for name, (t, v, f) in want.items():
        assert len(t) > 0, name
        for got, exp in zip((cut[name].timestamps, cut[name].values, cut[name].flags), (t, v, f), strict=True):
            assert got.dtype == exp.dtype and got.tobytes() == exp.tobytes(), name


def test_flag_counts_are_counted_by_blocks(bench, monkeypatch) -> None:
    """validate's flagged and clipped sample counts: the same as on whole channels, no channel read whole."""
    from benchtwin.validation.flag_counts import flag_counts

    _trace, _spooled, recs = bench
    rec = recs["paper"]
    want = {"flagged_samples": {}, "clipped_samples": {}}
    for name, ch in rec.channels.items():
        for key, n in (("flagged_samples", np.count_nonzero(ch.flags)),
                       ("clipped_samples", np.count_nonzero(ch.flags & int(Flag.SATURATED)))):
            if n:
                want[key][name] = int(n)
    rec.drop()
    assert want["flagged_samples"]  # the paper bench flags some samples (lost frames, saturation)

    def whole(self: LazyChannel) -> list[np.ndarray]:
        if self._arrays is None:
            raise AssertionError(f"{self.name} read whole")
        return self._arrays

    monkeypatch.setattr(LazyChannel, "_load", whole)
    monkeypatch.setattr("benchtwin.validation.flag_counts.FLAG_BLOCK", 333)
    assert flag_counts(rec) == want


def test_the_held_out_cut_reads_the_channels_by_blocks(bench, monkeypatch) -> None:
    """without_window (the Recording the held-out identification sees) cuts each channel a block at a time: the
    source channel is never read whole, and the cut equals the whole channel's samples outside the window."""
    from benchtwin.validation import holdout

    _trace, _spooled, recs = bench
    rec = recs["paper"]
    want = {}
    for name, ch in rec.channels.items():
        m = (ch.timestamps < 12.0) | (ch.timestamps >= 41.0)
        want[name] = (ch.timestamps[m], ch.values[m], ch.flags[m])
    rec.drop()
    real_load = LazyChannel._load
    sources = {id(ch) for ch in rec.channels.values()}
    cut_loaded = []

    def whole(self: LazyChannel) -> list[np.ndarray]:
        if self._arrays is None and id(self) in sources:  # a channel of the chunk files
            raise AssertionError(f"{self.name} read whole")
        if self._arrays is None:
            cut_loaded.append(self.name)
        return real_load(self)

    monkeypatch.setattr(LazyChannel, "_load", whole)
    monkeypatch.setattr(holdout, "_BLOCK", 501)
    cut = holdout.without_window(rec, 12.0, 41.0)
    # the cut's blocks are read without reading the cut (or its source) whole, across the window's edges
    for name, (t, v, f) in want.items():
        got = cut[name]
        for a, b in ((0, 7), (len(t) // 3, len(t) // 3 + 900), (len(t) - 5, len(t) + 3), (0, len(t))):
            block = got.block(a, b)
            for x, y in zip(block, (t[a:b], v[a:b], f[a:b]), strict=True):
                assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), (name, a, b)
    assert cut_loaded == []
    for name, (t, v, f) in want.items():
        got = cut[name]
        assert len(got) == len(t), name
        for x, y in zip((got.timestamps, got.values, got.flags), (t, v, f), strict=True):
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name


class _Map(np.ndarray):
    """A time base as a spooled Trace maps it (a new map per use of ``time_s``): counts the samples sliced from it,
    the pages a map makes resident (an index search touches a few pages only: not counted)."""

    touched: list[int]

    def __getitem__(self, k):
        got = np.asarray(self).__getitem__(k)
        self.touched[0] += int(np.size(got))
        return got


def test_the_time_base_is_mapped_a_block_at_a_time(bench, monkeypatch) -> None:
    """The chain checks take from one map of the Trace's time base at most a block and its windows' margins: the plant
    step's median, selected in passes over the blocks, maps the time base again per block (one map held over the
    passes made every page of the time base resident: the whole 8.4 MB per paper campaign, 84 MB at ten times it).

    Bound: a block of ``CHECK_BLOCK_SAMPLES`` plant steps (+1 for its diffs), or a Trace window, which spans a block
    of Recording samples cut at ``CHECK_BLOCK_SAMPLES`` plant steps and the lags' margin each side (about 1 s, 100
    samples, see test_checks_read_no_whole_channel): under twice the block. Mutant: the map taken once before the
    passes (``tt = trace.time_s`` then ``tt[a:a + block + 1]``) touches all 6000 samples of one map: fails."""
    _trace, spooled, recs = bench
    block = 1000
    monkeypatch.setattr(vchain, "CHECK_BLOCK_SAMPLES", block)
    monkeypatch.setattr(vchain, "MEDIAN_CAP", 500)
    maps: list[list[int]] = []
    real = SpooledTrace.time_s.fget

    def mapped(self: SpooledTrace) -> np.ndarray:
        m = real(self).view(_Map)
        m.touched = [0]
        maps.append(m.touched)
        return m

    monkeypatch.setattr(SpooledTrace, "time_s", property(mapped))
    assert vchain._plant_step(spooled) == _trace.dt_s
    assert len(maps) >= len(spooled) // block and max(t[0] for t in maps) <= block + 1
    maps.clear()
    checks = chain_checks(spooled, recs["paper"], PAPER, profile="realistic")
    assert sum(c.passed for c in checks) > 10
    assert 0 < max(t[0] for t in maps) < 2 * block <= len(spooled) // 3


@pytest.mark.parametrize("guess", [0.0, 1e7])
def test_a_wrong_guess_of_the_latest_time_is_made_again(bench, monkeypatch: pytest.MonkeyPatch, guess: float) -> None:
    """The realistic check counts and bounds in one pass with the filter width of a guessed latest usable time; a
    guess whose width differs from the found time's is passed again, so the checks do not depend on it. A guess of
    1e7 s widens the slope's filter to the whole window (a drift of 10-20 ppm x 1e7 s: 100 s of lag): with the
    re-pass removed (mutant: ``break`` after the first pass) the fractions inside the bound change and this fails."""
    _trace, spooled, recs = bench
    want = chain_checks(spooled, recs["paper"], PAPER, profile="realistic")
    monkeypatch.setattr(vchain, "_latest_time", lambda ch: guess)
    got = chain_checks(spooled, recs["paper"], PAPER, profile="realistic")
    assert [repr(c) for c in got] == [repr(c) for c in want]
