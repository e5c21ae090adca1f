"""Transmission efficiency per gear: mesh efficiency eta_m and minimum input torque C0 (eq. 13-17).

From steady points with the lock-up clutch closed (turbine = pump = motor speed):

- input torque ``C_in`` = motor torque + engine torque (only with K0 closed), input speed = motor speed
  (a conventional car, without motor channels: the engine torque and speed);
- output power on the propeller shaft: shaft torque x shaft speed, the shaft speed from the vehicle
  speed, the wheel radius and the final drive (public specs).

Drive points (``P_out > 0``): ``eta = P_out / P_in = eta_m (1 - C0 / C_in)``, least squares on
regressors ``[1, -1/C_in]`` with unknowns ``[eta_m, eta_m C0]`` (eq. 15-17). Coast/regen points
(``P_out < 0``): ``eta = P_in / P_out = eta_m (1 - C0 / C)`` with ``C = |T_out| / i_g`` the
wheel-side torque referred to the input (docs/models.md). Each gear and direction is its own fit:
``transmission.gear5`` (drive) and ``transmission.gear5_coast``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import IdentificationError, InsufficientDataError
from benchtwin.identification._fit import FitResult, IdentificationResult, derived, linear_fit
from benchtwin.identification._signals import check_spread, raise_all_failed
from benchtwin.identification.engine_torque import add_engine_torque_fit
from benchtwin.identification.keys import FitKey
from benchtwin.identification.steady import SteadyWindows, Tolerance, find_steady_windows
from benchtwin.identification.transmission_drag import DRAG_KEY, add_drag_fit, temperature_supported
from benchtwin.identification.transmission_drag import MIN_SPAN_K as DRAG_MIN_SPAN_K
from benchtwin.identification.transmission_eq14 import direction_points, efficiency_design
from benchtwin.recording import Recording

__all__ = ["TransmissionPoints", "direction_points", "efficiency_design", "fit_transmission_efficiency",
           "identify_transmission", "transmission_points"]

RPM = 2.0 * math.pi / 60.0

_REQUIRED = ("vehicle_speed_kmh", "em_speed_rpm", "em_torque_nm", "engine_torque_nm", "shaft_torque_nm")
#: a conventional car (no traction motor): the engine drives the gearbox input alone
_REQUIRED_ENGINE_ONLY = ("vehicle_speed_kmh", "engine_speed_rpm", "engine_torque_nm", "shaft_torque_nm")
_STATES = ("gear_actual", "gear_target", "k0_closed", "lockup_closed")
#: the gearbox oil thermocouple: read when logged, for the temperature-dependent drag (transmission_drag)
OIL_ROLE = "gearbox_oil_degc"


@dataclass
class TransmissionPoints:
    """Steady operating points of the transmission (one per steady window).

    Attributes
    ----------
    gear:
        Actual gear.
    c_in, w_in:
        Input torque (Nm) and speed (rad/s).
    t_out, w_out:
        Propeller shaft torque (Nm) and speed (rad/s).
    p_in, p_out:
        Input and output power (W), window means of the products.
    usable:
        Points inside the model's domain (lock-up closed, no slip, engine torque accounted for).
    segments:
        Segment name per point.
    reasons:
        Why points were dropped (counts), for the fit's reasons.
    n_flagged:
        Grid samples excluded because a source sample was flagged.
    windows:
        The steady windows the points are means over (one per point).
    oil_degc:
        Gearbox oil temperature per point (degC), when the Recording logs it (role ``gearbox_oil_degc``).
    engine_in:
        Whether the engine's (ECU-estimated) torque is part of ``c_in`` at each point (K0 closed); None when
        the input is the engine alone (a conventional car).
    c_engine:
        The engine torque counted in ``c_in`` (Nm; 0 where K0 is open), so that the engine's and the
        motor's shares of the input torque stay known (their CAN estimates carry different errors).
    """

    gear: np.ndarray
    c_in: np.ndarray
    w_in: np.ndarray
    t_out: np.ndarray
    w_out: np.ndarray
    p_in: np.ndarray
    p_out: np.ndarray
    usable: np.ndarray
    segments: list[str]
    reasons: list[str]
    n_flagged: int
    windows: SteadyWindows | None = None
    oil_degc: np.ndarray | None = None
    engine_in: np.ndarray | None = None
    c_engine: np.ndarray | None = None


def transmission_points(rec: Recording, specs: VehicleSpecs, *, steady: SteadyWindows | None = None,
                        kinds: Iterable[str] | None = ("ramp_up", "constant_drive"), rate_hz: float = 10.0,
                        max_slip: float = 0.01, tolerances: Mapping[str, Tolerance] | None = None,
                        max_duration_s: float | None = None) -> TransmissionPoints:
    """Steady transmission points of a Recording.

    Parameters
    ----------
    rec:
        The Recording (roles of :mod:`benchtwin.roles`).
    specs:
        Public specs: gear ratios, final drive, wheel radius.
    steady:
        Steady windows already found on the required channels (else found here).
    kinds:
        Segment kinds to search when the Recording has a segment table.
    rate_hz:
        Grid rate for steady-state detection.
    max_slip:
        Largest relative difference between motor speed and shaft speed x gear ratio accepted as
        "lock-up closed" (torque converter slip would make the input torque unknown).
    tolerances:
        Overrides of the steadiness thresholds.
    max_duration_s:
        Cut long holds into pieces of this length.

    Returns
    -------
    TransmissionPoints

    Notes
    -----
    Without motor channels (a conventional car) the input is the engine alone: ``C_in`` is the engine
    torque and the input speed the engine speed.
    """
    engine_only = "em_speed_rpm" not in rec and "em_torque_nm" not in rec
    if steady is None:
        steady = find_steady_windows(rec, list(_REQUIRED_ENGINE_ONLY if engine_only else _REQUIRED), states=_STATES,
                                     extra=("gear_actual",), optional=() if engine_only else ("engine_speed_rpm",),
                                     kinds=kinds, rate_hz=rate_hz, tolerances=tolerances,
                                     max_duration_s=max_duration_s)
    g = steady.grid
    ratios = np.asarray(specs.gear_ratios, dtype=float)
    gear = steady.means("gear_actual").round()
    n = len(steady)
    reasons: list[str] = []
    k0 = steady.state("k0_closed") if "k0_closed" in g else None
    if engine_only:
        k0 = None
        reasons.append("no motor channels: the engine drives the gearbox input alone (conventional layout)")
        c_in = steady.raw_average(rec, "engine_torque_nm")
        c_engine = c_in
        w_in = steady.raw_average(rec, "engine_speed_rpm") * RPM
    elif k0 is None:
        if "engine_speed_rpm" in g:
            # K0 state not recorded: the engine is coupled when it turns with the motor
            eng = steady.means("engine_speed_rpm")
            em = steady.means("em_speed_rpm")
            k0 = (np.abs(eng - em) <= 0.02 * np.maximum(np.abs(em), 1.0)).astype(float)
            reasons.append("k0_closed not recorded: K0 taken as closed where engine speed = motor speed")
        else:
            k0 = np.ones(n)
            reasons.append("k0_closed and engine speed not recorded: engine torque always counted as input")
    if not engine_only:
        k0 = np.nan_to_num(k0, nan=0.0) > 0.5
        # window means over each source's own samples (the grid only locates the windows)
        t_em = steady.raw_average(rec, "em_torque_nm")
        t_eng = steady.raw_average(rec, "engine_torque_nm")
        c_in = np.where(k0, t_em + t_eng, t_em)
        c_engine = np.where(k0, t_eng, 0.0)
        w_in = steady.raw_average(rec, "em_speed_rpm") * RPM
    p_in = c_in * w_in
    t_out = steady.raw_average(rec, "shaft_torque_nm")
    w_out = steady.raw_average(rec, "vehicle_speed_kmh") / 3.6 / specs.wheel_radius_m * specs.final_drive_ratio
    p_out = t_out * w_out
    usable = np.ones(n, dtype=bool)
    in_range = (gear >= 1) & (gear <= ratios.size)
    if (~in_range).any():
        reasons.append(f"{int((~in_range).sum())} steady windows in neutral or an unknown gear")
    usable &= in_range
    if "gear_target" in g:
        shifting = in_range & (steady.state("gear_target").round() != gear)
        if shifting.any():
            reasons.append(f"{int(shifting.sum())} windows with a shift pending (target gear != actual gear)")
        usable &= ~shifting
    ig = np.where(in_range, ratios[np.clip(gear.astype(int) - 1, 0, ratios.size - 1)], np.nan)
    slip = np.abs(w_in - w_out * ig) / np.maximum(np.abs(w_out * ig), 1e-6)
    slipping = in_range & ~(slip <= max_slip)
    if "lockup_closed" in g:
        slipping |= in_range & ~(steady.state("lockup_closed") > 0.5)
    if slipping.any():
        reasons.append(f"{int(slipping.sum())} windows with the lock-up open or slipping (> {max_slip:.0%})")
    usable &= ~slipping
    still = ~(np.abs(w_out) > 1.0)
    if (still & usable).any():
        reasons.append(f"{int((still & usable).sum())} windows at standstill")
    usable &= ~still
    oil = steady.raw_average(rec, OIL_ROLE) if OIL_ROLE in rec else None
    return TransmissionPoints(gear, c_in, w_in, t_out, w_out, p_in, p_out, usable,
                              [w.segment for w in steady.windows], reasons, steady.n_excluded, steady, oil,
                              None if engine_only else np.asarray(k0, dtype=bool), c_engine)


def fit_transmission_efficiency(c: np.ndarray, eta: np.ndarray, *, what: str = "transmission",
                                segments: Sequence[str] = (), n_excluded: int = 0, min_points: int = 3,
                                min_rel_spread: float = 0.1, weighted: bool = True, min_r2: float = 0.5) -> FitResult:
    """Least squares of eq. 15-17: ``eta = eta_m - (eta_m C0) / C``.

    Parameters
    ----------
    c:
        Torque referred to the input (``C_in`` in drive, ``|T_out| / i_g`` in coast), Nm, positive.
    eta:
        Measured efficiency (drive ``P_out/P_in``, coast ``P_in/P_out``).
    min_rel_spread:
        Smallest spread of ``1/C`` relative to its mean that is accepted as excitation.
    weighted:
        Weight each point by ``C^2``. The torque sensors' noise is absolute, so the noise of a
        measured efficiency grows as ``1/C``; weighting by the inverse variance keeps low-torque
        points from dominating and makes the standard errors honest (the paper's plain OLS is
        ``weighted=False``; both give the same result on exact data).
    min_r2:
        Below this R^2 the fit is flagged (the paper reports 0.95 in 5th gear).

    Returns
    -------
    FitResult
        Parameters ``eta_m``, ``eta_m_C0`` and derived ``C0`` (Nm); data ``c``, ``eta``, ``eta_fit``
        and the model curve ``c_curve``, ``eta_curve``.

    Raises
    ------
    InsufficientDataError, NoExcitationError, CollinearError
    """
    c = np.asarray(c, dtype=float)
    eta = np.asarray(eta, dtype=float)
    if c.size < max(min_points, 3):
        raise InsufficientDataError(f"{what}: {c.size} steady points; need at least {max(min_points, 3)}")
    inv = 1.0 / c
    check_spread(inv, min_rel_spread * float(np.mean(np.abs(inv))), what, "1/C_in", "1/Nm")
    A, w = efficiency_design(c, weighted=weighted)
    fit = linear_fit(A, eta, ["eta_m", "eta_m_C0"], units=["-", "Nm"], segments=segments, min_points=min_points,
                     n_excluded=n_excluded, what=what, weights=w)
    derived(fit, "C0", lambda x: x[1] / x[0], unit="Nm")
    cc = np.linspace(max(float(c.min()) * 0.8, 1e-3), float(c.max()) * 1.1, 200)
    fit.data.update(c=c, eta=eta, eta_fit=fit.data["y_fit"], c_curve=cc,
                    eta_curve=fit.value("eta_m") * (1.0 - fit.value("C0") / cc))
    if not 0.5 < fit.value("eta_m") <= 1.0:
        fit.flag(f"eta_m = {fit.value('eta_m'):.4f} is outside (0.5, 1]: the points do not follow eq. 14")
    if not fit.r2 >= min_r2:
        fit.flag(f"R^2 = {fit.r2:.2f} < {min_r2}: eq. 14 does not explain these points (noise, unsteady points?)")
    return fit


def _drag_groups(pts: TransmissionPoints, ratios: np.ndarray, min_points: int, *, motor_only: bool = False
                 ) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Per gear and direction with enough points: ``(C, eta, T_oil, |w_in|)`` of the points with an oil reading
    (``motor_only``: of the points with the engine decoupled)."""
    out = {}
    oil_all = pts.oil_degc if pts.oil_degc is not None else np.full(pts.gear.shape, np.nan)
    if motor_only and pts.engine_in is not None:
        oil_all = np.where(pts.engine_in, np.nan, oil_all)
    for g in sorted({int(x) for x in pts.gear[pts.usable]}):
        if not 1 <= g <= ratios.size:
            continue
        for direction in ("drive", "coast"):
            m, dom, c, eta = direction_points(pts, g, direction, float(ratios[g - 1]))
            oil = oil_all[m]
            keep = dom & np.isfinite(oil)
            if int(keep.sum()) >= min_points:
                out[f"g{g}" + ("_coast" if direction == "coast" else "")] = (c[keep], eta[keep], oil[keep],
                                                                             np.abs(pts.w_in[m][keep]))
    return out


def identify_transmission(rec: Recording, specs: VehicleSpecs, *, gears: Iterable[int] | None = None,
                          points: TransmissionPoints | None = None, min_points: int = 3,
                          **kwargs: object) -> IdentificationResult:
    """eta_m and C0 per gear, drive and coast, from the steady points of a Recording.

    Parameters
    ----------
    rec:
        The Recording.
    specs:
        Public specs (gear ratios, final drive, wheel radius).
    gears:
        Gears to fit (default: every gear with steady points).
    points:
        Points from :func:`transmission_points` (else computed here; ``kwargs`` go to it).
    min_points:
        Fewest points per gear and direction.

    Returns
    -------
    IdentificationResult
        Fits ``transmission.gear<g>`` (drive) and ``transmission.gear<g>_coast``; gears or
        directions that could not be fitted are in ``errors`` with the reason. With the oil temperature
        logged (and every gear fitted), also ``transmission.drag``
        (:mod:`~benchtwin.identification.transmission_drag`). Besides the points (``c``, ``eta``) each fit's data
        hold ``gear_ratio``, ``speed_rpm`` and ``c_engine``, the engine torque counted in each point's input
        torque (0 with K0 open), and ``oil_degc``, each point's oil temperature (NaN where not read), when the
        Recording logs the oil.

    Raises
    ------
    InsufficientDataError
        When no gear at all could be fitted.
    """
    pts = points if points is not None else transmission_points(rec, specs, **kwargs)  # type: ignore[arg-type]
    ratios = np.asarray(specs.gear_ratios, dtype=float)
    out = IdentificationResult()
    failures: dict[str, IdentificationError] = {}
    present = sorted({int(x) for x in pts.gear[pts.usable]})
    wanted = present if gears is None else [int(x) for x in gears]
    n_dropped = int((~pts.usable).sum())
    for gg in wanted:
        ig = ratios[gg - 1] if 1 <= gg <= ratios.size else float("nan")
        for direction in ("drive", "coast"):
            key = str(FitKey.transmission(gg, direction))
            m, dom, c, eta = direction_points(pts, gg, direction, ig)
            n_dom = int((~dom).sum())
            segs = sorted({s for s, k in zip(np.asarray(pts.segments, dtype=object)[m], dom) if k and s})
            try:
                fit = fit_transmission_efficiency(c[dom], eta[dom], what=key, segments=segs,
                                                  n_excluded=pts.n_flagged + n_dom, min_points=min_points)
            except IdentificationError as exc:
                out.errors[key] = f"{type(exc).__name__}: {exc}"
                continue
            fit.data["speed_rpm"] = (pts.w_in[m][dom] / RPM)
            fit.data["gear_ratio"] = np.array([ig])
            if pts.c_engine is not None:  # the engine's share of each point's input torque (drive and coast)
                fit.data["c_engine"] = pts.c_engine[m][dom]
            if pts.oil_degc is not None:  # the conditions C0 was identified at (validation/gearbox.py)
                fit.data["oil_degc"] = np.asarray(pts.oil_degc, dtype=float)[m][dom]
            for r in pts.reasons:
                fit.reasons.append(r)
            if n_dom:
                fit.reasons.append(f"{n_dom} points outside the model's domain (dead band or eta >= 1.2)")
            out.fits[key] = fit
    out.meta["transmission"] = {"steady_points": int(pts.gear.size), "dropped_points": n_dropped,
                                "flagged_samples": pts.n_flagged}
    if out.fits and gears is None and pts.oil_degc is not None and np.isfinite(pts.oil_degc).any():
        # the drag is a few Nm: the engine's torque is the ECU's estimate (a few % and Nm off on a real car), the
        # motor's the inverter's, so the points with the engine decoupled identify it when they span the oil range
        groups = _drag_groups(pts, ratios, max(min_points, 3), motor_only=True)
        oil = np.concatenate([v[2] for v in groups.values()]) if groups else np.array([0.0])
        note = "points with the engine decoupled (K0 open): the ECU's engine torque left out"
        if np.ptp(oil) < DRAG_MIN_SPAN_K or len(groups) < 2:
            groups = _drag_groups(pts, ratios, max(min_points, 3))
            note = "all points (too few with the engine decoupled span the oil temperature)"
        add_drag_fit(out, groups, list(pts.segments), note=note)
        drag = out.fits.get(DRAG_KEY)
        motor_only = drag is not None and note.startswith("points with the engine decoupled")
        # the reference of the ECU's torque: the drag model where its temperature term is supported, else each
        # gear's eq. 14 (a k_T within 3 standard errors of 0 is noise, carried over the oil span into the offset:
        # +4.5 Nm of a true -0.7 on an 11-bit telemetry's ridge, -2.3 Nm of 0 at 10 bits, issue #8)
        add_engine_torque_fit(out, pts, ratios, drag=drag if motor_only and temperature_supported(drag) else None)
    elif out.fits and gears is None:
        add_engine_torque_fit(out, pts, ratios)
    if not out.fits:
        if not failures:
            raise InsufficientDataError("transmission: no steady point in any gear with the lock-up closed")
        raise_all_failed("transmission (every gear)", failures)
    return out
