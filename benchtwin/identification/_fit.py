"""Shared least-squares machinery and result types for every identification method.

Each ``identify_*`` function builds its regressors and calls :func:`linear_fit` or
:func:`nonlinear_fit`; both check the data first (enough points, excitation, collinearity) and
return a :class:`FitResult` whose parameters carry estimate, standard error, 95 % interval, the fit's
R^2, the number of points and the segments used. Transformed parameters (e.g. ``C0 = X2 / X1``)
get their uncertainty by the delta method through :func:`derived`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import optimize

from benchtwin.errors import CollinearError, FitFailedError, InsufficientDataError, NoExcitationError
from benchtwin.identification._gum import Z95, coverage_factor, dof_of_interval, t975

__all__ = [
    "Z95",
    "FitResult",
    "IdentificationResult",
    "ParameterEstimate",
    "coverage_factor",
    "derived",
    "linear_fit",
    "nonlinear_fit",
    "r_squared",
    "serial_inflation",
]


@dataclass
class ParameterEstimate:
    """One identified parameter with its statistics.

    Attributes
    ----------
    name, unit:
        Parameter name and unit.
    value:
        Estimate.
    std_error:
        Standard error (NaN when it cannot be computed).
    ci95:
        95 % confidence interval ``(low, high)``.
    r2:
        R^2 of the fit the parameter came from.
    n_points:
        Number of points used.
    segments:
        Names of the segments the points came from (empty when none were known).
    status:
        ``"ok"`` or ``"flagged"``; ``reason`` says why when flagged.
    u_type_b:
        Standard uncertainty from the systematic errors the setup declares (GUM type B), propagated
        through the fit (:mod:`benchtwin.identification.uncertainty`); 0 when none are declared.
    u_total:
        Combined standard uncertainty ``sqrt(std_error^2 + u_type_b^2)``.
    ci95_total:
        95 % interval of the combined uncertainty, ``value +- k u_total`` with ``k`` the Student-t
        quantile at the Welch-Satterthwaite effective degrees of freedom (equal to ``ci95`` when
        ``u_type_b`` is 0).
    type_b:
        The type B budget: source (``shaft_torque_nm.gain``, ``em_torque_nm.offset`` ...) -> its
        contribution to the parameter's standard uncertainty, in the parameter's unit.
    type_b_dof:
        Degrees of freedom of the components that are not exactly known (missing: infinite); kept so that a
        later :meth:`combine_type_b` with ``keep=True`` weighs them alike (not written by :meth:`to_dict`).
    """

    name: str
    value: float
    std_error: float
    ci95: tuple[float, float]
    r2: float
    n_points: int
    unit: str = ""
    segments: list[str] = field(default_factory=list)
    status: str = "ok"
    reason: str = ""
    u_type_b: float = 0.0
    u_total: float = float("nan")
    ci95_total: tuple[float, float] | None = None
    type_b: dict[str, float] = field(default_factory=dict)
    type_b_dof: dict[str, float] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if self.ci95_total is None:
            self.ci95_total = (float(self.ci95[0]), float(self.ci95[1]))
        if not math.isfinite(self.u_total) and self.u_type_b == 0.0:
            self.u_total = self.std_error

    def combine_type_b(self, contributions: dict[str, float], dof: dict[str, float] | None = None, *,
                       keep: bool = False) -> None:
        """Combine the type B contributions with the statistical uncertainty (GUM, JCGM 100 sections 5 and G).

        The statistical degrees of freedom are read back from ``ci95`` (its half-width is ``t(nu_A)``
        standard errors); type B components count as exactly known (infinite degrees of freedom) unless
        ``dof`` says otherwise (a component estimated from a few Monte Carlo draws), and the coverage factor
        is ``k = t_0.975(nu_eff)`` at the Welch-Satterthwaite effective degrees of freedom.

        Parameters
        ----------
        contributions:
            Source -> standard uncertainty of the parameter from that source (sign ignored).
        dof:
            Source -> degrees of freedom of that contribution (missing: infinite).
        keep:
            Keep the components already in the budget that ``contributions`` does not name (e.g. a method's own
            calibration term, set when the parameter was estimated), with their degrees of freedom.
        """
        if keep:
            contributions = {**self.type_b, **contributions}
            dof = {**self.type_b_dof, **(dof or {})}
        self.type_b = {k: abs(float(v)) for k, v in contributions.items() if math.isfinite(v)}
        self.type_b_dof = {k: float(v) for k, v in (dof or {}).items() if k in self.type_b}
        u_b = math.sqrt(sum(v * v for v in self.type_b.values()))
        self.u_type_b = u_b
        se = self.std_error
        if not math.isfinite(se):
            self.u_total = float("nan")
            self.ci95_total = (float("nan"), float("nan"))
            return
        self.u_total = math.sqrt(se * se + u_b * u_b)
        dof = dof or {}
        terms = [(se, dof_of_interval(self.ci95, se))] + [(v, dof.get(k, math.inf)) for k, v in self.type_b.items()]
        k = coverage_factor(self.u_total, terms)
        self.ci95_total = (self.value - k * self.u_total, self.value + k * self.u_total)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        d = asdict(self)
        d["ci95"] = list(self.ci95)
        d["ci95_total"] = list(self.ci95_total) if self.ci95_total is not None else None
        d["type_b"] = {k: v for k, v in self.type_b.items() if math.isfinite(v)}
        d.pop("type_b_dof", None)
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


@dataclass
class FitResult:
    """The result of one fit.

    Attributes
    ----------
    params:
        Name -> :class:`ParameterEstimate`.
    r2, adj_r2, rmse:
        Goodness of fit over the points used.
    n_points, n_excluded:
        Points used and points excluded (clipped, flagged, outside the model's domain).
    segments:
        Segments the points came from.
    status, reasons:
        ``"ok"`` or ``"flagged"`` and the reasons.
    data:
        Arrays for figures and reports (``x``, ``y``, ``y_fit`` ...).
    """

    params: dict[str, ParameterEstimate]
    r2: float
    adj_r2: float
    rmse: float
    n_points: int
    n_excluded: int = 0
    segments: list[str] = field(default_factory=list)
    status: str = "ok"
    reasons: list[str] = field(default_factory=list)
    data: dict[str, np.ndarray] = field(default_factory=dict)

    def __getitem__(self, name: str) -> ParameterEstimate:
        return self.params[name]

    def value(self, name: str) -> float:
        """Estimate of parameter ``name``."""
        return self.params[name].value

    def flag(self, reason: str) -> None:
        """Mark the fit and all its parameters as flagged with ``reason``."""
        self.status = "flagged"
        self.reasons.append(reason)
        for p in self.params.values():
            p.status = "flagged"
            p.reason = "; ".join(self.reasons)

    def add(self, param: ParameterEstimate) -> None:
        """Add a (derived) parameter."""
        if self.status != "ok":
            param.status, param.reason = self.status, "; ".join(self.reasons)
        self.params[param.name] = param

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (without the figure arrays)."""
        def clean(x: float) -> float | None:
            return x if math.isfinite(x) else None

        return {
            "params": {k: p.to_dict() for k, p in self.params.items()},
            "r2": clean(self.r2),
            "adj_r2": clean(self.adj_r2),
            "rmse": clean(self.rmse),
            "n_points": self.n_points,
            "n_excluded": self.n_excluded,
            "segments": list(self.segments),
            "status": self.status,
            "reasons": list(self.reasons),
        }


@dataclass
class IdentificationResult:
    """Every fit of an identification run, by subsystem and fit name (``transmission.gear5``)."""

    fits: dict[str, FitResult] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    def parameters(self) -> dict[str, ParameterEstimate]:
        """Flat ``fit.param`` -> estimate mapping."""
        return {f"{fk}.{pk}": p for fk, fit in self.fits.items() for pk, p in fit.params.items()}

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict: every fit with its parameters and statistics, plus errors."""
        return {
            "fits": {k: f.to_dict() for k, f in self.fits.items()},
            "errors": dict(self.errors),
            "meta": self.meta,
        }


def r_squared(y: np.ndarray, y_fit: np.ndarray, n_params: int = 1) -> tuple[float, float]:
    """Coefficient of determination and its adjusted form.

    Returns
    -------
    r2, adj_r2
        ``1 - SS_res/SS_tot`` (SS_tot about the mean of ``y``) and
        ``1 - (1 - r2)(n - 1)/(n - p)``; NaN when undefined.
    """
    y = np.asarray(y, dtype=float)
    y_fit = np.asarray(y_fit, dtype=float)
    n = y.size
    ss_res = float(np.sum((y - y_fit) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2)) if n else 0.0
    if n < 2 or ss_tot <= 0.0:
        return float("nan"), float("nan")
    r2 = 1.0 - ss_res / ss_tot
    adj = 1.0 - (1.0 - r2) * (n - 1) / (n - n_params) if n > n_params else float("nan")
    return r2, adj


def _check_design(A: np.ndarray, names: Sequence[str], min_points: int, cond_max: float,
                  what: str) -> None:
    n, p = A.shape
    if n < max(min_points, p + 1):
        raise InsufficientDataError(
            f"{what}: {n} usable points for {p} parameters ({', '.join(names)}); need at least "
            f"{max(min_points, p + 1)}"
        )
    scale = np.sqrt(np.sum(A**2, axis=0))
    dead = [nm for nm, s in zip(names, scale) if not s > 0]
    if dead:
        raise NoExcitationError(f"{what}: regressor(s) for {', '.join(dead)} are all zero")
    # a regressor that is a constant multiple of the all-ones vector is fine (intercept); a
    # regressor that does not vary *relative to another constant column* is collinear: checked
    # by the condition number of the column-normalised design
    An = A / scale
    sv = np.linalg.svd(An, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    if cond > cond_max:
        raise CollinearError(
            f"{what}: regressors for {', '.join(names)} are nearly collinear (condition number "
            f"{cond:.3g} > {cond_max:.3g}); the data do not separate these parameters"
        )


def serial_inflation(resid: np.ndarray) -> tuple[float, float]:
    """Lag-1 autocorrelation of time-ordered residuals and the variance inflation it implies.

    Residuals of a fit over consecutive samples of a time series are not independent: with an AR(1)
    correlation ``rho`` the variance of a mean (and, to first order, of least-squares estimates) grows by
    ``(1 + rho) / (1 - rho)`` over the independent-samples formula, i.e. the data hold
    ``n_eff = n (1 - rho) / (1 + rho)`` independent points. ``rho`` is clipped to ``[0, 0.999]``.

    Returns
    -------
    rho, factor
        The lag-1 autocorrelation and the variance inflation factor (>= 1).
    """
    r = np.asarray(resid, dtype=float)
    r = r[np.isfinite(r)]
    if r.size < 3:
        return 0.0, 1.0
    r = r - r.mean()
    den = float(r @ r)
    rho = float(r[1:] @ r[:-1]) / den if den > 0 else 0.0
    rho = min(max(rho, 0.0), 0.999)
    return rho, (1.0 + rho) / (1.0 - rho)


def linear_fit(
    A: np.ndarray,
    b: np.ndarray,
    names: Sequence[str],
    *,
    units: Sequence[str] | None = None,
    segments: Sequence[str] = (),
    min_points: int = 3,
    cond_max: float = 1e7,
    n_excluded: int = 0,
    what: str = "fit",
    weights: np.ndarray | None = None,
    serial: bool = False,
) -> FitResult:
    """Ordinary (or weighted) least squares ``A x = b`` with full statistics.

    Parameters
    ----------
    A:
        Design matrix ``(n, p)``.
    b:
        Observations ``(n,)``.
    names, units:
        Parameter names and units, one per column.
    segments:
        Segment names the rows came from.
    min_points:
        Minimum number of rows (at least ``p + 1`` in any case).
    cond_max:
        Largest accepted condition number of the column-normalised design.
    n_excluded:
        Rows the caller excluded before the fit (reported, not used).
    what:
        Name of the fit, for messages.
    weights:
        Optional per-row weights (1/variance).
    serial:
        The rows are consecutive samples of a time series (in time order): the covariance is inflated
        for the residuals' serial correlation (:func:`serial_inflation`) and the Student-t quantile uses
        the effective number of points, so the intervals do not claim the precision of independent
        samples that the data do not have.

    Returns
    -------
    FitResult
        Estimates with standard errors from ``s^2 (A^T A)^-1`` and Student-t 95 % intervals.

    Raises
    ------
    InsufficientDataError, NoExcitationError, CollinearError
        When the data cannot support the fit.
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    if A.ndim != 2 or b.shape != (A.shape[0],):
        raise ValueError(f"{what}: A {A.shape} and b {b.shape} do not match")
    finite = np.all(np.isfinite(A), axis=1) & np.isfinite(b)
    n_nonfinite = int((~finite).sum())
    A, b = A[finite], b[finite]
    w = None
    if weights is not None:
        w = np.sqrt(np.asarray(weights, dtype=float)[finite])
    p = A.shape[1]
    _check_design(A, names, min_points, cond_max, what)
    Aw, bw = (A * w[:, None], b * w) if w is not None else (A, b)
    x, *_ = np.linalg.lstsq(Aw, bw, rcond=None)
    y_fit = A @ x
    resid = bw - Aw @ x
    n = A.shape[0]
    dof = n - p
    s2 = float(resid @ resid) / dof if dof > 0 else float("nan")
    try:
        cov = s2 * np.linalg.inv(Aw.T @ Aw)
    except np.linalg.LinAlgError:
        cov = np.full((p, p), np.nan)
    rho, inflation = serial_inflation(resid) if serial else (0.0, 1.0)
    cov = cov * inflation
    dof_t = max(int(n / inflation) - p, 1) if serial else dof
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    tq = t975(dof_t) if dof > 0 else float("nan")
    r2, adj = r_squared(b, y_fit, p)
    rmse = float(np.sqrt(np.mean((b - y_fit) ** 2)))
    units = list(units) if units is not None else [""] * p
    params = {
        nm: ParameterEstimate(nm, float(x[i]), float(se[i]), (float(x[i] - tq * se[i]), float(x[i] + tq * se[i])),
                              r2, n, units[i], list(segments))
        for i, nm in enumerate(names)
    }
    res = FitResult(params, r2, adj, rmse, n, n_excluded + n_nonfinite, list(segments),
                    data={"A": A, "y": b, "y_fit": y_fit})
    res.data["cov"] = cov
    if serial:
        res.data["serial_rho"] = np.array([rho])
        res.data["n_effective"] = np.array([n / inflation])
    return res


def nonlinear_fit(
    residual: Callable[[np.ndarray], np.ndarray],
    x0: Sequence[float],
    names: Sequence[str],
    y: np.ndarray,
    *,
    units: Sequence[str] | None = None,
    bounds: tuple[Sequence[float], Sequence[float]] | None = None,
    segments: Sequence[str] = (),
    min_points: int = 5,
    n_excluded: int = 0,
    what: str = "fit",
    x_scale: Sequence[float] | str = "jac",
) -> FitResult:
    """Nonlinear least squares with scipy, statistics from the Jacobian at the optimum.

    Parameters
    ----------
    residual:
        ``f(x) -> y_model - y`` over the points used.
    x0:
        Starting point.
    names, units:
        Parameter names and units.
    y:
        The observations (for R^2).
    bounds:
        Optional ``(lower, upper)``.

    Raises
    ------
    InsufficientDataError
        Too few points.
    FitFailedError
        The optimiser did not converge.
    CollinearError
        The Jacobian is rank deficient at the optimum (parameters not separable).
    """
    y = np.asarray(y, dtype=float)
    n, p = y.size, len(names)
    if n < max(min_points, p + 1):
        raise InsufficientDataError(f"{what}: {n} usable points for {p} parameters; need {max(min_points, p + 1)}")
    kw: dict[str, Any] = {"x_scale": x_scale}
    if bounds is not None:
        kw["bounds"] = bounds
    sol = optimize.least_squares(residual, np.asarray(x0, dtype=float), method="trf", **kw)
    if not sol.success:
        raise FitFailedError(f"{what}: optimiser did not converge ({sol.message})")
    J = sol.jac
    resid = sol.fun
    dof = n - p
    s2 = float(resid @ resid) / dof if dof > 0 else float("nan")
    sv = np.linalg.svd(J, compute_uv=False)
    if sv.size == 0 or sv[-1] <= sv[0] * 1e-10:
        raise CollinearError(f"{what}: parameters {', '.join(names)} are not separable from these data")
    cov = s2 * np.linalg.pinv(J.T @ J)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    tq = t975(dof)
    y_fit = y + resid
    r2, adj = r_squared(y, y_fit, p)
    rmse = float(np.sqrt(np.mean(resid**2)))
    units = list(units) if units is not None else [""] * p
    x = sol.x
    params = {
        nm: ParameterEstimate(nm, float(x[i]), float(se[i]), (float(x[i] - tq * se[i]), float(x[i] + tq * se[i])),
                              r2, n, units[i], list(segments))
        for i, nm in enumerate(names)
    }
    res = FitResult(params, r2, adj, rmse, n, n_excluded, list(segments), data={"y": y, "y_fit": y_fit})
    res.data["cov"] = cov
    return res


def derived(fit: FitResult, name: str, func: Callable[[np.ndarray], float], *, unit: str = "",
            step: float = 1e-6) -> ParameterEstimate:
    """A parameter computed from a fit's parameters, with delta-method uncertainty.

    Parameters
    ----------
    fit:
        The fit; its ``data['cov']`` is the covariance of its parameters in order.
    name:
        Name of the derived parameter.
    func:
        Function of the fit's parameter vector (in the order of ``fit.params``).

    Returns
    -------
    ParameterEstimate
        Added to ``fit`` as well.
    """
    x = np.array([p.value for p in fit.params.values()][: fit.data["cov"].shape[0]])
    cov = fit.data["cov"]
    val = float(func(x))
    grad = np.zeros_like(x)
    for i in range(x.size):
        h = step * max(1.0, abs(x[i]))
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        grad[i] = (func(xp) - func(xm)) / (2 * h)
    var = float(grad @ cov @ grad)
    se = math.sqrt(var) if var >= 0 and math.isfinite(var) else float("nan")
    dof = max(fit.n_points - x.size, 1)
    tq = t975(dof)
    est = ParameterEstimate(name, val, se, (val - tq * se, val + tq * se), fit.r2, fit.n_points, unit,
                            list(fit.segments))
    fit.add(est)
    return est
