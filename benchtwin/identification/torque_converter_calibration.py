"""The uncertainty of the converter's two calibrations, carried into every converter parameter.

:func:`~benchtwin.identification.torque_converter_points.converter_points` corrects eq. 31's turbine speed and
eq. 32's turbine torque by a scale measured on the lock-up-closed samples (``turbine_speed_scale``,
``turbine_torque_scale``), and the converter is then fitted on the corrected points as if the scales were exact.
They are not: the torque scale is the median of a few gears' medians (its standard error from their spread, with
as many degrees of freedom as gears less one), and every torque ratio moves with it. Near the coupling point the
torque ratio falls by about 2 per unit of speed ratio (``dTR/dSR`` of the paper's converter), so a scale error
``e`` moves the root of ``TR = 1`` by about ``e / 2``: on the paper campaign's ideal setup the torque scale's
standard error of 0.16 % is 0.0008 on ``gamma_coupling``, four times the fit's own standard error, and the
coupling point's interval missed the truth by that much.

The correction's uncertainty is a component of each parameter's budget (JCGM 100 3.2.4 and 5.1.2): the method is
run again with the corrected points moved by one standard error of the scale, the change of every parameter
being its contribution (``turbine_torque_scale.calibration``, ``turbine_speed_scale.calibration``), with the
scale's degrees of freedom for the Welch-Satterthwaite coverage factor. A move that changes the converter's mode
split (``data["split"]``) crossed a jump of the coupling point: it is taken the other way and smaller, as the
declared errors' re-runs are (:data:`~benchtwin.identification.uncertainty.SPLIT_STEPS`), and the fit says so.
The setup's declared errors are added later on top (:mod:`benchtwin.identification.uncertainty`, which keeps these
components).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from benchtwin.identification._fit import FitResult
from benchtwin.identification._reuse import only_values
from benchtwin.identification.torque_converter_points import ConverterPoints
from benchtwin.identification.uncertainty import SPLIT_STEPS, splits

__all__ = ["SPEED_SCALE_SOURCE", "TORQUE_SCALE_SOURCE", "calibration_budget", "torque_scale_dof"]

#: budget key of the turbine-torque calibration's uncertainty
TORQUE_SCALE_SOURCE = "turbine_torque_scale.calibration"
#: budget key of the turbine-speed calibration's uncertainty
SPEED_SCALE_SOURCE = "turbine_speed_scale.calibration"


def torque_scale_dof(pts: ConverterPoints, min_points: int) -> float:
    """Degrees of freedom of the torque scale's standard error: the gears whose median it was taken over, less one.

    Parameters
    ----------
    pts:
        The converter points (their ``torque_calibration`` samples).
    min_points:
        Least samples of a gear in the calibration (as :func:`turbine_torque_scale` took them).
    """
    cal = pts.torque_calibration
    if cal is None:
        return math.inf
    _, counts = np.unique(np.asarray(cal.gear), return_counts=True)
    return float(max(int((counts >= min_points).sum()) - 1, 1))


def calibration_budget(res: dict[str, FitResult], pts: ConverterPoints,
                       solve: Callable[[np.ndarray, np.ndarray], dict[str, FitResult]], min_points: int) -> None:
    """Add the calibrations' components to every parameter of ``res`` (in place; module docstring).

    Parameters
    ----------
    res:
        The converter's fits on the corrected points.
    pts:
        Those points, with the scales' standard errors (``tscale_se``, ``scale_se``).
    solve:
        The method from the points on: ``solve(w_t, t_t)`` returns the fits.
    min_points:
        Least samples of a gear in the torque calibration.
    """
    if only_values():  # a type B re-run: its caller reads the values only, which the budget leaves as they are
        return
    moves: list[tuple[str, Callable[[float], tuple[np.ndarray, np.ndarray]], float]] = []
    if pts.n_tcal and math.isfinite(pts.tscale_se) and pts.tscale_se > 0:
        rel = pts.tscale_se / pts.tscale
        moves.append((TORQUE_SCALE_SOURCE, lambda f, rel=rel: (pts.w_t, pts.t_t * (1.0 + f * rel)),
                      torque_scale_dof(pts, min_points)))
    if pts.n_cal and math.isfinite(pts.scale_se) and pts.scale_se > 0:
        # the speed scale is a median over n_cal samples: its degrees of freedom are many (taken as infinite)
        rel = pts.scale_se / pts.scale
        moves.append((SPEED_SCALE_SOURCE, lambda f, rel=rel: (pts.w_t * (1.0 + f * rel), pts.t_t), math.inf))
    split0 = splits(res, res)
    for source, move, dof in moves:
        # one standard error; a move that changes the mode split crossed a jump of the coupling point, not a slope:
        # then the other way and smaller (SPLIT_STEPS) until the split holds, the change divided by the step
        moved, frac = solve(*move(1.0)), 1.0
        if splits(moved, res) != split0:
            first = moved
            for f in SPLIT_STEPS[1:]:
                moved, frac = solve(*move(f)), f
                if splits(moved, res) == split0:
                    res["converter"].reasons.append(f"{source}: the mode split changes at +1 standard error; its "
                                                    f"contribution is the change at {f:+g} divided by {f:+g}")
                    break
            else:
                moved, frac = first, 1.0
                res["converter"].reasons.append(f"{source}: the mode split changes at every step tried; the change "
                                                "at +1 standard error kept (a jump)")
        for fk, fit in res.items():
            other = moved.get(fk)
            if other is None:
                continue
            for pk, p in fit.params.items():
                q = other.params.get(pk)
                if q is None or not (math.isfinite(q.value) and math.isfinite(p.value)):
                    continue
                p.combine_type_b({source: (q.value - p.value) / frac}, {source: dof}, keep=True)
