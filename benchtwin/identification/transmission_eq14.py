"""Eq. 15-17's points and design, shared by the transmission fit, the ECU engine-torque fit and the planner.

``direction_points`` picks a gear's steady points of one direction as eq. 14's fit takes them, and
``efficiency_design`` gives the fit's regressors ``[1, -1/C]`` and its ``C^2`` weights.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["direction_points", "efficiency_design"]


def efficiency_design(c: np.ndarray, *, weighted: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Design matrix and row weights of eq. 15-17 for torques ``c`` (Nm, positive).

    Columns ``[1, -1/C]`` for the unknowns ``[eta_m, eta_m C0]``; weights ``C^2`` normalised to mean 1
    (None when ``weighted`` is false).
    """
    c = np.asarray(c, dtype=float)
    A = np.column_stack([np.ones_like(c), -1.0 / c])
    return A, (c**2 / np.mean(c**2) if weighted else None)


def direction_points(pts: Any, gear: int, direction: str, ratio: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points of one gear and direction that the fit uses.

    Parameters
    ----------
    pts:
        Steady points from :func:`~benchtwin.identification.transmission.transmission_points`.
    gear, direction:
        Gear and ``"drive"`` (``P_out > 0``) or ``"coast"`` (``P_out < 0``).
    ratio:
        The gear's ratio ``i_g``.

    Returns
    -------
    m, dom, c, eta
        Mask over all points of the gear and direction; mask over those inside the model's domain
        (``0 < eta < 1.2``, ``C > 0``); the torque referred to the input and the efficiency of the
        masked points (drive ``C_in``, ``P_out/P_in``; coast ``|T_out| / i_g``, ``P_in/P_out``).
    """
    sel = pts.usable & (pts.gear == gear)
    with np.errstate(invalid="ignore", divide="ignore"):
        if direction == "drive":
            m = sel & (pts.p_out > 0) & (pts.p_in > 0)
            c = pts.c_in[m]
            eta = pts.p_out[m] / pts.p_in[m]
        else:
            m = sel & (pts.p_out < 0) & (pts.p_in < 0)
            c = np.abs(pts.t_out[m]) / ratio
            eta = pts.p_in[m] / pts.p_out[m]
    dom = (eta > 0.0) & (eta < 1.2) & (c > 0)
    return m, dom, c, eta
