"""Recovery is a property: every identified parameter of a family within a stated tolerance, for drawn vehicles
and setups.

One example = a drawn vehicle and bench, the paper campaign's tests of one family moved to that vehicle
(:func:`strategies.campaign_for`), simulated (about 0.1 s), pushed through sensors -> chain ->
identification of that family only, and every check of the family judged with the tolerance of
:mod:`_tolerance` (floor + noise x k sigma at the paper setup + the setup's declared systematic errors).
R^2 against the paper's is left out: it falls with the noise by construction.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from _profiles import profile
from _tolerance import property_checks
from hypothesis import example, given
from hypothesis import strategies as st
from pydantic import ValidationError
from strategies import (
    FAMILY_PICKS,
    IDEAL_SETUP,
    PAPER_VEHICLE,
    TC_KINDS,
    DrawnSetup,
    campaign_for,
    pinned,
    pinned_gears,
    seeds,
    setups,
    vehicles,
)

from benchtwin.config.vehicle import VehicleConfig
from benchtwin.emulator import simulate_campaign
from benchtwin.identification._fit import IdentificationResult
from benchtwin.identification.torque_converter_borrowed import UncalibratedShare
from benchtwin.sensors.telemetry import k_tot, torque_step_nm
from benchtwin.validation.families import FAMILIES
from benchtwin.validation.report import Check
from benchtwin.validation.run import validate


def _says_too_little(note: str) -> bool:
    # the reason names the error, or the points it lacks with their count below the count it needs ("0
    # coupling-mode points (SR >= 0.933; need 10): a6..a8 not identified"); a bare "not identified" does not say
    # why, and a count at or above the need does not excuse it: both stay failures
    lacking = [int(n) < int(need) for n, need in re.findall(r"(\d+) [\w-]+ points \([^)]*need (\d+)\)", note)]
    return any(w in note for w in ("NoExcitationError", "InsufficientDataError", "CollinearError",
                                   "not identifiable")) or (bool(lacking) and all(lacking))


def _run(family: str, vehicle: VehicleConfig, drawn: DrawnSetup, seed: int, **pick: object) -> None:
    fam = FAMILIES[family]
    campaign = campaign_for(vehicle, fam.kinds, seed=seed, **pick)
    trace = simulate_campaign(vehicle, campaign)
    # the property reads the identification only: the chain's checks are not made
    report = validate(vehicle, drawn.setup, campaign, trace=trace, families=[family], profile="realistic",
                      chain_checks=False)
    gears = sorted({int(s.settings["gear"]) for s in trace.segments if s.kind == "ramp_up"}) or None
    checks = property_checks(report.identification, vehicle, drawn.setup, drawn.noise, gears, {family})
    _judge(family, checks, vehicle, drawn, report.identification)


TC_FAMILY = "torque_converter"
#: the converter checks that read the turbine torque (eq. 32): those a clipped gear's missing model leaves unidentified
TURBINE_CHECKS = ("torque_converter.converter.gamma_coupling", "torque_converter.torque_ratio_curve",
                  "torque_converter.coupling_cf_curve")


def _clipped_on_this_bench(check: Check, result: IdentificationResult | None, drawn: DrawnSetup) -> bool:
    # a converter check "not identified" because the bench's telemetry clipped: the converter fit's structure
    # (UncalibratedShare) names the gears whose eq. 14 the clip guard's exclusion left without points, those gears'
    # points alone carry the share past the rule (clip_explains: without them the rest would be identified), the
    # range the data clipped at is the drawn gain's (Table 2: k_tot x vout_max; the AD codes end at the rail or
    # one step below it), and the check's note says so in the cause's words
    if check.name not in TURBINE_CHECKS or math.isfinite(check.identified) or result is None:
        return False
    conv = result.fits.get("torque_converter.converter")
    share = conv.data.get(UncalibratedShare.KEY) if conv is not None else None
    if not isinstance(share, UncalibratedShare) or not share.clip_explains():
        return False
    tel = drawn.setup.telemetry
    rail = k_tot(tel.shaft, tel.k_tel) * tel.vout_max_v
    step = torque_step_nm(tel.shaft, tel.k_tel)
    return all(abs(c.range_nm - rail) <= 1.01 * step and c.reason() in check.note for c in share.clipped.values())


def _judge(family: str, checks: list[Check], vehicle: VehicleConfig, drawn: DrawnSetup,
           result: IdentificationResult | None = None) -> None:
    assert checks, f"no check of family {family}"
    # "every identified parameter": a fit the campaign does not excite enough is not identified, and says so
    # (its reason names the spread or the points it lacks); that is the guards' property, not a recovery
    # failure. The family must still identify most of its checks, but for those the bench's own clipping left
    # unidentified (_clipped_on_this_bench: traced, in the fit's structure, to the clip guard's exclusion; issue #8:
    # a clipping bench stays in the draws, its clipped gear's curves are the guards' property)
    unexcited = [c for c in checks if not math.isfinite(c.identified) and _says_too_little(c.note)]
    clipped = [c for c in unexcited if _clipped_on_this_bench(c, result, drawn)]
    assert len(unexcited) - len(clipped) <= len(checks) // 2, (
        f"{family}: {len(unexcited)} of {len(checks)} checks not excited ({len(clipped)} traced to the bench's "
        "clipping)")
    bad = [c for c in checks if not c.passed and c not in unexcited]
    assert not bad, (f"{vehicle.name}, noise x{drawn.noise:.2f}, K_TEL {drawn.setup.telemetry.k_tel}: "
                     + "; ".join(f"{c.name} error {c.error:.4g} > {c.tolerance:.4g} ({c.note[:80]})" for c in bad))


#: two gears of a vehicle as (first, step): gears ``first`` and ``first + step`` counted round the vehicle's
#: gears (two distinct gears of an 8- or a 9-speed; a plain pair, so a finding can be pinned by ``@example``)
gear_pairs = st.tuples(st.integers(1, 9), st.integers(1, 7))


def _two_gears(pair: tuple[int, int], n_gears: int) -> set[int]:
    first = (pair[0] - 1) % n_gears
    return {first + 1, (first + pair[1]) % n_gears + 1}


def _pinned_transmission(name: str) -> tuple[VehicleConfig, DrawnSetup, int, tuple[int, int]]:
    vehicle, drawn, seed = pinned(name)
    g = pinned_gears(name)
    return vehicle, drawn, seed, (g[0], g[1] - g[0])


@profile()
@given(vehicles(), setups(), seeds, gear_pairs)
@example(*_pinned_transmission("transmission_engine_gain_low_torque"))
def test_transmission_recovers_eta_m_and_c0(vehicle: VehicleConfig, drawn: DrawnSetup, seed: int,
                                             pair: tuple[int, int]) -> None:
    # two gears of the vehicle, each with its paper ramp-ups (electric and hybrid): 2-5 tests
    _run("transmission", vehicle, drawn, seed, gears=_two_gears(pair, vehicle.n_gears))


@profile()
@given(vehicles(), setups(), seeds)
@example(*pinned("motor_hpcu_offset"))
def test_motor_recovers_willans_lines(vehicle: VehicleConfig, drawn: DrawnSetup, seed: int) -> None:
    _run("motor", vehicle, drawn, seed, **FAMILY_PICKS["motor"])


@profile()
@given(vehicles(), setups(), seeds)
@example(*pinned("engine_petrol_corner"))
def test_engine_recovers_bsfc(vehicle: VehicleConfig, drawn: DrawnSetup, seed: int) -> None:
    _run("engine", vehicle, drawn, seed, **FAMILY_PICKS["engine"])


@profile()
@given(vehicles(), setups(), seeds)
def test_battery_recovers_alpha_beta(vehicle: VehicleConfig, drawn: DrawnSetup, seed: int) -> None:
    _run("battery", vehicle, drawn, seed, **FAMILY_PICKS["battery"])


@profile()
@given(vehicles(), setups(), seeds)
def test_brakes_recover_axle_gains(vehicle: VehicleConfig, drawn: DrawnSetup, seed: int) -> None:
    _run("brakes", vehicle, drawn, seed)


@profile()
@given(vehicles(), setups(), seeds)
def test_road_load_recovers_f0_f1_f2(vehicle: VehicleConfig, drawn: DrawnSetup, seed: int) -> None:
    _run("road_load", vehicle, drawn, seed)


@profile()
@given(vehicles(), setups(), seeds)
def test_shift_lines_recovered(vehicle: VehicleConfig, drawn: DrawnSetup, seed: int) -> None:
    _run("shifts", vehicle, drawn, seed)


def _converter_checks_pass(vehicle: VehicleConfig, drawn: DrawnSetup, seed: int) -> None:
    fam = FAMILIES["torque_converter"]
    campaign = campaign_for(vehicle, fam.kinds, seed=seed, **FAMILY_PICKS[fam.name])
    trace = simulate_campaign(vehicle, campaign)
    report = validate(vehicle, drawn.setup, campaign, trace=trace, families=[fam.name], profile="realistic",
                      chain_checks=False)
    checks = property_checks(report.identification, vehicle, drawn.setup, drawn.noise, None, {fam.name})
    _judge(fam.name, checks, vehicle, drawn, report.identification)


@profile()
@given(vehicles(), setups(), seeds)
@example(*pinned("converter_coupling_pump_inertia"))
@example(*pinned("converter_coupling_unexcited"))
@example(*pinned("converter_ecu_offset_noise_free"))
@example(*pinned("converter_ecu_offset_flagged_gears"))
@example(*pinned("converter_ecu_offset_gamma"))
@example(*pinned("converter_ecu_offset_gear3"))
@example(*pinned("converter_ktel_gear1_uncalibrated"))
@example(*pinned("converter_ktel_clipped_9speed_diesel"))
@example(*pinned("converter_ktel_clipped_8speed_diesel"))
@example(*pinned("converter_shaft_clock_drift"))
@example(*pinned("converter_borrowed_gear_kink"))
@example(*pinned("converter_drag_no_gear1_group"))
@example(*pinned("converter_drag_reference_10bit"))
def test_torque_converter_curves_recovered(vehicle: VehicleConfig, drawn: DrawnSetup, seed: int) -> None:
    # found here: the loose converter's coupling curve, the family's tests alone, the loose converter on a 10-bit
    # telemetry (tests below), the coupling mode fitted on a pump torque that kept part of the pump's inertia
    # torque (the pinned example: coupling CF curve 10.4 % off at SR 0.95, now 0.9 %) and coupling points over
    # SR 0.847-0.861 only, where a6 and a8 are collinear (test_torque_converter_b: now a8 = 0 and flagged); a
    # 9-speed petrol whose fit finds no coupling-mode point above its Gamma 0.933 (the second pinned example:
    # a6..a8 flagged as not identified, which was counted as a failure; now judged as in the other families); four
    # setups whose ECU engine torque is off beyond its data sheet (4.5-7.7 Nm, 3-5 %): eq. 32 read gears 1-3's
    # transmission fits, which took that torque in at their hybrid points (C0 up to 7 Nm off, or flagged and
    # borrowed), so Gamma was 0.05-0.12 off and the curves 5-20 % (the ecu_offset examples); now eq. 32 reads each
    # gear's eq. 14 on its motor-only points (identification/torque_converter_gearbox.py); three benches at K_TEL
    # 8000 whose 1st-gear ramp-ups clip (gear 1 without a model of its own, most converter points through it left
    # uncalibrated: TR, Gamma and the coupling curve not identified, 3 of 4 checks; the ktel examples): the clip is
    # now traced in the fit's structure and excused (_clipped_on_this_bench); an 8-speed diesel whose
    # telemetry clock runs 37 ppm slow on the family's 1,662 s of tests (too short for the acquisition's drift
    # windows): the shaft torque read from 6 ms early to 48 ms late, the take-offs' torque ratios up to 6 % off and
    # the TR curve 3.6 % (> 2.0 %); now the converter lines the shaft torque up with the dyno's axle forces test by
    # test (identification/shaft_clock.py; the shaft_clock_drift example: 1.1 %); a 9-speed diesel whose gear 1, on
    # gear 2's model, took its turbine-torque offset +4.61 Nm for 4.14 on converter-mode points above a Gamma fitted
    # low (0.886 for 0.906; TR 4.3 % off near it with the shaft torque lined up): now the offset is read at gear 1's
    # own kink (the borrowed_gear_kink example, test_borrowed_gear_calibration.py: +4.29 Nm, Gamma 0.903); a
    # 9-speed diesel at noise x2.81 on an
    # 11-bit telemetry whose drag fit ran along its speed ridge and was used: gear 1 (no drag group: run only in a
    # hybrid ramp-up) on gear 2's drag model, uncalibrated, 3 of 4 checks not identified; now the speed term must
    # also lower the SSE (transmission_drag.LR_3SIGMA) and the drag is not used (converter_drag_no_gear1_group); the
    # ECU torque's reference is the drag only where its k_T is supported (converter_drag_reference_10bit)
    _converter_checks_pass(vehicle, drawn, seed)


def test_only_a_reasoned_lack_of_excitation_is_excused() -> None:
    # what the property lets pass as "not excited": the reason must say why; a count of points at or above the
    # need, or no reason at all, stays a failure
    assert _says_too_little("not identified: 0 coupling-mode points (SR >= 0.933; need 10): a6..a8 not identified")
    assert _says_too_little("InsufficientDataError: 3 points")
    assert not _says_too_little("not identified")
    assert not _says_too_little("not identified: 95 coupling-mode points (SR >= 0.850; need 10): a6..a8 not "
                                "identified")
    assert not _says_too_little("not identified: 0 coupling-mode points (SR >= 0.933): a6..a8 not identified")


@pytest.mark.parametrize("setup_name", ["ideal", "paper"])
def test_converter_identifies_every_curve_on_the_paper_vehicle(setup_name: str) -> None:
    # the property lets a flagged, reasoned "not identified" pass (above); a converter fit that flagged everything
    # so would then pass it too. The paper vehicle reaches coupling mode in its 1st-gear ramp-ups and the
    # coastdown's run-up on the property's own cut campaign: every converter check there must be a finite
    # estimate within the property's tolerance, none excused (about 2 s)
    from strategies import PAPER_SETUP

    drawn = DrawnSetup(IDEAL_SETUP, 0.0, False) if setup_name == "ideal" else DrawnSetup(PAPER_SETUP, 1.0, False)
    fam = FAMILIES["torque_converter"]
    campaign = campaign_for(PAPER_VEHICLE, fam.kinds, seed=0, **FAMILY_PICKS[fam.name])
    report = validate(PAPER_VEHICLE, drawn.setup, campaign, trace=simulate_campaign(PAPER_VEHICLE, campaign),
                      families=[fam.name], profile="realistic")
    checks = property_checks(report.identification, PAPER_VEHICLE, drawn.setup, drawn.noise, None, {fam.name})
    assert {c.name for c in checks} >= {"torque_converter.coupling_cf_curve", "torque_converter.torque_ratio_curve"}
    bad = [(c.name, c.identified, c.error, c.tolerance, c.note[:80]) for c in checks
           if not (c.passed and math.isfinite(c.identified))]
    assert not bad, bad


def test_converter_example_runs_its_family_tests_cut_to_the_converter_points() -> None:
    # what the converter's property example runs (FAMILY_PICKS): the family's own kinds only, ramp-ups in gears
    # 1-3, accelerations to 40 km/h, ramp-downs from 40 km/h, a 10 s coast; a cap is an upper bound (the
    # decelerations keep 100 km/h under a 150 km/h cap) and is validated like a user's test (a zero end speed
    # is refused, not run)
    fam = FAMILIES["torque_converter"]
    campaign = campaign_for(PAPER_VEHICLE, fam.kinds, seed=0, **FAMILY_PICKS[fam.name])
    kinds = {t.kind for t in campaign.tests}
    assert kinds == set(fam.kinds), kinds
    assert {t.gear for t in campaign.tests if t.kind == "ramp_up"} == {1, 2, 3}
    assert all(t.end_speed_kmh == 40.0 for t in campaign.tests if t.kind == "acceleration")
    assert all(t.start_speed_kmh == 40.0 for t in campaign.tests if t.kind == "ramp_down")
    assert [t.max_duration_s for t in campaign.tests if t.kind == "coastdown"] == [10.0]
    assert all(t.start_speed_kmh == 100.0 for t in campaign.tests if t.kind == "deceleration")
    loose = campaign_for(PAPER_VEHICLE, ("deceleration",), seed=0, caps={"deceleration": {"start_speed_kmh": 150.0}})
    assert [t.start_speed_kmh for t in loose.tests] == [100.0] * 6
    with pytest.raises(ValidationError):
        campaign_for(PAPER_VEHICLE, ("acceleration",), seed=0, caps={"acceleration": {"end_speed_kmh": 0.0}})


def test_converter_with_gear_1_on_a_borrowed_transmission_model() -> None:
    # found by test_torque_converter_curves_recovered in the thorough profile once the coupling fit was fixed: an
    # 8-speed draw whose converter-mode points are all in gear 1 (no lock-up there, so no transmission model of its
    # own: gear 2's C0 11.9 Nm for 2.0) above SR 0.6: the turbine torque read ~8.5 Nm high, TR never reached 1
    # (TR curve 35x off, Gamma 0.931 for 0.883). Now gear 1's turbine torque is calibrated on its own coupling
    # points (offset reported; significant: 8.6 Nm, some 75 standard errors over its passes, far beyond the
    # 3-sigma gate), and the stall end, which no point excites, is flagged and not judged. Then, after the plant's
    # regeneration fix, the TR curve 2.23 % off (1.38 % before): the offset was the median over the gear's coupling
    # points of d = T_t - (T_motor - J dw_p/dt), which reads 1.4 Nm higher on the passes that slow the pump than on
    # those that speed it up (the inertia torque the converter fit's J leaves in), and the plant change left one
    # slowing pass fewer: offset 8.27 Nm for 8.65, turbine torque ~1 Nm high near Gamma. Now the offset is read at
    # dw_p = 0 on the line through the passes (8.63 Nm; TR curve 1.13 %, 1.39 % on the old plant) (about 45 s)
    vehicle, drawn, seed = pinned("converter_gear1_borrowed_model")
    campaign = campaign_for(vehicle, TC_KINDS, seed=seed)
    report = validate(vehicle, drawn.setup, campaign, trace=simulate_campaign(vehicle, campaign),
                      families=["torque_converter"], profile="realistic")
    conv = report.identification.fits["torque_converter.converter"]
    # the calibration is the gear's and said as such: the offset is what borrowing gear 2's C0 adds, the true
    # C0(gear 2) - C0(gear 1) = 8.7 Nm (less gear 2's own C0 error and the turbine torque scale, a few %); bound:
    # a quarter of the error the uncalibrated borrow carried
    offset = conv.value("turbine_torque_offset_g1")
    truth = vehicle.transmission.c0_nm[1] - vehicle.transmission.c0_nm[0]
    assert abs(offset - truth) < 0.25 * truth, (offset, truth)
    assert any("coupling-mode points" in r and "gear 1" in r for r in conv.reasons), conv.reasons
    assert any("none below" in r and "extrapolation" in r for r in conv.reasons), conv.reasons
    checks = property_checks(report.identification, vehicle, drawn.setup, drawn.noise, None, {"torque_converter"})
    bad = [c for c in checks if not c.passed]
    assert checks and not bad, "; ".join(f"{c.name} error {c.error:.4g} > {c.tolerance:.4g}" for c in bad)


def test_converter_through_a_clipped_gear_1_says_its_curves_are_not_identified() -> None:
    # found by test_torque_converter_curves_recovered: K_TEL 8000 (+-273 Nm shaft range) clips the 1st-gear
    # ramp-ups, gear 1 borrows gear 2's transmission model and is left uncalibrated (no coupling mode in the gears of
    # their own model to anchor it), and 663 of the 679 converter points are in gear 1: the TR curve was reported
    # 16 % off as a finite number. Then the fit said so (more than half of the points, MAX_UNCALIBRATED_SHARE) and the
    # curves that read the turbine torque were "not identified", 3 of the 4 checks: the property's "most checks
    # identified" failed the draw. Now the verdict is a structure in the converter fit (UncalibratedShare) with its
    # cause: gear 1's eq. 14 lost its points to the clip guard (SATURATED samples excluded), at the bench's rail; the
    # property excuses those checks, the capacity factor (pump side) is still judged (about 2 s)
    vehicle, drawn, seed = pinned("converter_ktel_gear1_uncalibrated")
    fam = FAMILIES[TC_FAMILY]
    campaign = campaign_for(vehicle, fam.kinds, seed=seed, **FAMILY_PICKS[fam.name])
    report = validate(vehicle, drawn.setup, campaign, trace=simulate_campaign(vehicle, campaign),
                      families=[fam.name], profile="realistic")
    share = report.identification.fits["torque_converter.converter"].data[UncalibratedShare.KEY]
    assert share.points_by_gear == {1: 663} and share.n_points == 679, share
    assert list(share.clipped) == [1] and share.clip_explains(), share
    cause = share.clipped[1]
    assert "InsufficientDataError" in cause.fit_error and cause.clipped_samples > 0 and cause.engaged_s > 0, cause
    checks = {c.name: c for c in property_checks(report.identification, vehicle, drawn.setup, drawn.noise, None,
                                                 {fam.name})}
    for name in TURBINE_CHECKS:
        c = checks[name]
        assert not math.isfinite(c.identified) and "gear 1 on gear 2's" in c.note and cause.reason() in c.note, c.note
        assert _clipped_on_this_bench(c, report.identification, drawn), (name, c.note)
    assert checks["torque_converter.capacity_factor_curve"].passed
    # the same draw at K_TEL 4000 (range +-547 Nm) clips nowhere in 1st: gear 1 keeps its model, nothing to excuse
    tel = drawn.setup.telemetry.model_copy(update={"k_tel": 4000})
    wide = DrawnSetup(drawn.setup.model_copy(update={"telemetry": tel}), drawn.noise, drawn.beyond_sheet)
    report = validate(vehicle, wide.setup, campaign, trace=simulate_campaign(vehicle, campaign),
                      families=[fam.name], profile="realistic")
    assert "transmission.gear1" in report.identification.fits
    assert UncalibratedShare.KEY not in report.identification.fits["torque_converter.converter"].data


def _synthetic_clip_report(clipped: bool, *, rail: float | None = None, uncalibrated: dict[int, int] | None = None,
                           note_from_clipped: bool | None = None) -> tuple[list[Check], IdentificationResult]:
    """The converter's four checks, three 'not identified' through an uncalibrated gear 1, with the structure."""
    from dataclasses import replace

    from benchtwin.identification._fit import FitResult
    from benchtwin.identification.torque_converter_borrowed import uncalibrated_share
    from benchtwin.identification.transmission_clip import ClipCause

    _vehicle, drawn, _seed = pinned("converter_ktel_gear1_uncalibrated")
    tel = drawn.setup.telemetry
    pts = uncalibrated or {1: 663}
    gear = np.concatenate([np.full(v, k) for k, v in pts.items()] + [np.full(679 - sum(pts.values()), 2)])
    share = uncalibrated_share(gear, np.ones(679, dtype=bool), {k: 2 for k in pts}, set())
    assert share is not None
    cause = ClipCause(1, 11993, 24.0, 70.0, k_tot(tel.shaft, tel.k_tel) * tel.vout_max_v if rail is None else rail,
                      "InsufficientDataError: transmission.gear1: 2 steady points; need at least 3")
    traced = replace(share, clipped={1: cause})
    said = traced if (clipped if note_from_clipped is None else note_from_clipped) else share
    result = IdentificationResult()
    result.fits["torque_converter.converter"] = FitResult({}, 1.0, 1.0, 0.0, 679,
                                                          data={UncalibratedShare.KEY: traced if clipped else share})
    nan = float("nan")
    checks = [Check(TC_FAMILY, n, nan, 1.0, nan, 0.02, "rel", "-", False, f"not identified: {said.reason()}")
              for n in TURBINE_CHECKS]
    checks.append(Check(TC_FAMILY, "torque_converter.capacity_factor_curve", 13.0, 12.9, 0.008, 0.02, "rel", "-",
                        True, ""))
    return checks, result


def test_only_the_benchs_traced_clipping_excuses_most_converter_checks_not_identified() -> None:
    # the rule of _judge, on synthetic reports (no run): three of four converter checks "not identified" pass only
    # when the converter fit's structure traces them to the bench's clipping. Mutants: _clipped_on_this_bench
    # accepting any not-identified turbine check fails the unrelated, the foreign-rail and the minority cases; one
    # that skips the note's words fails the words case
    _vehicle, drawn, _seed = pinned("converter_ktel_gear1_uncalibrated")
    checks, result = _synthetic_clip_report(True)
    _judge(TC_FAMILY, checks, PAPER_VEHICLE, drawn, result)  # traced: passes
    cases = {
        "unrelated (no cause in the structure)": _synthetic_clip_report(False),
        "no identification result": (checks, None),
        "the rail of another gain (K_TEL 4000)": _synthetic_clip_report(True, rail=546.8),
        "the clipped gear a minority (gear 4's points keep the share)": _synthetic_clip_report(
            True, uncalibrated={1: 150, 4: 400}),
        "the cause not in the checks' words": _synthetic_clip_report(True, note_from_clipped=False),
    }
    for what, (c, r) in cases.items():
        try:
            _judge(TC_FAMILY, c, PAPER_VEHICLE, drawn, r)
        except AssertionError as exc:
            assert "3 of 4 checks not excited" in str(exc), (what, str(exc))
        else:
            pytest.fail(f"{what}: excused")
    # a bare "not identified" is no excuse at all, traced structure or not
    bare = [Check(c.group, c.name, c.identified, c.truth, c.error, c.tolerance, c.mode, c.unit, c.passed,
                  "not identified" if c.name in TURBINE_CHECKS else c.note) for c in checks]
    with pytest.raises(AssertionError, match="error nan"):
        _judge(TC_FAMILY, bare, PAPER_VEHICLE, drawn, result)


def test_loose_converter_on_a_10_bit_telemetry() -> None:
    # found by test_torque_converter_curves_recovered: Gamma 0.62 for 0.80 (the first estimate compared the
    # turbine torque with a motor torque that also accelerates the pump) and the TR curve 5-7 % off near Gamma,
    # where gear 1's C0 from quantised ramp-ups moves the small turbine torques; now Gamma 0.76 and the TR curve
    # and Gamma judged with the transmission's quantisation bound carried through eq. 32 (about 8 s)
    _converter_checks_pass(*pinned("converter_loose_10bit"))


def _loose_converter() -> VehicleConfig:
    d = PAPER_VEHICLE.model_dump()
    d["torque_converter"].update(a_nm_per_radps2=[0.0055, 0.0, -0.0045, 0.00935, -0.008, -0.000515625, 0.0131,
                                                  -0.0131, 0.0], coupling_speed_ratio=0.80)
    return VehicleConfig.model_validate(d)


def test_loose_converter_coupling_curve_on_the_ideal_chain() -> None:
    # found by test_torque_converter_curves_recovered (the strategy's lowest capacity and stall ratio): its
    # coupling points span SR 0.80-0.85 only (above, the pump torque falls below the 20 Nm threshold), and
    # three free a6..a8 put the coupling curve 10-30 % off at SR 0.95; fitted with no torque without slip
    # (a6 + a7 + a8 = 0) it is 0.7 % off
    vehicle = _loose_converter()
    campaign = campaign_for(vehicle, TC_KINDS, seed=0)
    report = validate(vehicle, IDEAL_SETUP, campaign, trace=simulate_campaign(vehicle, campaign),
                      families=["torque_converter"])
    bad = [c.name for c in report.checks if c.group == "torque_converter" and not c.passed]
    assert not bad, bad


def test_converter_fit_of_the_family_tests_alone_on_the_ideal_chain() -> None:
    # the family's tests in a row (no neutral braking between them) were 25 % off: the motor's spin-up from
    # stand-still at the start of each deceleration and coastdown passed the quasi-steady filter, and without
    # the ramp-downs no quasi-steady point lay below SR 0.32, so the stall end was extrapolated from them
    campaign = campaign_for(PAPER_VEHICLE, FAMILIES["torque_converter"].kinds, seed=0)
    report = validate(PAPER_VEHICLE, IDEAL_SETUP, campaign, trace=simulate_campaign(PAPER_VEHICLE, campaign),
                      families=["torque_converter"])
    bad = [c.name for c in report.checks if c.group == "torque_converter" and not c.passed]
    assert not bad, bad


@pytest.mark.parametrize("name", ["engine_petrol_corner", "motor_hpcu_offset"])
def test_pinned_findings_hold_at_the_noise_free_bound(name: str) -> None:
    # the pinned examples have no noise: their fixes must meet the plain bound floor + systematic, without
    # the property's allowance for noise and for many checks (before the fixes: BSFC map 3.2 % > 1.5 %,
    # W_loss_gen 7.5 % > 1 %)
    vehicle, drawn, seed = pinned(name)
    family = name.split("_", 1)[0]
    campaign = campaign_for(vehicle, FAMILIES[family].kinds, seed=seed, **FAMILY_PICKS[family])
    report = validate(vehicle, drawn.setup, campaign, trace=simulate_campaign(vehicle, campaign), families=[family],
                      profile="realistic")
    checks = property_checks(report.identification, vehicle, drawn.setup, 0.0, None, {family}, noise_free=True)
    bad = [(c.name, c.error, c.tolerance) for c in checks if not c.passed]
    assert checks and not bad, bad


def test_tolerance_grows_with_noise_and_declared_errors() -> None:
    # the tolerance function itself: at noise 0 and no declared error it is the ideal floor plus a quarter of
    # the paper's noise tolerance; it grows
    # linearly with the noise and with the declared gain errors (a mutant that drops a term fails here)
    from strategies import PAPER_SETUP

    from benchtwin.identification._fit import IdentificationResult

    empty = IdentificationResult()
    t0 = {c.name: c.tolerance for c in property_checks(empty, PAPER_VEHICLE, IDEAL_SETUP, 0.0, None, {"battery"})}
    t1 = {c.name: c.tolerance for c in property_checks(empty, PAPER_VEHICLE, IDEAL_SETUP, 1.0, None, {"battery"})}
    tp = {c.name: c.tolerance for c in property_checks(empty, PAPER_VEHICLE, PAPER_SETUP, 1.0, None, {"battery"})}
    assert np.isclose(t0["battery.alpha"], 1.5 * (1e-3 + 0.25 * 2e-3))
    assert np.isclose(t1["battery.alpha"], 1.5 * (1e-3 + 2e-3))
    assert np.isclose(tp["battery.alpha"], 1.5 * (1e-3 + 2e-3) + 0.0005)  # + the paper shunt's 0.05 % voltage gain


def test_quantisation_floor_follows_a_coarser_declared_converter() -> None:
    # found by test_transmission_recovers_eta_m_and_c0 with a 10-bit telemetry converter (declared as a
    # quantisation step of 4 wire steps) and no noise: gear 1 eta_m 2.75 % off against a floor computed from
    # the 12-bit step; the floor must scale with the step the setup declares (linear in it)
    from strategies import PAPER_SETUP

    from benchtwin.identification._fit import FitResult, ParameterEstimate
    from benchtwin.sensors.telemetry import torque_step_nm
    from benchtwin.validation.parameters import _quantisation_bound

    c = np.linspace(20.0, 300.0, 12)
    fit = FitResult({n: ParameterEstimate(n, v, 0.0, (v, v), 1.0, c.size) for n, v in (("eta_m", 0.95), ("C0", 5.0))},
                    1.0, 1.0, 0.0, c.size, data={"c": c, "gear_ratio": np.array([4.7])})
    step = torque_step_nm(PAPER_SETUP.telemetry.shaft, PAPER_SETUP.telemetry.k_tel)
    coarse = PAPER_SETUP.model_copy(update={"telemetry": PAPER_SETUP.telemetry.model_copy(
        update={"errors": PAPER_SETUP.telemetry.errors.model_copy(update={"quantisation_step": 4 * step})})})
    for p in ("eta_m", "C0"):
        q12, q10 = _quantisation_bound(fit, p, PAPER_SETUP), _quantisation_bound(fit, p, coarse)
        assert q12 > 0 and np.isclose(q10, 4 * q12)
