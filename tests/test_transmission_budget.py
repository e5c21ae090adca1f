"""The declared torque errors propagated through a transmission fit (validation/transmission_budget.py).

Expected values are derived by hand from eq. 14, ``eta = eta_m (1 - C0 / C)``, on exact points:

* an offset ``d`` on the motor torque (drive, K0 open): ``C' = C + d`` and ``eta' = eta C / C'``, so
  ``eta' = eta_m - eta_m (C0 + d) / C'``: ``eta_m`` unchanged, ``C0`` moved by ``d``;
* a gain ``g`` on the motor torque: ``C' = C (1 + g)``, ``eta' = eta / (1 + g)``: ``eta_m`` moved by
  ``g / (1 + g)`` (relative), ``C0`` by ``C0 g``;
* a gain ``g`` on the shaft torque: ``eta' = eta (1 + g)``: ``eta_m`` by ``g``, ``C0`` unchanged;
* an engine gain ``g`` on points where the engine torque is ``C + M`` and the motor's ``-M`` (a charging
  hybrid point): ``C' = C + g (C + M)``, the same as a motor gain ``g`` plus an offset ``g M``.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.identification._fit import FitResult, ParameterEstimate
from benchtwin.validation.transmission_budget import declared_torque_bound

ETA_M, C0, RATIO = 0.95, 5.0, 3.2
ZERO = {k: 0.0 for k in ("engine_torque_gain", "engine_torque_offset", "em_torque_gain", "em_torque_offset",
                         "shaft_gain", "shaft_offset")}


def _fit(c: np.ndarray, c_engine: np.ndarray) -> FitResult:
    eta = ETA_M * (1.0 - C0 / c)
    params = {n: ParameterEstimate(n, v, 0.0, (v, v), 1.0, c.size) for n, v in (("eta_m", ETA_M), ("C0", C0))}
    return FitResult(params, 1.0, 1.0, 0.0, c.size,
                     data={"c": c, "eta": eta, "gear_ratio": np.array([RATIO]), "c_engine": c_engine})


C = np.linspace(20.0, 90.0, 5)
ELECTRIC = _fit(C, np.zeros_like(C))


@pytest.mark.parametrize(("key", "a", "eta_rel", "c0_nm"), [
    ("em_torque_offset", 2.0, 0.0, 2.0),
    ("em_torque_gain", 0.02, 0.02 / 1.02, C0 * 0.02),
    ("shaft_gain", 0.01, 0.01, 0.0),
    ("engine_torque_gain", 0.05, 0.0, 0.0),  # the engine is not counted with K0 open
])
def test_one_source_matches_the_hand_derivation(key: str, a: float, eta_rel: float, c0_nm: float) -> None:
    b = {**ZERO, key: a}
    assert declared_torque_bound(ELECTRIC, "eta_m", b, coast=False) == pytest.approx(eta_rel, abs=1e-9)
    assert declared_torque_bound(ELECTRIC, "C0", b, coast=False) == pytest.approx(c0_nm, abs=1e-9)


def test_engine_gain_acts_on_the_engine_torque_not_on_the_input() -> None:
    # charging hybrid points: engine C + 150 Nm, motor -150 Nm; a 4 % engine gain is a 4 % input gain plus a
    # 6 Nm offset (the fixed sum of gains allowed eta_m only the 4 %)
    m, g = 150.0, 0.04
    hybrid = _fit(C, C + m)
    b = {**ZERO, "engine_torque_gain": g}
    as_motor = {**ZERO, "em_torque_gain": g}
    # the exact moved points are C(1+g) + g M: the gain part and the offset part do not add linearly, so the
    # comparison is with a refit of those points, done here by hand in the unweighted-equivalent closed form
    c2 = C * (1 + g) + g * m
    eta2 = ETA_M * (1.0 - C0 / C) * C / c2
    A = np.column_stack([np.ones_like(c2), -1.0 / c2]) * c2[:, None]
    x = np.linalg.lstsq(A, eta2 * c2, rcond=None)[0]
    assert declared_torque_bound(hybrid, "eta_m", b, coast=False) == pytest.approx(abs(x[0] / ETA_M - 1), rel=1e-6)
    assert declared_torque_bound(hybrid, "C0", b, coast=False) == pytest.approx(abs(x[1] / x[0] - C0), rel=1e-6)
    assert declared_torque_bound(hybrid, "eta_m", b, coast=False) > 3 * declared_torque_bound(
        hybrid, "eta_m", as_motor, coast=False)


def test_sources_add_and_a_fit_without_points_keeps_the_fixed_sum() -> None:
    b = {**ZERO, "em_torque_gain": 0.02, "shaft_gain": 0.01}
    assert declared_torque_bound(ELECTRIC, "eta_m", b, coast=False) == pytest.approx(0.02 / 1.02 + 0.01, abs=1e-9)
    bare = FitResult(ELECTRIC.params, 1.0, 1.0, 0.0, 5, data={"c": C})
    assert declared_torque_bound(bare, "eta_m", b, coast=False) is None
    assert declared_torque_bound(None, "eta_m", b, coast=False) is None


def test_coast_offset_on_the_shaft_moves_c0_by_it_over_the_ratio() -> None:
    # coast: C = |T_out| / i and eta = i C_in / T_out; an offset d on |T_out| is the drive case's input
    # offset seen from the wheel side: C' = C + d / i, eta' = eta C / C', so C0 moves by d / i
    d = 3.0
    coast = _fit(C, np.zeros_like(C))
    b = {**ZERO, "shaft_offset": d}
    assert declared_torque_bound(coast, "C0", b, coast=True) == pytest.approx(d / RATIO, abs=1e-9)
    assert declared_torque_bound(coast, "eta_m", b, coast=True) == pytest.approx(0.0, abs=1e-9)
