"""The gearbox model the converter method reads eq. 32 through: each gear's eq. 14 on its motor-only points.

The converter's points are taken with K0 open (the motor drives the pump alone), and its turbine torque is the
shaft torque referred back through the engaged gear, ``T_t = T_out / (i_g eta_m) + C0``. A gear's transmission
fit ``transmission.gear<g>`` takes its hybrid ramp-ups too, whose input torque adds the ECU's engine torque: an
estimate a few % and a few Nm off (the data sheet's 1.5 Nm, up to 3x beyond it), and that error lands in the gear's
``eta_m`` and ``C0`` (a 4.5-7.7 Nm engine offset moved ``C0`` of gears 1-3 by about as much on drawn vehicles). The
converter's turbine torque then carries it, its torque ratio is off by several % where the torques are small,
the coupling point moves by 0.05-0.12 and the converter and coupling fits split the points wrongly (property
draws, 2026-11-25). The gear's motor-only points (``c_engine`` = 0) carry the motor's torque alone, the same
torque the converter's pump side reads: eq. 14 on them is the model eq. 32 needs. A gear whose motor-only points
cannot carry eq. 14 (fewer than three, or too little spread of ``1/C``) keeps its fit on all points and says so.

:func:`converter_with_gearbox` is the orchestrator's converter method (``identification.run``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.identification._fit import FitResult, IdentificationResult
from benchtwin.identification.engine_torque import ENGINE_TORQUE_KEY, _eq14, corrected_engine_torque
from benchtwin.identification.keys import FitKey
from benchtwin.identification.torque_converter import identify_torque_converter
from benchtwin.identification.torque_converter_borrowed import UncalibratedShare
from benchtwin.identification.transmission_clip import clip_causes
from benchtwin.identification.transmission_drag import DRAG_KEY
from benchtwin.recording import Recording

__all__ = ["converter_gearbox_table", "converter_with_gearbox"]


def _motor_only(fit: FitResult) -> tuple[float, float, int] | None:
    """``(eta_m, C0, n)`` of eq. 14 on the fit's motor-only points, None when it has no engine point or they cannot
    carry it."""
    c, eta, c_eng = (np.asarray(fit.data.get(k, []), dtype=float) for k in ("c", "eta", "c_engine"))
    if c_eng.size != c.size or c.size != eta.size or not np.any(c_eng != 0.0):
        return None
    m = c_eng == 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        e14 = _eq14(c[m], eta[m])
    return None if e14 is None else (e14[0], e14[1], int(m.sum()))


def _corrected(fit: FitResult, can: FitResult) -> tuple[float, float] | None:
    """``(eta_m, C0)`` of eq. 14 on all the fit's points, the engine points' input torque with the ECU's engine
    torque corrected by ``engine.can_torque`` (``(C_can - offset) / gain``); None when they cannot carry it."""
    c, eta, c_eng = (np.asarray(fit.data.get(k, []), dtype=float) for k in ("c", "eta", "c_engine"))
    if c_eng.size != c.size or c.size != eta.size:
        return None
    c_new = c - c_eng + np.where(c_eng != 0.0, corrected_engine_torque(can.value("gain"), can.value("offset"),
                                                                     c_eng), 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        eta_new = eta * c / c_new  # P_out / P_in at the corrected input torque, same speeds
        ok = np.isfinite(eta_new) & (c_new > 0) & (eta_new > 0) & (eta_new < 1.2)
        return _eq14(c_new[ok], eta_new[ok])


def converter_gearbox_table(result: IdentificationResult) -> tuple[dict[int, tuple[float, float]], list[str]]:
    """Gear -> ``(eta_m, C0)`` for eq. 32 of the converter method, and what was taken for each gear.

    For each drive fit ``transmission.gear<g>``: when it took engine points (K0 closed), eq. 14 of its motor-only
    points; when those cannot carry it and the ECU's engine torque was calibrated (``engine.can_torque``, not
    flagged), eq. 14 of all its points with that torque corrected; else the fit's own ``eta_m`` and ``C0`` when it
    is not flagged (as ``transmission_table``). A flagged fit (R^2 below its bound, an ``eta_m`` outside (0.5, 1])
    whose motor-only or corrected points carry eq. 14 is taken with them, and said so.

    Parameters
    ----------
    result:
        An identification result holding the transmission fits.
    """
    table: dict[int, tuple[float, float]] = {}
    notes: list[str] = []
    can = result.fits.get(ENGINE_TORQUE_KEY)
    can = can if can is not None and can.status == "ok" else None
    for name, fit in result.fits.items():
        key = FitKey.parse(name)
        if key.subsystem != "transmission" or key.direction != "drive" or key.gear is None:
            continue
        try:
            own = (fit.value("eta_m"), fit.value("C0"))
        except KeyError:
            continue
        n_eng = int(np.count_nonzero(np.asarray(fit.data.get("c_engine", []), dtype=float)))
        flagged = "" if fit.status == "ok" else " (the gear's fit is flagged)"
        mo = _motor_only(fit) if n_eng else None
        if mo is not None:
            table[key.gear] = (mo[0], mo[1])
            notes.append(f"gear {key.gear}: eq. 32 through eq. 14 of its {mo[2]} motor-only points (eta_m "
                         f"{mo[0]:.4f}, C0 {mo[1]:.2f} Nm; the gear's fit with {n_eng} engine points: {own[0]:.4f}, "
                         f"{own[1]:.2f} Nm{flagged}), the ECU's engine torque left out")
            continue
        co = _corrected(fit, can) if n_eng and can is not None else None
        if co is not None:
            table[key.gear] = co
            notes.append(f"gear {key.gear}: eq. 32 through eq. 14 of its points with the ECU's engine torque "
                         f"corrected by {ENGINE_TORQUE_KEY} (eta_m {co[0]:.4f}, C0 {co[1]:.2f} Nm; the gear's fit: "
                         f"{own[0]:.4f}, {own[1]:.2f} Nm{flagged}): too few motor-only points for eq. 14")
            continue
        if fit.status != "ok":
            continue
        table[key.gear] = own
        if n_eng:
            notes.append(f"gear {key.gear}: eq. 32 through its fit on all points ({n_eng} with the engine coupled "
                         "carry the ECU's engine torque, not calibrated): its motor-only points cannot carry eq. 14")
    return table, notes


def converter_with_gearbox(rec: Recording, specs: VehicleSpecs | None, res: IdentificationResult,
                           opts: Mapping[str, Any]) -> Any:
    """The converter method of the orchestrator: the given ``transmission`` option, else
    :func:`converter_gearbox_table` of the transmission result, and the drag where the transmission uses it.

    Parameters
    ----------
    rec, specs:
        The Recording and the public specs.
    res:
        The results so far (the transmission's).
    opts:
        The method's options (``transmission``: gear -> ``(eta_m, C0)`` given in code).
    """
    o = dict(opts)
    given = o.pop("transmission", None)
    table, notes = (given, []) if given else converter_gearbox_table(res)
    drag = res.fits.get(DRAG_KEY)  # the drag at the oil temperature where the transmission method uses it
    use = drag is not None and drag.status == "ok" and bool(np.all(np.asarray(drag.data.get("use", [False]))))
    o["drag"] = drag if use else None
    out = identify_torque_converter(rec, specs, transmission=table or None, **o)  # type: ignore[arg-type]
    if table and not use:  # with the drag in use, eq. 32 reads the drag model, not the table
        out["converter"].reasons.extend(notes)
    _trace_clipping(rec, res, out)
    return out


def _trace_clipping(rec: Recording, res: IdentificationResult, out: Mapping[str, FitResult]) -> None:
    """When the converter's turbine-torque curves are not identified (:class:`UncalibratedShare` in its data), add
    the cause where the telemetry's clipping left a gear without a transmission model of its own
    (:func:`~benchtwin.identification.transmission_clip.clip_causes`): in the structure and in the reasons."""
    conv = out.get("converter")
    share = conv.data.get(UncalibratedShare.KEY) if conv is not None else None
    if not isinstance(share, UncalibratedShare):
        return
    causes = clip_causes(rec, res, share.points_by_gear)
    if not causes:
        return
    conv.data[share.KEY] = replace(share, clipped=causes)
    for c in causes.values():
        for fit in (conv, out.get("coupling")):
            if fit is not None:
                fit.flag(c.reason())
