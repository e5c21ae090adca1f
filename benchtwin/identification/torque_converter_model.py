"""The torque converter's model forms (eq. 35-39) and the designs of its two fits.

Shared by the identification (:mod:`benchtwin.identification.torque_converter`), the planner and the
validation: the model torques, the coupling point of a converter fit, the stacked converter-mode design and the
coupling-mode design with its constraints (no torque without slip; slip only over a narrow SR span).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "converter_design",
    "coupling_coefficients",
    "coupling_design",
    "coupling_point",
    "speed_products",
    "tc_torques",
]


def tc_torques(a: np.ndarray, gamma: float, w_p: np.ndarray, w_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pump and turbine torque of the model (eq. 35-36) for coefficients ``a = a0..a8``.

    Parameters
    ----------
    a:
        ``a0..a8`` (Nm s^2/rad^2).
    gamma:
        Coupling speed ratio: converter mode below, coupling mode at and above.
    w_p, w_t:
        Pump and turbine speed, rad/s.

    Returns
    -------
    t_p, t_t
        Pump and turbine torque, Nm.
    """
    a = np.asarray(a, dtype=float)
    w_p = np.asarray(w_p, dtype=float)
    w_t = np.asarray(w_t, dtype=float)
    q = np.stack([w_p**2, w_p * w_t, w_t**2])
    tp = a[0:3] @ q
    tt = a[3:6] @ q
    tc = a[6:9] @ q
    sr = np.divide(w_t, w_p, out=np.zeros_like(w_t), where=w_p != 0)
    coupling = sr >= gamma
    return np.where(coupling, tc, tp), np.where(coupling, tc, tt)


def coupling_point(a_conv: np.ndarray, *, lo: float = 0.0, hi: float = 1.2) -> float:
    """Smallest SR in ``(lo, hi]`` where the converter-mode torque ratio equals 1 (NaN if none).

    ``(a3 - a0) + (a4 - a1) SR + (a5 - a2) SR^2 = 0``.

    Parameters
    ----------
    a_conv:
        ``a0..a5``.
    lo, hi:
        Search interval of SR.
    """
    a = np.asarray(a_conv, dtype=float)
    c0, c1, c2 = a[3] - a[0], a[4] - a[1], a[5] - a[2]
    roots = np.roots([c2, c1, c0]) if abs(c2) > 1e-30 else (np.array([-c0 / c1]) if c1 != 0 else np.array([]))
    real = np.sort([r.real for r in np.atleast_1d(roots) if abs(r.imag) < 1e-12 and lo < r.real <= hi])
    return float(real[0]) if real.size else float("nan")


def speed_products(w_p: np.ndarray, w_t: np.ndarray) -> np.ndarray:
    """The regressors of each mode's torque (eq. 35-36): columns ``w_p^2, w_p w_t, w_t^2``."""
    return np.column_stack([w_p**2, w_p * w_t, w_t**2])


def converter_design(w_p: np.ndarray, w_t: np.ndarray, dw_p: np.ndarray | None = None) -> np.ndarray:
    """The stacked converter-mode design (eq. 37-38): pump rows over turbine rows.

    Columns ``a0..a5`` (and the pump inertia when ``dw_p`` is given); the right-hand side is
    ``[t_p; t_t]``. Shared by :func:`fit_torque_converter` and the planner.

    Parameters
    ----------
    w_p, w_t:
        Pump and turbine speeds, rad/s.
    dw_p:
        Pump acceleration, rad/s^2 (None: no inertia column).
    """
    q = speed_products(w_p, w_t)
    n = q.shape[0]
    z = np.zeros((n, 3))
    top = [q, z] + ([np.asarray(dw_p, dtype=float)[:, None]] if dw_p is not None else [])
    bot = [z, q] + ([np.zeros((n, 1))] if dw_p is not None else [])
    return np.vstack([np.hstack(top), np.hstack(bot)])


def coupling_design(w_p: np.ndarray, w_t: np.ndarray, zero_slip: bool = True, slip_only: bool = False
                    ) -> np.ndarray:
    """The coupling-mode design (eq. 39); shared by :func:`fit_torque_converter` and the planner.

    ``zero_slip``: columns ``w_p (w_p - w_t), -w_t (w_p - w_t)`` for ``a6, a8`` with ``a7 = -a6 - a8`` (no torque
    without slip); else :func:`speed_products` for ``a6, a7, a8``. ``slip_only``: the one column ``w_p (w_p - w_t)``
    for ``a6`` with ``a7 = -a6`` and ``a8 = 0`` (the torque in proportion to pump speed times slip), for coupling
    points over too narrow an SR span to tell ``a6`` from ``a8``.

    Parameters
    ----------
    w_p, w_t:
        Pump and turbine speeds of the coupling points, rad/s.
    zero_slip:
        Fit with ``a6 + a7 + a8 = 0``.
    slip_only:
        Fit ``a6`` alone (implies ``zero_slip``).
    """
    slip = w_p - w_t
    if slip_only:
        return (w_p * slip)[:, None]
    if not zero_slip:
        return speed_products(w_p, w_t)
    return np.column_stack([w_p * slip, -w_t * slip])


def coupling_coefficients(x: np.ndarray, zero_slip: bool = True, slip_only: bool = False) -> np.ndarray:
    """``a6, a7, a8`` from the coupling fit's unknowns.

    Parameters
    ----------
    x:
        The unknowns of :func:`coupling_design`'s fit: ``a6`` with ``slip_only``, ``a6, a8`` with ``zero_slip``,
        else ``a6, a7, a8``.
    zero_slip, slip_only:
        As :func:`coupling_design` (``a7 = -a6 - a8``; ``a7 = -a6``, ``a8 = 0``).
    """
    x = np.asarray(x, dtype=float)
    if slip_only:
        return np.array([x[0], -x[0], 0.0])
    return np.array([x[0], -x[0] - x[1], x[1]]) if zero_slip else x[:3].copy()


def _zero_torque_sr(x: np.ndarray) -> float:
    """SR in (0.5, 1.5) where the coupling torque ``a6 + a7 SR + a8 SR^2`` vanishes (closest to 1)."""
    roots = np.roots([x[2], x[1], x[0]]) if abs(x[2]) > 1e-30 else np.array([-x[0] / x[1]])
    real = [r.real for r in np.atleast_1d(roots) if abs(r.imag) < 1e-9 and 0.5 < r.real < 1.5]
    return float(min(real, key=lambda r: abs(r - 1.0))) if real else float("nan")


def _robust_z(r: np.ndarray, floor: float) -> np.ndarray:
    """``|r - median|`` in units of 1.4826 x MAD, the scale floored at ``floor`` (exact data: no outliers)."""
    med = float(np.median(r))
    mad = 1.4826 * float(np.median(np.abs(r - med)))
    return np.abs(r - med) / max(mad, floor)


def _gamma_from_data(sr: np.ndarray, tr: np.ndarray, tr_tol: float, bin_width: float = 0.02,
                     min_bin: int = 3) -> float:
    """First SR bin whose median TR is within ``tr_tol`` of 1 (or below) and stays so in the next bins."""
    edges = np.arange(0.0, max(1.0, float(sr.max())) + bin_width, bin_width)
    idx = np.digitize(sr, edges) - 1
    meds = []
    for k in range(edges.size - 1):
        m = idx == k
        if m.sum() >= min_bin:
            meds.append((edges[k], float(np.median(tr[m]))))
    for j, (lo, med) in enumerate(meds):
        if med <= 1.0 + tr_tol and all(m2 <= 1.0 + 2 * tr_tol for _, m2 in meds[j:j + 3]):
            return float(lo)
    return float("nan")
