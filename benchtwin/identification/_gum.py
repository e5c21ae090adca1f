"""GUM helpers: the coverage factor of a combined uncertainty and the degrees of freedom of a Student-t interval."""

from __future__ import annotations

import math

from scipy import optimize, stats

__all__ = ["Z95", "coverage_factor", "dof_of_interval"]

#: two-sided 95 % quantile of the normal distribution
Z95 = float(stats.norm.ppf(0.975))


def dof_of_interval(ci95: tuple[float, float], se: float) -> float:
    """Degrees of freedom of a Student-t 95 % interval of half-width ``t(nu) se`` (inf when <= the normal one)."""
    half = 0.5 * (float(ci95[1]) - float(ci95[0]))
    if not (se > 0 and math.isfinite(half)):
        return float("inf")
    k = half / se
    if k <= Z95 * (1.0 + 1e-9):
        return float("inf")
    if k >= float(stats.t.ppf(0.975, 1.0)):
        return 1.0
    return float(optimize.brentq(lambda nu: float(stats.t.ppf(0.975, nu)) - k, 1.0, 1e9))


def coverage_factor(dof_stat: float, u_stat: float, u_total: float) -> float:
    """Coverage factor of a 95 % interval of a combined uncertainty (Welch-Satterthwaite, JCGM 100 G.4).

    Parameters
    ----------
    dof_stat:
        Degrees of freedom of the statistical (type A) part.
    u_stat, u_total:
        The type A and the combined standard uncertainty; the rest (type B) has infinite degrees of freedom.

    Returns
    -------
    float
        ``t_0.975(nu_eff)`` with ``nu_eff = dof_stat (u_total / u_stat)^4`` (1.96 when infinite).
    """
    if not (u_stat > 0) or not math.isfinite(dof_stat):
        return Z95
    nu = dof_stat * (u_total / u_stat) ** 4
    return Z95 if nu > 1e9 else float(stats.t.ppf(0.975, max(nu, 1.0)))
