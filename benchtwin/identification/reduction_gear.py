"""Efficiency of a battery-electric car's fixed reduction gear, from the dyno's roller forces and the motor torque.

A BEV's log has no shaft-torque sensor and no gear: between the motor and the rollers there is one fixed ratio
``i`` (``VehicleSpecs.final_drive_ratio``). In a steady window at constant speed (the dyno holding the speed,
no braking) the rollers take the tractive force, so with eq. 14's form over the whole driveline

``F_roller r = eta i T_m - (D0 + D1 v)``

where ``D0 + D1 v`` lumps the gear's drag torque and the tyres' and bearings' loss on the rollers (at the wheel,
Nm), linear in speed. The least squares of ``F_roller r`` on ``[i T_m, -1, -v]`` give ``eta`` (motoring
windows only: generating and hydraulic braking load the gear from the other side). Windows whose speed ratio
``omega_m / omega_wheel`` differs from ``i`` by more than :data:`RATIO_TOLERANCE` are left out (a slipping
clutch or tyre, a log from a car with a gearbox) and counted.
"""

from __future__ import annotations

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import InsufficientDataError
from benchtwin.identification._fit import FitResult, linear_fit
from benchtwin.identification._signals import check_spread
from benchtwin.identification.steady import find_steady_windows
from benchtwin.recording import Recording

__all__ = ["RATIO_TOLERANCE", "identify_reduction_gear"]

RPM = np.pi / 30.0
#: largest relative difference of a window's speed ratio from the specified ratio
RATIO_TOLERANCE = 0.01
_BRAKES = ("brake_pressure_fl_bar", "brake_pressure_fr_bar", "brake_pressure_rl_bar", "brake_pressure_rr_bar")


def identify_reduction_gear(rec: Recording, specs: VehicleSpecs, *, min_torque_nm: float = 5.0, min_points: int = 3,
                            rate_hz: float = 10.0) -> FitResult:
    """Efficiency ``eta`` of the fixed reduction gear (and the lumped drag ``D0``, ``D1``) of a BEV log.

    Parameters
    ----------
    rec:
        Recording with ``em_torque_nm``, ``em_speed_rpm``, ``vehicle_speed_kmh``, ``dyno_force_front_n`` and
        ``dyno_force_rear_n`` (brake pressures, when present, exclude braked windows).
    specs:
        ``final_drive_ratio`` (the one ratio, motor to wheel) and ``wheel_radius_m``.
    min_torque_nm:
        Windows with a lower motor torque are left out.
    min_points:
        Fewest steady windows (3: one more than the unknowns at one test speed; the interval then carries the
        Student-t quantile of one degree of freedom).
    rate_hz:
        Grid rate of the steady search.

    Returns
    -------
    FitResult
        ``eta`` (-), ``D0`` (Nm at the wheel), ``D1`` (Nm per km/h); data ``wheel_torque_nm``, ``input_nm``
        (``i T_m``), ``speed_kmh``, ``ratio_seen``.

    Raises
    ------
    InsufficientDataError, NoExcitationError
        Too few motoring windows at the specified ratio, or the torque did not vary.
    """
    what = "reduction_gear"
    i, r = float(specs.final_drive_ratio), float(specs.wheel_radius_m)
    brakes = [b for b in _BRAKES if b in rec]
    steady = find_steady_windows(rec, ["em_speed_rpm", "em_torque_nm", "vehicle_speed_kmh"],
                                 extra=("dyno_force_front_n", "dyno_force_rear_n"), optional=brakes,
                                 kinds=("ramp_up", "constant_drive"), rate_hz=rate_hz)
    t_m = steady.raw_average(rec, "em_torque_nm")
    n_m = steady.raw_average(rec, "em_speed_rpm")
    v = steady.raw_average(rec, "vehicle_speed_kmh")
    force = steady.raw_average(rec, "dyno_force_front_n") + steady.raw_average(rec, "dyno_force_rear_n")
    braked = np.zeros(t_m.size, dtype=bool)
    for b in brakes:
        braked |= ~(np.abs(steady.raw_average(rec, b)) < 0.3)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = n_m * RPM / (v / 3.6 / r)
    at_ratio = np.abs(ratio / i - 1.0) <= RATIO_TOLERANCE
    use = np.isfinite(force) & (t_m > min_torque_nm) & ~braked & (v > 5.0) & at_ratio
    n_off = int(np.count_nonzero((t_m > min_torque_nm) & ~braked & (v > 5.0) & ~at_ratio))
    if use.sum() < min_points:
        raise InsufficientDataError(f"{what}: {int(use.sum())} steady motoring windows at the specified ratio "
                                    f"{i:g} (+-{RATIO_TOLERANCE:.0%}; {n_off} at another ratio); need at least "
                                    f"{min_points}")
    x_in, y, vv = i * t_m[use], force[use] * r, v[use]
    check_spread(x_in, 50.0, what, "motor torque x ratio", "Nm")
    cols = [x_in, -np.ones_like(x_in)] + ([-vv] if np.ptp(vv) > 5.0 else [])
    names = ["eta", "D0", "D1"][: len(cols)]
    segs = [w.segment for w, u in zip(steady.windows, use) if u and w.segment]
    fit = linear_fit(np.column_stack(cols), y, names, units=["-", "Nm", "Nm h/km"][: len(cols)],
                     segments=sorted(set(segs)), min_points=min_points, n_excluded=steady.n_excluded + n_off,
                     what=what)
    if len(cols) == 2:
        fit.reasons.append("one test speed: the drag's speed term D1 is not separated (D0 holds it at that speed)")
    if n_off:
        fit.reasons.append(f"{n_off} steady motoring windows left out: their speed ratio differs from "
                           f"{i:g} by more than {RATIO_TOLERANCE:.0%}")
    fit.data.update(wheel_torque_nm=y, input_nm=x_in, speed_kmh=vv, ratio_seen=ratio)
    if not 0.5 < fit.value("eta") <= 1.0:
        fit.flag(f"eta = {fit.value('eta'):.4f} is not physical: check the ratio, the wheel radius and the signs")
    return fit
