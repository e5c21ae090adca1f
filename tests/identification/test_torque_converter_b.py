"""Torque converter identification (eq. 31-39) on synthetic Recordings from the model forms."""

from __future__ import annotations

import numpy as np
import pytest
from _synth_b import SPECS, TC_TRUTH, TRANSMISSION_TRUTH, tc_recording, tc_truth_vector

from benchtwin.errors import ConfigError, InsufficientDataError, MissingChannelError
from benchtwin.identification.torque_converter import (
    coupling_point,
    fit_torque_converter,
    identify_torque_converter,
    tc_torques,
)
from benchtwin.identification.torque_converter_points import unsettled
from benchtwin.recording import Channel, Flag, Recording


@pytest.fixture(scope="module")
def ideal():
    rec, truth = tc_recording()
    return rec, truth, identify_torque_converter(rec, SPECS, transmission=TRANSMISSION_TRUTH)


def test_coefficients_and_coupling_point_recovered(ideal):
    _, truth, res = ideal
    a = tc_truth_vector()
    got = [res["converter"].value(f"a{k}") for k in range(6)] + [res["coupling"].value(f"a{k}") for k in (6, 7, 8)]
    np.testing.assert_allclose(got, a, rtol=1e-3, atol=1e-3 * np.abs(a).max())
    np.testing.assert_allclose(res["converter"].value("gamma_coupling"), truth["gamma"], rtol=1e-3)
    assert res["converter"].status == "ok"
    assert res["torque_ratio"].r2 > 0.9999
    assert res["capacity_factor"].r2 > 0.9999
    assert res["capacity_factor_coupling"].r2 > 0.9999


def test_coupling_point_is_root_of_tr_equal_one():
    a = tc_truth_vector()
    assert coupling_point(a[:6]) == pytest.approx(TC_TRUTH["gamma"], rel=1e-9)


def test_noisy_torques_give_paper_like_curves():
    # 1.5 Nm (1 sigma) on the motor torque and the shaft torque referred to the input
    rec, truth = tc_recording(noise_nm=1.5, seed=5)
    res = identify_torque_converter(rec, SPECS, transmission=TRANSMISSION_TRUTH)
    assert res["torque_ratio"].r2 > 0.81  # paper: 0.81
    assert res["capacity_factor"].r2 > 0.89  # paper: 0.89 in converter mode
    assert res["capacity_factor_coupling"].r2 > 0.75  # paper: about 0.75
    assert abs(res["converter"].value("gamma_coupling") - truth["gamma"]) < 0.01
    for k, tol in ((0, 0.01), (1, 0.05), (2, 0.02), (3, 0.01), (4, 0.01), (5, 0.01)):
        np.testing.assert_allclose(res["converter"].value(f"a{k}"), truth[f"a{k}"], rtol=tol, err_msg=f"a{k}")


def test_without_transmission_model_is_flagged_and_biased(ideal):
    rec, truth, _ = ideal
    res = identify_torque_converter(rec, SPECS)
    assert res["converter"].status == "flagged"
    assert any("eta = 1" in r for r in res["converter"].reasons)
    # turbine torque without gearbox losses is lower: stall torque ratio a3/a0 underestimated
    assert res["converter"].value("a3") < truth["a3"]


def test_lockup_closed_everywhere_gives_insufficient_data(ideal):
    rec, _, _ = ideal
    r = Recording(dict(rec.channels), rec.segments)
    lk = rec["lockup_closed"]
    r.add(Channel("lockup_closed", "", lk.timestamps, np.ones(len(lk))))
    with pytest.raises(InsufficientDataError):
        identify_torque_converter(r, SPECS, transmission=TRANSMISSION_TRUTH)


def test_fast_pump_transients_are_left_out(ideal):
    rec, _, base = ideal
    r = Recording(dict(rec.channels), rec.segments)
    # speed oscillations in the first 100 s; the motor torque also carries the inertia torque J dw/dt
    n, _tq, v = rec["em_speed_rpm"], rec["em_torque_nm"], rec["vehicle_speed_kmh"]
    t = n.timestamps
    bump = 300.0 * np.sin(2 * np.pi * t / 2.0) * (t < 100)
    w_p = (n.values + bump) * 2 * np.pi / 60
    w_t = v.values / 3.6 / SPECS.wheel_radius_m * SPECS.gear_ratios[0] * SPECS.final_drive_ratio
    tp, _ = tc_torques(tc_truth_vector(), TC_TRUTH["gamma"], w_p, w_t)
    inertia = 0.12 * np.gradient(w_p, t)
    r.add(Channel("em_speed_rpm", "rpm", t, w_p * 60 / (2 * np.pi)))
    r.add(Channel("em_torque_nm", "Nm", t, tp + inertia))
    res = identify_torque_converter(r, SPECS, transmission=TRANSMISSION_TRUTH)
    assert res["converter"].n_excluded > base["converter"].n_excluded + 500
    np.testing.assert_allclose(res["converter"].value("a0"), TC_TRUTH["a0"], rtol=1e-3)


def test_missing_channel(ideal):
    rec, _, _ = ideal
    r = Recording({k: v for k, v in rec.channels.items() if k != "shaft_torque_nm"})
    with pytest.raises(MissingChannelError, match="shaft_torque_nm"):
        identify_torque_converter(r, SPECS)


def test_no_coupling_points_flags_fit():
    a = tc_truth_vector()
    w_p = np.full(200, 200.0)
    sr = np.linspace(0.0, 0.7, 200)
    w_t = sr * w_p
    q = np.stack([w_p**2, w_p * w_t, w_t**2])
    res = fit_torque_converter(w_p, w_t, a[0:3] @ q, a[3:6] @ q)
    assert "coupling" not in res
    assert res["converter"].status == "flagged"
    np.testing.assert_allclose([res["converter"].value(f"a{k}") for k in range(6)], a[:6], rtol=1e-6)


def test_pump_inertia_identified_with_the_pump_coefficients():
    rec, _ = tc_recording(pump_inertia_kgm2=0.18)
    res = identify_torque_converter(rec, SPECS, transmission=TRANSMISSION_TRUTH)
    conv = res["converter"]
    # the central difference over 0.4 s of a 7 s sine underestimates dw/dt by about 0.5 %
    np.testing.assert_allclose(conv.value("J_pump_kgm2"), 0.18, rtol=0.01)
    np.testing.assert_allclose([conv.value(f"a{k}") for k in range(6)], tc_truth_vector()[:6], rtol=2e-3)
    without = identify_torque_converter(rec, SPECS, transmission=TRANSMISSION_TRUTH, pump_inertia=False,
                                        max_pump_accel_rpm_s=1e4)
    assert without["torque_ratio"].r2 < res["torque_ratio"].r2


def test_coupling_derived_quantities(ideal):
    _, truth, res = ideal
    coup = res["coupling"]
    g = truth["gamma"]
    np.testing.assert_allclose(coup.value("k_at_gamma"), truth["a6"] + truth["a7"] * g + truth["a8"] * g**2,
                               rtol=1e-3)
    np.testing.assert_allclose(coup.value("sr_zero_torque"), 1.0, rtol=1e-3)


def test_speedometer_error_is_calibrated_on_lockup_closed_samples():
    # the CAN speed reads 4 % high; with the lock-up closed the turbine turns with the motor, which fixes it
    rec, truth = tc_recording(speed_reading_bias=0.04, lockup_closed_s=120.0)
    res = identify_torque_converter(rec, SPECS, transmission=TRANSMISSION_TRUTH)
    conv = res["converter"]
    np.testing.assert_allclose(conv.value("turbine_speed_scale"), 1 / 1.04, rtol=1e-6)
    assert conv["turbine_speed_scale"].n_points > 1000
    np.testing.assert_allclose(conv.value("gamma_coupling"), truth["gamma"], rtol=1e-3)
    np.testing.assert_allclose([conv.value(f"a{k}") for k in range(6)], tc_truth_vector()[:6], rtol=1e-3,
                               atol=1e-6)
    raw = identify_torque_converter(rec, SPECS, transmission=TRANSMISSION_TRUTH, calibrate_turbine_speed=False)
    assert raw["converter"].value("gamma_coupling") > truth["gamma"] * 1.02  # every SR 4 % high


def test_saturated_shaft_torque_is_excluded_and_counted(ideal):
    rec, _, base = ideal
    r = Recording(dict(rec.channels), rec.segments)
    sh = rec["shaft_torque_nm"]
    values, flags = sh.values.copy(), sh.flags.copy()
    clip = slice(2000, 2600)  # the telemetry clipped at its range for a minute
    values[clip] = 900.0
    flags[clip] = int(Flag.SATURATED)
    r.add(Channel("shaft_torque_nm", "Nm", sh.timestamps, values, flags, sh.source))
    res = identify_torque_converter(r, SPECS, transmission=TRANSMISSION_TRUTH)
    # part of that minute was outside the model's domain anyway; the rest is now excluded too
    assert res["converter"].n_excluded >= base["converter"].n_excluded + 100
    np.testing.assert_allclose([res["converter"].value(f"a{k}") for k in range(6)], tc_truth_vector()[:6],
                               rtol=1e-3, atol=1e-6)
    # the same clipped values without their flags do get in (the robust step only softens them)
    r.add(Channel("shaft_torque_nm", "Nm", sh.timestamps, values, None, sh.source))
    unflagged = identify_torque_converter(r, SPECS, transmission=TRANSMISSION_TRUTH, outlier_sigma=None)
    assert abs(unflagged["converter"].value("a3") / TC_TRUTH["a3"] - 1) > 1e-3


def test_lockup_state_inferred_from_slip_when_not_logged():
    rec, truth = tc_recording(lockup_closed_s=120.0)
    r = Recording({k: v for k, v in rec.channels.items() if k != "lockup_closed"}, rec.segments)
    res = identify_torque_converter(r, SPECS, transmission=TRANSMISSION_TRUTH)
    conv = res["converter"]
    assert conv.status == "flagged" and any("slip" in x for x in conv.reasons)
    np.testing.assert_allclose([conv.value(f"a{k}") for k in range(6)], tc_truth_vector()[:6], rtol=1e-3,
                               atol=1e-6)
    np.testing.assert_allclose(conv.value("gamma_coupling"), truth["gamma"], rtol=1e-3)


def test_coupling_curve_pinned_at_zero_slip_over_a_narrow_range():
    # coupling points only over SR 0.80-0.85 (a loose converter's torque falls below the torque threshold
    # above): three free a6..a8 extrapolate to SR 0.95 through nearly collinear regressors; with the
    # physical end point (no torque without slip) the curve up to 0.95 follows from two. Noise of 0.3 % of
    # the torque; the bound on the constrained fit is 3 sigma of a straight line T / (w_p (w_p - w_t)) =
    # a6 - a8 SR fitted over a uniform SR spread of width 0.05 (sd 0.05 / sqrt 12) and extrapolated to 0.95:
    # 3 x 0.003 / sqrt(n) x sqrt(1 + ((0.95 - 0.825) / sd)^2)
    rng = np.random.default_rng(7)
    a678 = np.array([0.0131, -0.0131, 0.0])  # T = 0.0131 w_p (w_p - w_t): zero at SR 1
    n = 400
    sr = rng.uniform(0.80, 0.85, n)
    w_p = rng.uniform(140.0, 180.0, n)
    w_t = sr * w_p
    q = np.stack([w_p**2, w_p * w_t, w_t**2])
    t = a678 @ q * (1.0 + 0.003 * rng.standard_normal(n))
    # converter-mode points below, exact, so that the split is found at 0.80
    a_conv = np.array([0.0055, 0.0, -0.0045, 0.00935, -0.008, -0.000515625])
    sr_c = np.linspace(0.1, 0.79, 300)
    w_pc = np.full(sr_c.size, 150.0)
    qc = np.stack([w_pc**2, w_pc * sr_c * w_pc, (sr_c * w_pc) ** 2])
    args = (np.r_[w_pc, w_p], np.r_[sr_c * w_pc, w_t], np.r_[a_conv[:3] @ qc, t], np.r_[a_conv[3:] @ qc, t])
    s95 = np.array([0.95])

    def rel_error_at_095(res: dict) -> float:
        c = res["coupling"]
        x = np.array([c.value(f"a{k}") for k in (6, 7, 8)])
        return abs(float((x @ [1.0, s95[0], s95[0] ** 2]) / (a678 @ [1.0, s95[0], s95[0] ** 2])) - 1.0)

    pinned = fit_torque_converter(*args, gamma=0.80)
    free = fit_torque_converter(*args, gamma=0.80, coupling_zero_slip=False)
    c = pinned["coupling"]
    assert abs(c.value("a6") + c.value("a7") + c.value("a8")) < 1e-12
    sd = 0.05 / np.sqrt(12.0)
    assert rel_error_at_095(pinned) < 3 * 0.003 / np.sqrt(n) * np.sqrt(1 + ((0.95 - 0.825) / sd) ** 2)
    assert rel_error_at_095(free) > rel_error_at_095(pinned)


def test_samples_left_out_until_the_pump_speed_settles_after_a_step():
    # 10 Hz, derivative window 0.4 s (h = 2 samples either side), limit 400 rpm/s: a step is a one-sample change
    # above 400 x 0.4 = 160 rpm, a calm one-sample change is within 400 x 0.1 = 40 rpm. The motor jumps from
    # 1000 to 1500 rpm between samples 19 and 20, falls back 50 rpm (not calm) and 20 rpm (calm), then holds.
    # Settled from sample 21 (changes 21->22 .. 24->25 calm: a whole window of 2h = 4); left out: the samples
    # whose window reaches the step (18, 19) up to the last whose window reaches the unsettled change 20->21
    # (k + h - 1 = 22). A fixed hold of 0.5 s would leave out 14..25.
    t = np.arange(40) * 0.1
    n = np.full(40, 1000.0)
    n[20:] = [1500.0, 1450.0] + [1430.0] * 18
    out = unsettled(n, t, 400.0, 0.4)
    assert np.flatnonzero(out).tolist() == [18, 19, 20, 21, 22]
    # a ramp at the limit itself has no step; ringing that never settles leaves out the rest of the record
    assert not unsettled(1000.0 + 400.0 * t, t, 400.0, 0.4).any()
    ring = n.copy()
    ring[20::2] += 45.0
    assert np.flatnonzero(unsettled(ring, t, 400.0, 0.4)).tolist() == list(range(18, 40))


def test_torque_gain_error_is_calibrated_on_lockup_closed_samples():
    # the motor torque reads 3 % high: with the lock-up closed (and K0 open) the turbine torque of eq. 32 is the
    # motor torque, so the scale is 1.03 and the torque ratio curve (a3..a5 against a0..a2) is the true one;
    # uncalibrated, every torque ratio is 3 % low
    rec, _ = tc_recording(em_torque_gain=1.03, lockup_closed_s=120.0)
    a = tc_truth_vector()
    sr = np.linspace(0.0, 0.8, 9)

    def tr(res: dict) -> np.ndarray:
        x = [res["converter"].value(f"a{k}") for k in range(6)]
        return (x[3] + x[4] * sr + x[5] * sr**2) / (x[0] + x[1] * sr + x[2] * sr**2)

    tr_true = (a[3] + a[4] * sr + a[5] * sr**2) / (a[0] + a[1] * sr + a[2] * sr**2)
    res = identify_torque_converter(rec, SPECS, transmission=TRANSMISSION_TRUTH)
    np.testing.assert_allclose(res["converter"].value("turbine_torque_scale"), 1.03, rtol=1e-6)
    np.testing.assert_allclose(tr(res), tr_true, rtol=1e-4)
    raw = identify_torque_converter(rec, SPECS, transmission=TRANSMISSION_TRUTH, calibrate_turbine_torque=False)
    np.testing.assert_allclose(tr(raw), tr_true / 1.03, rtol=1e-4)


def _converter_rows(a_conv: np.ndarray, sr_hi: float) -> tuple[np.ndarray, ...]:
    """Exact converter-mode points below ``sr_hi`` (pump at 150 rad/s), so that the split is the given Gamma."""
    sr_c = np.linspace(0.1, sr_hi, 300)
    w_pc = np.full(sr_c.size, 150.0)
    qc = np.stack([w_pc**2, w_pc * sr_c * w_pc, (sr_c * w_pc) ** 2])
    return w_pc, sr_c * w_pc, a_conv[:3] @ qc, a_conv[3:6] @ qc


def test_coupling_mode_fitted_on_the_turbine_torque_not_the_pump_inertia():
    # found by the converter property (ci profile): along a lock-up-open ramp-up in 1st gear the pump accelerates at
    # up to the quasi-steady limit while the coupling torque falls towards SR 1; the recorded motor torque exceeds the
    # coupling torque by an inertia torque the converter fit's J does not carry (here: none in converter mode, 0.2 kg
    # m^2 x dw_p in coupling mode), which bent the coupling curve fitted on the pump torque. Exact data: the turbine
    # torque gives a6..a8 to rounding
    rng = np.random.default_rng(3)
    a = tc_truth_vector()
    g = TC_TRUTH["gamma"]
    w_pc, w_tc, tpc, ttc = _converter_rows(a, g - 0.01)
    n = 150
    sr = rng.uniform(g, 0.97, n)
    w_p = rng.uniform(70.0, 200.0, n)
    w_t = sr * w_p
    t_c = a[6:9] @ np.stack([w_p**2, w_p * w_t, w_t**2])
    dw = 40.0 * (sr - g) / (0.97 - g)  # faster towards SR 1, as in a 1st-gear ramp-up
    args = (np.r_[w_pc, w_p], np.r_[w_tc, w_t], np.r_[tpc, t_c + 0.2 * dw], np.r_[ttc, t_c])
    acc = np.r_[rng.uniform(-20.0, 20.0, w_pc.size), dw]
    s = np.array([1.0, 0.95, 0.95**2])

    def rel_error_at_095(res: dict) -> float:
        x = np.array([res["coupling"].value(f"a{k}") for k in (6, 7, 8)])
        return abs(float(x @ s / (a[6:9] @ s)) - 1.0)

    turbine = fit_torque_converter(*args, gamma=g, dw_p=acc, outlier_sigma=None)
    pump = fit_torque_converter(*args, gamma=g, dw_p=acc, outlier_sigma=None, coupling_torque="pump")
    np.testing.assert_allclose([turbine["coupling"].value(f"a{k}") for k in (6, 7, 8)], a[6:9], rtol=1e-6,
                               atol=1e-9)
    assert rel_error_at_095(turbine) < 1e-6
    assert rel_error_at_095(pump) > 0.05
    # the pump rows' fit rides along for the map-based model (what the motor pays in coupling mode)
    np.testing.assert_array_equal(turbine["coupling"].data["pump_side_a678"],
                                  [pump["coupling"].value(f"a{k}") for k in (6, 7, 8)])
    with pytest.raises(ConfigError, match="coupling_torque"):
        fit_torque_converter(*args, gamma=g, coupling_torque="both")


def test_coupling_points_over_a_too_narrow_span_fit_slip_only_and_flag():
    # found by the converter property (a drawn petrol on a bench beyond the data sheets): 13 coupling points over SR
    # 0.847-0.861 only, where a6 and a8 (with no torque without slip, T / (w_p (w_p - w_t)) = a6 - a8 SR) are
    # collinear; the curve at SR 0.95 was 56 % off. Below min_coupling_span the torque is fitted in proportion to
    # w_p (w_p - w_t) (a8 = 0) and flagged. Bound on its torque at SR 0.95, derived from the model: the neglected
    # a8 moves T / (w_p (w_p - w_t)) by a8 (0.95 - SR) over the points' SR (at most 0.95 - 0.847), relative to
    # a6 - 0.95 a8, plus 3 sigma of a mean of 13 points with 0.3 % noise
    rng = np.random.default_rng(11)
    g, k_g, a8 = 0.845, 0.0055, 4e-3  # a8 at the strategy's largest
    a6 = k_g / (1.0 - g) + a8 * g  # continuous with the converter mode at Gamma
    a678 = np.array([a6, -a6 - a8, a8])
    a_conv = np.array([0.0055, 0.0, 0.0, 0.01, -0.004, 0.0])
    a_conv[5] = (k_g - a_conv[3] - a_conv[4] * g) / g**2  # TR 1 at Gamma
    a_conv[2] = (k_g - a_conv[0]) / g**2
    w_pc, w_tc, tpc, ttc = _converter_rows(a_conv, g - 0.01)
    n = 13
    sr = np.linspace(0.847, 0.861, n)
    w_p = rng.uniform(100.0, 200.0, n)
    w_t = sr * w_p
    t = a678 @ np.stack([w_p**2, w_p * w_t, w_t**2]) * (1.0 + 0.003 * rng.standard_normal(n))
    args = (np.r_[w_pc, w_p], np.r_[w_tc, w_t], np.r_[tpc, t], np.r_[ttc, t])
    s = np.array([1.0, 0.95, 0.95**2])
    res = fit_torque_converter(*args, gamma=g, outlier_sigma=None)
    c = res["coupling"]
    assert c.status == "flagged" and any("not told apart" in r for r in c.reasons)
    x = np.array([c.value(f"a{k}") for k in (6, 7, 8)])
    assert x[2] == 0.0 and x[0] + x[1] == 0.0
    err = abs(float(x @ s / (a678 @ s)) - 1.0)
    bound = a8 * (0.95 - 0.847) / (a6 - 0.95 * a8) + 3 * 0.003 / np.sqrt(n)
    assert err < bound
    two = fit_torque_converter(*args, gamma=g, outlier_sigma=None, min_coupling_span=0.0)["coupling"]
    assert "a8" in two.params and two.status == "ok"
    assert abs(float(np.array([two.value(f"a{k}") for k in (6, 7, 8)]) @ s / (a678 @ s)) - 1.0) > err
