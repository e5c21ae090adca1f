"""The gearbox's drag as a function of oil temperature and input speed (issue 9).

Eq. 14 gives each gear one constant drag ``C0``. A real gearbox's load-independent spin loss falls as the oil
warms (the ATF's viscosity falls about 1-2 %/K) and grows with the input speed (churning, the pump), so a ``C0``
identified on points run with the oil at one temperature and speed misjudges a drive at others. When the
Recording logs the gearbox oil (role ``gearbox_oil_degc``, a thermocouple in the sump), every steady point of
:func:`~benchtwin.identification.transmission.transmission_points` carries its oil temperature, and one fit over
all gears and directions finds

``eta = eta_m,g - eta_m,g C0_g (1 + k_w |w_in|) exp(-k_T (T - T_ref)) / C``

(drive ``C = C_in``; coast ``C = |T_out| / i_g``) with ``k_T`` and ``k_w`` shared by the gears (the same oil and
pump) and ``eta_m``, ``C0`` per gear and direction, weighted as eq. 15-17 (``C^2``, normalised per group). For
given ``(k_T, k_w)`` the problem is linear per group; the two minimise the profile sum of squares, and their
covariance comes from the profile's curvature (``2 s^2 H^-1``, ``s^2 = SSE / (N - 2 G - 2)``). ``T_ref`` is the
points' median oil temperature. When the speed term is not supported (Hessian not positive definite, ``k_w``
within three standard errors of zero, or its drop of the SSE below :data:`LR_3SIGMA` residual variances) it is
dropped and ``k_T`` fitted alone.

Fit ``transmission.drag``: ``k_T`` (1/K), ``k_w`` (s/rad), ``T_ref`` (degC) and ``eta_m_<group>``,
``C0_<group>`` per group (``g5``, ``g5_coast``). The map-based vehicle model applies it (``data["use"]``) only
when the data support it: the oil temperature spans at least :data:`MIN_SPAN_K`, ``k_T`` is at least three
standard errors from zero and the drag it implies changes by at least :data:`MIN_EFFECT` over the span; else
eq. 14's constant ``C0`` stays and the fit says why (flagged when the span is too small to tell).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize

from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate

__all__ = ["DRAG_KEY", "LR_3SIGMA", "MIN_EFFECT", "MIN_SPAN_K", "add_drag_fit", "drag_c0", "drag_factor",
           "temperature_supported"]

DRAG_KEY = "transmission.drag"
#: the least oil-temperature span over the points that can show a temperature dependence, K (at ~1 %/K a 15 K
#: span moves the drag by ~15 %, several times the scatter of a per-gear C0 on the paper's bench)
MIN_SPAN_K = 15.0
#: the least relative change of the drag over the points' span that is worth a model (below it eq. 14 stays)
MIN_EFFECT = 0.05
#: the SSE drop (in residual variances) the speed term must bring to be kept: the likelihood-ratio counterpart of
#: "three standard errors from zero" (3^2 on one degree of freedom). Both are required: where the profile runs along
#: its ridge (k_w off to ~1e6 s/rad with every C0 -> 0: a drag proportional to the speed) the curvature gives tiny,
#: meaningless standard errors (k_w and k_T) while the SSE barely moves (an 11-bit telemetry at K_TEL 250, 8.5 Nm
#: steps); with the speed term dropped k_T is fitted alone, off the ridge
LR_3SIGMA = 9.0

Groups = dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]


def drag_factor(fit: FitResult, oil_degc: np.ndarray | float, speed_radps: np.ndarray | float) -> np.ndarray:
    """The drag's factor shared by the gears, ``(1 + k_w |w_in|) exp(-k_T (T_oil - T_ref))`` (1 at ``T_ref``, rest).

    Parameters
    ----------
    fit:
        The fit ``transmission.drag``.
    oil_degc, speed_radps:
        Oil temperature (degC) and gearbox input speed (rad/s), scalars or arrays that broadcast.

    Returns
    -------
    numpy.ndarray
        The factor; a group's drag is its ``C0`` times it (:func:`drag_c0`).
    """
    t = np.asarray(oil_degc, dtype=float)
    w = np.abs(np.asarray(speed_radps, dtype=float))
    kw = fit.value("k_w") if "k_w" in fit.params else 0.0
    return (1.0 + kw * w) * np.exp(-fit.value("k_T") * (t - fit.value("T_ref")))


def drag_c0(fit: FitResult, group: str, oil_degc: np.ndarray | float, speed_radps: np.ndarray | float
            ) -> np.ndarray:
    """The drag of one group (``"g5"``, ``"g5_coast"``) at oil temperature ``oil_degc`` and input speed, Nm."""
    return fit.value(f"C0_{group}") * drag_factor(fit, oil_degc, speed_radps)


class _Points:
    """The groups' points concatenated, with each point's group index and weight (one vectorised solve per call)."""

    def __init__(self, groups: Groups) -> None:
        self.names = list(groups)
        self.idx = np.concatenate([np.full(v[0].size, k) for k, v in enumerate(groups.values())])
        self.c = np.concatenate([v[0] for v in groups.values()])
        self.eta = np.concatenate([v[1] for v in groups.values()])
        self.oil = np.concatenate([v[2] for v in groups.values()])
        self.w_in = np.concatenate([v[3] for v in groups.values()])
        self.w = np.concatenate([v[0] ** 2 / np.mean(v[0] ** 2) for v in groups.values()])
        g = len(self.names)
        self.s11 = np.bincount(self.idx, self.w, g)
        self.r1 = np.bincount(self.idx, self.w * self.eta, g)
        self.yy = float(np.sum(self.w * self.eta**2))

    def solve(self, k: float, kw: float, t_ref: float) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """Weighted least squares of every group at ``(k_T, k_w)``: total SSE, ``eta_m``, ``eta_m C0`` per group
        and the normal matrices' entries ``(S11, S12, S22)`` per group (rows of a ``(G, 3)`` array)."""
        g = len(self.names)
        b = -(1.0 + kw * self.w_in) * np.exp(-k * (self.oil - t_ref)) / self.c
        s12 = np.bincount(self.idx, self.w * b, g)
        s22 = np.bincount(self.idx, self.w * b * b, g)
        r2 = np.bincount(self.idx, self.w * b * self.eta, g)
        det = self.s11 * s22 - s12**2
        x1 = (s22 * self.r1 - s12 * r2) / det
        x2 = (self.s11 * r2 - s12 * self.r1) / det
        sse = max(self.yy - float(np.sum(x1 * self.r1 + x2 * r2)), 0.0)
        return sse, x1, x2, np.column_stack([self.s11, s12, s22])


def _hessian(f, x: np.ndarray, h: np.ndarray) -> np.ndarray:
    n = x.size
    H = np.zeros((n, n))
    f0 = f(x)
    for i in range(n):
        ei = np.zeros(n)
        ei[i] = h[i]
        H[i, i] = (f(x + ei) - 2.0 * f0 + f(x - ei)) / h[i] ** 2
        for j in range(i + 1, n):
            ej = np.zeros(n)
            ej[j] = h[j]
            H[i, j] = H[j, i] = (f(x + ei + ej) - f(x + ei - ej) - f(x - ei + ej) + f(x - ei - ej)) / (4 * h[i] * h[j])
    return H


def temperature_supported(fit: FitResult) -> bool:
    """Whether the drag fit's ``k_T`` is at least three standard errors from zero (the data show a temperature
    dependence, whatever its size)."""
    k, se = fit.value("k_T"), fit.params["k_T"].std_error
    return bool(np.isfinite(se) and abs(k) >= 3.0 * se)


def _lr(sse_without: float, sse_with: float, dof: int) -> float:
    """The SSE drop of one term in units of the fuller model's residual variance ``s^2 = SSE / dof`` (the
    likelihood-ratio statistic, chi-square with one degree of freedom; ``inf`` on exact points)."""
    drop = max(sse_without - sse_with, 0.0)
    s2 = sse_with / dof
    return drop / s2 if s2 > 0 else (math.inf if drop > 0 else 0.0)


def _profile(pts: _Points, t_ref: float, with_speed: bool, dof: int) -> tuple[np.ndarray, np.ndarray, float]:
    """``(k_T, k_w)``, their covariance and the SSE at the minimum (``k_w`` = 0 without the speed term)."""
    if with_speed:
        def f(x: np.ndarray) -> float:
            return pts.solve(float(x[0]), float(x[1]), t_ref)[0]
        x0, h = np.array([0.01, 0.001]), np.array([1e-4, 1e-5])
    else:
        def f(x: np.ndarray) -> float:
            return pts.solve(float(x[0]), 0.0, t_ref)[0]
        x0, h = np.array([0.01]), np.array([1e-4])
    res = minimize(f, x0, method="Nelder-Mead", options={"xatol": 1e-8, "fatol": 1e-14, "maxiter": 4000})
    x = np.asarray(res.x, dtype=float)
    sse = float(f(x))
    H = _hessian(f, x, h)
    try:
        cov = 2.0 * sse / dof * np.linalg.inv(H)
    except np.linalg.LinAlgError:
        cov = np.full(H.shape, np.inf)
    if not np.all(np.isfinite(cov)) or np.any(np.diag(cov) < 0):
        cov = np.diag(np.full(x.size, np.inf))
    if not with_speed:
        x, cov = np.array([x[0], 0.0]), np.array([[cov[0, 0], 0.0], [0.0, 0.0]])
    return x, cov, sse


def add_drag_fit(result: IdentificationResult, groups: Groups, segments: list[str], *, note: str = "") -> None:
    """Fit ``transmission.drag`` on the steady points (with their oil temperature) and put it into ``result``.

    Parameters
    ----------
    result:
        Where the fit (or why not) goes.
    groups:
        Group name (``"g5"``, ``"g5_coast"``) -> ``(C, eta, T_oil, |w_in|)`` of its points inside eq. 14's domain
        with an oil reading (:func:`~benchtwin.identification.transmission.identify_transmission` builds them).
    segments:
        Segments the points came from.
    note:
        Which points the groups hold (goes into the fit's reasons).

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
    dof = n - 2 * len(groups) - 2
    if dof < 1:
        result.errors[DRAG_KEY] = (f"InsufficientDataError: transmission.drag: {n} points for {2 * len(groups) + 2} "
                                   "unknowns")
        return
    notes = []
    pts = _Points(groups)
    x, cov, sse = _profile(pts, t_ref, True, dof)
    se = np.sqrt(np.diag(cov))
    x_t, cov_t, sse_t = _profile(pts, t_ref, False, dof + 1)
    lr_w = _lr(sse_t, sse, dof)
    wald_w = bool(np.isfinite(se[1]) and abs(x[1]) >= 3.0 * se[1] and x[1] > -1.0 / 1000.0)
    if not (wald_w and lr_w >= LR_3SIGMA):
        notes.append(f"speed term not supported (k_w = {x[1]:.2e} +/- {se[1]:.1e} s/rad"
                     + (f", but it lowers the SSE by only {lr_w:.2g} s^2 < {LR_3SIGMA:g} s^2" if wald_w else "")
                     + "): dropped")
        x, cov, sse = x_t, cov_t, sse_t
    se = np.sqrt(np.diag(cov))
    k, kw = float(x[0]), float(x[1])
    se_k, se_kw = float(se[0]), float(se[1])
    sse0 = pts.solve(0.0, 0.0, t_ref)[0]
    _, x1, x2, nm = pts.solve(k, kw, t_ref)
    s2 = sse / dof
    segs = sorted({s for s in segments if s})

    def est(name: str, value: float, std: float, unit: str) -> ParameterEstimate:
        return ParameterEstimate(name, value, std, (value - 1.96 * std, value + 1.96 * std), float("nan"), n, unit,
                                 segs)

    params = {"k_T": est("k_T", k, se_k, "1/K"), "k_w": est("k_w", kw, se_kw, "s/rad"),
              "T_ref": est("T_ref", t_ref, 0.0, "degC")}
    for gi, name in enumerate(pts.names):
        s11, s12, s22 = nm[gi]
        det = s11 * s22 - s12**2
        seg_ = np.sqrt(np.maximum(np.array([s22, s11]) / det * s2, 0.0))  # diagonal of (A'WA)^-1 s^2
        xg = (float(x1[gi]), float(x2[gi]))
        eta_m = xg[0]
        c0 = xg[1] / xg[0]
        se_c0 = float(abs(c0) * math.hypot(seg_[1] / max(abs(xg[1]), 1e-12), seg_[0] / max(abs(xg[0]), 1e-12)))
        params[f"eta_m_{name}"] = est(f"eta_m_{name}", eta_m, float(seg_[0]), "-")
        params[f"C0_{name}"] = est(f"C0_{name}", c0, se_c0, "Nm")
    y = np.concatenate([v[1] for v in groups.values()])
    sst = float(np.sum((y - np.mean(y)) ** 2))
    fit = FitResult(params, r2=1.0 - sse / sst if sst > 0 else float("nan"), adj_r2=float("nan"),
                    rmse=math.sqrt(sse / n), n_points=n, segments=segs)
    effect = abs(math.expm1(-k * span))
    significant = bool(np.isfinite(se_k) and abs(k) >= 3.0 * se_k)
    use = span >= MIN_SPAN_K and significant and effect >= MIN_EFFECT and all(
        0.5 < params[f"eta_m_{g}"].value <= 1.0 for g in pts.names)
    fit.reasons.append(f"oil {oil.min():.1f}..{oil.max():.1f} degC over {n} points in {len(groups)} gear/direction "
                       f"groups; k_T = {k:.4f} +/- {se_k:.4f} 1/K (drag {-k * 100:+.2f} %/K), k_w = {kw:.2e} +/- "
                       f"{se_kw:.1e} s/rad; weighted SSE {sse:.3g} against {sse0:.3g} with a constant C0 per group")
    fit.reasons.extend(([note] if note else []) + notes)
    if span < MIN_SPAN_K:
        fit.flag(f"the oil temperature spans {span:.1f} K < {MIN_SPAN_K:g} K: too little to identify k_T; the "
                 "constant C0 of eq. 14 is kept")
    elif not use:
        fit.reasons.append("the data do not support a temperature dependence (k_T within 3 standard errors of 0, "
                           f"or the drag moves by {effect:.1%} < {MIN_EFFECT:.0%} over the span, or an eta_m "
                           "outside (0.5, 1]): the constant C0 of eq. 14 is kept")
    else:
        fit.reasons.append("used by the map-based vehicle model at the drive's oil temperature and input speed")
    fit.data.update(use=np.array([use]), oil_span_k=np.array([span]), sse_constant=np.array([sse0]))
    result.fits[DRAG_KEY] = fit
