"""End to end: the paper campaign through the chain and identification, judged against the truth.

These are the acceptance tests of identification (issue #4): with the ideal chain every parameter
comes back within 0.1 % of the vehicle file or within the bound stated (with its reason) in
:func:`benchtwin.validation.truth_expectations`; with the paper's realistic bench every parameter is
within its stated tolerance (widened only by the systematic errors the setup declares) and every R^2
reaches the paper's.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.config import load_campaign, load_setup, load_vehicle, scenario_path
from benchtwin.errors import ConfigError
from benchtwin.trace import Trace
from benchtwin.validation import (
    PAPER_R2,
    ValidationReport,
    compare_with_truth,
    select_gain,
    validate,
)
from benchtwin.validation.run import _setup_is_ideal

VEHICLE = load_vehicle()
CAMPAIGN = load_campaign("paper.toml")


@pytest.fixture(scope="module")
def ideal_report(paper_trace: Trace) -> ValidationReport:
    """The paper campaign through the ideal bench, validated once for the tests that judge it (read only).

    ``paper_trace`` (tests/conftest.py) is the paper campaign on the shipped vehicle: VEHICLE and CAMPAIGN here.
    """
    return validate(VEHICLE, load_setup("ideal"), CAMPAIGN, trace=paper_trace)


#: prediction checks the ideal bench misses today, each explained in docs/fidelity.md (none since the model counts
#: the pump's run-down at standstill: the NEDC's electric energy went from -7.2 % to +1.6 %)
KNOWN_MISSES_IDEAL: set[str] = set()


def _fail_text(report: ValidationReport) -> str:
    return "\n" + report.format_table(only_failed=True) + f"\nerrors: {report.identification.errors}"


def _worst_case_eta_bound(c_in: np.ndarray, ratio: float, k_tel: int) -> float:
    """Largest relative error of eta_m that rounding every point's shaft torque by half a converter step can cause.

    Independent of the code under test: the step follows from facts.md (K_TOT = 218,725 / K_TEL Nm/V, 12 bits
    over +-10 V), each point's efficiency eta = T_out / (i C) moves by at most (q / 2) / (i C) (relative, eta ~ 1),
    and a least-squares estimate x = (A^T W A)^-1 A^T W y of eq. 16 (eta = eta_m - eta_m C0 / C, weights C^2)
    moves by at most sum_k |row_k| |dy_k| when every |dy_k| is at its bound.
    """
    q = 218_725.0 / k_tel * 20.0 / 4096
    a = np.column_stack([np.ones_like(c_in), -1.0 / c_in])
    w = c_in**2
    gain = np.linalg.solve((a.T * w) @ a, a.T * w)  # rows: eta_m, eta_m C0
    dy = 0.5 * q / (ratio * c_in) * 1.05  # 5 % for eta_m itself up to ~1.05 in coast (eta = i T_in / T_out)
    return float(np.abs(gain[0]) @ dy)


def test_ideal_chain_recovers_every_parameter(ideal_report: ValidationReport) -> None:
    setup = load_setup("ideal")
    report = ideal_report
    assert report.meta["profile"] == "ideal"
    # every check passes but the open misses listed (docs/fidelity.md, "A second cycle: the NEDC held out"); a listed
    # check must keep failing until the model is fixed (then drop it from there), and nothing else may fail
    failed = {c.name for c in report.checks if not c.passed}
    assert failed == KNOWN_MISSES_IDEAL, _fail_text(report)
    # transmission: judged against a worst-case bound derived here, not the tolerance the report computed
    fits = report.identification.fits
    by_name = {c.name: c for c in report.checks}
    for g in range(1, VEHICLE.n_gears + 1):
        for suffix in ("", "_coast"):
            fit = fits[f"transmission.gear{g}{suffix}"]
            bound = max(1e-3, _worst_case_eta_bound(np.asarray(fit.data["c"], float), VEHICLE.specs.gear_ratios[g - 1],
                                                    setup.telemetry.k_tel))
            check = by_name[f"transmission.gear{g}{suffix}.eta_m"]
            assert abs(check.error) <= bound, (check.name, check.error, bound)
            # the report may not claim more room than the converter step can explain: a 3-sigma bound of uniform
            # roundings (sigma q / sqrt(12)) propagated by the same weights is at most sqrt(3) times the worst case,
            # since sqrt(sum g^2) <= sum |g|
            assert check.tolerance <= max(np.sqrt(3.0) * bound * 1.001, 8e-3), (check.name, check.tolerance, bound)
    names = {c.name for c in report.checks}
    # every subsystem of the paper was judged, every gear and every gear pair both ways
    for g in range(1, VEHICLE.n_gears + 1):
        assert f"transmission.gear{g}.eta_m" in names and f"transmission.gear{g}_coast.C0" in names
    for g in range(1, VEHICLE.n_gears):
        assert f"shifts.up_{g}_{g + 1}" in names and f"shifts.down_{g + 1}_{g}" in names
    for key in ("motor.motoring.e", "motor.generating.W_loss_gen", "engine.bsfc.bsfc_min", "road_load.F2",
                "brakes.distribution.k_f", "battery.beta_charge", "torque_converter.capacity_factor_curve",
                "chain.shaft_torque_nm", "chain.engine_coolant_out_degc"):
        assert key in names
    # the 0.1 % bound holds for every gain and efficiency except where the check states a reason
    rel = [c for c in report.checks if c.mode == "rel" and c.group in ("motor", "brakes", "battery")
           and c.name.rsplit(".", 1)[-1] in ("e", "e_gen", "m_f", "m_r", "k_f", "alpha", "beta_charge",
                                              "beta_discharge")]
    assert len(rel) == 8 and all(c.tolerance <= 1e-3 for c in rel)
    looser = [c for c in report.checks if c.group not in ("chain", "r2") and c.mode == "rel" and c.tolerance > 1e-3]
    assert all(c.note for c in looser)
    # the identified maps predict the WLTC held out of identification, a second WLTC from a low SOC and a second
    # cycle, the NEDC, from 7 points above the 15 % sustain threshold: it runs electric, then the engine sustains
    assert report.prediction["held_out"] == "wltc_class3b"
    for drive in ("wltc_class3b", "wltc_low_soc", "nedc"):
        for what in ("fuel", "electric", "final_soc"):
            assert f"{drive}.{what}" in names
    (nedc,) = [d for d in report.prediction["drives"] if d["name"] == "nedc"]
    assert abs(nedc["measured"]["initial_soc_pct"] - 22.0) < 0.5
    assert nedc["measured"]["fuel_g"] > 50.0 and nedc["measured"]["electric_wh"] > 100.0  # both sides judged
    assert abs(nedc["measured"]["distance_km"] - 11.0) < 0.1  # the NEDC's, not the WLTC's 23.3 km
    assert {"submodel.motor_loss_rms", "submodel.battery_voltage_rms", "submodel.bsfc_rms_covered"} <= names
    assert all(c.note for c in report.checks if c.group == "prediction")


def test_realistic_bench_within_tolerance_and_paper_r2(paper_trace: Trace) -> None:
    report = validate(VEHICLE, load_setup("paper"), CAMPAIGN, trace=paper_trace)
    assert report.meta["profile"] == "realistic"
    assert report.passed, _fail_text(report)
    r2 = {c.name.rsplit(".", 1)[0]: c for c in report.checks if c.group == "r2"}
    assert set(r2) == set(PAPER_R2)
    # the chain really was imperfect: samples were flagged (drops, Modbus timeouts) and values carry noise
    assert sum(report.chain["flagged_samples"].values()) > 0


def test_second_vehicle_recovered_without_retuning() -> None:
    alt = load_vehicle(scenario_path("vehicles", "p2_phev_alt.toml"))
    assert alt.specs.gear_ratios != VEHICLE.specs.gear_ratios
    report = validate(alt, load_setup("ideal"), CAMPAIGN)
    # the same open misses as the default car's (docs/fidelity.md), nothing else
    assert {c.name for c in report.checks if not c.passed} == KNOWN_MISSES_IDEAL, _fail_text(report)


def test_a_wrong_truth_fails(ideal_report: ValidationReport) -> None:
    """The comparison can fail: the same identification judged against a perturbed vehicle file."""
    report = ideal_report
    wrong = VEHICLE.model_copy(deep=True)
    wrong.transmission.eta_m = [e - 0.01 for e in wrong.transmission.eta_m]
    wrong.battery.beta_charge *= 1.02
    checks = compare_with_truth(report.identification, wrong, profile="ideal")
    failed = {c.name for c in checks if not c.passed}
    assert "transmission.gear5.eta_m" in failed and "battery.beta_charge" in failed
    with pytest.raises(ConfigError):
        compare_with_truth(report.identification, VEHICLE, profile="optimistic")


def test_setup_ideal_detection() -> None:
    assert _setup_is_ideal(load_setup("ideal"))
    assert not _setup_is_ideal(load_setup("paper"))


def test_gain_selection_covers_peak_and_prefers_resolution(paper_trace: Trace) -> None:
    setup = load_setup("paper")
    best, options = select_gain(paper_trace, setup, seed=1)
    peak = float(np.max(np.abs(paper_trace["shaft_torque_nm"])))
    by_gain = {o.k_tel: o for o in options}
    assert sorted(by_gain) == [250, 500, 1000, 2000, 4000, 8000]
    chosen = by_gain[best]
    assert chosen.range_nm >= 1.1 * peak and chosen.clipped_frac == 0.0
    higher = [o for o in options if o.k_tel > best]
    # the next gain up either lacks headroom or clips: the choice is the best resolution that fits
    assert all(o.range_nm < 1.1 * peak or o.clipped_frac > 0 for o in higher)
    assert by_gain[8000].clipped_frac > 0 and by_gain[8000].clipped_segments
    # Table 2 of the paper
    assert by_gain[1000].k_tot_nm_per_v == pytest.approx(218.7, abs=0.05)
    assert by_gain[250].resolution_nm == pytest.approx(4.27, abs=0.005)
