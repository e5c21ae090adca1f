"""The setup's declared torque errors propagated through a transmission fit's own points (eq. 15-17).

A gain error of the CAN engine torque scales the engine's torque, not the gearbox input: in a hybrid
ramp-up that charges (engine torque up, motor torque negative, their sum small) 2 % of a 150 Nm engine
torque is 3 Nm, 8 % of a 37 Nm input. An offset moves every input torque alike, which a fit over a narrow
torque range (a high K_TEL clips the rest) carries into ``eta_m`` as well as into ``C0``. So the
tolerance a setup's systematic errors add to ``eta_m`` and ``C0`` is not a fixed sum of gain errors: it
is found here from the points the fit used.

Derivation (first order, each declared error at its bound ``a``, signs worst case): a point of the fit is
``(C, eta)`` with the input torque ``C_in = C_eng + C_em`` (``C_eng`` the engine torque counted, 0 with K0
open) and the shaft torque ``T_out``; with the lock-up closed ``w_in = i w_out``, so

* drive: ``C = C_in``, ``T_out = eta C i``, ``eta = T_out / (i C_in)``;
* coast: ``C = |T_out| / i``, ``C_in = -eta C`` (the input absorbs), ``eta = i C_in / T_out``.

Each source moves its quantity: engine torque ``C_eng (1 + a)`` or ``+ a`` (only where counted), motor
torque ``C_em (1 + a)`` or ``+ a``, shaft torque ``T_out (1 + a)`` or ``+ a``. The points are recomputed
with one source moved, refitted by the fit's weighted least squares (``[1, -1/C]``, weights ``C^2``), and
the change of ``eta_m`` (relative) and ``C0`` (Nm) taken; the bound is the sum of the absolute changes
over the sources (each source's error is the same at every point, so within a source the changes are
kept with their signs; across sources the worst combination of signs adds them).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["declared_torque_bound"]

#: (budget key, moved quantity, kind)
_SOURCES = (("engine_torque_gain", "eng", "gain"), ("engine_torque_offset", "eng", "offset"),
            ("em_torque_gain", "em", "gain"), ("em_torque_offset", "em", "offset"),
            ("shaft_gain", "out", "gain"), ("shaft_offset", "out", "offset"))


def _wls(c: np.ndarray, eta: np.ndarray) -> tuple[float, float]:
    A = np.column_stack([np.ones_like(c), -1.0 / c])
    w = np.sqrt(c**2 / np.mean(c**2))
    x, *_ = np.linalg.lstsq(A * w[:, None], eta * w, rcond=None)
    return float(x[0]), float(x[1] / x[0])


def _moved(c: np.ndarray, eta: np.ndarray, c_eng: np.ndarray, counted: np.ndarray, ratio: float, coast: bool,
           what: str, kind: str, a: float) -> tuple[np.ndarray, np.ndarray]:
    """The points ``(C, eta)`` as the chain would give them with one source off by ``a``."""
    c_in = -eta * c if coast else c.copy()
    t_out = -c * ratio if coast else eta * c * ratio
    eng = np.where(counted, c_eng, 0.0)
    em = c_in - eng
    if what == "eng":
        eng = eng * (1.0 + a) if kind == "gain" else np.where(counted, eng + a, eng)
    elif what == "em":
        em = em * (1.0 + a) if kind == "gain" else em + a
    else:
        t_out = t_out * (1.0 + a) if kind == "gain" else t_out + a
    c_in2 = eng + em
    if coast:
        return np.abs(t_out) / ratio, ratio * c_in2 / t_out
    return c_in2, t_out / (ratio * c_in2)


def declared_torque_bound(fit: Any, param: str, budget: dict[str, float], *, coast: bool) -> float | None:
    """The declared systematic torque errors' worst-case effect on a transmission fit's parameter.

    Parameters
    ----------
    fit:
        A ``transmission.gear<g>[_coast]`` fit with data ``c``, ``eta``, ``gear_ratio`` and ``c_engine``.
    param:
        ``eta_m`` (the bound is relative) or ``C0`` (Nm).
    budget:
        The declared errors by quantity (``validation.parameters._budget``): gain errors as fractions,
        offsets in Nm, of ``engine_torque``, ``em_torque`` and ``shaft``.
    coast:
        Whether the fit is a coast fit.

    Returns
    -------
    float or None
        The bound; None when the fit lacks the data to propagate through (the caller keeps its fixed sum).
    """
    if fit is None or param not in ("eta_m", "C0") or "eta_m" not in getattr(fit, "params", {}):
        return None
    if any(k not in fit.data for k in ("c", "eta", "gear_ratio", "c_engine")):
        return None
    c = np.asarray(fit.data["c"], dtype=float)
    eta = np.asarray(fit.data["eta"], dtype=float)
    c_eng = np.asarray(fit.data["c_engine"], dtype=float)
    ratio = float(np.asarray(fit.data["gear_ratio"], dtype=float).ravel()[0])
    ok = np.isfinite(c) & np.isfinite(eta) & np.isfinite(c_eng) & (c > 0)
    if ok.sum() < 3 or c_eng.shape != c.shape or not (math.isfinite(ratio) and ratio > 0):
        return None
    c, eta, c_eng = c[ok], eta[ok], c_eng[ok]
    counted = c_eng != 0.0
    try:
        eta_m0, c00 = _wls(c, eta)
    except np.linalg.LinAlgError:
        return None
    total = 0.0
    for key, what, kind in _SOURCES:
        a = abs(float(budget.get(key, 0.0)))
        if a == 0.0:
            continue
        c2, eta2 = _moved(c, eta, c_eng, counted, ratio, coast, what, kind, a)
        # a point the error would push out of the model's domain (C <= 0) is one the identification drops
        keep = np.isfinite(c2) & (c2 > 0) & np.isfinite(eta2)
        if keep.sum() < 3:
            return None
        eta_m, c0 = _wls(c2[keep], eta2[keep])
        total += abs(eta_m / eta_m0 - 1.0) if param == "eta_m" else abs(c0 - c00)
    return total
