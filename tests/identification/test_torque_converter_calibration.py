"""The turbine-torque calibration's uncertainty in the converter parameters' budget.

The converter is fitted on turbine torques corrected by a scale measured on the lock-up-closed samples; the scale
carries a standard error ``s`` (the spread of the gears' medians). A scale error ``e`` moves the root of
``TR = 1`` by about ``e / |dTR/dSR|`` (about ``e / 2`` here), far beyond the fit's own standard error when the points
are many, so without this component the coupling point's total interval misses the truth most of the time.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from benchtwin.identification._fit import ParameterEstimate
from benchtwin.identification.torque_converter import fit_torque_converter, tc_torques
from benchtwin.identification.torque_converter_calibration import (
    SPEED_SCALE_SOURCE,
    TORQUE_SCALE_SOURCE,
    calibration_budget,
)
from benchtwin.identification.torque_converter_points import ConverterPoints

#: the paper campaign's vehicle's converter (scenarios/vehicles/p2_phev_9at.toml): TR = 1 at SR 0.85
A_TRUE = np.array([7.54e-3, 4.0e-4, -3.5e-3, 1.508e-2, -6.0e-3, -6.406574e-3, 3.5675e-2, -3.5675e-2, 0.0])
GAMMA = 0.85
#: relative standard error of the torque scale (0.2 %, about the paper campaign's ideal setup's 0.16 %)
SCALE_SE = 0.002
#: seeds (one drawn scale error and torque noise each)
N = 250
#: least intervals that must hold the truth: the 0.1 % quantile of Binomial(N, 0.95), which an honest 95 %
#: interval falls below once in a thousand suites, and above 90 % of N
MIN_INSIDE = int(stats.binom.ppf(0.001, N, 0.95))


def _points(seed: int) -> tuple[ConverterPoints, float]:
    """Converter points whose turbine torque carries the scale error drawn for ``seed``, and that error."""
    rng = np.random.default_rng(seed)
    n = 300
    sr = rng.uniform(0.05, 0.97, n)
    w_p = rng.uniform(120.0, 260.0, n)
    w_t = sr * w_p
    t_p, t_t = tc_torques(A_TRUE, GAMMA, w_p, w_t)
    e = rng.normal(0.0, SCALE_SE)  # what the calibration leaves of the turbine torque's gain error
    t_p = t_p + rng.normal(0.0, 0.5, n)
    t_t = t_t * (1.0 + e) + rng.normal(0.0, 0.5, n)
    keep = t_p > 20.0
    pts = ConverterPoints(np.arange(n)[keep] * 0.1, w_p[keep], w_t[keep], t_p[keep], t_t[keep], np.zeros(keep.sum()),
                          np.ones(keep.sum(), dtype=int), np.ones(keep.sum()), [], 0, 1.0, float("nan"), 0,
                          tscale=1.0, tscale_se=SCALE_SE, n_tcal=500)
    return pts, e


def _fit(pts: ConverterPoints, w_t: np.ndarray, t_t: np.ndarray) -> dict:
    return fit_torque_converter(pts.w_p, w_t, pts.t_p, t_t)


def _gamma(seed: int, budget: bool) -> ParameterEstimate:
    pts, _ = _points(seed)
    res = _fit(pts, pts.w_t, pts.t_t)
    if budget:
        calibration_budget(res, pts, lambda w_t, t_t: _fit(pts, w_t, t_t), 10)
    return res["converter"].params["gamma_coupling"]


def _inside(p: ParameterEstimate) -> bool:
    lo, hi = p.ci95_total
    return lo <= GAMMA <= hi


def test_the_coupling_points_total_interval_covers_the_truth_over_drawn_scale_errors():
    inside = sum(_inside(_gamma(seed, budget=True)) for seed in range(N))
    assert MIN_INSIDE >= 0.9 * N
    assert inside >= MIN_INSIDE, f"{inside}/{N} total intervals hold the coupling point"


def test_without_the_calibration_term_the_interval_misses():
    # the fit's own interval is the mutant "no calibration component": it must fail the same bound, else the
    # test above could not tell the term's presence
    inside = sum(_inside(_gamma(seed, budget=False)) for seed in range(N))
    assert inside < MIN_INSIDE


def test_the_component_is_named_and_about_the_scale_error_over_the_slope():
    p = _gamma(0, budget=True)
    assert set(p.type_b) == {TORQUE_SCALE_SOURCE}  # no speed calibration ran (its se is NaN)
    # independent estimate: dGamma/ds = -(dTR/ds)/(dTR/dSR) at Gamma, with dTR/ds = TR = 1
    a = A_TRUE
    num_d = a[4] + 2 * a[5] * GAMMA
    den = a[0] + a[1] * GAMMA + a[2] * GAMMA**2
    den_d = a[1] + 2 * a[2] * GAMMA
    slope = (num_d - den_d) / den  # dTR/dSR at Gamma, where TR = 1
    assert p.type_b[TORQUE_SCALE_SOURCE] == pytest.approx(SCALE_SE / abs(slope), rel=0.1)
    assert p.u_total == pytest.approx(math.hypot(p.std_error, p.type_b[TORQUE_SCALE_SOURCE]))


def test_the_speed_calibration_is_a_component_when_it_ran():
    pts, _ = _points(1)
    pts.scale_se, pts.n_cal = 1e-3, 400
    res = _fit(pts, pts.w_t, pts.t_t)
    calibration_budget(res, pts, lambda w_t, t_t: _fit(pts, w_t, t_t), 10)
    p = res["converter"].params["gamma_coupling"]
    # every SR 0.1 % high moves the root by 0.1 % of itself
    assert p.type_b[SPEED_SCALE_SOURCE] == pytest.approx(1e-3 * GAMMA, rel=0.1)


def test_a_later_budget_keeps_the_methods_own_components():
    p = ParameterEstimate("g", 1.0, 0.01, (0.98, 1.02), float("nan"), 10)
    p.combine_type_b({TORQUE_SCALE_SOURCE: 0.02}, {TORQUE_SCALE_SOURCE: 3.0})
    p.combine_type_b({"shaft_torque_nm.gain": 0.01}, keep=True)
    assert p.type_b == {TORQUE_SCALE_SOURCE: 0.02, "shaft_torque_nm.gain": 0.01}
    assert p.u_type_b == pytest.approx(math.hypot(0.02, 0.01))
    # 3 degrees of freedom on the dominant term: a wider coverage factor than the normal one
    half = 0.5 * (p.ci95_total[1] - p.ci95_total[0])
    assert half / p.u_total > 2.2
    assert "type_b_dof" not in p.to_dict()
    q = ParameterEstimate("g", 1.0, 0.01, (0.98, 1.02), float("nan"), 10)
    q.combine_type_b({TORQUE_SCALE_SOURCE: 0.02})
    q.combine_type_b({"shaft_torque_nm.gain": 0.01})
    assert set(q.type_b) == {"shaft_torque_nm.gain"}  # without keep the budget is replaced, as before
