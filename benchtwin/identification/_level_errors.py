"""The rounding draws' kernels of :mod:`~benchtwin.identification.uncertainty`: a draw's level errors added.

Each is one pass free of the GIL with the same floating-point operations, in the same order, as the NumPy expressions
they replace, so a draw's numbers do not depend on which kernel made them.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from benchtwin.recording import Flag

__all__ = ["BAD_BITS", "add_level_errors", "block_level_errors"]


@numba.njit(cache=True, nogil=True)
def add_level_errors(values: np.ndarray, scaled: np.ndarray, phase: float, errors: np.ndarray,
                     positions: np.ndarray) -> np.ndarray:
    """``values`` plus, at each good sample (``positions``, or all), the error of its level ``floor(scaled + phase)``.

    One pass without temporaries, free of the GIL; the same operations as the NumPy expression
    ``values[good] + errors[np.floor(scaled + phase).astype(int)]``, so the same numbers.
    """
    if positions.size == 0:
        out = np.empty_like(values)
        for i in range(values.size):
            out[i] = values[i] + errors[math.floor(scaled[i] + phase)]
        return out
    out = values.copy()
    for j in range(positions.size):
        k = positions[j]
        out[k] = values[k] + errors[math.floor(scaled[j] + phase)]
    return out


#: the bits of :meth:`Flag.bad` (a flagged sample keeps its value in a draw)
BAD_BITS = int(Flag.bad())


@numba.njit(cache=True, nogil=True)
def block_level_errors(values: np.ndarray, flags: np.ndarray, bad_bits: int, lo: float, scale: float, phase: float,
                       errors: np.ndarray) -> np.ndarray:
    """A block of a channel with one draw's level errors added to its good samples (free of ``bad_bits``, finite).

    One pass free of the GIL with the very operations of :func:`add_level_errors` on ``(values[good] - lo) /
    scale`` (a subtraction and a division per sample, then the floor of the sum with ``phase``), so the same numbers
    without the good mask, the positions and the scaled levels as arrays.
    """
    out = np.empty_like(values)
    for i in range(values.size):
        x = values[i]
        if (flags[i] & bad_bits) == 0 and math.isfinite(x):
            out[i] = x + errors[math.floor((x - lo) / scale + phase)]
        else:
            out[i] = x
    return out
