"""The cold-start fuel factor (identification.engine_cold) and the map model's warm-up (validation.cold_start)."""

from __future__ import annotations

import numpy as np

from benchtwin.identification._fit import IdentificationResult
from benchtwin.identification.engine_cold import COLD_KEY, WARMUP_KEY, cold_factor, fit_cold_factor
from benchtwin.validation.cold_start import ColdStart, cold_start_model


def _points(k: float, t_warm: float, n: int = 120, sigma: float = 0.005, seed: int = 3) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    t = np.concatenate([rng.uniform(23.0, 80.0, n // 3), rng.uniform(82.0, 92.0, n - n // 3)])
    return cold_factor(k, t_warm, t) * (1.0 + rng.normal(0.0, sigma, t.size)), t


def test_factor_recovered_from_synthetic_points() -> None:
    # truth of the high-fidelity engine: +12 % at 20 degC, none from 80 degC -> k = 0.12 / 60 = 0.002 /K.
    # 40 cold points over ~57 K with 0.5 % noise: SE(b) ~ 0.005 / (sqrt(40) 16 K) ~ 5e-5; 1.5e-4 is 3 SE
    r, t = _points(0.002, 80.0)
    fit = fit_cold_factor(r, t)
    assert fit.status == "ok"
    assert abs(fit.value("k") - 0.002) < 1.5e-4
    assert abs(float(fit.data["T_warm_degc"][0]) - 80.0) <= 3.0
    assert bool(fit.data["use"][0])
    assert abs(fit.value("a") - 1.0) < 0.003  # the warm ratio: 80 warm points, SE ~ 0.005 / 9


def test_no_cold_points_flagged() -> None:
    rng = np.random.default_rng(4)
    t = rng.uniform(83.0, 92.0, 60)
    fit = fit_cold_factor(1.0 + rng.normal(0.0, 0.005, t.size), t)
    assert fit.status == "flagged"
    assert any("no cold points" in r for r in fit.reasons)
    assert not bool(fit.data["use"][0])
    model, note = cold_start_model(_result(fit))
    assert model is None and "no cold points" in note


def test_never_warm_flagged() -> None:
    # the quick campaign's engine: 23-37 degC throughout, so its "warm level" is no warm reference
    rng = np.random.default_rng(6)
    t = rng.uniform(23.0, 45.0, 60)
    fit = fit_cold_factor(cold_factor(0.002, 80.0, t), t)
    assert fit.status == "flagged" and any("no warm engine" in r for r in fit.reasons)
    assert not bool(fit.data["use"][0])


def test_warm_engine_factor_not_used() -> None:
    # cold points, but the fuel does not depend on the coolant (the paper-form engine): k's interval holds zero
    r, t = _points(0.0, 80.0, seed=5)
    fit = fit_cold_factor(r, t)
    assert abs(fit.value("k")) < 1.5e-4
    assert not bool(fit.data["use"][0])
    assert fit.status == "flagged" and any("not significant" in r for r in fit.reasons)
    assert cold_start_model(_result(fit))[0] is None


def _result(cold: object, warm: object | None = None) -> IdentificationResult:
    res = IdentificationResult()
    res.fits[COLD_KEY] = cold  # type: ignore[assignment]
    if warm is not None:
        res.fits[WARMUP_KEY] = warm  # type: ignore[assignment]
    return res


def test_warmup_follows_the_lumped_solution_and_the_factor() -> None:
    # dT/dt = h P - g T + c with constant heat: T(t) = T_ss + (T0 - T_ss) exp(-g t), T_ss = (h P + c) / g.
    # With the brake power equal to the fuel power less P the heat is P whatever the factor (k = 0 here).
    h, g, c, lhv, dt = 5e-6, 4.5e-4, 0.0104, 42.8e6, 0.1
    m = ColdStart(k_per_k=0.0, t_warm_degc=80.0, h_k_per_j=h, g_per_s=g, c_k_per_s=c, t_reg_degc=200.0)
    n = 20000
    warm = np.full(n, 1.5)  # g/s: 64.2 kW of fuel
    p_heat = 4e3  # T_ss = (0.02 + 0.0104) / 4.5e-4 = 67.6 degC
    brake = warm * 1e-3 * lhv - p_heat
    fuel, temp = m.run(warm, brake, np.ones(n, bool), dt, 23.0, lhv)
    tt = np.arange(n) * dt
    t_ss = (h * p_heat + c) / g
    exact = t_ss + (23.0 - t_ss) * np.exp(-g * tt)
    # explicit Euler: relative error of the decay ~ g dt / 2 = 2e-5 per unit of (T_ss - T0) ~ 0.01 K
    assert np.max(np.abs(temp - exact)) < 0.05
    assert np.allclose(fuel, warm)
    # the thermostat: held at the regulated level
    m_reg = ColdStart(0.0, 80.0, h, g, c, t_reg_degc=60.0)
    long = np.full(3 * n, 1.5)  # 6000 s: the free solution would pass 60 degC after ~2700 s
    _, temp_reg = m_reg.run(long, long * 1e-3 * lhv - p_heat, np.ones(3 * n, bool), dt, 23.0, lhv)
    assert temp_reg.max() <= 60.0 + 1e-9 and temp_reg[-1] > 59.9
    # the factor on the predicted coolant: 1 + k (T_warm - T) at each sample, 1 when warm
    m_k = ColdStart(0.002, 80.0, h, g, c, t_reg_degc=200.0)
    fuel_k, temp_k = m_k.run(warm, brake, np.ones(n, bool), dt, 23.0, lhv)
    assert np.allclose(fuel_k, warm * (1.0 + 0.002 * np.maximum(80.0 - temp_k, 0.0)))
    assert fuel_k[0] == 1.5 * (1.0 + 0.002 * 57.0)
    # an engine that never fires: no fuel, the coolant cools to T_env = c / g
    off, temp_off = m_k.run(warm, brake, np.zeros(n, bool), dt, 50.0, lhv)
    assert not off.any() and temp_off[-1] < 50.0 and temp_off[-1] > c / g
