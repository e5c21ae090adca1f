"""Runs of a mask and the smooth (Savitzky-Golay) derivative computed run by run (re-exported by ``_signals``)."""

from __future__ import annotations

import numpy as np

__all__ = ["runs", "smooth_derivative"]


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Contiguous runs of True in ``mask`` as half-open index ranges ``(i0, i1)``."""
    m = np.asarray(mask, dtype=bool).astype(np.int8)
    if m.size == 0:
        return []
    d = np.diff(np.concatenate(([0], m, [0])))
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1)
    return list(zip(starts.tolist(), ends.tolist()))


def smooth_derivative(x: np.ndarray, dt: float, window_s: float, *, valid: np.ndarray | None = None,
                      polyorder: int = 3) -> np.ndarray:
    """Savitzky-Golay derivative of ``x`` (uniform step ``dt``), computed run by run over ``valid``.

    Samples outside ``valid`` and runs shorter than the window get NaN, so a derivative never
    spans a flagged sample or a gap. Within a run the result is that of
    ``scipy.signal.savgol_filter(run, w, polyorder, deriv=1, delta=dt, mode="interp")``: the
    centred filter inside, the derivative of the polynomial fitted to the first and last ``w``
    samples at the edges. The filter and the edge fits are linear in the data, so they are applied
    to every run at once as fixed coefficients (one ``polyfit`` per run edge would cost far more on
    a long log with thousands of runs).

    Parameters
    ----------
    x:
        Samples on a uniform grid.
    dt:
        Grid step, s.
    window_s:
        Filter window, s (rounded to an odd number of samples, at least ``polyorder + 2``).
    valid:
        Samples that may be used (default: the finite ones).
    polyorder:
        Order of the fitted polynomial.

    Returns
    -------
    numpy.ndarray
        ``dx/dt`` per sample, NaN outside the usable runs.
    """
    x = np.asarray(x, dtype=float)
    valid = np.isfinite(x) if valid is None else (np.asarray(valid, dtype=bool) & np.isfinite(x))
    w = max(round(window_s / dt) | 1, polyorder + 2 | 1)
    out = np.full(x.shape, np.nan)
    spans = np.array(runs(valid), dtype=np.int64).reshape(-1, 2)
    spans = spans[spans[:, 1] - spans[:, 0] >= w]
    if spans.size == 0:
        return out
    h = w // 2
    coef = _savgol_dot_coeffs(w, polyorder, dt)
    xf = np.where(valid, x, 0.0)
    # centred filter over the whole grid: a window inside a run sees only that run's samples
    inside = np.zeros(x.size + 1, dtype=np.int64)
    np.add.at(inside, spans[:, 0] + h, 1)
    np.add.at(inside, spans[:, 1] - h, -1)
    inner = np.cumsum(inside[:-1]) > 0
    centre = np.correlate(xf, coef[h], mode="valid")  # centre[m] belongs to sample m + h
    idx = np.flatnonzero(inner)
    out[idx] = centre[idx - h]
    # edges: the polynomial through the first / last w samples of each run, evaluated at its h outer samples
    k = np.arange(w)
    head = xf[spans[:, 0, None] + k] @ coef[:h].T
    tail = xf[spans[:, 1, None] - w + k] @ coef[w - h:].T
    out[spans[:, 0, None] + np.arange(h)] = head
    out[spans[:, 1, None] - h + np.arange(h)] = tail
    return out


_SAVGOL_CACHE: dict[tuple[int, int, float], np.ndarray] = {}


def _savgol_dot_coeffs(w: int, polyorder: int, dt: float) -> np.ndarray:
    """Rows k = 0..w-1: coefficients giving the first derivative at position k of the degree-``polyorder``
    least-squares polynomial through ``w`` samples (``coef[k] @ window``).

    The polynomial is written in the centred, scaled abscissa ``u = (k - c) / c``, ``c = (w - 1) / 2``, so the
    Vandermonde matrix stays well conditioned for long windows (as in ``numpy.polynomial.Polynomial.fit``).
    """
    key = (w, polyorder, float(dt))
    c = _SAVGOL_CACHE.get(key)
    if c is None:
        half = (w - 1) / 2.0
        u = (np.arange(w) - half) / half
        j = np.arange(polyorder + 1)
        vander = u[:, None] ** j  # w x (p + 1)
        deriv = np.zeros_like(vander)
        deriv[:, 1:] = j[1:] * u[:, None] ** (j[1:] - 1)  # d/du of each basis function at every sample
        c = deriv @ np.linalg.pinv(vander) / (half * dt)
        if len(_SAVGOL_CACHE) < 64:
            _SAVGOL_CACHE[key] = c
    return c
