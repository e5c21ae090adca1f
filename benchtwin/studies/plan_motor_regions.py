"""The motor map regions the Willans lines need (eq. 18-25), and those no planned test visits.

The Willans line of each side, ``T omega = e P_el - W_loss`` (motoring, eq. 19-20) and
``P_el = e_gen T omega + W_loss_gen`` (generating), is one straight line in the mechanical power: its
intercept (the loss) is fixed by the points where the loss weighs most, at low torque, and its slope (``e``)
by those at high torque, where the loss is a small share of the power. Eq. 20 is a plane over ``p_ma`` and
``c_m`` (Figure 10): the paper explores "the whole EM working map" (Figure 9), whose full-load curve has a
constant-torque part below the base speed ``n_b = P_max / T_max`` and a constant-power part above it
(the rating of the specs: 440 Nm, 90 kW, 6,000 rpm, so ``n_b`` = 1,953 rpm on the paper vehicle). A line
fitted on one part only is extrapolated to the other, where the efficiency map of eq. 25 is then not checked.

So a region is a side (motoring ``T > 5`` Nm, generating ``T < -5`` Nm, as :func:`~benchtwin.identification.
motor.side_points` splits them) x a speed band (below or above ``n_b``, up to the rated speed) x a torque level
(``|T|`` up to or above half the full-load torque ``min(T_max, P_max / omega)`` at the point's speed). A region
without a single steady point of the planned tests is flagged with the parameter it leaves unexcited (the
loss at low torque, the efficiency at high torque) and the ramp-up to add: a gear and dyno speed that put the
motor in the band, with the paper's pedal steps (motoring) or brake steps (generating) over both levels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import BenchtwinError
from benchtwin.identification.motor import RPM, motor_points, side_points
from benchtwin.recording import Recording
from benchtwin.studies.plan_fits import PlannedParameter

__all__ = ["MotorRegion", "base_speed_rpm", "full_load_torque", "motor_regions", "plan_motor_regions",
           "region_counts", "suggest_region_test"]

#: the torque level split, as a share of the full-load torque at the point's speed
LEVEL_SPLIT = 0.5
#: the paper's steps of the electric ramp-ups (paper.toml): both torque levels in one test
_PEDAL = "[5.0, 10.0, 20.0, 30.0, 45.0, 60.0, 80.0]"
_BRAKE = "[4.0, 8.0, 12.0, 16.0, 20.0]"


@dataclass(frozen=True)
class MotorRegion:
    """One region of the motor map: a side, a speed band (rpm, ``lo < n <= hi``) and a torque level."""

    side: str
    band: str
    level: str
    lo_rpm: float
    hi_rpm: float

    @property
    def name(self) -> str:
        """The plan row's name, e.g. ``motor.generating.region.above_base_speed.high_torque``."""
        return f"motor.{self.side}.region.{self.band}_base_speed.{self.level}_torque"

    @property
    def parameters(self) -> tuple[str, ...]:
        """The Willans parameters the region's points fix: the loss at low torque, the efficiency at high."""
        gen = self.side == "generating"
        if self.level == "low":
            return ("W_loss_gen",) if gen else ("W_loss",)
        return ("e_gen",) if gen else ("e", "eta_peak")

    def describe(self) -> str:
        """E.g. ``generating at 1953-6000 rpm, |T| above half the full-load torque``."""
        hi = f"{self.hi_rpm:.0f}" if math.isfinite(self.hi_rpm) else "the top speed"
        lvl = "above" if self.level == "high" else "up to"
        return f"{self.side} at {self.lo_rpm:.0f}-{hi} rpm, |T| {lvl} half the full-load torque"


def base_speed_rpm(specs: VehicleSpecs) -> float | None:
    """``P_max / T_max`` in rpm, or None when the specs do not give the motor's rating."""
    if specs.em_max_torque_nm is None or specs.em_max_power_w is None:
        return None
    return specs.em_max_power_w / specs.em_max_torque_nm / RPM


def full_load_torque(specs: VehicleSpecs, speed_rpm: np.ndarray) -> np.ndarray:
    """``min(T_max, P_max / omega)`` (Nm) at each speed; raises ValueError without a rating."""
    if specs.em_max_torque_nm is None or specs.em_max_power_w is None:
        raise ValueError("the specs give no em_max_torque_nm and em_max_power_w")
    w = np.maximum(np.asarray(speed_rpm, dtype=float), 1e-9) * RPM
    return np.minimum(specs.em_max_torque_nm, specs.em_max_power_w / w)


def motor_regions(specs: VehicleSpecs) -> list[MotorRegion]:
    """The eight regions (2 sides x 2 speed bands x 2 torque levels); empty without a rating."""
    nb = base_speed_rpm(specs)
    if nb is None:
        return []
    top = specs.em_max_speed_rpm if specs.em_max_speed_rpm is not None else math.inf
    bands = (("below", 50.0, nb), ("above", nb, top))
    return [MotorRegion(side, band, level, lo, hi) for side in ("motoring", "generating")
            for band, lo, hi in bands for level in ("low", "high")]


def region_counts(specs: VehicleSpecs, torque_nm: np.ndarray, speed_rpm: np.ndarray,
                  sides: dict[str, np.ndarray]) -> dict[str, int]:
    """Points of each region (by name); ``sides`` maps a side to the mask of its points (:func:`side_points`)."""
    t = np.asarray(torque_nm, dtype=float)
    n = np.asarray(speed_rpm, dtype=float)
    regions = motor_regions(specs)
    if not regions:
        return {}
    with np.errstate(invalid="ignore"):
        high = np.abs(t) > LEVEL_SPLIT * full_load_torque(specs, n)
        out = {}
        for r in regions:
            m = sides[r.side] & (n > r.lo_rpm) & (n <= r.hi_rpm) & (high if r.level == "high" else ~high)
            out[r.name] = int(np.count_nonzero(m))
    return out


def suggest_region_test(specs: VehicleSpecs, region: MotorRegion) -> str:
    """The electric ramp-up to add for a region: a gear and speed that put the motor in the band's middle.

    The motor turns with the gearbox input (K0 open, lock-up closed): ``n = v / 3.6 / r_w * i_fd * i_g``. The
    target is ``0.75 n_b`` below the base speed and ``1.5 n_b`` (at most halfway to the rated speed) above it;
    of the gears that reach it between 30 and 130 km/h, the one nearest 80 km/h.
    """
    if region.band == "below":
        target = 0.75 * region.hi_rpm
    else:
        target = min(1.5 * region.lo_rpm, 0.5 * (region.lo_rpm + region.hi_rpm)) \
            if math.isfinite(region.hi_rpm) else 1.5 * region.lo_rpm
    k = specs.final_drive_ratio / 3.6 / specs.wheel_radius_m / RPM  # rpm per (km/h) and unit gear ratio
    speeds = [(g + 1, target / (k * ratio)) for g, ratio in enumerate(specs.gear_ratios)]
    fit = [(g, v) for g, v in speeds if 30.0 <= v <= 130.0] or speeds
    gear, v = min(fit, key=lambda gv: abs(gv[1] - 80.0))
    v = float(min(max(5.0 * round(v / 5.0), 10.0), 200.0))
    steps = f"brake_steps_pct = {_BRAKE}, pedal_steps_pct = [5.0, 10.0]" if region.side == "generating" \
        else f"pedal_steps_pct = {_PEDAL}"
    return (f"add [[tests]] kind = \"ramp_up\", mode = \"electric\", gear = {gear}, speed_kmh = {v:.1f}, "
            f"{steps}, engine = \"off\", k0 = \"open\", lockup = \"closed\" (motor at about {target:.0f} rpm)")


def plan_motor_regions(rec: Recording, specs: VehicleSpecs) -> tuple[list[PlannedParameter], dict[str, object]]:
    """Rows for the motor regions the planned steady points never visit, and the count of every region.

    Parameters
    ----------
    rec:
        The plan's noise-free Recording (:func:`~benchtwin.studies.plan.planned_recording`).
    specs:
        The vehicle's specs (the motor's rating gives the regions).

    Returns
    -------
    rows, meta
        One not-identifiable :class:`PlannedParameter` per unvisited region (named by
        :attr:`MotorRegion.name`, with the parameters it leaves unexcited and the test to add); ``meta``
        holds ``counts`` (points per region) or ``not_checked`` (why not).
    """
    regions = motor_regions(specs)
    if not regions:
        return [], {"not_checked": "the specs give no em_max_torque_nm and em_max_power_w (the full-load curve)"}
    try:
        pts = motor_points(rec)
    except BenchtwinError:
        return [], {"not_checked": "no steady motor point (see motor.*)"}
    sides = {side: sel for side, sel, _f in side_points(pts)}
    counts = region_counts(specs, pts.torque_nm, pts.speed_rpm, sides)
    rows = []
    for r in regions:
        if counts[r.name]:
            continue
        why = (f"{r.describe()} never visited: {', '.join(r.parameters)} of motor.{r.side} not excited there "
               f"(the Willans line is extrapolated into it)")
        rows.append(PlannedParameter(r.name, "", float("nan"), float("nan"), False, why, suggest_region_test(specs, r)))
    return rows, {"counts": counts, "base_speed_rpm": base_speed_rpm(specs), "level_split": LEVEL_SPLIT}
