"""GUM type B: the declared budget, its propagation through a fit, and the combined interval."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from benchtwin.chain.acquisition import declared_uncertainty
from benchtwin.config import scenario_path
from benchtwin.config.setup import load_setup
from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate
from benchtwin.identification._gum import coverage_factor, dof_of_interval
from benchtwin.identification.uncertainty import Component, components, dithered, propagate_type_b
from benchtwin.recording import Channel, Recording
from benchtwin.sensors.registry import devices
from benchtwin.sensors.telemetry import torque_step_nm


def test_welch_satterthwaite_by_hand() -> None:
    # u_A = 1 with 4 dof, u_B = 1 exact: nu_eff = u_c^4 / (u_A^4 / 4) = 4 * 4 = 16
    assert coverage_factor(math.sqrt(2.0), [(1.0, 4.0), (1.0, math.inf)]) == pytest.approx(stats.t.ppf(0.975, 16))
    assert coverage_factor(1.0, [(1.0, math.inf)]) == pytest.approx(1.959964, abs=1e-6)
    # a Monte Carlo component of 6 draws alone: t(6)
    assert coverage_factor(1.0, [(1.0, 6.0)]) == pytest.approx(stats.t.ppf(0.975, 6))
    assert dof_of_interval((-stats.t.ppf(0.975, 7), stats.t.ppf(0.975, 7)), 1.0) == pytest.approx(7.0, rel=1e-6)


def test_combine_type_b_widens_and_budget_is_kept() -> None:
    t = stats.t.ppf(0.975, 10)
    p = ParameterEstimate("x", 5.0, 0.3, (5.0 - t * 0.3, 5.0 + t * 0.3), 0.99, 12)
    assert p.ci95_total == pytest.approx(p.ci95) and p.u_total == pytest.approx(0.3)
    p.combine_type_b({"a.gain": 0.4, "b.offset": -1.2})
    assert p.u_type_b == pytest.approx(math.hypot(0.4, 1.2))
    assert p.u_total == pytest.approx(math.sqrt(0.09 + 0.16 + 1.44))
    nu = 10 * (p.u_total / 0.3) ** 4
    half = stats.t.ppf(0.975, nu) * p.u_total
    assert p.ci95_total == pytest.approx((5.0 - half, 5.0 + half))
    d = p.to_dict()
    assert d["type_b"] == {"a.gain": 0.4, "b.offset": 1.2} and len(d["ci95_total"]) == 2


def _rec(budget: dict | None, n: int = 500) -> Recording:
    t = np.arange(n) * 0.01
    x = 10.0 + np.sin(t)
    rec = Recording({"x": Channel("x", "Nm", t, x), "y": Channel("y", "Nm", t, 3.0 + 0 * t)})
    if budget is not None:
        rec.meta["declared_uncertainty"] = budget
    return rec


def _mean_fit(rec: Recording) -> IdentificationResult:
    """A toy 'method': theta = 2 mean(x) - mean(y), se 0.01."""
    v = 2 * float(np.mean(rec["x"].values)) - float(np.mean(rec["y"].values))
    fit = FitResult({"theta": ParameterEstimate("theta", v, 0.01, (v - 0.0196, v + 0.0196), 1.0, 500)}, 1.0, 1.0,
                    0.0, 500)
    return IdentificationResult(fits={"toy": fit})


def test_propagation_matches_the_analytic_sensitivities() -> None:
    budget = {"x": {"gain_frac": 0.01, "offset": 0.3, "resolution": 0.0},
              "y": {"gain_frac": 0.0, "offset": 0.6, "resolution": 0.0}}
    rec = _rec(budget)
    res = _mean_fit(rec)
    meta = propagate_type_b(res, rec, [({"toy"}, ["x", "y"], _mean_fit)])
    assert meta["declared"] and meta["reruns"] == 3
    p = res.fits["toy"].params["theta"]
    mean_x = float(np.mean(rec["x"].values))
    # d theta / d gain_x = 2 mean(x); d theta / d offset_x = 2; d theta / d offset_y = -1; u = a / sqrt(3)
    assert p.type_b["x.gain"] == pytest.approx(2 * mean_x * 0.01 / math.sqrt(3), rel=1e-9)
    assert p.type_b["x.offset"] == pytest.approx(2 * 0.3 / math.sqrt(3), rel=1e-9)
    assert p.type_b["y.offset"] == pytest.approx(0.6 / math.sqrt(3), rel=1e-9)
    assert p.ci95_total[0] < p.ci95[0] and p.ci95_total[1] > p.ci95[1]


def test_shared_declaration_moves_its_roles_together() -> None:
    budget = {"x": {"gain_frac": 0.0, "offset": 0.3, "resolution": 0.0, "group": "dev"},
              "y": {"gain_frac": 0.0, "offset": 0.3, "resolution": 0.0, "group": "dev"}}
    rec = _rec(budget)
    res = _mean_fit(rec)
    propagate_type_b(res, rec, [({"toy"}, ["x", "y"], _mean_fit)])
    # one correlated offset: 2 u - u = u (independent components would give sqrt(5) u)
    assert res.fits["toy"].params["theta"].type_b == {"dev.offset": pytest.approx(0.3 / math.sqrt(3), rel=1e-9)}


def test_no_declared_budget_leaves_the_statistical_interval() -> None:
    rec = _rec(None)
    res = _mean_fit(rec)
    meta = propagate_type_b(res, rec, [({"toy"}, ["x", "y"], _mean_fit)])
    p = res.fits["toy"].params["theta"]
    assert not meta["declared"] and "statistical" in meta["note"]
    assert p.ci95_total == p.ci95 and p.u_type_b == 0.0


def test_rounding_draws_move_a_steady_reading_as_a_whole_with_the_uniform_spread() -> None:
    q = 2.0
    rec = _rec({"y": {"gain_frac": 0.0, "offset": 0.0, "resolution": q}})
    (comp,) = components(rec, ["y"])
    assert comp == Component("resolution", ("y",), "resolution", 0.0, (q,))
    rng = np.random.default_rng(3)
    shifts = []
    for _ in range(2000):
        v = dithered(rec, comp, rng)["y"].values - 3.0
        assert np.ptp(v) == 0.0  # one level, one rounding error
        shifts.append(v[0])
    # the standard deviation of U(-q/2, q/2) is q/sqrt(12); 2000 draws estimate it within ~1.6 % (1 sigma)
    assert np.std(shifts) == pytest.approx(q / math.sqrt(12), rel=0.06)
    assert np.max(np.abs(shifts)) <= q / 2


def test_acquisition_declares_the_paper_bench_budget() -> None:
    setup = load_setup(scenario_path("setups", "paper.toml"))
    roles = {"shaft_torque_nm", "engine_torque_nm", "brake_pressure_fl_bar", "brake_pressure_rr_bar",
             "battery_current_a"}
    b = declared_uncertainty(devices(setup), roles)
    assert b["shaft_torque_nm"]["gain_frac"] == pytest.approx(0.005)
    assert b["shaft_torque_nm"]["resolution"] == pytest.approx(torque_step_nm(setup.telemetry.shaft,
                                                                              setup.telemetry.k_tel))
    assert b["engine_torque_nm"]["gain_frac"] == pytest.approx(0.02) and b["engine_torque_nm"]["offset"] == 3.0
    assert b["brake_pressure_fl_bar"]["group"] == b["brake_pressure_rr_bar"]["group"] == "pressure"
    assert "group" not in b["battery_current_a"]
    assert set(b) == roles
