"""Operating cells of the engine's steady points: repeats of one operating point merged into one weighted point.

A campaign that drives the same speed x torque point several times (the same ramp-up repeated, or a level
visited twice within a ramp-up) gives several steady points whose means differ by less than the sensors can
tell apart. Fitting the BSFC map's thin plate through every one of them costs O(n^2) memory and O(n^3) time
in the number of points, and its cross-validation leaks: a repeat left out is predicted by its twin kept in.

Two steady points are one operating cell when their mean speeds differ by less than the speed channel's step
and their mean torques by less than the torque channel's step (the resolution the setup declares for the
roles, ``Recording.meta["declared_uncertainty"]``): readings one whole step apart are two levels the sensor
told apart, closer means are one level read twice (the difference of two readings' rounding errors, each
within +-q/2, spans +-q). Cells are the connected components of that relation (single linkage; the repeats of
a steady level never span a step, so no chain joins two levels one step apart).

A cell is fitted as one point at the mean speed, torque and fuel of its members with the thin plate's
smoothing divided by its count: the penalised least squares through ``c`` points at one place,
``sum_k (y_k - f(x))^2 = c (mean(y) - f(x))^2 + const``, is the one point ``mean(y)`` with weight ``c``
(scipy ``RBFInterpolator`` takes a smoothing per point, the inverse of the weight). The merged point's noise is
the members' divided by ``sqrt(c)``; the map's cross-validation leaves whole cells out and its bootstrap
draws each cell's cross-validated error, so the interval sees that smaller noise and no leak between repeats.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["OperatingCells", "declared_cell", "operating_cells"]

#: the roles whose declared steps make a cell: speed (rpm), torque (Nm)
CELL_ROLES = ("engine_speed_rpm", "engine_torque_nm")


class OperatingCells:
    """Steady points merged by operating cell: mean speed, torque and fuel, member count, each point's cell."""

    def __init__(self, speed_rpm: np.ndarray, torque_nm: np.ndarray, fuel_gps: np.ndarray, count: np.ndarray,
                 label: np.ndarray) -> None:
        self.speed_rpm = speed_rpm
        self.torque_nm = torque_nm
        self.fuel_gps = fuel_gps
        #: steady points in each cell
        self.count = count
        #: each steady point's cell (index into the cell arrays)
        self.label = label


def declared_cell(meta: Mapping[str, object]) -> tuple[float, float] | None:
    """The cell size (speed step in rpm, torque step in Nm) the Recording's declared budget gives, else None.

    Parameters
    ----------
    meta:
        ``Recording.meta``; its ``declared_uncertainty`` entries of ``engine_speed_rpm`` and ``engine_torque_nm``
        are read (``resolution``). A real log without a declared budget has none: its points are not merged.
    """
    table = meta.get("declared_uncertainty") or {}
    if not isinstance(table, Mapping):
        return None
    steps = []
    for role in CELL_ROLES:
        d = table.get(role) or {}
        q = float(d.get("resolution", 0.0) or 0.0) if isinstance(d, Mapping) else 0.0
        if not (np.isfinite(q) and q > 0):
            return None
        steps.append(q)
    return steps[0], steps[1]


def operating_cells(speed_rpm: np.ndarray, torque_nm: np.ndarray, fuel_gps: np.ndarray,
                    cell: tuple[float, float] | None) -> OperatingCells:
    """Merge steady points closer than one step in both speed and torque into one point per operating cell.

    Parameters
    ----------
    speed_rpm, torque_nm, fuel_gps:
        Steady points (finite).
    cell:
        Speed step (rpm) and torque step (Nm); None or a non-positive step merges nothing (every point its own
        cell, in its own order).

    Returns
    -------
    OperatingCells
        Cells in the order of their first member, each the plain mean of its members.
    """
    n = np.asarray(speed_rpm, dtype=float)
    t = np.asarray(torque_nm, dtype=float)
    f = np.asarray(fuel_gps, dtype=float)
    m = n.size
    if cell is None or m < 2 or not (cell[0] > 0 and cell[1] > 0):
        return OperatingCells(n, t, f, np.ones(m, dtype=np.int64), np.arange(m))
    # Chebyshev distance in steps; strictly less than one step (a whole step apart: two levels told apart)
    pairs = cKDTree(np.column_stack([n / cell[0], t / cell[1]])).query_pairs(1.0 - 1e-9, p=np.inf,
                                                                               output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(m, m))
    _, raw = connected_components(graph, directed=False)
    # number the cells by their first member, so a campaign without repeats keeps its points' order
    first = np.full(raw.max() + 1, m)
    np.minimum.at(first, raw, np.arange(m))
    order = np.argsort(first, kind="stable")
    label = np.empty_like(order)
    label[order] = np.arange(order.size)
    label = label[raw]
    count = np.bincount(label).astype(np.int64)

    def mean(x: np.ndarray) -> np.ndarray:
        return np.bincount(label, weights=x) / count

    if count.max() == 1:
        return OperatingCells(n, t, f, count, label)
    return OperatingCells(mean(n), mean(t), mean(f), count, label)
