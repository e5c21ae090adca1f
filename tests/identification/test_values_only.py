"""A type B re-run reads the parameters' values only (``_reuse.values_only``): work whose only output is a standard
error or an interval is left out there, every value stays bit for bit, and the nominal run keeps it all.

The BSFC map's wild bootstrap (the standard errors of its minimum) on the Mercedes 1.7 l points, and the converter's
calibration budget on synthetic converter points (test_torque_converter_calibration's). About 2 s.
"""

from __future__ import annotations

import threading

import numpy as np
from test_engine import MERCEDES_SPECS
from test_torque_converter_calibration import _fit, _points

from benchtwin.identification._reuse import only_values, values_only
from benchtwin.identification.engine import fit_bsfc_map
from benchtwin.identification.run import _rerun
from benchtwin.identification.torque_converter_calibration import TORQUE_SCALE_SOURCE, calibration_budget
from benchtwin.recording import Recording


def _values(fit) -> dict[str, float]:  # type: ignore[no-untyped-def]
    return {k: p.value for k, p in fit.params.items()}


def test_the_bsfc_map_s_values_without_its_bootstrap(mercedes_points) -> None:
    d = mercedes_points
    full = fit_bsfc_map(MERCEDES_SPECS, d["speed_rpm"], d["torque_nm"], d["fuel_gps"])
    with values_only():
        quick = fit_bsfc_map(MERCEDES_SPECS, d["speed_rpm"], d["torque_nm"], d["fuel_gps"])
    assert _values(quick) == _values(full)  # bit for bit
    for k in ("map_bsfc", "bsfc_fit", "bsfc_cv", "map_best_region"):
        np.testing.assert_array_equal(quick.data[k], full.data[k])
    assert full["bsfc_min"].std_error > 0.5  # the bootstrap ran (about 2 g/kWh: test_engine)
    assert quick["bsfc_min"].std_error == 0.0  # and here it did not
    # after the block the nominal fit has its bootstrap again
    assert fit_bsfc_map(MERCEDES_SPECS, d["speed_rpm"], d["torque_nm"], d["fuel_gps"])["bsfc_min"].std_error == \
        full["bsfc_min"].std_error


def test_the_converter_s_values_without_its_calibration_budget() -> None:
    pts, _ = _points(0)
    full = _fit(pts, pts.w_t, pts.t_t)
    calibration_budget(full, pts, lambda w_t, t_t: _fit(pts, w_t, t_t), 10)
    quick = _fit(pts, pts.w_t, pts.t_t)
    with values_only():
        calibration_budget(quick, pts, lambda w_t, t_t: _fit(pts, w_t, t_t), 10)
    for fk in full:
        assert _values(quick[fk]) == _values(full[fk])
    assert TORQUE_SCALE_SOURCE in full["converter"].params["gamma_coupling"].type_b
    assert not quick["converter"].params["gamma_coupling"].type_b


def test_the_flag_holds_in_its_block_and_thread_only() -> None:
    seen: list[bool] = []
    assert not only_values()
    with values_only():
        assert only_values()
        t = threading.Thread(target=lambda: seen.append(only_values()))  # another thread: a nominal run's
        t.start()
        t.join()
        with values_only():
            assert only_values()
        assert only_values()
    assert not only_values()
    assert seen == [False]


def test_the_orchestrator_s_re_runs_read_values_only(monkeypatch) -> None:
    """``run._rerun`` (the function propagate_type_b calls) runs the method inside the block, and only there."""
    import benchtwin.identification.run as run

    inside: list[bool] = []

    def method(rec, specs, result, opts):  # type: ignore[no-untyped-def]
        inside.append(only_values())
        return {}

    monkeypatch.setattr(run, "METHODS", (run.Method("shifts", (), method, needs_specs=False),))
    _rerun("shifts", None, {})(Recording())
    assert inside == [True] and not only_values()
