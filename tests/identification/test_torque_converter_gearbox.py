"""The gearbox model of the converter's eq. 32: each gear's eq. 14 without the ECU's engine torque (milliseconds)."""

from __future__ import annotations

import numpy as np

from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate
from benchtwin.identification.engine_torque import ENGINE_TORQUE_KEY
from benchtwin.identification.torque_converter_gearbox import converter_gearbox_table
from benchtwin.identification.transmission import fit_transmission_efficiency

ETA_M, C0 = 0.95, 5.0
#: the ECU's engine torque: 4 % gain and 6 Nm offset, the data sheet's errors taken 3x and 4x (as drawn setups do)
GAIN, OFFSET = 1.04, 6.0


def _gear_fit(n_motor: int) -> FitResult:
    """A gear's eq. 14 fit on ``n_motor`` motor-only points (15-250 Nm) and 6 hybrid points (motor 40 Nm, engine
    80-200 Nm) whose input torque is the motor's plus the ECU's engine torque, exact otherwise."""
    c_motor = np.linspace(15.0, 250.0, n_motor)
    c_eng_true = np.linspace(80.0, 200.0, 6)
    c_true = np.r_[c_motor, 40.0 + c_eng_true]
    c_eng_can = np.r_[np.zeros(n_motor), GAIN * c_eng_true + OFFSET]
    c_read = c_true - np.r_[np.zeros(n_motor), c_eng_true] + c_eng_can
    eta = ETA_M * (1.0 - C0 / c_true) * c_true / c_read  # P_out / P_in with the input power at the read torque
    fit = fit_transmission_efficiency(c_read, eta, what="transmission.gear2")
    fit.data["c_engine"] = c_eng_can
    return fit


def _can_fit() -> FitResult:
    return FitResult({n: ParameterEstimate(n, v, 0.0, (v, v), 1.0, 6) for n, v in (("gain", GAIN), ("offset", OFFSET))},
                     1.0, 1.0, 0.0, 6)


def test_motor_only_points_give_the_gearbox_without_the_engine_torque_error() -> None:
    # the gear's fit on all its points carries the ECU's offset in C0 (several Nm); eq. 14 of its motor-only points
    # is exact (mutant: taking the gear's own fit back leaves C0 > 1 Nm off and fails)
    fit = _gear_fit(8)
    assert abs(fit.value("C0") - C0) > 1.0
    table, notes = converter_gearbox_table(IdentificationResult(fits={"transmission.gear2": fit}))
    assert np.allclose(table[2], (ETA_M, C0), atol=1e-9)
    assert any("8 motor-only points" in n and "gear 2" in n for n in notes), notes


def test_too_few_motor_only_points_take_the_calibrated_engine_torque() -> None:
    # two motor-only points cannot carry eq. 14: the engine points with the ECU's torque corrected by engine.can_torque
    # (mutant: the correction's sign or its gain dropped leaves C0 off by Nm); without that calibration (or with it
    # flagged) the gear's own fit, flagged here (R^2: the ECU's error bends its points), is left out as in
    # transmission_table
    fit = _gear_fit(2)
    assert fit.status == "flagged" and abs(fit.value("C0") - C0) > 1.0
    res = IdentificationResult(fits={"transmission.gear2": fit, ENGINE_TORQUE_KEY: _can_fit()})
    table, notes = converter_gearbox_table(res)
    assert np.allclose(table[2], (ETA_M, C0), atol=1e-9)
    assert any("corrected by engine.can_torque" in n for n in notes), notes
    table, notes = converter_gearbox_table(IdentificationResult(fits={"transmission.gear2": fit}))
    assert table == {}
    flagged_can = _can_fit()
    flagged_can.flag("4 engine points from 1 gear(s): need 6 from at least 2")
    table, _ = converter_gearbox_table(IdentificationResult(fits={"transmission.gear2": fit,
                                                                  ENGINE_TORQUE_KEY: flagged_can}))
    assert table == {}


def test_a_flagged_gear_fit_enters_only_through_its_motor_only_points() -> None:
    # a gear's fit flagged (here: R^2 below its bound) is left out as in transmission_table, unless its motor-only
    # points carry eq. 14; a coast fit never enters
    fit = _gear_fit(8)
    fit.flag("R^2 = 0.01 < 0.5: eq. 14 does not explain these points (noise, unsteady points?)")
    table, notes = converter_gearbox_table(IdentificationResult(fits={"transmission.gear2": fit}))
    assert np.allclose(table[2], (ETA_M, C0), atol=1e-9)
    assert any("flagged" in n for n in notes), notes
    only_engine = _gear_fit(2)
    only_engine.flag("R^2 = 0.01 < 0.5")
    coast = _gear_fit(8)
    table, _ = converter_gearbox_table(IdentificationResult(fits={"transmission.gear3": only_engine,
                                                                  "transmission.gear2_coast": coast}))
    assert table == {}
