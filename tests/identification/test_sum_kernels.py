"""The steady-window searches' running-sum kernels against the NumPy expressions they replace: equal bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.identification._signals import BAD_FLAGS, Grid
from benchtwin.identification._sum_kernels import centred_sums, window_sums
from benchtwin.identification._window_sums import running_sums
from benchtwin.identification.steady_windowed import window_stats


def _numpy_running_sums(vals, fl, pair, lo, hi, c0, n0):
    """The former body of ``running_sums`` after the edge search (kept here as the reference)."""
    cnt_all = np.maximum(hi - lo, 0)
    off = np.concatenate(([0], np.cumsum(cnt_all)))
    sel = np.repeat(lo - off[:-1], cnt_all) + np.arange(off[-1])
    v = vals[sel]
    good = ((fl[sel] & BAD_FLAGS) == 0) & np.isfinite(v)
    if pair is not None:
        v2 = pair[0][sel]
        good &= ((pair[1][sel] & BAD_FLAGS) == 0) & np.isfinite(v2)
        with np.errstate(invalid="ignore"):
            v = v * v2
    cs = np.cumsum(np.concatenate(([c0], np.where(good, v, 0.0))))
    cn = np.concatenate(([n0], n0 + np.cumsum(good)))
    return cs[off], cn[off]


def _channel(rng, n):
    """Values with NaN, inf, -0.0 and flagged samples, on a level far from zero (the sums' rounding shows)."""
    v = 1234.5 + rng.normal(0.0, 3.0, n) * rng.uniform(0.0, 1.0, n) ** 3
    v[rng.random(n) < 0.02] = np.nan
    v[rng.random(n) < 0.005] = np.inf
    v[rng.random(n) < 0.01] = -0.0
    fl = np.zeros(n, dtype=np.uint16)
    fl[rng.random(n) < 0.03] = np.uint16(BAD_FLAGS & -BAD_FLAGS)  # the lowest bad bit
    fl[rng.random(n) < 0.03] = np.uint16(1 << 15) if not BAD_FLAGS & (1 << 15) else 0  # a flag that is not bad
    return v, fl


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("paired", [False, True])
def test_window_sums_equal_numpy(seed: int, paired: bool) -> None:
    rng = np.random.default_rng(seed)
    n = 5000
    vals, fl = _channel(rng, n)
    pair = _channel(rng, n) if paired else None
    ts = np.arange(n) * 0.01
    starts = np.sort(rng.uniform(-1.0, 51.0, 40))
    ends = starts + rng.uniform(-0.5, 6.0, 40)  # some empty (end before start), some overlapping, some past the end
    c0, n0 = float(rng.normal(0.0, 1e3)), int(rng.integers(0, 1000))
    got = running_sums(ts, vals, fl, pair, 0.0, starts, ends, c0, n0)
    lo = np.searchsorted(ts, starts, side="left")
    hi = np.searchsorted(ts, ends, side="left")
    want = _numpy_running_sums(vals, fl, pair, lo, hi, c0, n0)
    assert got[0].dtype == want[0].dtype and got[1].dtype == want[1].dtype
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    assert got[0].tobytes() == want[0].tobytes()  # signs of zeros too


def test_window_sums_start_at_c0_itself() -> None:
    """A run of windows starting from ``-0.0`` with only bad samples keeps ``-0.0`` first (cumsum's first term)."""
    vals = np.array([np.nan, 1.0])
    fl = np.zeros(2, dtype=np.uint16)
    cs, cn = window_sums(vals, fl, vals, fl, False, int(BAD_FLAGS), np.array([0]), np.array([1]), -0.0, 0)
    want = np.cumsum(np.concatenate(([-0.0], [0.0])))
    assert cs.tobytes() == np.array([-0.0, want[-1]]).tobytes() and cn.tolist() == [0, 0]


def _numpy_centred(x, ref):
    fin = np.isfinite(x)
    xc = np.where(fin, x - ref, 0.0)
    i = np.arange(x.size, dtype=float)
    return (np.concatenate(([0.0], np.cumsum(xc))), np.concatenate(([0.0], np.cumsum(xc * xc))),
            np.concatenate(([0.0], np.cumsum(i * xc))), np.concatenate(([0], np.cumsum(fin))))


@pytest.mark.parametrize("seed", range(6))
def test_centred_sums_equal_numpy(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    x, _ = _channel(rng, 3000)
    x[0] = [np.nan, -0.0, 1234.5, 7.0, np.inf, 1.0][seed]  # the first term: cumsum starts from it
    ref = float(np.nanmedian(x[np.isfinite(x)]))
    for r in (ref, 1234.5, 0.0):
        got = centred_sums(x, r, True)
        want = _numpy_centred(x, r)
        for g, w in zip(got, want, strict=True):
            assert g.dtype == w.dtype and g.tobytes() == w.tobytes()
        assert not centred_sums(x, r, False)[2].any()  # the index sums only when asked


def test_window_stats_and_detect_steady_unchanged() -> None:
    """The callers' results equal those of the NumPy expressions (statistics and windows found)."""
    rng = np.random.default_rng(7)
    n = 4000
    x = np.repeat(rng.uniform(900.0, 2500.0, 8), n // 8) + rng.normal(0.0, 0.5, n)
    y = np.repeat(rng.uniform(10.0, 300.0, 8), n // 8) + rng.normal(0.0, 0.2, n)
    x[rng.random(n) < 0.01] = np.nan
    t = np.arange(n) * 0.1
    grid = Grid(t, {"x": x, "y": y}, np.zeros(n, bool), np.zeros(n, bool), 10.0, set(), {})
    spans = [(a, a + 37) for a in range(0, n - 40, 97)] + [(5, 5)]
    got = window_stats(grid, spans)
    a_idx = np.array([a for a, _ in spans])
    b_idx = np.array([b for _, b in spans])
    for name, v in grid.values.items():
        ref = float(np.nanmedian(v))
        c1, c2, _ci, cn = _numpy_centred(v, ref)
        cnt = cn[b_idx] - cn[a_idx]
        with np.errstate(invalid="ignore", divide="ignore"):
            m = (c1[b_idx] - c1[a_idx]) / cnt
            var = np.clip((c2[b_idx] - c2[a_idx]) / cnt - m * m, 0.0, None)
        assert got[name][0].tobytes() == np.where(cnt > 0, m + ref, np.nan).tobytes()
        assert got[name][1].tobytes() == np.where(cnt > 0, np.sqrt(var), np.nan).tobytes()


def test_detect_steady_unchanged(monkeypatch: pytest.MonkeyPatch) -> None:
    """The windows found are those of the NumPy running sums (the kernel swapped for them), on noise near the
    tolerances (windows that a rounding of the sums could flip)."""
    from benchtwin.identification import steady

    rng = np.random.default_rng(11)
    n = 20000
    x = np.repeat(rng.uniform(900.0, 2500.0, 40), n // 40) + rng.normal(0.0, 1.0, n)
    y = np.repeat(rng.uniform(10.0, 300.0, 40), n // 40) + rng.normal(0.0, 0.3, n)
    x[rng.random(n) < 0.002] = np.nan
    tols = {"x": steady.Tolerance(std_abs=1.0, slope_abs=0.4), "y": steady.Tolerance(std_abs=0.3, slope_abs=0.1)}
    got = steady.detect_steady(0.1, {"x": x, "y": y}, tols, window_s=2.0, min_duration_s=3.0, max_duration_s=20.0)
    monkeypatch.setattr(steady, "centred_sums", lambda v, r, _i: _numpy_centred(v, r))
    want = steady.detect_steady(0.1, {"x": x, "y": y}, tols, window_s=2.0, min_duration_s=3.0, max_duration_s=20.0)
    assert got == want and len(want) > 20
