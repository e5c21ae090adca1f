"""Transmission eta_m and C0 per gear (eq. 13-17) recovered from synthetic ramp-up Recordings."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _synth_a import SPECS, Truth, ramp_up_plant, to_recording

from benchtwin.errors import CollinearError, InsufficientDataError, NoExcitationError
from benchtwin.identification.transmission import fit_transmission_efficiency, identify_transmission
from benchtwin.recording import Flag


def _gear(key: str) -> int:
    return int(key.split("gear")[1].split("_")[0])


def test_noise_free_recovers_every_gear_drive_and_coast(ramp_rec, truth) -> None:
    res = identify_transmission(ramp_rec, SPECS)
    assert not res.errors
    assert {f"transmission.gear{g}{d}" for g in range(3, 8) for d in ("", "_coast")} == set(res.fits)
    for key, fit in res.fits.items():
        g = _gear(key)
        assert fit.status == "ok"
        np.testing.assert_allclose(fit.value("eta_m"), truth.eta_m[g], rtol=1e-4)
        np.testing.assert_allclose(fit.value("C0"), truth.c0[g], rtol=1e-3)
        assert fit.r2 > 0.9999
        assert fit.n_points == (16 if "coast" not in key else 6)
        assert fit["C0"].segments and all(s.startswith(f"ramp_up_g{g}") for s in fit["C0"].segments)
        lo, hi = fit["eta_m"].ci95
        assert lo <= fit.value("eta_m") <= hi
        # figure arrays: measured points and the model curve
        assert fit.data["c"].shape == fit.data["eta"].shape == (fit.n_points,)
        assert fit.data["eta_curve"].shape == fit.data["c_curve"].shape


def test_noisy_estimates_lie_within_their_intervals(ramp_rec_noisy, truth) -> None:
    """With sensor noise every estimate is within 5 standard errors, eta_m within 1 % and C0 within 10 % of truth,
    and most 95 % intervals cover the truth (6 seeds gave RMS z-scores of 1.1-1.4: the ratio of noisy powers
    is slightly biased, so the intervals are a little optimistic)."""
    res = identify_transmission(ramp_rec_noisy, SPECS)
    covered, total = 0, 0
    for key, fit in res.fits.items():
        g = _gear(key)
        for name, true in (("eta_m", truth.eta_m[g]), ("C0", truth.c0[g])):
            p = fit[name]
            assert abs(p.value - true) < 5 * p.std_error, (key, name, p.value, true, p.std_error)
            covered += p.ci95[0] <= true <= p.ci95[1]
            total += 1
        assert abs(fit.value("eta_m") - truth.eta_m[g]) < 0.01 * truth.eta_m[g]
        assert abs(fit.value("C0") - truth.c0[g]) < 0.1 * truth.c0[g]
        assert fit.r2 > 0.95  # the paper reports 0.95 in 5th gear
    assert covered / total >= 0.7


def test_steady_detection_without_segment_table_and_slipping_hold_excluded(ramp_plant, truth) -> None:
    t, sig, _ = ramp_plant
    rec = to_recording(t, sig)  # no segment table: windows found by themselves
    res = identify_transmission(rec, SPECS)
    fit = res.fits["transmission.gear5"]
    np.testing.assert_allclose(fit.value("eta_m"), truth.eta_m[5], rtol=1e-4)
    assert any("lock-up open or slipping" in r for r in fit.reasons)
    assert fit.n_points == 16


def test_flagged_shaft_torque_is_excluded_and_counted(ramp_plant, truth) -> None:
    t, sig, segs = ramp_plant
    rec = to_recording(t, sig, segments=segs)
    ch = rec["shaft_torque_nm"]
    hit = (ch.timestamps > segs[4].start_s + 20) & (ch.timestamps < segs[4].start_s + 23)
    ch.values[hit] = 3000.0  # clipped garbage
    ch.flags[hit] = int(Flag.SATURATED)
    res = identify_transmission(rec, SPECS)
    fit = res.fits["transmission.gear5"]
    assert fit.n_excluded >= hit.sum() // 10  # grid samples at 10 Hz
    np.testing.assert_allclose(fit.value("eta_m"), truth.eta_m[5], rtol=1e-4)
    np.testing.assert_allclose(fit.value("C0"), truth.c0[5], rtol=1e-3)


def test_bad_data_paths() -> None:
    with pytest.raises(InsufficientDataError):
        fit_transmission_efficiency(np.array([50.0, 80.0]), np.array([0.9, 0.92]))
    with pytest.raises(NoExcitationError):
        fit_transmission_efficiency(np.full(8, 100.0), np.full(8, 0.92))
    # points that do not follow eq. 14 at all: a flagged result with the reason, not confident numbers
    rng = np.random.default_rng(0)
    c = np.linspace(20, 200, 12)
    junk = fit_transmission_efficiency(c, 0.9 + rng.normal(0, 0.03, c.size))
    assert junk.status == "flagged" and any("R^2" in r for r in junk.reasons)
    assert junk["C0"].status == "flagged"
    # two "points" that are the same point many times over and nothing else: collinear design
    c = np.array([100.0, 100.0 + 1e-9] * 5)
    with pytest.raises((CollinearError, NoExcitationError)):
        fit_transmission_efficiency(c, np.full(10, 0.9), min_rel_spread=0.0)


def test_one_gear_without_data_is_reported_not_fatal(truth) -> None:
    t, sig, segs = ramp_up_plant(truth, settings=[(5, 85.0), (6, 100.0)], levels=[-40.0, 30.0, 60.0, 120.0, 200.0])
    rec = to_recording(t, sig, segments=segs)
    res = identify_transmission(rec, SPECS)
    assert "transmission.gear5" in res.fits
    assert "InsufficientDataError" in res.errors["transmission.gear5_coast"]


def test_recovers_a_different_vehicle() -> None:
    """Nothing is tuned to one vehicle: other ratios, efficiencies and losses come back too."""
    other = dataclasses.replace(Truth(), eta_m={g: 0.93 + 0.005 * g for g in range(1, 10)},
                                c0={g: 12.0 - g for g in range(1, 10)})
    specs = SPECS.model_copy(update={"gear_ratios": [4.7, 3.1, 2.1, 1.67, 1.29, 1.0, 0.84, 0.67, 0.56],
                                     "final_drive_ratio": 3.07, "wheel_radius_m": 0.35})
    t, sig, segs = ramp_up_plant(other, specs, settings=[(4, 60.0), (4, 90.0), (6, 80.0), (6, 120.0)])
    res = identify_transmission(to_recording(t, sig, segments=segs), specs)
    for g in (4, 6):
        np.testing.assert_allclose(res.fits[f"transmission.gear{g}"].value("eta_m"), other.eta_m[g], rtol=1e-4)
        np.testing.assert_allclose(res.fits[f"transmission.gear{g}"].value("C0"), other.c0[g], rtol=1e-3)


def test_emulated_ramp_up_through_the_ideal_chain(quick_ideal) -> None:
    """The emulator's 5th-gear hybrid ramp-up through the ideal chain: eta_m within 0.5 % and C0 within 15 %
    (measured: 0.13 % / 2 % on the paper vehicle, 0.15 % / 8 % on the second one). The shaft torque's 2.1 Nm
    resolution (K_TEL 500, 12 bit) is not averaged out on constant holds; at the lowest step (about 20 Nm
    input) it is a 4 % error of the efficiency, which is what limits C0 with four points."""
    vehicle, rec = quick_ideal
    res = identify_transmission(rec, vehicle.specs)
    fit = res.fits["transmission.gear5"]
    np.testing.assert_allclose(fit.value("eta_m"), vehicle.transmission.eta_m[4], rtol=5e-3)
    np.testing.assert_allclose(fit.value("C0"), vehicle.transmission.c0_nm[4], rtol=0.15)
    assert fit.segments == ["ramp_up_g5_85kmh_hybrid"]
