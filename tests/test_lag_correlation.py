"""The cross-correlation of :mod:`benchtwin.lag` without scipy's dispatch: the same bits as ``scipy.signal.correlate``.

The oracle is scipy itself (its FFT method on the same arrays) and the running sums as ``_correlate`` took them
before (``concatenate`` of a zero and ``cumsum``): every comparison is exact, ``np.array_equal`` / ``==``, since the
type B budgets of the converter (``shaft_clock``) are kept bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import correlate

from benchtwin.lag import _correlate, _valid_correlation, detect_lag

#: lengths of ``a`` (the grid) with small and large prime factors, and extra lengths of ``b`` (2 m, m = 0 included)
A_SIZES = (10, 97, 500, 1001, 2048, 3001, 4097, 6007, 12289)
EXTRAS = (0, 2, 100, 201)


@pytest.mark.parametrize("n", A_SIZES)
@pytest.mark.parametrize("extra", EXTRAS)
def test_valid_correlation_is_scipys_bit_for_bit(n: int, extra: int) -> None:
    rng = np.random.default_rng(n * 1000 + extra)
    a = rng.normal(size=n)
    b = rng.normal(size=n + extra) * 40.0 + 3.0
    expected = correlate(b, a, mode="valid", method="fft")
    got = _valid_correlation(b, a)
    assert got.shape == expected.shape == (extra + 1,)
    assert np.array_equal(got, expected)


def _correlate_before(t_a, x_a, t_b, x_b, lo, hi, rate_hz, max_lag_s, min_correlation):
    """``benchtwin.lag._correlate`` as it was (scipy's correlate, prepended running sums): the oracle."""
    if hi - lo < 4 * max_lag_s:
        return None
    if hi - lo > 3600.0:
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 1800.0, mid + 1800.0
    m = round(max_lag_s * rate_hz)
    grid = np.arange(lo, hi, 1.0 / rate_hz)
    a = np.interp(grid, t_a, x_a)
    a = a - a.mean()
    ext = np.concatenate([grid[0] - np.arange(m, 0, -1) / rate_hz, grid, grid[-1] + np.arange(1, m + 1) / rate_hz])
    b = np.interp(ext, t_b, x_b)
    n = a.size
    ea = float(np.sum(a * a))
    if ea == 0:
        return None
    cov = correlate(b, a, mode="valid", method="fft")
    cs, cs2 = np.concatenate([[0.0], np.cumsum(b)]), np.concatenate([[0.0], np.cumsum(b * b)])
    s1 = cs[n:n + 2 * m + 1] - cs[:2 * m + 1]
    s2 = cs2[n:n + 2 * m + 1] - cs2[:2 * m + 1]
    var = s2 - s1 * s1 / n
    with np.errstate(invalid="ignore", divide="ignore"):
        r = cov / np.sqrt(np.clip(var, 1e-300, None) * ea)
    k = int(np.nanargmax(r))
    if not r[k] >= min_correlation:
        return None
    frac = 0.0
    if 0 < k < r.size - 1:
        den = r[k - 1] - 2 * r[k] + r[k + 1]
        frac = 0.5 * (r[k - 1] - r[k + 1]) / den if den != 0 else 0.0
    return float((k - m + frac) / rate_hz)


@pytest.mark.parametrize("seed", range(12))
def test_correlate_gives_the_lags_of_before_bit_for_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    span = float(rng.uniform(8.0, 120.0))
    lag = float(rng.uniform(-0.3, 0.3))
    t_b = np.sort(rng.uniform(0.0, span, int(span * 50)))
    t_a = np.sort(rng.uniform(0.0, span, int(span * 80)))
    x_b = np.cumsum(rng.normal(size=t_b.size)) + 0.01 * rng.normal(size=t_b.size)
    x_a = np.interp(t_a + lag, t_b, x_b) + 0.05 * rng.normal(size=t_a.size)
    for max_lag_s, rate_hz in ((0.5, 100.0), (1.0, 50.0), (0.02, 100.0)):
        lo, hi = max(t_a[0], t_b[0]) + max_lag_s, min(t_a[-1], t_b[-1]) - max_lag_s
        before = _correlate_before(t_a, x_a, t_b, x_b, lo, hi, rate_hz, max_lag_s, 0.0)
        now = _correlate(t_a, x_a, t_b, x_b, lo, hi, rate_hz, max_lag_s, 0.0)
        assert (before is None and now is None) or before == now


def test_detect_lag_still_finds_a_known_lag() -> None:
    """An independent check of the sign and size: ``b`` is ``a`` 0.12 s later, so 0.12 s added to ``a``'s times lines
    it up (to within the parabola's refinement of a 100 Hz grid, a fraction of a 10 ms step)."""
    t = np.arange(0.0, 60.0, 0.01)
    x = np.sin(0.7 * t) + 0.5 * np.sin(2.3 * t)
    lag = detect_lag(t, x, t + 0.12, x, rate_hz=100.0, max_lag_s=0.5)
    assert lag is not None and abs(lag - 0.12) < 0.005


@pytest.mark.parametrize("seed", range(6))
def test_detect_lag_with_non_finite_samples_is_the_lag_without_them(seed: int) -> None:
    """NaN and inf samples are left out: the lag is, bit for bit, that of the arrays with them removed beforehand
    (the all-finite case skips the copy; a sample that is not finite must still be dropped)."""
    rng = np.random.default_rng(100 + seed)
    t = np.arange(0.0, 80.0, 0.01)
    x = np.cumsum(rng.normal(size=t.size))
    t_b, x_b = t + 0.07, x + 0.01 * rng.normal(size=t.size)
    bad_a, bad_b = rng.random(t.size) < 0.02, rng.random(t.size) < 0.02
    x_a = np.where(bad_a, np.nan, x)
    x_b_bad = np.where(bad_b, np.inf, x_b)
    window = (10.0, 70.0)
    for xb, keep_b in ((x_b, np.ones(t.size, bool)), (x_b_bad, ~bad_b)):
        got = detect_lag(t, x_a, t_b, xb, rate_hz=100.0, max_lag_s=0.5, window=window)
        expected = detect_lag(t[~bad_a], x[~bad_a], t_b[keep_b], x_b[keep_b], rate_hz=100.0, max_lag_s=0.5,
                              window=window)
        assert got is not None and got == expected
