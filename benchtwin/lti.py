"""A SISO transfer function discretised: what python-control's ``c2d`` computes, without importing python-control.

The emulator's speed PI (:mod:`benchtwin.emulator.params`, Tustin) and the sensors' LTI filters
(:mod:`benchtwin.sensors.imperfections`, zero-order hold) need only the discrete coefficients. python-control's
``TransferFunction.sample`` calls ``scipy.signal.cont2discrete`` on the (numerator, denominator) pair and drops the
leading zero coefficients of the result; importing python-control to do that imported matplotlib with it (0.4 s at
the start of every run). :func:`c2d` does the same two steps, so its coefficients are python-control's bit for bit
(tests/test_lti.py holds it to python-control as the oracle). A bottom-layer pure function: any layer may use it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["c2d"]

#: the methods :func:`c2d` takes (python-control's names that map straight onto ``scipy.signal.cont2discrete``)
METHODS = ("zoh", "tustin", "bilinear", "euler", "backward_diff", "foh", "impulse")


def _trimmed(poly: np.ndarray) -> np.ndarray:
    """``poly`` without its leading exact zeros (all zeros: ``[0.0]``), as python-control's transfer function
    stores it."""
    nonzero = np.flatnonzero(poly)
    return poly[nonzero[0]:] if nonzero.size else np.zeros(1)


def c2d(num: Sequence[float] | np.ndarray, den: Sequence[float] | np.ndarray, dt: float,
        method: str = "zoh") -> tuple[np.ndarray, np.ndarray]:
    """Discretise the continuous transfer function ``num(s) / den(s)`` with step ``dt``.

    Parameters
    ----------
    num, den:
        Polynomial coefficients in ``s``, highest power first (python-control's ``tf(num, den)``).
    dt:
        Sampling period (s), positive.
    method:
        One of :data:`METHODS` (``"tustin"`` is ``"bilinear"``).

    Returns
    -------
    (num_d, den_d)
        Polynomial coefficients in ``z``, highest power first, leading zeros dropped: equal to
        ``control.c2d(control.tf(num, den), dt, method)``'s ``num[0][0]`` and ``den[0][0]``; the denominator is
        not normalised (as python-control leaves it). A zero numerator gives ``([0.0], [1.0])``.

    Raises
    ------
    ValueError
        On a non-positive or non-finite ``dt``, an unknown method, a zero denominator or non-finite coefficients.
    """
    from scipy.signal import cont2discrete

    if method not in METHODS:
        raise ValueError(f"c2d: method {method!r} not one of {', '.join(METHODS)}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"c2d: the step must be positive and finite, got {dt}")
    n = _trimmed(np.atleast_1d(np.asarray(num, dtype=np.float64)))
    d = _trimmed(np.atleast_1d(np.asarray(den, dtype=np.float64)))
    if n.ndim != 1 or d.ndim != 1:
        raise ValueError("c2d: a SISO transfer function takes 1-D coefficient sequences")
    if not (np.isfinite(n).all() and np.isfinite(d).all()):
        raise ValueError("c2d: the coefficients must be finite")
    if not d.any():
        raise ValueError("c2d: the denominator is zero")
    if not n.any():  # python-control: a zero numerator has the denominator 1 (and stays so when sampled)
        d = np.ones(1)
    numd, dend, _ = cont2discrete((n, d), float(dt), method)
    num_d = _trimmed(np.atleast_1d(np.asarray(numd, dtype=np.float64)[0]))
    den_d = _trimmed(np.atleast_1d(np.asarray(dend, dtype=np.float64)))
    if not num_d.any():
        den_d = np.ones(1)
    return num_d, den_d
