"""Torque converter identification (eq. 31-39 of the paper): a0..a8, the coupling point, TR and CF curves.

Model (docs/models.md), speeds in rad/s, torques in Nm, ``SR = w_t / w_p``:

- converter mode, ``SR < Gamma``: ``T_p = a0 w_p^2 + a1 w_p w_t + a2 w_t^2`` and
  ``T_t = a3 w_p^2 + a4 w_p w_t + a5 w_t^2`` (eq. 35), fitted together by one stacked least-squares
  problem (eq. 37-38);
- coupling mode, ``SR >= Gamma``: ``T_p = T_t = a6 w_p^2 + a7 w_p w_t + a8 w_t^2`` (eq. 36, 39), fitted to the
  turbine torque (which carries no pump-side inertia torque) with no torque without slip, and with ``a8 = 0``
  when the coupling points span too narrow an SR range to tell ``a6`` from ``a8`` (flagged).

``Gamma`` is "the first SR where TR reaches 1": a first estimate from the binned median torque ratio
of the data, refined as the root of ``TR_model(SR) = 1`` of the converter fit, after which the data
are split again at the refined value and both modes refitted.

From a Recording (:func:`identify_torque_converter`): the turbine speed comes from the vehicle speed
(eq. 31: ``w_t = v / R_w * i_g * i_fd``), the turbine torque from the propeller-shaft torque through
the transmission model of the engaged gear (eq. 32 in the form of docs/models.md:
``T_t = T_out / (i_g eta_m) + C0``), the pump speed and torque are the motor's (K0 open: the engine is
decoupled); on a conventional car's log (no motor channels) they are the engine's, which drives the pump
alone. Only samples with the lock-up open, no shift in progress (target = actual gear, held for
a while), positive torques and a quasi-steady pump speed are used.

The curves: torque ratio ``TR = T_t / T_p`` against SR (Figure 18) and capacity factor
``CF = n_p / sqrt(T_p)`` (rpm / sqrt(Nm), i.e. the K-factor) against SR (Figure 19), each with the R^2
of the model curve against the data points.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import ConfigError, InsufficientDataError
from benchtwin.identification._fit import FitResult, ParameterEstimate, derived, linear_fit, r_squared
from benchtwin.identification.torque_converter_borrowed import borrowed_gear_offsets, uncalibrated_share
from benchtwin.identification.torque_converter_calibration import calibration_budget
from benchtwin.identification.torque_converter_model import (
    _gamma_from_data,
    _robust_z,
    _zero_torque_sr,
    converter_design,
    coupling_coefficients,
    coupling_design,
    coupling_point,
    speed_products,
    tc_torques,
)
from benchtwin.identification.torque_converter_points import (
    RPM_PER_RADS,
    ConverterPoints,
    converter_points,
)
from benchtwin.identification.torque_converter_table import fit_converter_table
from benchtwin.recording import Recording

__all__ = [
    "RPM_PER_RADS",
    "STALL_END_SR",
    "ConverterPoints",
    "converter_design",
    "converter_points",
    "coupling_coefficients",
    "coupling_design",
    "coupling_point",
    "fit_torque_converter",
    "identify_torque_converter",
    "speed_products",
    "tc_torques",
]  # the model forms and designs live in torque_converter_model; re-exported here


#: converter-mode points must reach below this SR for the stall end of the curves to be measured, not extrapolated
STALL_END_SR = 0.3


def fit_torque_converter(
    w_p: np.ndarray,
    w_t: np.ndarray,
    t_p: np.ndarray,
    t_t: np.ndarray,
    *,
    gamma: float | None = None,
    tr_tol: float = 0.02,
    min_points: int = 10,
    segments: list[str] | None = None,
    n_excluded: int = 0,
    dw_p: np.ndarray | None = None,
    outlier_sigma: float | None = 5.0,
    coupling_zero_slip: bool = True,
    coupling_torque: str = "turbine",
    min_coupling_span: float = 0.03,
) -> dict[str, FitResult]:
    """Fit a0..a8 and the coupling point to pump/turbine speed and torque points.

    Parameters
    ----------
    w_p, w_t:
        Pump and turbine speed, rad/s.
    t_p, t_t:
        Pump and turbine torque, Nm (positive: drive).
    gamma:
        Coupling speed ratio if known; else found from the data (module docstring).
    tr_tol:
        Tolerance on "TR reaches 1" for the first estimate of ``gamma``.
    min_points:
        Minimum points per mode.
    segments, n_excluded:
        Segment names and the count of points the caller excluded, carried into the results.
    dw_p:
        Pump acceleration (rad/s^2). When given, ``t_p`` is the torque *applied* to the pump shaft
        (the motor torque) and the pump-side inertia ``J_pump_kgm2`` (motor rotor + pump) is
        identified in the same least squares: ``t_p = a0 w_p^2 + a1 w_p w_t + a2 w_t^2 + J dw_p/dt``.
        The torque-ratio and capacity-factor curves then use the inertia-corrected pump torque.
    outlier_sigma:
        After a first fit, points whose pump or turbine residual exceeds this many robust standard
        deviations (1.4826 x median absolute deviation) are left out and the fit repeated once
        (transients the quasi-steady filter let through: lock-up engagement, torque steps); the
        count is in ``n_excluded`` and the reasons. ``None``: no rejection.
    coupling_zero_slip:
        Fit the coupling mode with ``a6 + a7 + a8 = 0``: a fluid coupling transmits no torque without
        slip (``SR = 1``). The coupling points span a narrow SR range (from Gamma to where the pump
        torque falls below the torque threshold, often less than 0.1), over which three free
        coefficients are nearly collinear and their curve is an extrapolation towards SR 1; the
        physical end point pins it. ``sr_zero_torque`` is then 1 by construction. ``False``: a6..a8
        free (eq. 39 as in the paper).
    coupling_torque:
        The torque the coupling mode is fitted to, ``"turbine"`` (default) or ``"pump"``: in coupling mode
        ``T_p = T_t`` (eq. 36), so either reads the coupling torque, but the pump's is the motor torque less the
        pump-side inertia torque, and along a lock-up-open ramp-up in 1st gear the pump accelerates at up to the
        quasi-steady limit (about 40 rad/s^2) while the coupling torque falls towards SR 1: an inertia torque of
        several Nm that ``J_pump_kgm2`` of the converter fit (correlated with ``a0..a2`` there) leaves in part,
        and that bends the small coupling torques near SR 1 (CF 10 % off at SR 0.95). The turbine torque (eq. 32,
        the shaft torque through the transmission model, calibrated against the motor torque where the
        lock-up is closed) carries no pump inertia. The transients left out (``outlier_sigma``) are still
        decided on the pump rows' residuals: the motor torque is a CAN signal, the same rows whatever the
        shaft torque's noise, whereas the 5-sigma residuals of a few dozen quantised shaft-torque points change
        with the noise and, with ``a6`` and ``a8`` nearly collinear, moved ``a6`` by 4 % from seed to seed.
    min_coupling_span:
        Coupling points over an SR span narrower than this cannot tell ``a6`` from ``a8`` (with no torque
        without slip, ``T / (w_p (w_p - w_t)) = a6 - a8 SR``: a straight line over the span, extrapolated to SR
        0.95 and beyond; over a span of 0.03 its slope already carries the noise of one point times about
        ``13 / sqrt(n)`` there): the torque is then fitted in proportion to pump speed times slip (``a8 = 0``,
        ``a7 = -a6``; a real converter's ``a8`` moves the curve by about 1 % between Gamma and 0.95) and the fit
        is flagged with the reason. Applies with ``coupling_zero_slip``.

    Returns
    -------
    dict
        ``converter`` (a0..a5, ``J_pump_kgm2`` with ``dw_p``, and ``gamma_coupling``; data ``sr_covered``: the
        SR range of its inlier points, flagged when it starts above ``STALL_END_SR``), ``coupling``
        (a6..a8 plus the well-determined ``k_at_gamma`` = T/w_p^2 at Gamma and ``sr_zero_torque``;
        missing when the data have fewer than ``min_points`` coupling points, see
        ``converter.reasons``), ``torque_ratio`` (R^2 of TR over the points kept by the fits; data
        ``sr``, ``tr``, ``tr_model``, ``inlier``), ``capacity_factor`` (R^2 of CF in converter mode;
        data ``cf``, ``cf_model``, ``coupling``) and ``capacity_factor_coupling`` (R^2 of CF in
        coupling mode) when it exists, and ``table`` (the binned monotone curves on the same inlier points,
        :mod:`benchtwin.identification.torque_converter_table`).

    Raises
    ------
    InsufficientDataError
        Too few converter-mode points.
    """
    w_p, w_t, t_p, t_t = (np.asarray(x, dtype=float) for x in (w_p, w_t, t_p, t_t))
    acc = None if dw_p is None else np.asarray(dw_p, dtype=float)
    ok = np.isfinite(w_p) & np.isfinite(w_t) & np.isfinite(t_p) & np.isfinite(t_t) & (w_p > 0) & (t_p > 0)
    ok &= (w_t >= 0) & (w_t <= 1.05 * w_p)
    if acc is not None:
        ok &= np.isfinite(acc)
    n_excluded += int((~ok).sum())
    w_p, w_t, t_p, t_t = w_p[ok], w_t[ok], t_p[ok], t_t[ok]
    if acc is not None:
        acc = acc[ok]
    segments = list(segments or [])
    if w_p.size < 2 * min_points:
        raise InsufficientDataError(f"torque converter: {w_p.size} usable points, need {2 * min_points}")
    sr = w_t / w_p
    tr = t_t / t_p
    reasons = []
    g0 = float(gamma) if gamma is not None else _gamma_from_data(sr, tr, tr_tol)
    if not np.isfinite(g0):
        g0 = float(sr.max()) + 1e-9
        reasons.append("the torque ratio never reaches 1 in the data: no coupling-mode points")
    names6 = [f"a{k}" for k in range(6)] + (["J_pump_kgm2"] if acc is not None else [])
    units6 = ["Nm*s^2/rad^2"] * 6 + (["kg*m^2"] if acc is not None else [])

    inlier = np.ones(sr.shape, dtype=bool)

    def robust(A: np.ndarray, b: np.ndarray, n: int, names: list[str], units: list[str], what: str,
               n_min: int, idx: np.ndarray, stacked: bool) -> FitResult:
        """Fit, drop rows beyond ``outlier_sigma`` robust sigma (pump and turbine rows together), refit."""
        fit = linear_fit(A, b, names, units=units, segments=segments, min_points=n_min, n_excluded=n_excluded,
                         what=what)
        if outlier_sigma is None:
            return fit
        res = b - fit.data["y_fit"]
        floor = 1e-6 * float(np.sqrt(np.mean(b**2)))
        keep = _robust_z(res[:n], floor) <= outlier_sigma
        if stacked:
            keep &= _robust_z(res[n:], floor) <= outlier_sigma
        n_out = int((~keep).sum())
        if n_out == 0 or keep.sum() < min_points:
            return fit
        kk = np.r_[keep, keep] if stacked else keep
        fit = linear_fit(A[kk], b[kk], names, units=units, segments=segments, min_points=n_min,
                         n_excluded=n_excluded + n_out, what=what)
        fit.reasons.append(f"{n_out} points beyond {outlier_sigma:g} robust sigma left out (transients)")
        inlier[idx[~keep]] = False
        return fit

    def conv_fit(mask: np.ndarray) -> FitResult:
        n = int(mask.sum())
        if n < min_points:
            raise InsufficientDataError(f"torque converter: {n} converter-mode points (SR < {g0:.3f}), "
                                        f"need {min_points}")
        inlier[:] = True
        A = converter_design(w_p[mask], w_t[mask], None if acc is None else acc[mask])
        b = np.r_[t_p[mask], t_t[mask]]
        return robust(A, b, n, names6, units6, "torque converter (eq. 37-38)", 2 * min_points,
                      np.flatnonzero(mask), True)

    conv = conv_fit(sr < g0)
    if gamma is None and acc is not None:
        # the first estimate compares the turbine torque with the motor torque, which also accelerates the pump
        # side (several % of the pump torque in slow take-offs): again with the inertia of that fit taken out
        t_p_net = t_p - conv.value("J_pump_kgm2") * acc
        tr_p = t_t / np.where(t_p_net > 0, t_p_net, np.nan)
        fin = np.isfinite(tr_p)
        g0b = _gamma_from_data(sr[fin], tr_p[fin], tr_tol) if fin.sum() >= 2 * min_points else float("nan")
        if np.isfinite(g0b) and g0b != g0 and int((sr < g0b).sum()) >= min_points:
            g0 = g0b
            conv = conv_fit(sr < g0)
    g, refined = g0, False
    if gamma is None:
        g1 = coupling_point(np.array([conv.value(f"a{k}") for k in range(6)]), lo=0.3, hi=1.0)
        if np.isfinite(g1) and abs(g1 - g0) < 0.15 and int((sr < g1).sum()) >= min_points:
            g, refined = g1, True
            conv = conv_fit(sr < g)
    conv.data["split"] = np.array([g0, float(refined)])  # the mode split's decisions (uncertainty.SPLIT_KEY)
    derived(conv, "gamma_coupling",
            lambda x: coupling_point(x[:6], lo=0.3, hi=1.0) if gamma is None else float(gamma))
    if gamma is not None or not np.isfinite(conv.value("gamma_coupling")):
        conv.params["gamma_coupling"].value = g
    conv.params["gamma_coupling"].unit = ""
    cm = sr >= g
    out: dict[str, FitResult] = {"converter": conv}
    a = np.full(9, np.nan)
    a[:6] = [conv.value(f"a{k}") for k in range(6)]
    j_pump = conv.value("J_pump_kgm2") if acc is not None else 0.0
    if coupling_torque not in ("turbine", "pump"):
        raise ConfigError(f"coupling_torque must be 'turbine' or 'pump', not {coupling_torque!r}")
    if int(cm.sum()) >= min_points:
        # the pump inertia comes from the converter fit (the coupling range alone separates it poorly)
        t_pump = t_p[cm] - (j_pump * acc[cm] if acc is not None else 0.0)
        unit = "Nm*s^2/rad^2"
        zs = coupling_zero_slip
        span = float(np.ptp(sr[cm]))
        one = zs and span < min_coupling_span
        names = ["a6"] if one else ["a6", "a8"] if zs else ["a6", "a7", "a8"]
        what = "torque converter coupling (eq. 39" + (", torque in proportion to pump speed times slip"
                                                      if one else ", no torque without slip" if zs else "")
        A_c = coupling_design(w_p[cm], w_t[cm], zs, one)
        # the transients are left out on the pump rows' residuals (see ``coupling_torque``)
        coup = robust(A_c, t_pump, int(cm.sum()), names, [unit] * len(names), what + ")", min_points,
                      np.flatnonzero(cm), False)
        pump_side = coupling_coefficients(np.array([coup.value(n) for n in names]), zs, one)
        if coupling_torque == "turbine":
            keep = inlier[cm]
            turb = linear_fit(A_c[keep], t_t[cm][keep], names, units=[unit] * len(names), segments=segments,
                              min_points=min_points, n_excluded=n_excluded + int((~keep).sum()),
                              what=what + ", on the turbine torque)")
            turb.reasons.extend(coup.reasons)
            coup = turb
        if one:
            derived(coup, "a7", lambda x: -x[0], unit=unit)
            derived(coup, "a8", lambda x: 0.0, unit=unit)
            coup.flag(f"coupling points over SR {float(sr[cm].min()):.3f}-{float(sr[cm].max()):.3f} only (span "
                      f"{span:.3f} < {min_coupling_span:g}): a6 and a8 not told apart, a8 = 0 taken (torque in "
                      "proportion to pump speed times slip)")
        elif zs:
            derived(coup, "a7", lambda x: -x[0] - x[1], unit=unit)
        coup.data["torque"] = coupling_torque
        # the same fit on the pump rows (a6..a8): what the motor pays in coupling mode, for the map-based model
        coup.data["pump_side_a678"] = np.asarray(pump_side, dtype=float)
        coup.data["slip_only"] = one
        a[6:] = [coup.value(f"a{k}") for k in (6, 7, 8)]
        # over the narrow coupling range a6..a8 are strongly correlated; these two are well determined:
        gg = float(conv.value("gamma_coupling"))
        derived(coup, "k_at_gamma", lambda x: float(coupling_coefficients(x, zs, one) @ [1.0, gg, gg**2]), unit=unit)
        derived(coup, "sr_zero_torque", lambda x: _zero_torque_sr(coupling_coefficients(x, zs, one)), unit="")
        out["coupling"] = coup
    else:
        reasons.append(f"{int(cm.sum())} coupling-mode points (SR >= {g:.3f}; need {min_points}): a6..a8 not "
                       "identified")
    # the stall end: without converter-mode points near SR 0 the curves there are an extrapolation
    conv_pts = (sr < g) & inlier
    lo = float(sr[conv_pts].min()) if conv_pts.any() else float("nan")
    conv.data["sr_covered"] = np.array([lo, float(sr[conv_pts].max()) if conv_pts.any() else float("nan")])
    if np.isfinite(lo) and lo > STALL_END_SR:
        reasons.append(f"converter-mode points only from SR {lo:.2f} (none below {STALL_END_SR:g}, too little "
                       f"excitation near stall): the curves below SR {lo:.2f} are an extrapolation")
    for r in reasons:
        conv.flag(r)
    # curves (with the pump torque corrected for the pump-side inertia when it was identified)
    if acc is not None:
        t_p = t_p - j_pump * acc
        tr = t_t / t_p
    conv_m = ~cm
    den = a[0] + a[1] * sr + a[2] * sr**2
    tr_model = np.where(cm, 1.0, (a[3] + a[4] * sr + a[5] * sr**2) / den)
    tr_r2, _ = r_squared(tr[inlier], tr_model[inlier])
    tp_coef = np.where(cm, a[6] + a[7] * sr + a[8] * sr**2, den)
    with np.errstate(invalid="ignore"):
        cf = w_p * RPM_PER_RADS / np.sqrt(t_p)
    with np.errstate(invalid="ignore", divide="ignore"):
        cf_model = RPM_PER_RADS / np.sqrt(tp_coef)
    curve_data = {"sr": sr, "tr": tr, "tr_model": tr_model, "cf": cf, "cf_model": cf_model,
                  "coupling": cm.astype(float), "w_p": w_p, "w_t": w_t, "t_p": t_p, "t_t": t_t,
                  "a": a, "gamma": np.array([g]), "inlier": inlier.astype(float)}
    out["torque_ratio"] = FitResult({}, tr_r2, float("nan"),
                                    float(np.sqrt(np.mean((tr[inlier] - tr_model[inlier]) ** 2))), int(inlier.sum()),
                                    segments=segments, data=curve_data)
    cv = conv_m & inlier & np.isfinite(cf) & np.isfinite(cf_model)
    cf_r2, _ = r_squared(cf[cv], cf_model[cv])
    out["capacity_factor"] = FitResult({}, cf_r2, float("nan"),
                                       float(np.sqrt(np.mean((cf[cv] - cf_model[cv]) ** 2))),
                                       int(cv.sum()), segments=segments, data=curve_data)
    iw = inlier.astype(bool)
    try:  # the empirical curves beside eq. 35-36
        out["table"] = fit_converter_table(w_p[iw], w_t[iw], t_p[iw], t_t[iw], *tc_torques(a, g, w_p[iw], w_t[iw]),
                                           segments=segments, n_excluded=n_excluded + int((~iw).sum()))
    except InsufficientDataError as exc:
        conv.reasons.append(f"no converter table: {exc}")
    if "coupling" in out:
        fin = cm & inlier & np.isfinite(cf_model) & np.isfinite(cf)
        cf_r2c, _ = r_squared(cf[fin], cf_model[fin])
        out["capacity_factor_coupling"] = FitResult(
            {}, cf_r2c, float("nan"), float(np.sqrt(np.mean((cf[fin] - cf_model[fin]) ** 2))) if fin.any()
            else float("nan"), int(fin.sum()), segments=segments, data=curve_data)
    return out


def identify_torque_converter(
    rec: Recording,
    specs: VehicleSpecs,
    *,
    transmission: Mapping[int, tuple[float, float]] | None = None,
    rate_hz: float = 10.0,
    max_pump_accel_rpm_s: float = 400.0,
    min_pump_speed_rpm: float = 300.0,
    min_pump_torque_nm: float = 20.0,
    shift_hold_s: float = 1.0,
    gamma: float | None = None,
    min_points: int = 10,
    pump_inertia: bool = True,
    derivative_window_s: float = 0.4,
    calibrate_turbine_speed: bool = True,
    calibrate_turbine_torque: bool = True,
    min_calibration_points: int = 50,
    outlier_sigma: float | None = 5.0,
    lockup_slip_tol: float = 0.01,
    coupling_zero_slip: bool = True,
    coupling_torque: str = "turbine",
    min_coupling_span: float = 0.03,
    drag: FitResult | None = None,
    calibration_uncertainty: bool = True,
) -> dict[str, FitResult]:
    """Identify the torque converter from a Recording (module docstring).

    Parameters
    ----------
    rec:
        Needs ``vehicle_speed_kmh``, ``shaft_torque_nm``, ``gear_actual`` and the pump's speed and torque:
        ``em_speed_rpm`` and ``em_torque_nm`` (P2 hybrid, K0 open), or, without motor channels,
        ``engine_speed_rpm`` and ``engine_torque_nm`` (conventional car: the engine drives the pump alone);
        uses ``lockup_closed``, ``gear_target``, ``k0_closed`` (else ``engine_on``) when present.
    specs:
        Gear ratios, final drive, wheel radius.
    rate_hz:
        Common time base of the channels.
    transmission:
        Gear -> ``(eta_m, C0)`` from the transmission identification. A gear without a model uses
        the nearest gear's (flagged with the reason), its turbine torque then offset to meet the pump torque on
        its own coupling-mode points (``turbine_torque_offset_g<k>``, iterated with the coupling point;
        :func:`~benchtwin.identification.torque_converter_borrowed.borrowed_gear_offsets`), or left as it is and
        flagged when it has too few of them. Without any, eta = 1 and C0 = 0 and the result
        is flagged (turbine torque underestimated by the gearbox losses).
    max_pump_accel_rpm_s:
        Quasi-steady limit on ``|d n_p / dt|``: inertia torques stay small (and are identified, see
        ``pump_inertia``).
    min_pump_speed_rpm:
        Points below this pump speed are left out (creep, stand-still).
    min_pump_torque_nm:
        Points below this pump torque are left out: there the torque ratio is mostly sensor noise.
    gamma, min_points:
        See :func:`fit_torque_converter`.
    shift_hold_s:
        Samples within this time of a gear change (target or actual) are left out.
    pump_inertia:
        Identify the pump-side inertia with the pump coefficients (see :func:`fit_torque_converter`):
        the motor torque also accelerates the rotor and the pump, which biases ``a0..a2`` in the
        slow-but-not-static take-offs of a real test unless it is accounted for.
    derivative_window_s:
        Span of the central difference for the pump acceleration. With ``max_pump_accel_rpm_s`` it also
        sets which pump speed changes are steps the difference cannot resolve, and when the pump speed has
        settled after one: samples from the step until then are left out (see
        :func:`~benchtwin.identification.torque_converter_points.unsettled`; e.g. the motor spun up from
        stand-still to idle within one sample).
    calibrate_turbine_speed:
        Eq. 31 needs the effective rolling radius and a true vehicle speed; a vehicle CAN speed that
        reads a few % high, or a catalogue tyre radius, shifts every SR. Where the lock-up is closed
        (and the gear engaged, no shift, quasi-steady), the turbine turns with the pump exactly, so the
        median of ``w_p / w_t(eq. 31)`` over those samples is the correction factor; it is applied to
        all turbine speeds and reported as ``turbine_speed_scale`` (flagged when it is more than 10 %
        from 1: check the gear ratios, final drive and wheel radius). Needs at least
        ``min_calibration_points`` such samples, else eq. 31 is used as is.
    calibrate_turbine_torque:
        Likewise for eq. 32: where the lock-up is closed and K0 open (gear engaged, no shift, the pump speed
        within a tenth of ``max_pump_accel_rpm_s``, so that the inertia torque stays below about 1 % of the
        pump torque), the turbine torque is the motor torque. A torque sensor's gain error that the
        transmission identification does not absorb (it reads the input torque of the hybrid ramp-ups too)
        scales every torque ratio alike; the median over the gears of each gear's median
        ``T_motor / T_t(eq. 32)`` over those samples corrects it, reported as ``turbine_torque_scale``
        (flagged beyond 5 %). Needs the K0 or engine state and ``min_calibration_points`` such samples in a
        gear with a transmission model of its own (a borrowed model's efficiency error is that gear's, not a
        common gain), else eq. 32 is used as is.
    outlier_sigma, coupling_zero_slip, coupling_torque, min_coupling_span:
        See :func:`fit_torque_converter`.
    lockup_slip_tol:
        Without a ``lockup_closed`` channel, samples with ``|1 - w_t / w_p|`` below this count as
        lock-up closed (flagged: the converter's own near-1 speed ratios are then cut off).
    drag:
        ``transmission.drag`` when used: eq. 32's eta_m and C0 per point at the logged oil temperature.
    calibration_uncertainty:
        Carry the standard errors of the turbine speed and torque calibrations into every parameter's budget
        (:mod:`~benchtwin.identification.torque_converter_calibration`: the method re-run once per scale).

    Returns
    -------
    dict
        As :func:`fit_torque_converter`; ``converter`` also carries ``turbine_speed_scale``.

    Raises
    ------
    MissingChannelError, InsufficientDataError
    """
    pts = converter_points(rec, specs, transmission=transmission, rate_hz=rate_hz,
                           max_pump_accel_rpm_s=max_pump_accel_rpm_s, min_pump_speed_rpm=min_pump_speed_rpm,
                           min_pump_torque_nm=min_pump_torque_nm, shift_hold_s=shift_hold_s,
                           derivative_window_s=derivative_window_s, calibrate_turbine_speed=calibrate_turbine_speed,
                           min_calibration_points=min_calibration_points, lockup_slip_tol=lockup_slip_tol,
                           calibrate_turbine_torque=calibrate_turbine_torque, drag=drag)

    def solve(w_t: np.ndarray, t_t: np.ndarray) -> tuple[dict[str, FitResult], dict, dict[int, str]]:
        """The fits on the points with these turbine speeds and torques (the calibrations' re-runs move them)."""
        p = pts if w_t is pts.w_t and t_t is pts.t_t else replace(pts, w_t=w_t, t_t=t_t)

        def fit(t_t: np.ndarray) -> dict[str, FitResult]:
            return fit_torque_converter(p.w_p, p.w_t, p.t_p, t_t, gamma=gamma, min_points=min_points,
                                        segments=p.segments, n_excluded=p.n_excluded,
                                        dw_p=p.dw_p if pump_inertia else None, outlier_sigma=outlier_sigma,
                                        coupling_zero_slip=coupling_zero_slip, coupling_torque=coupling_torque,
                                        min_coupling_span=min_coupling_span)

        res = fit(p.t_t)
        offsets: dict[int, tuple[float, float, int]] = {}
        off_reasons: dict[int, str] = {}
        # a gear on a borrowed transmission model: its turbine torque offset to meet the pump torque on its own
        # coupling points; the coupling point moves with the offset, so both are iterated to a fixed point
        for _it in range(8 if p.borrowed else 0):
            conv = res["converter"]
            j = conv.value("J_pump_kgm2") if "J_pump_kgm2" in conv.params else 0.0
            new, off_reasons = borrowed_gear_offsets(p, conv.value("gamma_coupling"), j,
                                                     0.1 * max_pump_accel_rpm_s / RPM_PER_RADS, min_points)
            # a gear calibrated in an earlier round keeps its offset if the moved coupling point leaves it too few
            off_reasons = {k: r for k, r in off_reasons.items() if k not in offsets}
            new = {**{k: v for k, v in offsets.items() if k not in new}, **new}
            moved = max((abs(new[k][0] - offsets.get(k, (0.0,))[0]) for k in new), default=0.0)
            if moved < 1e-12:
                break
            offsets = new
            res = fit(p.t_t - sum(o * (p.gear == k) for k, (o, _se, _n) in offsets.items()))
            if moved < 0.02:
                break
        return res, offsets, off_reasons

    res, offsets, off_reasons = solve(pts.w_t, pts.t_t)
    if calibration_uncertainty:  # the scales' standard errors into every parameter's budget
        calibration_budget(res, pts, lambda w_t, t_t: solve(w_t, t_t)[0], min_calibration_points)
    scale, scale_se, segs = pts.scale, pts.scale_se, pts.segments
    res["converter"].add(ParameterEstimate(
        "turbine_speed_scale", scale, scale_se, (scale - 1.96 * scale_se, scale + 1.96 * scale_se), float("nan"),
        pts.n_cal, "", segs))
    ts, ts_se = pts.tscale, pts.tscale_se
    res["converter"].add(ParameterEstimate(
        "turbine_torque_scale", ts, ts_se, (ts - 1.96 * ts_se, ts + 1.96 * ts_se), float("nan"), pts.n_tcal, "",
        segs))
    g_fit = res["converter"].value("gamma_coupling")
    for k, (o, o_se, n_o) in offsets.items():
        res["converter"].add(ParameterEstimate(f"turbine_torque_offset_g{k}", o, o_se,
                                               (o - 1.96 * o_se, o + 1.96 * o_se), float("nan"), n_o, "Nm", segs))
        pts.reasons.append(f"gear {k} on gear {pts.borrowed[k]}'s transmission model: its turbine torque taken "
                           f"{o:+.2f} Nm off, calibrated against the pump torque on its {n_o} coupling-mode points "
                           f"(the coupling point now {g_fit:.3f})")
    pts.reasons.extend(off_reasons.values())
    ok = np.isfinite(pts.w_p) & np.isfinite(pts.w_t) & np.isfinite(pts.t_p) & np.isfinite(pts.t_t)
    if (share := uncalibrated_share(pts.gear, ok, pts.borrowed, set(offsets))) is not None:  # run adds its cause
        res["converter"].data[share.KEY] = share
        pts.reasons.append(share.reason())
    res["converter"].reasons.extend(pts.notes)
    for r in pts.reasons:
        res["converter"].flag(r)
        if "coupling" in res:
            res["coupling"].flag(r)
    return res
