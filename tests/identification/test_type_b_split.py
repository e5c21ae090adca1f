"""GUM type B across a discrete split: a re-run that changes a fit's split is a jump, not a sensitivity.

A toy method reads ``theta = mean(x) + JUMP * [mean(x) > threshold]`` and publishes the indicator as its split
(``data["split"]``), as the converter publishes its mode split. Its smooth sensitivity to an offset of ``x`` is 1
(``d mean(x) / d offset``), so the offset's contribution is ``u`` itself, whichever side of the jump a step lands.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate
from benchtwin.identification.uncertainty import SPLIT_KEY, propagate_type_b
from benchtwin.recording import Channel, Recording

#: the declared offset half-width of x and its standard uncertainty (rectangular: a / sqrt(3))
A_OFFSET = 0.3
U = A_OFFSET / math.sqrt(3.0)
JUMP = 5.0


def _rec() -> Recording:
    t = np.arange(500) * 0.01
    rec = Recording({"x": Channel("x", "Nm", t, 10.0 + np.sin(t))})
    rec.meta["declared_uncertainty"] = {"x": {"gain_frac": 0.0, "offset": A_OFFSET, "resolution": 0.0}}
    return rec


def _toy(threshold: float, split_of=None):
    """The toy method with its jump at ``mean(x) = threshold``; ``split_of(m)`` overrides the published split."""
    def run(rec: Recording) -> IdentificationResult:
        m = float(np.mean(rec["x"].values))
        above = m > threshold
        v = m + JUMP * above
        fit = FitResult({"theta": ParameterEstimate("theta", v, 0.01, (v - 0.0196, v + 0.0196), 1.0, 500)}, 1.0, 1.0,
                        0.0, 500)
        fit.data[SPLIT_KEY] = np.array([float(above) if split_of is None else split_of(m)])
        return IdentificationResult(fits={"toy": fit})
    return run


def _budget(run) -> tuple[ParameterEstimate, dict]:
    rec = _rec()
    res = run(rec)
    meta = propagate_type_b(res, rec, [(["toy"], ["x"], run)])
    return res.fits["toy"].params["theta"], meta | {"reasons": res.fits["toy"].reasons}


def test_a_step_that_crosses_the_split_is_taken_the_other_way() -> None:
    m0 = float(np.mean(_rec()["x"].values))
    p, meta = _budget(_toy(m0 + 0.5 * U))  # +1 u crosses the jump, -1 u does not
    # the smooth sensitivity (1) times u; the one-sided difference across the jump would be u + JUMP
    assert p.type_b["x.offset"] == pytest.approx(U, rel=1e-9)
    assert p.u_total < 0.1 * JUMP
    assert meta["reruns"] == 2 and len(meta["split_held"]) == 1
    assert "-1 u" in meta["split_held"][0] and any("type B" in r for r in meta["reasons"])


def test_both_full_steps_crossing_take_a_smaller_one() -> None:
    m0 = float(np.mean(_rec()["x"].values))
    # the split is "within 0.7 u of the nominal mean": +-1 u leave it, +-1/2 u keep it
    p, meta = _budget(_toy(m0 + 0.5 * U, split_of=lambda m: float(abs(m - m0) > 0.7 * U)))
    assert p.type_b["x.offset"] == pytest.approx(U, rel=1e-9)
    assert meta["reruns"] == 3 and "+0.5 u" in meta["split_held"][0]


def test_a_step_inside_the_split_is_unchanged() -> None:
    m0 = float(np.mean(_rec()["x"].values))
    p, meta = _budget(_toy(m0 + 2.0 * U))
    assert p.type_b["x.offset"] == pytest.approx(U, rel=1e-9)
    assert meta["reruns"] == 1 and meta["split_held"] == [] and meta["reasons"] == []


def test_a_split_that_changes_at_every_step_keeps_the_jump_and_says_so() -> None:
    m0 = float(np.mean(_rec()["x"].values))
    p, meta = _budget(_toy(m0 + 0.5 * U, split_of=lambda m: float(abs(m - m0) > 1e-9)))
    assert p.type_b["x.offset"] == pytest.approx(U + JUMP, rel=1e-9)  # the +1 u difference, as before
    assert meta["reruns"] == 6 and "every step" in meta["split_held"][0]


def test_the_converter_publishes_its_mode_split_and_the_budget_steps_inside_it() -> None:
    """The synthetic converter bench (tests/identification/_synth_b.py, Gamma 0.85): its first estimate of the
    coupling point is the 0.84 bin; the motor torque 2 Nm higher moves it to the 0.82 bin and 2 Nm lower past the
    last bin (no bin reaches TR 1: Gamma jumps to ~0.867), while 1 Nm either way keeps it. With a declared offset
    of u = 2 Nm the budget takes the +1/2 u difference, divided by 1/2, and says so."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from _synth_b import SPECS, TRANSMISSION_TRUTH, tc_recording

    from benchtwin.identification.torque_converter import identify_torque_converter
    from benchtwin.identification.uncertainty import Component, perturbed

    rec, _truth = tc_recording()

    def run(r: Recording) -> IdentificationResult:
        fits = identify_torque_converter(r, SPECS, transmission=TRANSMISSION_TRUTH)
        return IdentificationResult(fits={f"torque_converter.{k}": v for k, v in fits.items()})

    def gamma_and_split(offset: float) -> tuple[float, tuple]:
        conv = run(perturbed(rec, Component("x", ("em_torque_nm",), "offset", offset))).fits[
            "torque_converter.converter"]
        return conv.value("gamma_coupling"), tuple(conv.data[SPLIT_KEY])

    nominal = run(rec)
    g0, s0 = nominal.fits["torque_converter.converter"].value("gamma_coupling"), tuple(
        nominal.fits["torque_converter.converter"].data[SPLIT_KEY])
    assert s0 == (pytest.approx(0.84), 1.0)
    assert gamma_and_split(2.0)[1] != s0 and gamma_and_split(-2.0)[1] != s0
    g_half, s_half = gamma_and_split(1.0)
    g_minus, s_minus = gamma_and_split(-1.0)
    assert s_half == s_minus == s0
    rec.meta["declared_uncertainty"] = {"em_torque_nm": {"gain_frac": 0.0, "offset": 2.0 * math.sqrt(3.0),
                                                          "resolution": 0.0}}
    meta = propagate_type_b(nominal, rec, [(sorted(nominal.fits), ["em_torque_nm"], run)])
    p = nominal.fits["torque_converter.converter"].params["gamma_coupling"]
    assert p.type_b["em_torque_nm.offset"] == pytest.approx(abs(g_half - g0) / 0.5, rel=1e-9)
    # the smooth slope: the central difference over +-1 Nm, times u = 2 Nm (the -1 u step's jump is ~4x this)
    assert p.type_b["em_torque_nm.offset"] == pytest.approx(abs(g_half - g_minus), rel=0.25)
    assert meta["reruns"] == 3 and "+0.5 u" in meta["split_held"][0]


def test_the_converter_calibration_budget_steps_inside_the_split() -> None:
    """calibration_budget's move of the turbine torque scale by one standard error crossing the split: the
    contribution is the smooth slope times the move (d mean(t_t) / d scale = mean(t_t)), not the jump."""
    from types import SimpleNamespace

    from benchtwin.identification.torque_converter_calibration import TORQUE_SCALE_SOURCE, calibration_budget

    t_t = np.linspace(50.0, 150.0, 101)  # mean 100
    rel = 0.002  # the scale's standard error over the scale
    pts = SimpleNamespace(n_tcal=50, tscale_se=rel, tscale=1.0, n_cal=0, scale_se=float("nan"), scale=1.0,
                          w_t=np.ones(3), t_t=t_t, torque_calibration=None)

    def solve(_w_t: np.ndarray, tt: np.ndarray) -> dict[str, FitResult]:
        m = float(np.mean(tt))
        above = m > 100.0 + 0.5 * rel * 100.0  # +1 se crosses, -1 se does not
        v = m + JUMP * above
        fit = FitResult({"g": ParameterEstimate("g", v, 0.01, (v - 0.0196, v + 0.0196), 1.0, 101)}, 1.0, 1.0, 0.0, 101)
        fit.data[SPLIT_KEY] = np.array([float(above)])
        return {"converter": fit}

    res = solve(pts.w_t, t_t)
    calibration_budget(res, pts, solve, min_points=3)
    assert res["converter"].params["g"].type_b[TORQUE_SCALE_SOURCE] == pytest.approx(100.0 * rel, rel=1e-9)
    assert any("-1" in r and TORQUE_SCALE_SOURCE in r for r in res["converter"].reasons)
