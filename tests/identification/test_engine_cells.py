"""The BSFC map's operating cells: repeated steady points merged into one weighted point (engine_cells)."""

from __future__ import annotations

import numpy as np
import pytest
from _synth_a import SPECS

from benchtwin.errors import InsufficientDataError
from benchtwin.identification.engine import fit_bsfc_map, identify_engine
from benchtwin.identification.engine_cells import declared_cell, operating_cells
from benchtwin.recording import Recording

RPM = np.pi / 30
#: the paper setup's CAN steps (vehicle.dbc: EngSpeed 0.25 rpm, EngTorque 0.1 Nm)
CELL = (0.25, 0.1)


def _base(m: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``m`` scattered steady points of a Willans-like engine: fuel power = P_u / 0.42 + friction growing with speed."""
    rng = np.random.default_rng(seed)
    n = rng.uniform(1200, 3600, m)
    t = rng.uniform(30, 350, m)
    p_u = t * n * RPM
    p_f = p_u / 0.42 + 3e3 * (n / 1000) ** 1.5
    return n, t, p_f / 42.8e6 * 1e3


def test_points_without_repeats_are_their_own_cells_and_give_the_same_map() -> None:
    """A campaign without repeats: every point its own cell, in its order, and the map bit for bit the one fitted
    without cells (the smoothing per point is the scalar's over a count of one)."""
    n, t, f = _base(60)
    cells = operating_cells(n, t, f, CELL)
    assert np.array_equal(cells.label, np.arange(60)) and (cells.count == 1).all()
    a = fit_bsfc_map(SPECS, n, t, f, cell=CELL, n_boot=20)
    b = fit_bsfc_map(SPECS, n, t, f, cell=None, n_boot=20)
    assert a.n_points == b.n_points == 60
    for key in ("map_bsfc", "bsfc_fit", "bsfc_cv"):
        assert np.array_equal(a.data[key], b.data[key], equal_nan=True)
    for key in a.params:
        assert a[key].value == b[key].value and a[key].std_error == b[key].std_error


def test_a_whole_step_apart_is_two_cells() -> None:
    """Readings a whole step apart are two levels the sensor told apart; closer than a step, one level read twice."""
    n = np.array([2000.0, 2000.0 + 0.25, 2000.0, 2000.1])
    t = np.array([100.0, 100.0, 100.1, 150.05])
    cells = operating_cells(n, t, np.ones(4), CELL)
    assert cells.count.size == 4
    cells = operating_cells(np.array([2000.0, 2000.2, 2000.0]), np.array([100.0, 100.05, 150.0]), np.ones(3), CELL)
    assert cells.count.tolist() == [2, 1] and cells.label.tolist() == [0, 0, 1]
    np.testing.assert_allclose(cells.speed_rpm, [2000.1, 2000.0])


def test_merged_cells_give_the_fit_through_every_repeat() -> None:
    """Points repeated 1..4 times at one place with different fuel readings: the cells' fit (mean fuel, smoothing over
    the count) is the penalised least squares through every repeat, ``sum_k (y_k - f)^2 = c (mean y - f)^2 + const``:
    the same map to rounding. The smoothing is fixed and large (0.1) so that the weights matter; a fit that drops the
    weights (smoothing not over the count) moves the map by up to 1.3e-2 relative here, this bound is 1e-8."""
    n0, t0, f0 = _base(40, seed=1)
    rng = np.random.default_rng(5)
    reps = rng.integers(1, 5, 40)
    n, t = np.repeat(n0, reps), np.repeat(t0, reps)
    f = np.repeat(f0, reps) * (1 + rng.normal(0, 0.02, reps.sum()))
    merged = fit_bsfc_map(SPECS, n, t, f, cell=CELL, smoothing=0.1, n_boot=0)
    every = fit_bsfc_map(SPECS, n, t, f, cell=None, smoothing=0.1, n_boot=0)
    assert merged.n_points == 40 and every.n_points == reps.sum()
    assert np.array_equal(merged.data["cell_count"], reps)
    np.testing.assert_allclose(merged.data["map_bsfc"], every.data["map_bsfc"], rtol=1e-8)
    assert merged.value("bsfc_min") == pytest.approx(every.value("bsfc_min"), rel=1e-8)


def test_a_repeated_campaign_gives_the_unrepeated_map_within_the_averaging() -> None:
    """The campaign repeated 10 times, each repeat within a quarter step of the point and its fuel read with 0.5 %
    noise: one cell per point, and the map at the points is the unrepeated campaign's within what the averaging leaves
    (4 sigma of a mean of 10: 4 x 0.5 % / sqrt(10) = 0.63 %, plus the quarter step's share of BSFC = f / (T n): at
    most 0.025 / 30 + 0.0625 / 1200 relative)."""
    n0, t0, f0 = _base(60, seed=2)
    rng = np.random.default_rng(9)
    c = 10
    n = np.tile(n0, c) + rng.uniform(-CELL[0] / 4, CELL[0] / 4, 60 * c)
    t = np.tile(t0, c) + rng.uniform(-CELL[1] / 4, CELL[1] / 4, 60 * c)
    f = np.tile(f0, c) * (1 + rng.normal(0, 0.005, 60 * c))
    once = fit_bsfc_map(SPECS, n0, t0, f0, cell=CELL, n_boot=20)
    rep = fit_bsfc_map(SPECS, n, t, f, cell=CELL, n_boot=20)
    assert rep.n_points == 60 and (rep.data["cell_count"] == c).all()
    bound = 4 * 0.005 / np.sqrt(c) + 0.025 / 30 + 0.0625 / 1200
    rel = np.abs(rep.data["bsfc_fit"] / once.data["bsfc_fit"] - 1)
    assert rel.max() < bound


def test_all_points_in_one_cell_is_not_identified() -> None:
    """Bad input: one point, or many repeats of one operating point, gives a clear reason (cells counted)."""
    with pytest.raises(InsufficientDataError, match="1 usable steady points in 1 operating cells"):
        fit_bsfc_map(SPECS, np.array([2000.0]), np.array([100.0]), np.array([2.0]), cell=CELL)
    rng = np.random.default_rng(3)
    n = 2000 + rng.uniform(-0.05, 0.05, 20)
    t = 100 + rng.uniform(-0.02, 0.02, 20)
    with pytest.raises(InsufficientDataError, match="20 usable steady points in 1 operating cells"):
        fit_bsfc_map(SPECS, n, t, np.full(20, 2.0), cell=CELL)
    # through identify_engine: the map is not identified and says why; the Willans line needs spread too
    from benchtwin.identification.engine import EnginePoints

    rec = Recording(channels={}, meta={"declared_uncertainty": {"engine_speed_rpm": {"resolution": 0.25},
                                                                "engine_torque_nm": {"resolution": 0.1}}})
    with pytest.raises(InsufficientDataError, match="operating cells"):
        identify_engine(rec, SPECS, points=EnginePoints(n, t, np.full(20, 2.0)), willans=False, cold=False,
                        start=False)


def test_declared_cell_reads_the_budget() -> None:
    meta = {"declared_uncertainty": {"engine_speed_rpm": {"resolution": 0.25}, "engine_torque_nm": {"resolution": 0.1,
                                                                                                    "offset": 3.0}}}
    assert declared_cell(meta) == (0.25, 0.1)
    assert declared_cell({}) is None  # a real log without a budget: nothing merged
    assert declared_cell({"declared_uncertainty": {"engine_speed_rpm": {"resolution": 0.25}}}) is None
