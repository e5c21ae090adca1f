"""Running sums of the steady-window searches in one pass free of the GIL, bit for bit those of NumPy's ``cumsum``.

:func:`~benchtwin.identification._window_sums.running_sums`,
:func:`~benchtwin.identification.steady_windowed.window_stats` and
:func:`~benchtwin.identification.steady.detect_steady` build running sums of a channel's good samples (and of their
squares, or of their products with the sample index). NumPy's ``cumsum`` adds left to right (``s[k] = s[k - 1] +
x[k]``, starting from ``x[0]`` itself), so a loop that adds the same terms in the same order gives the same numbers;
the kernels here do that without the masks, the ``where`` copies and the gathered samples as temporaries, and free
of the GIL (the type B re-runs' second thread runs beside them). The dtypes are fixed (float64 values, uint16
flags): a caller with others keeps its NumPy expression.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["centred_sums", "window_sums"]


@numba.njit(cache=True, nogil=True)
def window_sums(vals: np.ndarray, fl: np.ndarray, vals2: np.ndarray, fl2: np.ndarray, paired: bool, bad: int,
                lo: np.ndarray, hi: np.ndarray, c0: float, n0: int) -> tuple[np.ndarray, np.ndarray]:
    """Running sums of the good samples ``lo[w]:hi[w]`` of the windows laid one after the other (their products
    with ``vals2`` when ``paired``), and of their counts, at each window's first sample and after the last one.

    A sample is good when its flags are free of ``bad`` and it is finite (and so is its pair's, when paired); the
    sum starts at ``c0`` and adds every sample, a bad one as ``0.0``: the terms of
    ``np.cumsum(np.concatenate(([c0], np.where(good, v, 0.0))))`` in its order, so the same numbers.
    """
    m = lo.size
    cs = np.empty(m + 1)
    cn = np.empty(m + 1, dtype=np.int64)
    c = c0
    n = n0
    for w in range(m):
        cs[w] = c
        cn[w] = n
        for k in range(lo[w], hi[w]):
            x = vals[k]
            good = (fl[k] & bad) == 0 and math.isfinite(x)
            if paired:
                y = vals2[k]
                good = good and (fl2[k] & bad) == 0 and math.isfinite(y)
                x = x * y
            if good:
                c = c + x
                n += 1
            else:
                c = c + 0.0
    cs[m] = c
    cn[m] = n
    return cs, cn


@numba.njit(cache=True, nogil=True)
def centred_sums(x: np.ndarray, ref: float, with_index: bool
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(c1, c2, ci, cn)``: running sums, each with a leading zero, of ``xc = x - ref`` (0.0 where ``x`` is not
    finite), of ``xc * xc``, of ``k * xc`` (``k`` the sample index as a float; zeros unless ``with_index``) and of
    the finite count: the numbers of ``np.concatenate(([0.0], np.cumsum(...)))`` of those arrays."""
    n = x.size
    c1 = np.empty(n + 1)
    c2 = np.empty(n + 1)
    ci = np.zeros(n + 1)
    cn = np.empty(n + 1, dtype=np.int64)
    c1[0] = 0.0
    c2[0] = 0.0
    cn[0] = 0
    s1 = 0.0
    s2 = 0.0
    si = 0.0
    cnt = 0
    for k in range(n):
        v = x[k]
        if math.isfinite(v):
            xc = v - ref
            cnt += 1
        else:
            xc = 0.0
        if k == 0:  # cumsum starts from the first term itself (0.0 + -0.0 would be +0.0)
            s1 = xc
            s2 = xc * xc
            si = float(k) * xc
        else:
            s1 = s1 + xc
            s2 = s2 + xc * xc
            si = si + float(k) * xc
        c1[k + 1] = s1
        c2[k + 1] = s2
        if with_index:
            ci[k + 1] = si
        cn[k + 1] = cnt
    return c1, c2, ci, cn
