"""Torque converter identification (eq. 31-39) on synthetic Recordings from the model forms."""

from __future__ import annotations

import numpy as np
import pytest
from _synth_b import SPECS, TC_TRUTH, TRANSMISSION_TRUTH, tc_recording, tc_truth_vector

from benchtwin.errors import InsufficientDataError, MissingChannelError
from benchtwin.identification.torque_converter import (
    coupling_point,
    fit_torque_converter,
    identify_torque_converter,
    tc_torques,
)
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
