"""A method's output shared by the type B step re-runs of one propagation (the transmission inside the converter's
re-runs): only for the very same moved Recording, as copies, within a bound in bytes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchtwin.identification import _reuse
from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate
from benchtwin.identification.run import _SHARED, _shared
from benchtwin.identification.uncertainty import propagate_type_b
from benchtwin.recording import Channel, Recording


def _rec(budget: dict) -> Recording:
    t = np.arange(400) * 0.01
    rec = Recording({"x": Channel("x", "Nm", t, 10.0 + np.sin(t)), "y": Channel("y", "Nm", t, 3.0 + 0 * t)})
    rec.meta["declared_uncertainty"] = budget
    return rec


def _fit(name: str, v: float) -> IdentificationResult:
    fit = FitResult({"theta": ParameterEstimate("theta", v, 0.01, (v - 0.02, v + 0.02), 1.0, 400)}, 1.0, 1.0, 0.0, 400)
    return IdentificationResult(fits={name: fit})


def test_step_reruns_share_an_inner_method_only_for_the_same_move() -> None:
    """Two methods run the same inner method first (means of x and y); each component moves other channels, so each
    computes it once and the other method takes it: the budgets are the analytic ones of unshared runs."""
    # x.offset and y.offset have the same u: a key without the component's roles or name would mix them up
    budget = {"x": {"gain_frac": 0.01, "offset": 0.3}, "y": {"offset": 0.3}}
    rec = _rec(budget)
    inner_runs: list[tuple[float, float]] = []

    def inner(r: Recording) -> tuple[float, float]:
        out = (float(np.mean(r["x"].values)), float(np.mean(r["y"].values)))
        inner_runs.append(out)
        return out

    def method(name: str, a: float, b: float):
        def run(r: Recording) -> IdentificationResult:
            mx, my = _reuse.shared_output("inner", (), (), lambda: inner(r))
            return _fit(name, a * mx + b * my)
        return run

    res = _fit("one", 0.0)
    res.fits.update(_fit("two", 0.0).fits)
    res.fits["one"].params["theta"].value = method("one", 2.0, -1.0)(rec).fits["one"].params["theta"].value
    res.fits["two"].params["theta"].value = method("two", 1.0, 3.0)(rec).fits["two"].params["theta"].value
    inner_runs.clear()
    meta = propagate_type_b(res, rec, [({"one"}, ["x", "y"], method("one", 2.0, -1.0)),
                                       ({"two"}, ["x", "y"], method("two", 1.0, 3.0))], workers=1)
    assert meta["reruns"] == 6 and not meta["failed"]
    assert len(inner_runs) == 3  # once per component, not once per method and component
    mean_x = float(np.mean(rec["x"].values))
    u_g, u_o = 0.01 / math.sqrt(3), 0.3 / math.sqrt(3)
    one, two = res.fits["one"].params["theta"].type_b, res.fits["two"].params["theta"].type_b
    assert one["x.gain"] == pytest.approx(2 * mean_x * u_g, rel=1e-9)
    assert one["x.offset"] == pytest.approx(2 * u_o, rel=1e-9)
    assert one["y.offset"] == pytest.approx(u_o, rel=1e-9)
    assert two["x.gain"] == pytest.approx(mean_x * u_g, rel=1e-9)
    assert two["x.offset"] == pytest.approx(u_o, rel=1e-9)
    assert two["y.offset"] == pytest.approx(3 * u_o, rel=1e-9)
    assert _reuse.shared_output_bytes() == 0  # the store goes with the propagation


def test_shared_output_only_inside_a_step_rerun_and_as_copies() -> None:
    calls = []

    def compute() -> dict:
        calls.append(1)
        return {"a": np.arange(3.0)}

    # no store, or a store but not a step re-run (the nominal run, a rounding draw): computed each time
    _reuse.shared_output("m", (), (), compute)
    with _reuse.sharing_outputs():
        _reuse.shared_output("m", (), (), compute)
        _reuse.shared_output("m", (), (), compute)
    assert len(calls) == 3
    calls.clear()
    with _reuse.sharing_outputs():
        with _reuse.moved_by(("rec", "x.gain", 1.0)):
            first = _reuse.shared_output("m", (), (), compute)
            first["a"][0] = 99.0  # a caller may change what it got
            again = _reuse.shared_output("m", (), (), compute)
            other_key = _reuse.shared_output("m", ("other options",), (), compute)
        with _reuse.moved_by(("rec", "x.gain", 2.0)):
            other_move = _reuse.shared_output("m", (), (), compute)
        assert _reuse.shared_output_bytes() > 0
    assert len(calls) == 3 and again["a"].tolist() == [0.0, 1.0, 2.0] and again is not first
    assert other_key["a"].tolist() == other_move["a"].tolist() == [0.0, 1.0, 2.0]


def test_shared_outputs_bounded_in_bytes(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []

    def compute() -> np.ndarray:
        calls.append(1)
        return np.zeros(1000)

    monkeypatch.setattr(_reuse, "OUTPUT_BYTES", 4000)  # less than one output pickled
    with _reuse.sharing_outputs(), _reuse.moved_by("k"):
        for _ in range(3):
            _reuse.shared_output("m", (), (), compute)
        assert _reuse.shared_output_bytes() == 0
    assert len(calls) == 3


def test_only_the_methods_others_run_first_are_shared() -> None:
    from benchtwin.identification.run import METHODS

    assert {"transmission"} == _SHARED
    known = {m.name: m for m in METHODS}
    assert _shared(known["transmission"], None, {}).run is not known["transmission"].run
    assert _shared(known["torque_converter"], None, {}) is known["torque_converter"]
