"""The resolution term's Monte Carlo estimate: its spread is what its stated degrees of freedom say, and the total
interval that carries them (Welch-Satterthwaite) holds the truth 95 % of the time.

A toy bench: ``K`` plateaus of a reading ``y`` at true values far apart (more than two rounding levels), recorded
rounded to the step ``q`` with no noise, so each plateau holds one rounding error, uniform in ``+-q/2`` over the
drawn true values (JCGM 100 F.2.2.1). The toy method is the least-squares intercept of the plateau means against
a known ``x``: a linear function ``theta = w . y`` with ``w`` known, so the resolution term is known analytically,
``u = q / sqrt(12) * |w|``, independently of the propagation, which is the reference of both tests.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate
from benchtwin.identification.uncertainty import RESOLUTION_DRAWS, propagate_type_b
from benchtwin.recording import Channel, Recording

K, SAMPLES, Q = 8, 20, 0.5
X = np.linspace(1.0, 8.0, K)
#: the intercept's weights of an ordinary least-squares line through (X, y): theta = W . y
_A = np.column_stack([np.ones(K), X])
W = np.linalg.solve(_A.T @ _A, _A.T)[0]
U_TRUE = Q / math.sqrt(12.0) * float(np.linalg.norm(W))
TRIALS = 600


def _toy(rec: Recording) -> IdentificationResult:
    means = rec["y"].values.reshape(K, SAMPLES).mean(axis=1)
    v = float(W @ means)
    tiny = 1e-12 * U_TRUE  # no statistical part: the interval is the resolution term's alone
    p = ParameterEstimate("theta", v, tiny, (v - 1.959964 * tiny, v + 1.959964 * tiny), 1.0, K)
    return IdentificationResult(fits={"toy": FitResult({"theta": p}, 1.0, 1.0, 0.0, K)})


def _trial(seed: int, draws: int | None = None) -> tuple[float, ParameterEstimate, float]:
    """One bench: plateaus 20 steps apart plus a uniform position; the estimate, with its budget, and the truth."""
    rng = np.random.default_rng(seed)
    true = 10.0 + 20.0 * Q * np.arange(K) + rng.uniform(0.0, 20.0 * Q, K) * 0.5
    recorded = Q * np.round(np.repeat(true, SAMPLES) / Q)
    t = np.arange(K * SAMPLES) * 0.1
    rec = Recording({"y": Channel("y", "Nm", t, recorded)})
    rec.meta["declared_uncertainty"] = {"y": {"gain_frac": 0.0, "offset": 0.0, "resolution": Q}}
    res = _toy(rec)
    propagate_type_b(res, rec, [(["toy"], ["y"], _toy)], workers=1, draws=draws)
    return float(W @ true), res.fits["toy"].params["theta"], seed


@pytest.fixture(scope="module")
def trials() -> list[tuple[float, ParameterEstimate, float]]:
    return [_trial(s) for s in range(TRIALS)]


def test_the_spread_of_the_term_is_that_of_its_stated_degrees_of_freedom(trials) -> None:
    r2 = np.array([(p.type_b["resolution"] / U_TRUE) ** 2 for _, p, _ in trials])
    n = trials[0][1].type_b_dof["resolution"]
    assert n == RESOLUTION_DRAWS
    # the mean of n squared draws of delta = w . e (e uniform, independent): E = U_TRUE^2 (unbiased), and its
    # relative variance (kurt(delta) - 1) / n with kurt(delta) = 3 - 1.2 sum w^4 / (sum w^2)^2 (a sum of uniforms)
    kurt = 3.0 - 1.2 * float(np.sum(W**4) / np.sum(W**2) ** 2)
    sd = math.sqrt((kurt - 1.0) / n)
    z = stats.norm.ppf(0.9995)
    assert abs(r2.mean() - 1.0) < z * sd / math.sqrt(TRIALS)
    # the sample sd of TRIALS values: its relative standard error is about sqrt((kurt(r2) - 1) / (4 TRIALS)), with
    # kurt(r2) = 3 + 12 / n for a scaled chi-square (5 at n = 6): 4.1 %; 15 % is about 3.6 of them
    assert 0.85 * sd < r2.std(ddof=1) < 1.15 * sd


def test_the_total_interval_with_the_terms_degrees_of_freedom_holds_the_truth(trials) -> None:
    inside = sum(p.ci95_total[0] <= truth <= p.ci95_total[1] for truth, p, _ in trials)
    # 95 % intervals: at least the 0.1 % quantile of Binomial(TRIALS, 0.95) (the intervals taken as exact 95 %:
    # the coverage factor t(n) of a Welch-Satterthwaite interval whose only term has n degrees of freedom)
    assert inside >= stats.binom.ppf(0.001, TRIALS, 0.95)
    # and the term's width is not inflated: at most the 99.9 % quantile
    assert inside <= stats.binom.ppf(0.999, TRIALS, 0.95)


def test_more_draws_narrow_the_spread_and_are_stated() -> None:
    many = [(_trial(s, draws=24)[1].type_b["resolution"] / U_TRUE) ** 2 for s in range(200)]
    kurt = 3.0 - 1.2 * float(np.sum(W**4) / np.sum(W**2) ** 2)
    assert np.std(many, ddof=1) < 1.2 * math.sqrt((kurt - 1.0) / 24)
    rec = Recording({"y": Channel("y", "Nm", np.arange(K * SAMPLES) * 0.1, np.zeros(K * SAMPLES))})
    rec.meta["declared_uncertainty"] = {"y": {"gain_frac": 0.0, "offset": 0.0, "resolution": Q}}
    meta = propagate_type_b(_toy(rec), rec, [(["toy"], ["y"], _toy)], workers=1, draws=24)
    assert meta["resolution_draws"] == 24 and meta["resolution_rel_u"] == pytest.approx(1 / math.sqrt(48), abs=1e-4)
    with pytest.raises(ValueError, match="at least 2"):
        propagate_type_b(_toy(rec), rec, [(["toy"], ["y"], _toy)], draws=1)
