"""GUM helpers: the coverage factor of a combined uncertainty and the degrees of freedom of a Student-t interval."""

from __future__ import annotations

import math
from collections.abc import Iterable

from scipy import optimize, special, stats

__all__ = ["Z95", "coverage_factor", "dof_of_interval", "t975"]

#: two-sided 95 % quantile of the normal distribution
Z95 = float(stats.norm.ppf(0.975))


def t975(nu: float) -> float:
    """Two-sided 95 % quantile of Student's t with ``nu`` degrees of freedom (NaN for ``nu <= 0``).

    The same number as ``scipy.stats.t.ppf(0.975, nu)`` (whose ``_ppf`` is this ``special.stdtrit``) without the
    distribution object's argument handling, which costs a millisecond a call: the root search of
    :func:`dof_of_interval` and every fit call it hundreds of times per identification.
    """
    return float(special.stdtrit(nu, 0.975)) if nu > 0 else float("nan")


def dof_of_interval(ci95: tuple[float, float], se: float) -> float:
    """Degrees of freedom of a Student-t 95 % interval of half-width ``t(nu) se`` (inf when <= the normal one)."""
    half = 0.5 * (float(ci95[1]) - float(ci95[0]))
    if not (se > 0 and math.isfinite(half)):
        return float("inf")
    k = half / se
    if k <= Z95 * (1.0 + 1e-9):
        return float("inf")
    if k >= t975(1.0):
        return 1.0
    return float(optimize.brentq(lambda nu: t975(nu) - k, 1.0, 1e9))


def coverage_factor(u_total: float, terms: Iterable[tuple[float, float]]) -> float:
    """Coverage factor of a 95 % interval of a combined uncertainty (Welch-Satterthwaite, JCGM 100 G.4).

    Parameters
    ----------
    u_total:
        The combined standard uncertainty.
    terms:
        ``(u_i, nu_i)`` of every component: the statistical part with its degrees of freedom, type B
        components with ``inf`` (exactly known) or the number of Monte Carlo draws that estimated them.

    Returns
    -------
    float
        ``t_0.975(nu_eff)`` with ``nu_eff = u_total^4 / sum(u_i^4 / nu_i)`` (1.96 when infinite).
    """
    den = sum(u**4 / nu for u, nu in terms if u > 0 and math.isfinite(nu) and nu > 0)
    if not (den > 0) or not (u_total > 0):
        return Z95
    nu = u_total**4 / den
    return Z95 if nu > 1e9 else t975(max(nu, 1.0))
