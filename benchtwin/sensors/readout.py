"""The per-sample part of :func:`~benchtwin.sensors.imperfections.measure` in one numba pass without the GIL.

``measure`` samples the filtered signal (linear interpolation, or a zero-order hold for states) and applies
the gain error, the offset, the noise (drawn by the caller from the device's generator, so every random
stream is unchanged), the quantisation and the output saturation. Done with numpy that is six to eight
array operations per call, about 7,500 calls on the paper campaign, each holding the GIL; :func:`read_out`
does the same arithmetic, in the same order on the same doubles, in one compiled pass that releases it, so
``run_chunked``'s decoding thread runs beside the encoder. The results are bit for bit those of the numpy
steps (``tests/sensors/test_readout.py``).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["read_out"]


@numba.njit(cache=True, nogil=True)
def _read_out(t_src: np.ndarray, x: np.ndarray, ts: np.ndarray, hold: bool, gain: bool, factor: float,
              offset: bool, offset_v: float, noise: np.ndarray, quantise: bool, step: float, has_lo: bool,
              lo: float, has_hi: bool, hi: float) -> np.ndarray:  # pragma: no cover - numba
    n = ts.size
    if hold:
        last = t_src.size - 1
        idx = np.searchsorted(t_src, ts, side="right") - 1
        y = np.empty(n, np.float64)
        for i in range(n):
            k = idx[i]
            y[i] = x[0 if k < 0 else (last if k > last else k)]
    else:
        y = np.interp(ts, t_src, x)
    noisy = noise.size > 0
    for i in range(n):
        v = y[i]
        if gain:
            v = v * factor
        if offset:
            v = v + offset_v
        if noisy:
            v = v + noise[i]
        if quantise:
            v = np.rint(v / step) * step
        # numpy's clip: max(v, lo) then min(v, hi), each keeping v only when strictly beyond the bound or NaN
        # (so -0.0 against a bound of 0.0 gives the bound)
        if has_lo and not (v > lo or np.isnan(v)):
            v = lo
        if has_hi and not (v < hi or np.isnan(v)):
            v = hi
        y[i] = v
    return y


def read_out(t_src: np.ndarray, x: np.ndarray, ts: np.ndarray, *, hold: bool, gain_error_frac: float,
             offset: float, noise: np.ndarray | None, quantisation_step: float, saturation_min: float | None,
             saturation_max: float | None) -> np.ndarray:
    """The sampled signal with the static errors, noise, quantisation and saturation (a new float64 array).

    Parameters
    ----------
    t_src, x:
        The (filtered) signal on its time base (float64, ``t_src`` increasing, at least one sample).
    ts:
        Sample times (plant time minus the latency).
    hold:
        Zero-order hold (held at the ends) instead of linear interpolation (``numpy.interp``).
    gain_error_frac, offset:
        Applied when nonzero: ``y * (1 + gain_error_frac)``, then ``+ offset``.
    noise:
        Drawn noise added sample by sample (``ts``'s shape), or None.
    quantisation_step:
        ``rint(y / step) * step`` when positive.
    saturation_min, saturation_max:
        ``numpy.clip``'s bounds (None: that side unbounded).
    """
    t_src = np.ascontiguousarray(t_src, dtype=np.float64)
    x = np.ascontiguousarray(x, dtype=np.float64)
    ts = np.ascontiguousarray(ts, dtype=np.float64)
    noise_a = np.zeros(0) if noise is None else np.ascontiguousarray(noise, dtype=np.float64).reshape(-1)
    if noise is not None and noise_a.size != ts.size:
        raise ValueError(f"noise has {noise_a.size} samples for {ts.size} sample times")
    if ts.ndim != 1 or t_src.ndim != 1 or x.shape != t_src.shape or t_src.size == 0:
        raise ValueError("read_out needs 1-D sample times and a non-empty 1-D signal on its time base")
    return _read_out(t_src, x, ts, bool(hold), bool(gain_error_frac), 1.0 + float(gain_error_frac),
                     bool(offset), float(offset), noise_a, quantisation_step > 0,
                     float(quantisation_step), saturation_min is not None,
                     0.0 if saturation_min is None else float(saturation_min), saturation_max is not None,
                     0.0 if saturation_max is None else float(saturation_max))
