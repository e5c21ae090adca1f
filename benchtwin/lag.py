"""The lag between two signals sampled on their own clocks: a normalised cross-correlation on a common grid.

Shared by the acquisition's clock alignment (:mod:`benchtwin.chain.alignment`) and by identification methods that
line one channel up with another (:mod:`benchtwin.identification.shaft_clock`), which may not import the chain:
a pure function of the samples, in the bottom layer.
"""

from __future__ import annotations

import numpy as np

__all__ = ["detect_lag"]


def detect_lag(t_a: np.ndarray, x_a: np.ndarray, t_b: np.ndarray, x_b: np.ndarray, *, rate_hz: float = 100.0,
               max_lag_s: float = 2.0, min_correlation: float = 0.6,
               window: tuple[float, float] | None = None) -> float | None:
    """Time to add to ``a``'s timestamps to line signal ``a`` up with ``b``.

    Normalised cross-correlation (Pearson coefficient per lag) of ``a`` over the common span
    (or ``window`` of ``a``'s time) against ``b`` shifted by up to ``+-max_lag_s`` on a ``rate_hz``
    grid, refined by a parabola through the peak. Returns None if the signals do not overlap
    enough, are flat, or the best correlation is below ``min_correlation`` (not the same quantity).
    """
    if window is not None:  # cut to the window first: the rest of the work is then small
        a0, a1 = np.searchsorted(t_a, [window[0] - max_lag_s, window[1] + max_lag_s])
        b0, b1 = np.searchsorted(t_b, [window[0] - 2 * max_lag_s, window[1] + 2 * max_lag_s])
        t_a, x_a, t_b, x_b = t_a[a0:a1], x_a[a0:a1], t_b[b0:b1], x_b[b0:b1]
    good_a, good_b = np.isfinite(x_a), np.isfinite(x_b)
    if not good_a.all():  # all finite (the usual case): the same samples without copying them
        t_a, x_a = t_a[good_a], x_a[good_a]
    if not good_b.all():
        t_b, x_b = t_b[good_b], x_b[good_b]
    if t_a.size < 10 or t_b.size < 10:
        return None
    lo, hi = max(t_a[0], t_b[0]) + max_lag_s, min(t_a[-1], t_b[-1]) - max_lag_s
    if window is not None:
        lo, hi = max(lo, window[0]), min(hi, window[1])
    return _correlate(t_a, x_a, t_b, x_b, lo, hi, rate_hz, max_lag_s, min_correlation)


def _central_hour(lo: float, hi: float) -> tuple[float, float]:
    """The span ``lo..hi``, cut to its central hour when longer (all a cross-correlation needs)."""
    if hi - lo > 3600.0:
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 1800.0, mid + 1800.0
    return lo, hi


def _valid_correlation(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``scipy.signal.correlate(b, a, mode="valid", method="fft")`` of two 1-D float64 arrays, ``b`` not shorter:
    the same transforms (``next_fast_len`` of the full length, ``rfft`` of ``b`` and of ``a`` reversed, their
    product, ``irfft``) and the same centred slice, so the same bits, without scipy's checks, axis bookkeeping and
    dispatch per call (867 calls in the type B re-runs of the paper campaign)."""
    from scipy import fft as sp_fft

    full = b.size + a.size - 1
    size = sp_fft.next_fast_len(full, True)
    ret = sp_fft.irfft(sp_fft.rfft(b, size) * sp_fft.rfft(a[::-1], size), size)
    start = (full - (b.size - a.size + 1)) // 2
    return ret[start:start + b.size - a.size + 1]


def _correlate(t_a: np.ndarray, x_a: np.ndarray, t_b: np.ndarray, x_b: np.ndarray, lo: float, hi: float,
               rate_hz: float, max_lag_s: float, min_correlation: float) -> float | None:
    """:func:`detect_lag` over the span ``lo..hi`` (its central hour), the samples finite ones: for each point of
    the grids only the finite samples either side of it matter (any run of them around the grids gives the
    same bits)."""
    if hi - lo < 4 * max_lag_s:
        return None
    lo, hi = _central_hour(lo, hi)
    m = round(max_lag_s * rate_hz)
    grid = np.arange(lo, hi, 1.0 / rate_hz)
    a = np.interp(grid, t_a, x_a)
    a = a - a.mean()
    ext = np.concatenate([grid[0] - np.arange(m, 0, -1) / rate_hz, grid, grid[-1] + np.arange(1, m + 1) / rate_hz])
    b = np.interp(ext, t_b, x_b)
    n = a.size
    # numpy's own (pairwise) sum, not np.dot: BLAS splits a long dot product over its threads as it finds them free
    # (OpenBLAS above 10,000 samples), so the same samples gave energies (and lags) differing in the last bits
    # from one call to the next, and the type B re-runs of the converter (shaft_clock) differed from plain ones
    ea = float(np.sum(a * a))
    if ea == 0:
        return None
    cov = _valid_correlation(b, a)  # cov[j] = sum a[i] b[i + j], j = 0..2m
    cs, cs2 = np.zeros(b.size + 1), np.zeros(b.size + 1)  # running sums from 0: the same sums, no copy to prepend
    np.cumsum(b, out=cs[1:])
    np.cumsum(b * b, out=cs2[1:])
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
