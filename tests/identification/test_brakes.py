"""Brake gains from neutral braking (eq. 41: k_f, k_r) and blending maps over speed x deceleration."""

from __future__ import annotations

import numpy as np
import pytest
from _synth_a import SPECS, blending_true_split, neutral_braking_plant, to_recording

from benchtwin.errors import InsufficientDataError, MissingChannelError, NoExcitationError
from benchtwin.identification.brakes import fit_brake_gain, identify_brake_blending, identify_brake_gains
from benchtwin.recording import Flag


def test_noise_free_gains_and_distribution(brake_plant, truth) -> None:
    t, sig, segs = brake_plant
    res = identify_brake_gains(to_recording(t, sig, segments=segs), SPECS)
    ff, fr, fd = res.fits["brakes.front"], res.fits["brakes.rear"], res.fits["brakes.distribution"]
    np.testing.assert_allclose([ff.value("m_f"), ff.value("c_f")], [truth.m_f, truth.c_f], rtol=1e-6)
    np.testing.assert_allclose([fr.value("m_r"), fr.value("c_r")], [truth.m_r, truth.c_r], rtol=1e-6)
    k_f = truth.m_f / (truth.m_f + truth.m_r)
    np.testing.assert_allclose(fd.value("k_f"), k_f, rtol=1e-9)
    np.testing.assert_allclose(fd.value("k_f") + fd.value("k_r"), 1.0)
    assert round(100 * fd.value("k_f")) == 66  # the paper's 66 / 34 %
    assert ff.n_points == 10 and ff.segments == ["neutral_braking_50kmh"]
    assert ff.data["p_bar"].shape == ff.data["torque_nm"].shape and ff.data["torque_curve_nm"].size == 100


def test_noisy_gains_within_intervals(brake_plant, truth) -> None:
    t, sig, segs = brake_plant
    res = identify_brake_gains(to_recording(t, sig, noise=1.0, seed=4, segments=segs), SPECS)
    for fit, name, true in ((res.fits["brakes.front"], "m_f", truth.m_f), (res.fits["brakes.rear"], "m_r", truth.m_r),
                            (res.fits["brakes.distribution"], "k_f", truth.m_f / (truth.m_f + truth.m_r))):
        p = fit[name]
        assert abs(p.value - true) < 4 * p.std_error and abs(p.value - true) < 1e-3 * true, (name, p.value, true)


def test_without_segments_braking_in_gear_is_not_used(truth) -> None:
    t, sig, _ = neutral_braking_plant(truth)
    sig = dict(sig)
    # the second half in gear with a different torque (powertrain drag): must be ignored
    late = t > t[-1] / 2
    sig["gear_actual"] = np.where(late, 4.0, 0.0)
    sig["dyno_force_rear_n"] = np.where(late, sig["dyno_force_rear_n"] - 500.0, sig["dyno_force_rear_n"])
    res = identify_brake_gains(to_recording(t, sig), SPECS)
    np.testing.assert_allclose(res.fits["brakes.rear"].value("m_r"), truth.m_r, rtol=1e-6)
    assert res.fits["brakes.rear"].n_points == 5


def test_bad_data_paths(brake_plant, truth) -> None:
    with pytest.raises(NoExcitationError, match="pressure"):
        fit_brake_gain(np.full(6, 20.0), np.full(6, 800.0), "front")
    with pytest.raises(InsufficientDataError):
        fit_brake_gain(np.array([5.0, 30.0]), np.array([200.0, 1200.0]), "rear")
    flipped = fit_brake_gain(np.array([5.0, 10, 20, 30, 40]), -25.0 * np.array([5.0, 10, 20, 30, 40]), "rear")
    assert flipped.status == "flagged" and any("sign" in r for r in flipped.reasons)
    t, sig, segs = brake_plant
    rec = to_recording(t, sig, segments=segs)
    for c in ("brake_pressure_rl_bar", "brake_pressure_rr_bar"):
        rec.channels.pop(c, None)
    with pytest.raises(MissingChannelError, match="rear caliper"):
        identify_brake_gains(rec, SPECS)
    # clipped pressures: excluded and counted, the estimates unchanged
    rec = to_recording(t, sig, segments=segs)
    ch = rec["brake_pressure_fl_bar"]
    hit = ch.values > 60
    ch.values[hit] = 100.0
    ch.flags[hit] = int(Flag.SATURATED)
    res = identify_brake_gains(rec, SPECS)
    assert res.fits["brakes.front"].n_excluded > 0 and res.fits["brakes.front"].n_points == 9
    np.testing.assert_allclose(res.fits["brakes.front"].value("m_f"), truth.m_f, rtol=1e-6)


def test_blending_maps_follow_the_true_split(blend_plant, brake_plant, truth) -> None:
    """Per braking sample the regenerative share equals the plant's within 0.1 % (median) - only the few
    samples where a smoothed deceleration straddles a change of level differ; the maps show regeneration
    dominating at low deceleration, nothing below 10 km/h, and the front share rising with deceleration."""
    gains = identify_brake_gains(to_recording(*brake_plant[:2], segments=brake_plant[2]), SPECS)
    t, sig, segs = blend_plant
    fit = identify_brake_blending(to_recording(t, sig, segments=segs), SPECS, gains)
    d = fit.data
    regen, hf, _ = blending_true_split(d["v_kmh"], d["decel_mps2"], d["torque_total_nm"])
    err_r = np.abs(d["regen_share"] - regen / d["torque_total_nm"])
    err_f = np.abs(d["front_share"] - hf / d["torque_total_nm"])
    assert np.median(err_r) < 1e-3 and np.percentile(err_r, 90) < 1e-2
    assert np.median(err_f) < 1e-3
    np.testing.assert_allclose(d["regen_share"] + d["hydraulic_share"], 1.0, atol=1e-9)
    m = d["map_regen_share"]
    assert m.shape == (d["map_decel_edges_mps2"].size - 1, d["map_speed_edges_kmh"].size - 1)
    low_v = d["map_speed_edges_kmh"][1:] <= 10.0
    assert np.nanmax(m[:, low_v]) < 0.05  # hydraulic only below the cut-off speed
    rows = np.flatnonzero(np.isfinite(m[:, 5]))
    assert m[rows[0], 5] > 0.95 and m[rows[-1], 5] < 0.6  # regen share falls with deceleration at 50-60 km/h
    fr = d["map_front_share"][:, 5]
    assert fr[rows[-1]] > fr[rows[0]]
    assert np.median(np.abs(d["front_check_residual_nm"])) < 1e-6
    assert not any("front roller" in r for r in fit.reasons)
    assert 0 < fit.value("regen_share_mean") < 1 and fit["regen_share_mean"].std_error > 0
    p95 = fit["regen_torque_p95_nm"]
    assert 0 < p95.std_error < 0.1 * p95.value and p95.ci95[0] <= p95.value <= p95.ci95[1]
    with pytest.raises(InsufficientDataError):
        identify_brake_blending(to_recording(*brake_plant[:2]), SPECS, gains, kinds=None)


def test_emulated_neutral_braking_and_blending_through_the_ideal_chain(quick_ideal) -> None:
    """The emulator's neutral-braking test: gains within 0.1 % and k_f = 66 % (eq. 41); the blending maps come
    from its deceleration tests."""
    from benchtwin.identification.brakes import identify_brakes

    vehicle, rec = quick_ideal
    res = identify_brakes(rec, vehicle.specs)
    b = vehicle.brakes
    np.testing.assert_allclose(res.fits["brakes.front"].value("m_f"), b.gain_front_nm_per_bar, rtol=1e-3)
    np.testing.assert_allclose(res.fits["brakes.rear"].value("m_r"), b.gain_rear_nm_per_bar, rtol=1e-3)
    k_f = b.gain_front_nm_per_bar / (b.gain_front_nm_per_bar + b.gain_rear_nm_per_bar)
    np.testing.assert_allclose(res.fits["brakes.distribution"].value("k_f"), k_f, rtol=1e-3)
    blend = res.fits["brakes.blending"]
    assert blend.n_points > 50 and 0.0 < blend.value("regen_share_mean") < 1.0
    assert np.nanmax(blend.data["map_regen_share"][:, 0]) < 0.1  # below 10 km/h: hydraulic only
