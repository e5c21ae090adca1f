"""A block of grid points sampled from a channel in one pass free of the GIL, bit for bit ``_signals._sample_block``.

``_sample_block`` brackets each grid time between two samples (from its fractional index), interpolates linearly
(or holds) and flags a point touched by a bad or non-finite sample, through a dozen NumPy temporaries. The kernel
here does the same operations per point in the same order (a floor, an integer subtraction, a conversion of the
index to float, one subtraction, one product and one sum; the clock map ``t + s`` or ``t + (offset + rate t)``), so
the same numbers, without the temporaries and free of the GIL. A fractional index that is not finite (whose floor
has no integer) makes it give up: the caller keeps its NumPy expression then, as for other dtypes.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["sample_block"]


@numba.njit(cache=True, nogil=True)
def sample_block(ts: np.ndarray, vs: np.ndarray, fl: np.ndarray, t: np.ndarray, fidx: np.ndarray, hold: bool,
                 affine: bool, offset: float, rate: float, k0: int, bad: int
                 ) -> tuple[bool, np.ndarray, np.ndarray]:
    """``(done, values, flagged)`` of the grid times ``t`` from the samples ``ts, vs, fl`` (part of the channel from
    its sample ``k0``; ``fidx``: whole-channel fractional indices). The clock map is ``ts + offset`` (``affine``
    False) or ``ts + (offset + rate ts)``. ``done`` is False (and the arrays unset) when a ``fidx`` is not finite."""
    m = t.size
    n = ts.size
    v = np.empty(m)
    flagged = np.empty(m, dtype=np.bool_)
    for i in range(m):
        if not math.isfinite(fidx[i]):
            return False, v, flagged
    x0 = ts[0]
    x1 = ts[n - 1]
    first = x0 + (offset + rate * x0) if affine else x0 + offset
    last = x1 + (offset + rate * x1) if affine else x1 + offset
    for i in range(m):
        f = fidx[i]
        ti = t[i]
        idx = np.int64(math.floor(f)) - k0
        if ti < first:
            idx = -1
        i0 = min(max(idx, 0), n - 1)
        i1 = min(max(idx + 1, 0), n - 1)
        a = vs[i0]
        fg = (fl[i0] & bad) != 0 or not math.isfinite(a)
        if hold:
            out = a
        else:
            b = vs[i1]
            frac = f - np.float64(max(idx, 0) + k0)
            out = a + frac * (b - a)
            xb = ts[i1]
            after = (xb + (offset + rate * xb) if affine else xb + offset) > ti
            fg = fg or (((fl[i1] & bad) != 0 or not math.isfinite(b)) and after)
        if idx < 0 or ti > last:
            out = np.nan
            fg = False
        v[i] = out
        flagged[i] = fg
    return True, v, flagged
