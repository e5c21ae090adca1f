"""The ECU's engine torque against the measured shaft torque: a gain and an offset of its own (issue 9).

The engine's torque on the vehicle CAN is the ECU's estimate (a torque model, typically a few % and a few Nm
off); the bench measures the propeller shaft torque. Where the engine is decoupled (K0 open) the gearbox input
is the motor's torque alone, so those steady points identify the gearbox without the ECU's estimate; at the
points of the same gear with K0 closed the shaft torque then gives the input torque back,
``C_in = T_out / (i_g eta_m) + C0``, and the engine's share is ``C_in - C_em``. The gearbox reference is the drag
fit ``transmission.drag`` when it was identified on the motor-only points and its ``k_T`` is three standard errors
from zero (``transmission_drag.temperature_supported``: a k_T of noise, carried over the oil span, moved the offset
by 2-5 Nm on coarse telemetry), at each point's oil temperature and input speed (the engine points run with hotter
oil, 100-120 degC against 50-75 degC for the electric ramps of the paper campaign, and a constant ``C0`` from the
motor-only points puts the drag's 1.2 %/K into the engine's torque, 5-10 Nm); else each gear's eq. 14 from its
motor-only points. The ECU's torque against that
share is a line,

``C_eng,CAN = g C_eng + o``,

fitted by least squares with its intervals (fit ``engine.can_torque``: ``gain`` and ``offset``, Nm;
``data["reference_drag"]`` says whether the drag fit was the reference). The map-based vehicle model uses it to
split a drive's pump torque between engine and motor (:mod:`benchtwin.validation.predict`) when its gearbox
model is that same drag fit: the replayed CAN torque corrected, ``(C_eng,CAN - o) / g``, so the motor takes the
rest of the torque the gearbox asks, not the rest of the ECU's estimate. The BSFC map stays at the CAN torque
(it was identified on it). With eq. 14 per gear as the gearbox model the CAN torque stays: those fits took it
into their input at their engine points, and its error is in their ``eta_m`` and ``C0``.

Only drive points are used (the shaft torque positive, lock-up closed); without the drag fit a gear's eq. 14
needs at least :data:`MIN_GEAR_POINTS` motor-only points with a spread of ``1/C``, and gears without are skipped. The
motor's torque is the inverter's estimate too: its gain error is common to the motor-only points and the engine
points, so it cancels from ``eta_m`` to first order and the engine's share is in the motor's units (those of
the motor's identified loss model). The fit is flagged when fewer than :data:`MIN_POINTS` points from at least
two gears, or an engine-torque span under :data:`MIN_SPAN_NM`, carry it, or when the gain is outside
:data:`GAIN_RANGE`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from benchtwin.errors import IdentificationError
from benchtwin.identification._fit import FitResult, IdentificationResult, linear_fit
from benchtwin.identification.transmission_drag import drag_c0
from benchtwin.identification.transmission_eq14 import direction_points, efficiency_design

__all__ = ["ENGINE_TORQUE_KEY", "GAIN_RANGE", "MIN_GEAR_POINTS", "MIN_POINTS", "MIN_SPAN_NM", "add_engine_torque_fit",
           "corrected_engine_torque"]

ENGINE_TORQUE_KEY = "engine.can_torque"
#: fewest motor-only drive points of a gear for its eq. 14 reference
MIN_GEAR_POINTS = 3
#: fewest engine points (K0 closed) over all gears for the line
MIN_POINTS = 6
#: least span of the engine's torque over the points, Nm (a gain needs a lever)
MIN_SPAN_NM = 40.0
#: a gain outside this range is no ECU torque model's error but a wrong reference
GAIN_RANGE = (0.85, 1.15)


def _eq14(c: np.ndarray, eta: np.ndarray) -> tuple[float, float] | None:
    """``(eta_m, C0)`` by eq. 15-17 (weights ``C^2``), None when the points cannot carry it."""
    inv = 1.0 / c
    if c.size < MIN_GEAR_POINTS or not np.ptp(inv) > 0.1 * float(np.mean(inv)):
        return None
    A, w = efficiency_design(c)
    sw = np.sqrt(w)
    x, *_ = np.linalg.lstsq(A * sw[:, None], eta * sw, rcond=None)
    if not (0.5 < x[0] <= 1.05 and math.isfinite(x[1])):
        return None
    return float(x[0]), float(x[1] / x[0])


def add_engine_torque_fit(out: IdentificationResult, pts: Any, ratios: np.ndarray, *,
                          drag: FitResult | None = None) -> None:
    """Fit ``engine.can_torque`` from the transmission's steady points into ``out``.

    Without points to carry it the fit is left out (an optional refinement, not a failure of the transmission) and
    ``out.meta["engine.can_torque"]["not_fitted"]`` says why.

    Parameters
    ----------
    out:
        The transmission's result; the fit (or the reason it is missing) is added.
    pts:
        :class:`~benchtwin.identification.transmission.TransmissionPoints` with ``engine_in`` and ``c_engine``
        (a hybrid's; a conventional car's carry no reference).
    ratios:
        Gear ratios (public specs).
    drag:
        The drag fit ``transmission.drag`` when it was identified on the motor-only points and its ``k_T`` is
        supported (the gearbox reference at each point's oil temperature and input speed); None: each gear's eq. 14
        from its motor-only points.
    """
    if pts.engine_in is None or pts.c_engine is None:
        return
    ref, can, gears, segs = [], [], [], []
    for g in sorted({int(x) for x in pts.gear[pts.usable]}):
        if not 1 <= g <= ratios.size:
            continue
        i_g = float(ratios[g - 1])
        m, dom, c, eta = direction_points(pts, g, "drive", i_g)
        eng = pts.engine_in[m]
        use = dom & eng
        if not use.any():
            continue
        if drag is not None and pts.oil_degc is not None:
            if f"C0_g{g}" not in drag.params:
                continue
            eta_m = drag.value(f"eta_m_g{g}")
            c0 = drag_c0(drag, f"g{g}", pts.oil_degc[m][use], pts.w_in[m][use])
            if not np.all(np.isfinite(c0)):
                continue
        else:
            motor = dom & ~eng
            with np.errstate(invalid="ignore", divide="ignore"):
                e14 = _eq14(c[motor], eta[motor])
            if e14 is None:
                continue
            eta_m, c0 = e14
        t_out = pts.t_out[m][use]
        c_in = t_out / (i_g * eta_m) + c0
        c_em = pts.c_in[m][use] - pts.c_engine[m][use]
        ref.append(c_in - c_em)
        can.append(pts.c_engine[m][use])
        gears.append(np.full(int(use.sum()), g))
        segs += [s for s, k in zip(np.asarray(pts.segments, dtype=object)[m], use) if k and s]
    if not ref:
        out.meta[ENGINE_TORQUE_KEY] = {"not_fitted": "no gear with both motor-only and engine drive points "
                                                     "(lock-up closed)"}
        return
    x, y, gear = np.concatenate(ref), np.concatenate(can), np.concatenate(gears)
    if x.size < 3:
        out.meta[ENGINE_TORQUE_KEY] = {"not_fitted": f"{x.size} engine points with a reference; need {MIN_POINTS}"}
        return
    A = np.column_stack([x, np.ones_like(x)])
    try:
        fit = linear_fit(A, y, ["gain", "offset"], units=["-", "Nm"], segments=sorted(set(segs)), min_points=3,
                         what=ENGINE_TORQUE_KEY)
    except IdentificationError as exc:  # e.g. every point at one torque: no line
        out.meta[ENGINE_TORQUE_KEY] = {"not_fitted": f"{type(exc).__name__}: {exc}"}
        return
    by_drag = drag is not None and pts.oil_degc is not None
    fit.data.update(c_engine_ref=x, c_engine_can=y, gear=gear.astype(float), reference_drag=np.array([by_drag]))
    ref_what = ("the drag fit transmission.drag (motor-only points) at each point's oil temperature and input speed"
                if by_drag else "each gear's eq. 14 from its motor-only drive points")
    fit.reasons.append(f"reference: {ref_what}; the shaft torque referred back to the input, the motor's torque "
                       "taken off")
    n_gears = len(set(gear.tolist()))
    if x.size < MIN_POINTS or n_gears < 2:
        fit.flag(f"{x.size} engine points from {n_gears} gear(s): need {MIN_POINTS} from at least 2")
    if not np.ptp(x) >= MIN_SPAN_NM:
        fit.flag(f"engine torque spans {np.ptp(x):.0f} Nm < {MIN_SPAN_NM:.0f} Nm: no lever for a gain")
    if not GAIN_RANGE[0] <= fit.value("gain") <= GAIN_RANGE[1]:
        fit.flag(f"gain {fit.value('gain'):.3f} outside {GAIN_RANGE}: the reference does not hold")
    out.fits[ENGINE_TORQUE_KEY] = fit


def corrected_engine_torque(gain: float, offset: float, can_nm: np.ndarray) -> np.ndarray:
    """The engine's torque from the ECU's: ``(C_can - offset) / gain``."""
    return (np.asarray(can_nm, dtype=float) - offset) / gain
