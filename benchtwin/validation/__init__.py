"""Validation: the only package where the truth (the vehicle file, the Trace) and the estimates meet.

It answers the questions a test engineer asks before instrumenting a car:

* does the acquisition chain deliver every channel faithfully (:mod:`~benchtwin.validation.chain`)?
* does the planned campaign identify every parameter, and how close does it get
  (:mod:`~benchtwin.validation.parameters`)?
* which telemetry gain K_TEL should the propeller-shaft torque use (:mod:`~benchtwin.validation.gain`)?
* what do the identified maps predict for a drive identification never saw, and which map is off
  (:mod:`~benchtwin.validation.predict`, :mod:`~benchtwin.validation.holdout`)?

:func:`~benchtwin.validation.run.validate` runs the whole chain and returns a
:class:`~benchtwin.validation.report.ValidationReport`.
"""

from benchtwin.validation.chain import chain_checks
from benchtwin.validation.gain import GainOption, select_gain
from benchtwin.validation.parameters import PAPER_R2, compare_with_truth, paper_estimation_fits, truth_expectations
from benchtwin.validation.report import Check, ValidationReport
from benchtwin.validation.run import validate

__all__ = [
    "PAPER_R2",
    "Check",
    "GainOption",
    "ValidationReport",
    "chain_checks",
    "compare_with_truth",
    "paper_estimation_fits",
    "select_gain",
    "truth_expectations",
    "validate",
]
