"""The gearbox's drag as a function of the oil temperature: ``C0_g(T) = C0_g,ref exp(-k_T (T - T_ref))``.

Eq. 14 gives each gear one constant drag ``C0``. A real gearbox's load-independent spin loss falls as the oil
warms (the ATF's viscosity falls about 1-2 %/K), so a ``C0`` identified on points run with the oil at one
temperature misjudges a drive at another. When the Recording logs the gearbox oil (role ``gearbox_oil_degc``,
a thermocouple in the sump), every steady point of :func:`~benchtwin.identification.transmission
.transmission_points` carries its oil temperature, and one fit over all gears and directions finds

``eta = eta_m,g - eta_m,g C0_g,ref exp(-k_T (T - T_ref)) / C``  (drive ``C = C_in``; coast ``C = |T_out| / i_g``)

with one ``k_T`` shared by the gears (the same oil) and ``eta_m``, ``C0_ref`` per gear and direction, weighted as
eq. 15-17 (``C^2``, normalised per group). For a given ``k_T`` the problem is linear per group; ``k_T`` minimises
the profile sum of squares, and its standard error comes from the profile's curvature
(``se^2 = 2 s^2 / SSE''``, ``s^2 = SSE / (N - 2 G - 1)``). ``T_ref`` is the points' median oil temperature.

Fit ``transmission.drag``: ``k_T`` (1/K), ``T_ref`` (degC) and ``eta_m_<group>``, ``C0_<group>`` per group
(``g5``, ``g5_coast``). The map-based vehicle model applies it (``data["use"]``) only when the data support it:
the oil temperature spans at least :data:`MIN_SPAN_K`, ``k_T`` is at least three standard errors from zero and
the drag it implies changes by at least :data:`MIN_EFFECT` over the span; else eq. 14's constant ``C0`` stays
and the fit says why (flagged when the span is too small to tell).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate

__all__ = ["DRAG_KEY", "MIN_EFFECT", "MIN_SPAN_K", "add_drag_fit", "drag_c0"]

DRAG_KEY = "transmission.drag"
#: the least oil-temperature span over the points that can show a temperature dependence, K (at ~1 %/K a 15 K
#: span moves the drag by ~15 %, several times the scatter of a per-gear C0 on the paper's bench)
MIN_SPAN_K = 15.0
#: the least relative change of the drag over the points' span that is worth a model (below it eq. 14 stays)
MIN_EFFECT = 0.05
#: bounds of the search for k_T, 1/K (an ATF's viscosity falls 1-3 %/K; a negative value is allowed to be found)
K_BOUNDS = (-0.05, 0.08)


def drag_c0(fit: FitResult, group: str, oil_degc: np.ndarray | float) -> np.ndarray:
    """The drag ``C0`` of one group (``"g5"``, ``"g5_coast"``) at the oil temperature ``oil_degc``, Nm."""
    t = np.asarray(oil_degc, dtype=float)
    return fit.value(f"C0_{group}") * np.exp(-fit.value("k_T") * (t - fit.value("T_ref")))


def _solve(groups: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], k: float, t_ref: float
           ) -> tuple[float, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Weighted least squares per group at a given ``k_T``: the total SSE and each group's (x, covariance / s^2)."""
    sse = 0.0
    sol = {}
    for name, (c, eta, oil) in groups.items():
        w = c**2 / np.mean(c**2)
        A = np.column_stack([np.ones_like(c), -np.exp(-k * (oil - t_ref)) / c])
        sw = np.sqrt(w)
        x, *_ = np.linalg.lstsq(A * sw[:, None], eta * sw, rcond=None)
        r = (eta - A @ x) * sw
        sse += float(r @ r)
        sol[name] = (x, np.linalg.pinv((A * sw[:, None]).T @ (A * sw[:, None])))
    return sse, sol


def add_drag_fit(result: IdentificationResult, groups: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
                 segments: list[str]) -> None:
    """Fit ``transmission.drag`` on the steady points (with their oil temperature) and put it into ``result``.

    Parameters
    ----------
    result:
        Where the fit (or why not) goes.
    groups:
        Group name (``"g5"``, ``"g5_coast"``) -> ``(C, eta, T_oil)`` of its points inside eq. 14's domain with an
        oil reading (:func:`~benchtwin.identification.transmission.identify_transmission` builds them).
    segments:
        Segments the points came from.

    Notes
    -----
    When the oil spans less than :data:`MIN_SPAN_K` the fit is added flagged with that reason and the constant
    ``C0`` of eq. 14 is kept (``data["use"]`` false).
    """
    n = sum(v[0].size for v in groups.values())
    if not groups:
        result.errors[DRAG_KEY] = "InsufficientDataError: transmission.drag: no gear with 3 points and an oil reading"
        return
    oil = np.concatenate([v[2] for v in groups.values()])
    t_ref = float(np.median(oil))
    span = float(oil.max() - oil.min())
    dof = n - 2 * len(groups) - 1
    if dof < 1:
        result.errors[DRAG_KEY] = (f"InsufficientDataError: transmission.drag: {n} points for {2 * len(groups) + 1} "
                                   "unknowns")
        return
    res = minimize_scalar(lambda k: _solve(groups, k, t_ref)[0], bounds=K_BOUNDS, method="bounded",
                          options={"xatol": 1e-7})
    k = float(res.x)
    sse, sol = _solve(groups, k, t_ref)
    sse0, _ = _solve(groups, 0.0, t_ref)
    s2 = sse / dof
    h = 1e-4
    curv = (_solve(groups, k + h, t_ref)[0] - 2.0 * sse + _solve(groups, k - h, t_ref)[0]) / h**2
    se_k = math.sqrt(2.0 * s2 / curv) if curv > 0 else float("inf")
    segs = sorted({s for s in segments if s})

    def est(name: str, value: float, se: float, unit: str) -> ParameterEstimate:
        return ParameterEstimate(name, value, se, (value - 1.96 * se, value + 1.96 * se), float("nan"), n, unit,
                                 segs)

    params = {"k_T": est("k_T", k, se_k, "1/K"), "T_ref": est("T_ref", t_ref, 0.0, "degC")}
    for name, (x, cov) in sol.items():
        se = np.sqrt(np.maximum(np.diag(cov) * s2, 0.0))
        eta_m = float(x[0])
        c0 = float(x[1] / x[0])
        se_c0 = float(abs(c0) * math.hypot(se[1] / max(abs(x[1]), 1e-12), se[0] / max(abs(x[0]), 1e-12)))
        params[f"eta_m_{name}"] = est(f"eta_m_{name}", eta_m, float(se[0]), "-")
        params[f"C0_{name}"] = est(f"C0_{name}", c0, se_c0, "Nm")
    y = np.concatenate([v[1] for v in groups.values()])
    ybar = float(np.mean(y))
    sst = float(np.sum((y - ybar) ** 2))
    fit = FitResult(params, r2=1.0 - sse / sst if sst > 0 else float("nan"),
                    adj_r2=float("nan"), rmse=math.sqrt(sse / n), n_points=n, segments=segs)
    effect = abs(math.expm1(-k * span))
    significant = abs(k) >= 3.0 * se_k
    use = span >= MIN_SPAN_K and significant and effect >= MIN_EFFECT and all(
        0.5 < params[f"eta_m_{g}"].value <= 1.0 for g in sol)
    fit.reasons.append(f"oil {oil.min():.1f}..{oil.max():.1f} degC over {n} points in {len(groups)} gear/direction "
                       f"groups; k_T = {k:.4f} +/- {se_k:.4f} 1/K (drag {-k * 100:+.2f} %/K); weighted SSE "
                       f"{sse:.3g} against {sse0:.3g} with a constant C0 per group")
    if span < MIN_SPAN_K:
        fit.flag(f"the oil temperature spans {span:.1f} K < {MIN_SPAN_K:g} K: too little to identify k_T; the "
                 "constant C0 of eq. 14 is kept")
    elif not use:
        fit.reasons.append("the data do not support a temperature dependence (k_T within 3 standard errors of 0, "
                           f"or the drag moves by {effect:.1%} < {MIN_EFFECT:.0%} over the span, or an eta_m "
                           "outside (0.5, 1]): the constant C0 of eq. 14 is kept")
    else:
        fit.reasons.append("used by the map-based vehicle model at the drive's oil temperature")
    fit.data.update(use=np.array([use]), oil_span_k=np.array([span]), sse_constant=np.array([sse0]))
    result.fits[DRAG_KEY] = fit
