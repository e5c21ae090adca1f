"""The empirical converter table (torque_converter.table) and the converter points' drag at the oil temperature.

Runs in about 3 s.
"""

from __future__ import annotations

import numpy as np
import pytest
from _synth_b import SPECS, TRANSMISSION_TRUTH, tc_recording, tc_truth_vector

from benchtwin.identification._fit import FitResult, ParameterEstimate
from benchtwin.identification.torque_converter import fit_torque_converter, identify_torque_converter
from benchtwin.identification.torque_converter_table import table_pump, table_torques
from benchtwin.recording import Channel

# a JDMA-shaped converter (the high-fidelity vehicle file's table): TR falls linearly to 1 at SR 0.9, the
# capacity (30/pi)^2 / K^2 is piecewise linear over SR (as the plant interpolates it) and vanishes at SR 1
SR = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95, 1.0])
K = np.array([110.0, 111.7, 113.8, 116.2, 119.9, 124.7, 131.2, 139.6, 150.3, 160.5, 173.1, 231.9, 1.0e4])
TR = np.array([2.0, 1.88, 1.77, 1.66, 1.55, 1.43, 1.32, 1.21, 1.10, 1.04, 1.0, 1.0, 1.0])
CAP = (30.0 / np.pi) ** 2 / K**2
NOISE = 0.01  # relative torque noise (1 sigma) on each of T_p and T_t
BIN = 0.025  # the table's default bin width


def _points(n: int = 4000, seed: int = 3) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    sr = rng.uniform(0.02, 0.94, n)
    w_p = rng.uniform(120.0, 260.0, n)
    t_p = np.interp(sr, SR, CAP) * w_p**2
    t_t = np.interp(sr, SR, TR) * t_p
    return (w_p, sr * w_p, t_p * (1 + NOISE * rng.standard_normal(n)), t_t * (1 + NOISE * rng.standard_normal(n)))


@pytest.fixture(scope="module")
def jdma() -> dict[str, FitResult]:
    return fit_torque_converter(*_points())


def _bound(table: FitResult, truth_sr: np.ndarray, truth_y: np.ndarray, sigma: float) -> np.ndarray:
    """Per node: 4 standard errors of a bin median (1.2533 sigma / sqrt(n)) plus the true curve's largest departure
    from its value at the node's SR within one bin (the bin's spread of the true curve: a median of a monotone curve
    over a bin is the curve at the median SR only where the curve is straight)."""
    s, n = table.data["sr_nodes"][:-1], table.data["n_nodes"][:-1]
    s, n = s[n > 0], n[n > 0]  # the nodes of the bins (not the stall node carried to SR 0)
    span = np.array([np.ptp(np.interp(np.linspace(x - BIN, x + BIN, 41), truth_sr, truth_y)) for x in s]) / 2
    return 4 * 1.2533 * sigma * np.interp(s, truth_sr, truth_y) / np.sqrt(n) + span


def test_table_recovers_the_tabulated_curves_within_the_point_scatter(jdma):
    tab = jdma["table"]
    binned = tab.data["n_nodes"] > 0  # the last node is SR 1 (no torque), set by the model
    s = tab.data["sr_nodes"][binned]
    assert tab.data["sr_nodes"][-1] == 1.0 and tab.data["cap_nodes"][-1] == 0.0
    # TR = T_t / T_p carries both torques' noise: sqrt(2) x 1 %
    err_tr = np.abs(tab.data["tr_nodes"][binned] - np.interp(s, SR, TR))
    assert np.all(err_tr <= _bound(tab, SR, TR, np.sqrt(2) * NOISE))
    err_cap = np.abs(tab.data["cap_nodes"][binned] - np.interp(s, SR, CAP))
    assert np.all(err_cap <= _bound(tab, SR, CAP, NOISE))
    # closer to the points than eq. 35-36's quadratics (the map-based model's rule for using it)
    assert bool(tab.data["better_than_eq35"][0])


def test_table_slip_loss_at_given_turbine_points(jdma):
    # a WLTC-like spread of operating points through the converter: the slip loss T_p w_p - T_t w_t
    rng = np.random.default_rng(11)
    sr = rng.uniform(0.6, 0.93, 500)
    w_p = rng.uniform(120.0, 220.0, 500)
    t_p = np.interp(sr, SR, CAP) * w_p**2
    t_t = np.interp(sr, SR, TR) * t_p
    w_t = sr * w_p
    loss = np.sum(t_p * w_p - t_t * w_t)
    wp_tab, tp_tab = table_pump(jdma["table"], w_t, t_t)
    err_tab = np.sum(tp_tab * wp_tab - t_t * w_t) / loss - 1
    # the loss is ~(1 - TR SR) T_p w_p; at SR 0.8 a TR node off by 4 standard errors of a median of ~100 points of
    # 1.4 % scatter (0.7 % of TR) is 0.8 x 0.7 % / (1 - 0.88) = 5 % of the loss
    assert abs(err_tab) < 0.05


def test_table_pump_inverts_table_torques(jdma):
    rng = np.random.default_rng(2)
    w_t = np.r_[0.0, rng.uniform(0.0, 200.0, 200)]
    t_t = np.r_[150.0, rng.uniform(5.0, 300.0, 200)]
    w_p, t_p = table_pump(jdma["table"], w_t, t_t)
    tp2, tt2 = table_torques(jdma["table"], w_p, w_t)
    np.testing.assert_allclose(tt2, t_t, rtol=2e-3)
    np.testing.assert_allclose(tp2, t_p, rtol=2e-3)
    assert np.all(w_p >= w_t)
    # overrun and zero torque are left rigid
    w_p0, t_p0 = table_pump(jdma["table"], np.array([100.0, 100.0]), np.array([0.0, -20.0]))
    np.testing.assert_array_equal(w_p0, [100.0, 100.0])
    np.testing.assert_array_equal(t_p0, [0.0, -20.0])


def test_table_not_preferred_on_eq35_shaped_points():
    # the paper-form plant's converter is eq. 35-36 itself: the table must not replace it
    rec, _ = tc_recording(noise_nm=1.5, seed=5)
    res = identify_torque_converter(rec, SPECS, transmission=TRANSMISSION_TRUTH)
    assert not bool(res["table"].data["better_than_eq35"][0])


def _drag_fit(gear: int, eta: float, c0_ref: float, k_t: float, t_ref: float) -> FitResult:
    fit = FitResult({}, float("nan"), float("nan"), float("nan"), 100, data={"use": np.array([True])})
    for name, v in (("k_T", k_t), ("k_w", 0.0), ("T_ref", t_ref), (f"eta_m_g{gear}", eta), (f"C0_g{gear}", c0_ref)):
        fit.add(ParameterEstimate(name, v, 0.0, (v, v), float("nan"), 100, "", []))
    return fit


def test_turbine_torque_from_the_drag_at_the_logged_oil_temperature():
    # the gearbox's drag at the take-offs' 110 degC is a third of eq. 14's C0 identified with cold oil (70 degC)
    eta, c0_cold, k_t, t_cold, oil = 0.968, 6.0, 0.012, 70.0, 110.0
    c0_hot = c0_cold * np.exp(-k_t * (oil - t_cold))
    rec, truth = tc_recording(noise_nm=0.0, transmission={1: (eta, c0_hot)})
    t = rec["em_speed_rpm"].timestamps
    rec.add(Channel("gearbox_oil_degc", "degC", t, np.full(t.size, oil), source="thermo"))
    cold = {1: (eta, c0_cold)}
    res = identify_torque_converter(rec, SPECS, transmission=cold, calibrate_turbine_torque=False,
                                    drag=_drag_fit(1, eta, c0_cold, k_t, t_cold))
    a = tc_truth_vector()
    got = [res["converter"].value(f"a{k}") for k in range(6)]
    np.testing.assert_allclose(got, a[:6], rtol=1e-3, atol=1e-3 * np.abs(a).max())
    assert res["converter"].value("gamma_coupling") == pytest.approx(truth["gamma"], rel=1e-3)
    # eq. 14's cold C0 overstates every turbine torque by C0_cold - C0_hot (3.1 Nm): the stall ratio a3 / a0 high
    res14 = identify_torque_converter(rec, SPECS, transmission=cold, calibrate_turbine_torque=False)
    got14 = np.array([res14["converter"].value(f"a{k}") for k in range(6)])
    assert np.max(np.abs(got14 - a[:6])) > 10 * 1e-3 * np.abs(a).max()


def test_table_curves_are_monotone_on_sparse_noisy_points():
    # 5 % scatter on 400 points: the bin medians alone zig-zag; the converter's curves do not
    rng = np.random.default_rng(4)
    w_p, w_t, t_p, t_t = _points(n=400, seed=4)
    t_p = t_p * (1 + 0.05 * rng.standard_normal(t_p.size))
    tab = fit_torque_converter(w_p, w_t, t_p, t_t, outlier_sigma=None)["table"]
    assert np.all(np.diff(tab.data["tr_nodes"]) <= 0) and np.all(tab.data["tr_nodes"] >= 1.0)
    assert np.all(np.diff(tab.data["cap_nodes"]) <= 0)


def test_table_reaches_the_stall_along_its_first_nodes():
    """Points from SR 0.04 up and two stall take-offs below it (the high-fidelity paper run's converter points):
    the table's curves at SR 0 follow its first nodes' line, and beat eq. 35-36 on the points. Held flat below the
    first node (as before), TR at stall was 0.05 low, its ~14 Nm turbine-torque residuals on the two stall points
    made the SR bin [0, 0.025) the worst of the score (each bin weighs alike), and eq. 35-36 were preferred."""
    rng = np.random.default_rng(3)
    sr = np.r_[rng.uniform(0.0, 0.015, 2), rng.uniform(0.04, 0.94, 4000)]
    w_p = rng.uniform(120.0, 260.0, sr.size)
    t_p = np.interp(sr, SR, CAP) * w_p**2
    t_t = np.interp(sr, SR, TR) * t_p
    noisy = (t_p * (1 + NOISE * rng.standard_normal(sr.size)), t_t * (1 + NOISE * rng.standard_normal(sr.size)))
    tab = fit_torque_converter(w_p, sr * w_p, *noisy)["table"]
    d = tab.data
    assert d["sr_nodes"][0] == 0.0 and d["n_nodes"][0] == 0
    # 4 standard errors of a count-weighted line's value at SR 0 through the first three bin nodes (each a median of
    # n points: 1.2533 sigma / sqrt(n)); the true curves are straight over SR 0-0.1 (TR 2.0 -> 1.88), so no bias
    s, n = d["sr_nodes"][1:4], d["n_nodes"][1:4]
    x = np.c_[np.ones(3), s]
    for y_true, sigma, y in ((TR[0], np.sqrt(2) * NOISE, d["tr_nodes"]), (CAP[0], NOISE, d["cap_nodes"])):
        var_node = (1.2533 * sigma * y_true) ** 2 / n
        cov = np.linalg.inv(x.T @ (x / var_node[:, None]))
        bound = 4 * np.sqrt(cov[0, 0])
        assert abs(y[0] - y_true) <= bound
        assert abs(y[1] - y_true) > bound  # the first node's value (the curve held flat) is outside it
    assert bool(d["better_than_eq35"][0])
