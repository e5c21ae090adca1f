"""A chain check is valid where the wire can carry the truth: samples whose truth lies beyond a signal's range
(a displayed SOC the plant drives below 0 % when a campaign's SOC runs on, issue #10) reach the acquisition
saturated, are counted and said in the note, and are not compared; inside the range the check is as strict as
before. Well under a second."""

from __future__ import annotations

import numpy as np

from benchtwin.config import load_setup
from benchtwin.recording import Channel, Recording
from benchtwin.trace import Trace
from benchtwin.validation.chain import _chain_truth, chain_checks

IDEAL = load_setup("ideal")
ROLE = "displayed_soc_pct"
#: the DBC's DisplayedSOC: 8 bits unsigned, 0.5 %/bit (vehicle.dbc), so 0 .. 127.5 %
STEP, LOW, HIGH = 0.5, 0.0, 127.5


def _run(truth_lo: float, truth_hi: float, shift_inside: float = 0.0):
    t = np.arange(0.0, 100.0, 0.01)
    x = np.linspace(truth_hi, truth_lo, t.size)
    tr = Trace(t, {ROLE: x})
    ts = t[::10]
    wire = np.clip(np.rint(x[::10] / STEP) * STEP, LOW, HIGH)  # what the 8-bit signal carries
    if shift_inside:
        k = np.flatnonzero((x[::10] >= LOW) & (x[::10] <= HIGH))
        wire[k[k.size // 2]] += shift_inside
    rec = Recording(channels={ROLE: Channel(ROLE, "%", ts, wire, source="vehicle_can")})
    (check,) = chain_checks(tr, rec, IDEAL, profile="ideal", roles=[ROLE])
    return check, int(np.count_nonzero(x[::10] < LOW - 0.5 * STEP))


def test_displayed_soc_span_is_the_dbc_signal_range() -> None:
    span = _chain_truth(IDEAL)[ROLE].span
    assert span == (LOW, HIGH)


def test_truth_below_the_range_is_outside_the_domain_not_a_failure() -> None:
    check, n_out = _run(-6.0, 5.0)
    assert n_out > 0
    assert check.passed, check.note
    assert f"{n_out} samples whose truth lies outside the wire's range" in check.note


def test_inside_the_range_a_wrong_sample_still_fails() -> None:
    check, _ = _run(-6.0, 5.0, shift_inside=STEP)  # one step off: twice the half-step tolerance
    assert not check.passed
    assert abs(check.error) > 0.5 * STEP


def test_truth_wholly_outside_the_range_fails_with_no_usable_sample() -> None:
    check, n_out = _run(-20.0, -10.0)
    assert not check.passed
    assert "no usable sample" in check.note and f"{n_out} samples" in check.note
