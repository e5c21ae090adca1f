"""A motor and inverter loss model fitted on the steady points, for a map-based vehicle model.

The paper's Willans lines (eq. 18-24, :mod:`benchtwin.identification.motor`) give the motor's DC power as
an affine function of ``T omega`` per side; a real machine's loss is not: copper loss grows with ``T^2``,
iron, friction and windage with speed, the inverter's switching loss with ``|T|`` (docs/fidelity.md). This
module fits the loss as a function of both, on the same steady points the Willans lines are fitted on (both
sides at once, since the loss is the same whether the machine motors or generates):

``P_loss = P_el - T omega = P0 + k_w omega + k_w2 omega^2 + k_cu T^2 + k_sw |T|``

with ``P_el = P_hpcu - P_lv / eta_dcdc`` the motor inverter's DC power. It is what the paper names as the
next step ("a map-based vehicle model"); the paper's Willans parameters stay reported and checked as they
are. The speed polynomial is read only over the speed range the points covered (:func:`loss_w`
clamps the speed to it); the fit's RMS residual is kept as the model-form uncertainty of a single point.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from benchtwin.errors import IdentificationError
from benchtwin.identification._fit import FitResult, IdentificationResult, derived, linear_fit

__all__ = ["ETA_DCDC_PLAUSIBLE", "LOSS_TERMS", "add_loss_fit", "fit_motor_loss", "loss_w"]

#: range a DC/DC efficiency can take (a Willans fit's estimate outside it is not used)
ETA_DCDC_PLAUSIBLE = (0.7, 1.0)

RPM = 2.0 * np.pi / 60.0
#: the loss model's parameters, in the order of its regressors
LOSS_TERMS = ("P0", "k_w", "k_w2", "k_cu", "k_sw")
_UNITS = ("W", "W s/rad", "W s^2/rad^2", "W/Nm^2", "W/Nm")


def _design(torque_nm: np.ndarray, speed_radps: np.ndarray) -> np.ndarray:
    t, w = np.asarray(torque_nm, float), np.asarray(speed_radps, float)
    return np.column_stack([np.ones_like(w), w, w * w, t * t, np.abs(t)])


def loss_w(coeffs: Iterable[float], torque_nm: np.ndarray, speed_radps: np.ndarray,
           speed_range_radps: tuple[float, float] | None = None, *, to_standstill: bool = False) -> np.ndarray:
    """The loss model ``P0 + k_w w + k_w2 w^2 + k_cu T^2 + k_sw |T|`` (W), never below zero.

    Parameters
    ----------
    coeffs:
        ``(P0, k_w, k_w2, k_cu, k_sw)`` (:data:`LOSS_TERMS`).
    torque_nm, speed_radps:
        Operating points.
    speed_range_radps:
        The speed range the fit covered: the speed terms are evaluated at the speed clamped to it (a
        polynomial is not extrapolated); None: no clamping.
    to_standstill:
        Below the range's lower end ``w_lo``, let the speed part ``S(w_lo) = k_w w_lo + k_w2 w_lo^2`` fall
        linearly to zero at standstill, ``P0 + S(w_lo) |w| / w_lo + ...``, instead of holding it: iron
        (hysteresis ~w, eddy ~w^2), friction (~w) and windage (~w^3) losses all vanish with the speed, what is
        left at rest is the intercept ``P0`` (the inverter's standby). The line is the chord of the terms over
        ``[0, w_lo]``, so for any convex speed loss it bounds it from above. Without a range: no change.
    """
    c = np.asarray(list(coeffs), float)
    if c.shape != (len(LOSS_TERMS),):
        raise ValueError(f"loss_w: {c.size} coefficients, expected {len(LOSS_TERMS)} ({', '.join(LOSS_TERMS)})")
    w = np.asarray(speed_radps, float)
    t = np.asarray(torque_nm, float)
    if speed_range_radps is None:
        return np.maximum(_design(t, w) @ c, 0.0)
    lo = float(speed_range_radps[0])
    wc = np.clip(w, *speed_range_radps)
    raw = _design(t, wc) @ c
    if to_standstill and lo > 0:
        s_lo = c[1] * lo + c[2] * lo * lo  # the speed part at the range's lower end
        raw = raw - np.where(np.abs(w) < lo, (1.0 - np.abs(w) / lo) * s_lo, 0.0)
    return np.maximum(raw, 0.0)


def fit_motor_loss(torque_nm: np.ndarray, speed_rpm: np.ndarray, p_el_w: np.ndarray, *, min_points: int = 12,
                   segments: Iterable[str] = (), n_excluded: int = 0, eta_dcdc_note: str = "") -> FitResult:
    """Least squares of the loss ``P_el - T omega`` on ``[1, omega, omega^2, T^2, |T|]`` over steady points.

    Parameters
    ----------
    torque_nm, speed_rpm:
        Motor torque (either sign) and speed of the steady points.
    p_el_w:
        Motor inverter DC power of the points (W): the HPCU power less the DC/DC draw.
    min_points:
        Fewest points.
    segments, n_excluded:
        Where the points came from and how many the caller left out (reported).
    eta_dcdc_note:
        Where the DC/DC efficiency used to form ``p_el_w`` came from (goes to the reasons).

    Returns
    -------
    FitResult
        ``P0, k_w, k_w2, k_cu, k_sw`` with the fit's standard errors; derived ``loss_rms_w`` is not a
        parameter: ``rmse`` is the RMS residual (the model-form scatter of one point). Data: ``torque_nm``,
        ``speed_rpm``, ``loss_w`` (measured), ``loss_fit_w``, ``speed_range_radps`` (the clamping range of
        :func:`loss_w`).

    Raises
    ------
    InsufficientDataError, NoExcitationError, CollinearError
        Too few points, or torque and speed did not vary enough to separate the terms.
    """
    what = "motor.loss"
    t = np.asarray(torque_nm, float)
    n = np.asarray(speed_rpm, float)
    p = np.asarray(p_el_w, float)
    if not (t.shape == n.shape == p.shape):
        raise IdentificationError(f"{what}: torque {t.shape}, speed {n.shape} and power {p.shape} differ in shape")
    w = n * RPM
    ok = np.isfinite(t) & np.isfinite(w) & np.isfinite(p) & (w > 0)
    t, w, p = t[ok], w[ok], p[ok]
    loss = p - t * w
    fit = linear_fit(_design(t, w), loss, list(LOSS_TERMS), units=list(_UNITS),
                     segments=sorted({s for s in segments if s}), min_points=min_points,
                     n_excluded=n_excluded + int((~ok).sum()), what=what, cond_max=1e9)
    derived(fit, "loss_at_200nm_3000rpm",
            lambda x: float(_design(np.array([200.0]), np.array([3000.0 * RPM]))[0] @ x[: len(LOSS_TERMS)]),
            unit="W")
    fit.data.update(torque_nm=t, speed_rpm=w / RPM, loss_w=loss, loss_fit_w=fit.data["y_fit"],
                    speed_range_radps=np.array([float(w.min()), float(w.max())]))
    if eta_dcdc_note:
        fit.reasons.append(eta_dcdc_note)
    if fit.value("k_cu") < 0:
        fit.flag(f"k_cu = {fit.value('k_cu'):.4g} W/Nm^2 is negative: the points do not show a copper loss "
                 "(too narrow a torque range)")
    return fit


def _eta_used(result: IdentificationResult, given: float | None) -> tuple[float, str]:
    """The DC/DC efficiency the Willans fits settled on (motoring, else generating, else zero-torque), and whence."""
    if given is not None:
        return float(given), "eta_dcdc given"
    lo, hi = ETA_DCDC_PLAUSIBLE
    for key in ("motor.motoring", "motor.generating", "motor.dcdc"):
        f = result.fits.get(key)
        if f is not None and "eta_dcdc" in f.params:
            p = f["eta_dcdc"]
            if p.status == "ok" and lo <= p.value <= hi:
                return p.value, f"eta_dcdc = {p.value:.3f} from {key}"
    return float("nan"), ""


def add_loss_fit(result: IdentificationResult, torque_nm: np.ndarray, speed_rpm: np.ndarray, p_hpcu_w: np.ndarray,
                 p_lv_w: np.ndarray | None, eta_dcdc: float | None, segments: list[str], n_excluded: int,
                 min_speed_rpm: float = 50.0) -> None:
    """Fit ``motor.loss`` on the steady points of both sides and put it (or why not) into ``result``.

    The DC/DC draw ``P_lv / eta_dcdc`` is taken off the HPCU power with the efficiency the Willans fits settled
    on (:func:`_eta_used`); without a DC/DC measurement the loss includes the DC/DC's draw (said in the reasons).
    Points turning slower than ``min_speed_rpm`` are left out, as for the Willans lines.
    """
    t, n, p = (np.asarray(a, float) for a in (torque_nm, speed_rpm, p_hpcu_w))
    if p_lv_w is None:
        p_el, note = p, "DC/DC power not measured: the loss includes the DC/DC converter's draw"
    else:
        eta, note = _eta_used(result, eta_dcdc)
        if not np.isfinite(eta):
            result.errors["motor.loss"] = ("IdentificationError: motor.loss: no plausible eta_dcdc to take the DC/DC "
                                           "draw off the HPCU power")
            return
        p_el = p - np.asarray(p_lv_w, float) / eta
        note += " takes the DC/DC draw off the HPCU power"
    keep = np.isfinite(p_el) & (n > min_speed_rpm)
    try:
        fit = fit_motor_loss(t[keep], n[keep], p_el[keep], eta_dcdc_note=note,
                             segments=[s for s, k in zip(segments, keep) if k],
                             n_excluded=n_excluded + int((~keep).sum()))
    except IdentificationError as exc:
        result.errors["motor.loss"] = f"{type(exc).__name__}: {exc}"
        return
    _compare_with_willans(result, fit, t[keep], n[keep] * RPM, p_el[keep])
    result.fits["motor.loss"] = fit


def _compare_with_willans(result: IdentificationResult, fit: FitResult, t: np.ndarray, w: np.ndarray,
                          p_el: np.ndarray, min_torque_nm: float = 5.0) -> None:
    """RMS DC-power residual of the loss model and of the Willans lines on the points both describe.

    The rule a map-based model applies (``better_than_willans`` in ``fit.data``): the loss model replaces the
    Willans lines only where its residual is smaller on the same points. On a machine whose loss is affine in
    ``T omega`` per side (the paper's form), the lines fit exactly and stay; on one with copper and speed losses
    the loss model is closer. Both sides' lines must be identified for the comparison.
    """
    mot, gen = result.fits.get("motor.motoring"), result.fits.get("motor.generating")
    if mot is None or gen is None or "e" not in mot.params or "e_gen" not in gen.params:
        fit.reasons.append("Willans lines of both sides not identified: the loss model is not compared with them")
        return
    sel = np.abs(t) > min_torque_nm
    tw = t * w
    p_will = np.where(t > 0, (tw + mot.value("W_loss")) / mot.value("e"), gen.value("e_gen") * tw
                      + gen.value("W_loss_gen"))
    p_loss = tw + loss_w([fit.value(k) for k in LOSS_TERMS], t, w)
    r_w = float(np.sqrt(np.mean((p_will - p_el)[sel] ** 2)))
    r_l = float(np.sqrt(np.mean((p_loss - p_el)[sel] ** 2)))
    fit.data.update(willans_rmse_w=np.array([r_w]), loss_rmse_w=np.array([r_l]),
                    better_than_willans=np.array([r_l < r_w]))
    fit.reasons.append(f"RMS DC-power residual on the {int(sel.sum())} points with |T| > {min_torque_nm:g} Nm: loss "
                       f"model {r_l:.0f} W, Willans lines {r_w:.0f} W ("
                       + ("the loss model is closer" if r_l < r_w else "the Willans lines are as close or closer")
                       + ")")
