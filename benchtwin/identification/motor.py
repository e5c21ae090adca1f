"""Electric motor Willans line (eq. 18-24), motoring and generating, and the efficiency map it implies.

Normalised with the rotor radius ``r`` and volume ``V`` (public specs):
``p_me = T / (2 V)``, ``p_ma = P_el / V * 2 pi / omega``, ``c_m = r omega``.

Motoring (``T > 0``): ``T omega = e P_el - W_loss``, i.e. eq. 20
``p_me = e p_ma / (4 pi) - r W_loss / (2 V c_m)``. Generating (``T < 0``):
``P_el = e_gen T omega + W_loss_gen`` (docs/models.md).

``P_el`` is the motor inverter's DC power, but the IVT-S on the HPCU high-voltage side also sees the
DC/DC converter: ``P_hpcu = P_el + P_lv / eta_dcdc`` with ``P_lv`` the DC/DC low-voltage output
measured by its own IVT-S. Since the 12 V loads vary, ``eta_dcdc`` is identified in the same least
squares: motoring regresses ``p_me`` on ``[p_ma_hpcu, -p_lv, -1/c_m]`` (``p_lv`` normalised like
``p_ma``) with unknowns ``[C0, C0 / eta_dcdc, C1]``, ``e = 4 pi C0``, ``W_loss = 2 V C1 / r`` (eq. 24);
generating regresses ``p_ma_hpcu`` on ``[p_me, 1/c_m, p_lv]`` with unknowns
``[4 pi e_gen, 2 pi r W_loss_gen / V, 1 / eta_dcdc]``.

On a motor whose loss is not affine in ``T omega`` (a real one: copper loss in ``T^2``), that curvature leaks
into the nearly collinear 12 V column. A joint estimate outside :data:`ETA_DCDC_PLAUSIBLE` or with a standard
error above :data:`ETA_DCDC_MAX_SE` is therefore replaced by :func:`fit_dcdc_within`'s, observed independently
inside steady zero-torque windows, and that side's line is refitted with it fixed.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import IdentificationError, InsufficientDataError
from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate, derived, linear_fit
from benchtwin.identification._signals import check_spread, raise_all_failed
from benchtwin.identification.motor_loss import ETA_DCDC_PLAUSIBLE, add_loss_fit
from benchtwin.identification.steady import SteadyWindows, Tolerance, find_steady_windows
from benchtwin.recording import Recording

__all__ = ["ETA_DCDC_MAX_SE", "ETA_DCDC_PLAUSIBLE", "MotorPoints", "dc_input_roles", "efficiency_map",
           "fit_dcdc_within", "fit_willans_generating", "fit_willans_motoring", "identify_motor", "motor_points",
           "side_points"]

RPM = 2.0 * math.pi / 60.0
_LV = ("dcdc_lv_current_a", "dcdc_lv_voltage_v")
_HPCU = ("hpcu_current_a", "hpcu_voltage_v")
#: without an inverter-side sensor (a BEV's log often has only the pack's), the pack's power is the DC input
_PACK = ("battery_current_a", "battery_voltage_v")
#: largest standard error of a joint Willans estimate of eta_dcdc that is used as it is
ETA_DCDC_MAX_SE = 0.05


def dc_input_roles(rec: Recording) -> tuple[str, str]:
    """The current and voltage roles that measure the motor's DC input: the HPCU's, else the pack's."""
    return _HPCU if all(c in rec for c in _HPCU) or not all(c in rec for c in _PACK) else _PACK


class MotorPoints:
    """Steady motor points: torque (Nm), speed (rpm), HPCU HV power and DC/DC LV power (W), segments.

    ``windows`` are the steady windows the points are means over (one per point), when known.
    """

    def __init__(self, torque_nm: np.ndarray, speed_rpm: np.ndarray, p_hpcu_w: np.ndarray, p_lv_w: np.ndarray | None,
                 segments: list[str], n_flagged: int = 0, windows: SteadyWindows | None = None) -> None:
        self.torque_nm = np.asarray(torque_nm, dtype=float)
        self.speed_rpm = np.asarray(speed_rpm, dtype=float)
        self.p_hpcu_w = np.asarray(p_hpcu_w, dtype=float)
        self.p_lv_w = None if p_lv_w is None else np.asarray(p_lv_w, dtype=float)
        self.segments = list(segments)
        self.n_flagged = n_flagged
        self.windows = windows


def motor_points(rec: Recording, *, steady: SteadyWindows | None = None,
                 kinds: Iterable[str] | None = ("ramp_up", "constant_drive"), rate_hz: float = 10.0,
                 tolerances: Mapping[str, Tolerance] | None = None,
                 max_duration_s: float | None = None) -> MotorPoints:
    """Steady motor points of a Recording (window means over each source's own samples).

    The DC/DC low-voltage power is included when both DC/DC channels are present. The DC input is the
    HPCU's current and voltage, or the pack's when the HPCU's are not recorded (:func:`dc_input_roles`).
    """
    dc = dc_input_roles(rec)
    if steady is None:
        steady = find_steady_windows(rec, ["em_speed_rpm", "em_torque_nm"],
                                     states=("gear_actual", "k0_closed", "lockup_closed", "hybrid_mode"),
                                     extra=dc, kinds=kinds, rate_hz=rate_hz,
                                     tolerances=tolerances, max_duration_s=max_duration_s)
    torque = steady.raw_average(rec, "em_torque_nm")
    speed = steady.raw_average(rec, "em_speed_rpm")
    p_hpcu = steady.raw_average(rec, *dc)
    p_lv = steady.raw_average(rec, *_LV) if all(c in rec for c in _LV) else None
    return MotorPoints(torque, speed, p_hpcu, p_lv, [w.segment for w in steady.windows], steady.n_excluded, steady)


def _norm(specs: VehicleSpecs, torque: np.ndarray, speed_rpm: np.ndarray, power: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    w = speed_rpm * RPM
    V, r = specs.em_rotor_volume_m3, specs.em_rotor_radius_m
    return torque / (2 * V), power / V * 2 * np.pi / w, r * w


def _check(pts_t: np.ndarray, pts_n: np.ndarray, what: str, min_points: int) -> None:
    if pts_t.size < min_points:
        raise InsufficientDataError(f"{what}: {pts_t.size} steady points; need at least {min_points}")
    check_spread(np.abs(pts_t), 10.0, what, "motor torque", "Nm")
    check_spread(pts_n, 0.1 * float(np.mean(pts_n)), what, "motor speed", "rpm")


def _lv(specs: VehicleSpecs, t: np.ndarray, n: np.ndarray, p_lv_w: np.ndarray | None, what: str
        ) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """DC/DC power (W) and its normalised form; zeros and a reason when not measured."""
    if p_lv_w is None:
        return np.zeros_like(t), np.zeros_like(t), [f"DC/DC power not measured: {what} includes the DC/DC "
                                                    "converter's draw"]
    p = np.asarray(p_lv_w, dtype=float)
    return p, _norm(specs, t, n, p)[1], []


def _check_form(form: str) -> None:
    if form not in ("normalised", "power"):
        raise IdentificationError(f"motor: form must be 'normalised' or 'power', got {form!r}")


def _prepare(specs: VehicleSpecs, torque_nm: np.ndarray, speed_rpm: np.ndarray, p_hpcu_w: np.ndarray,
             p_lv_w: np.ndarray | None, eta_dcdc: float | None, form: str, what: str, min_points: int,
             loss_name: str) -> tuple[Any, ...]:
    """The arrays both Willans fits start from (checked, normalised, with the DC/DC term)."""
    _check_form(form)
    t = np.asarray(torque_nm, dtype=float)
    n = np.asarray(speed_rpm, dtype=float)
    _check(t, n, what, min_points)
    p_hpcu = np.asarray(p_hpcu_w, dtype=float)
    p_me, p_ma_hpcu, c_m = _norm(specs, t, n, p_hpcu)
    p_lv, p_lv_n, reasons = _lv(specs, t, n, p_lv_w, loss_name)
    with_eta = p_lv_w is not None and eta_dcdc is None
    corr = 1.0 / eta_dcdc if eta_dcdc is not None else 0.0
    return (t, n, p_hpcu, p_me, p_ma_hpcu, c_m, specs.em_rotor_volume_m3, specs.em_rotor_radius_m, p_lv, p_lv_n,
            reasons, with_eta, corr, t * n * RPM)


def fit_willans_motoring(specs: VehicleSpecs, torque_nm: np.ndarray, speed_rpm: np.ndarray, p_hpcu_w: np.ndarray,
                         p_lv_w: np.ndarray | None = None, *, eta_dcdc: float | None = None, min_points: int = 5,
                         segments: Iterable[str] = (), n_excluded: int = 0, form: str = "normalised") -> FitResult:
    """Willans line of the motor in motoring (eq. 20-24), with the DC/DC efficiency when ``p_lv_w`` is given.

    Parameters
    ----------
    specs:
        Rotor radius and volume.
    torque_nm, speed_rpm:
        Motor torque (> 0) and speed of the steady points.
    p_hpcu_w:
        HPCU high-voltage power (W) of the points.
    p_lv_w:
        DC/DC low-voltage output power (W); None when not measured (W_loss then includes the DC/DC
        draw: that parameter is flagged with the reason).
    eta_dcdc:
        A known DC/DC efficiency; when given it is not identified.
    form:
        ``"normalised"`` (eq. 20-22: ``p_me`` on ``[p_ma_hpcu, -p_lv, -1/c_m]``, unknowns
        ``C0, C0/eta_dcdc, C1``; R^2 is that of ``p_me`` as in the paper) or ``"power"``
        (``P_hpcu`` on ``[T omega, 1, P_lv]``, unknowns ``1/e, W_loss/e, 1/eta_dcdc``). The model
        is the same; the normalised form weights the points by ``1/omega^2``.

    Returns
    -------
    FitResult
        The raw unknowns and derived ``e``, ``W_loss`` (W), ``eta_dcdc`` and ``eta_peak`` (the
        highest efficiency of the map inside the envelope seen); data ``p_me``, ``p_ma`` (motor
        only), ``c_m``, ``p_me_fit``, the points and the map (:func:`efficiency_map`).
    """
    what = "motor.motoring"
    t, n, p_hpcu, p_me, p_ma_hpcu, c_m, V, r, p_lv, p_lv_n, reasons, with_eta, corr, pm = _prepare(
        specs, torque_nm, speed_rpm, p_hpcu_w, p_lv_w, eta_dcdc, form, what, min_points, "W_loss")
    if form == "normalised":
        cols = [p_ma_hpcu - corr * p_lv_n, -1.0 / c_m] + ([-p_lv_n] if with_eta else [])
        names, units = ["C0", "C1"] + (["C0_over_eta_dcdc"] if with_eta else []), ["-", "Pa m/s", "-"]
        y = p_me

        def e_w_eta(x: np.ndarray) -> tuple[float, float, float]:
            return 4 * np.pi * x[0], 2 * V * x[1] / r, (x[0] / x[2] if with_eta else np.nan)
    else:
        cols = [pm, np.ones_like(pm)] + ([p_lv] if with_eta else [])
        names, units = ["inv_e", "W_loss_over_e"] + (["inv_eta_dcdc"] if with_eta else []), ["-", "W", "-"]
        y = p_hpcu - corr * p_lv

        def e_w_eta(x: np.ndarray) -> tuple[float, float, float]:
            return 1.0 / x[0], x[1] / x[0], (1.0 / x[2] if with_eta else np.nan)

    fit = linear_fit(np.column_stack(cols), y, names, units=units[: len(names)],
                     segments=sorted({s for s in segments if s}), min_points=min_points, n_excluded=n_excluded,
                     what=what)
    derived(fit, "e", lambda x: e_w_eta(x)[0], unit="-")
    derived(fit, "W_loss", lambda x: e_w_eta(x)[1], unit="W")
    if with_eta:
        derived(fit, "eta_dcdc", lambda x: e_w_eta(x)[2], unit="-")
        eta = fit.value("eta_dcdc")
    else:
        eta = eta_dcdc if eta_dcdc is not None else float("inf")
    p_el = p_hpcu - p_lv / eta
    mp = efficiency_map(fit.value("e"), fit.value("W_loss"), t, n)
    fit.data.update(mp)
    valid = np.isfinite(mp["map_eta"])
    P = (mp["map_torque_nm"][:, None] * mp["map_speed_rpm"][None, :] * RPM)[valid]
    derived(fit, "eta_peak", lambda x: float(np.max(e_w_eta(x)[0] * P / (P + e_w_eta(x)[1]))), unit="-")
    for reason in reasons:
        fit.reasons.append(reason)
        fit.params["W_loss"].status, fit.params["W_loss"].reason = "flagged", reason
    p_me_fit = fit.data["y_fit"] if form == "normalised" else \
        (fit.value("e") * p_el - fit.value("W_loss")) / (2 * V * n * RPM)
    fit.data.update(p_me=p_me, p_ma=_norm(specs, t, n, p_el)[1], c_m=c_m, p_me_fit=p_me_fit, torque_nm=t,
                    speed_rpm=n, p_el_w=p_el, eta_measured=pm / p_el)
    e = fit.value("e")
    if not 0.5 < e <= 1.0 or fit.value("W_loss") < 0:
        fit.flag(f"e = {e:.4f}, W_loss = {fit.value('W_loss'):.0f} W are not physical: check signs and channels")
    if with_eta and not 0.5 < eta <= 1.0:
        fit.flag(f"eta_dcdc = {eta:.3f} is not physical: the 12 V load did not vary enough to separate it")
    return fit


def fit_willans_generating(specs: VehicleSpecs, torque_nm: np.ndarray, speed_rpm: np.ndarray, p_hpcu_w: np.ndarray,
                           p_lv_w: np.ndarray | None = None, *, eta_dcdc: float | None = None, min_points: int = 5,
                           segments: Iterable[str] = (), n_excluded: int = 0, form: str = "normalised") -> FitResult:
    """Willans line in generating: ``P_el = e_gen T omega + W_loss_gen``.

    Parameters are as for :func:`fit_willans_motoring` (torque < 0). The normalised form regresses
    ``p_ma_hpcu`` on ``[p_me, 1/c_m, p_lv]`` (unknowns ``G0 = 4 pi e_gen``,
    ``G1 = 2 pi r W_loss_gen / V``, ``G2 = 1/eta_dcdc``); the power form ``P_hpcu`` on
    ``[T omega, 1, P_lv]`` (unknowns ``k_tw = e_gen``, ``k_1 = W_loss_gen``, ``k_lv = 1/eta_dcdc``).
    Derived: ``e_gen``, ``W_loss_gen`` (W), ``eta_dcdc``.
    """
    what = "motor.generating"
    t, n, p_hpcu, p_me, p_ma_hpcu, c_m, V, r, p_lv, p_lv_n, reasons, with_eta, corr, pm = _prepare(
        specs, torque_nm, speed_rpm, p_hpcu_w, p_lv_w, eta_dcdc, form, what, min_points, "W_loss_gen")
    if form == "normalised":
        cols = [p_me, 1.0 / c_m] + ([p_lv_n] if with_eta else [])
        y = p_ma_hpcu - corr * p_lv_n
        names, units = ["G0", "G1", "G2"][: len(cols)], ["-", "Pa m/s", "-"][: len(cols)]
        scale = (1.0 / (4 * np.pi), V / (2 * np.pi * r))
    else:
        cols = [pm, np.ones_like(pm)] + ([p_lv] if with_eta else [])
        y = p_hpcu - corr * p_lv
        names, units = ["k_tw", "k_1", "k_lv"][: len(cols)], ["-", "W", "-"][: len(cols)]
        scale = (1.0, 1.0)
    fit = linear_fit(np.column_stack(cols), y, names, units=units, segments=sorted({s for s in segments if s}),
                     min_points=min_points, n_excluded=n_excluded, what=what)
    derived(fit, "e_gen", lambda x: x[0] * scale[0], unit="-")
    derived(fit, "W_loss_gen", lambda x: x[1] * scale[1], unit="W")
    if with_eta:
        derived(fit, "eta_dcdc", lambda x: 1.0 / x[2], unit="-")
        eta = fit.value("eta_dcdc")
    else:
        eta = eta_dcdc if eta_dcdc is not None else float("inf")
    for reason in reasons:
        fit.reasons.append(reason)
        fit.params["W_loss_gen"].status, fit.params["W_loss_gen"].reason = "flagged", reason
    p_el = p_hpcu - p_lv / eta
    p_el_fit = fit.value("e_gen") * pm + fit.value("W_loss_gen")
    fit.data.update(p_me=p_me, p_ma=_norm(specs, t, n, p_el)[1], c_m=c_m, p_ma_fit=_norm(specs, t, n, p_el_fit)[1],
                    torque_nm=t, speed_rpm=n, p_el_w=p_el, eta_measured=p_el / pm)
    if not 0.5 < fit.value("e_gen") <= 1.0:
        fit.flag(f"e_gen = {fit.value('e_gen'):.4f} is not physical: check signs and channels")
    return fit


def efficiency_map(e: float, w_loss: float, torque_nm: np.ndarray, speed_rpm: np.ndarray, *,
                   n_speed: int = 40, n_torque: int = 40, n_bins: int = 12) -> dict[str, np.ndarray]:
    """Motoring efficiency ``e T w / (T w + W_loss)`` on a torque x speed grid inside the envelope seen.

    The envelope is the largest torque seen per speed bin (linearly interpolated between bins);
    nodes above it are NaN.

    Returns
    -------
    dict
        ``map_speed_rpm`` (n_speed,), ``map_torque_nm`` (n_torque,), ``map_eta`` (n_torque, n_speed),
        ``envelope_speed_rpm``, ``envelope_torque_nm``.
    """
    t = np.asarray(torque_nm, dtype=float)
    n = np.asarray(speed_rpm, dtype=float)
    edges = np.linspace(n.min(), n.max(), n_bins + 1)
    env_n, env_t = [], []
    for a, b in itertools.pairwise(edges):
        m = (n >= a) & (n <= b)
        if m.any():
            env_n.append(float(n[m].mean()))
            env_t.append(float(t[m].max()))
    sg = np.linspace(max(n.min(), 1.0), n.max(), n_speed)
    tg = np.linspace(0.0, t.max(), n_torque + 1)[1:]
    env = np.interp(sg, env_n, env_t)
    N, T = np.meshgrid(sg, tg)
    P = T * N * RPM
    eta = e * P / (P + w_loss)
    eta[env[None, :] * (1 + 1e-9) < T] = np.nan
    return {"map_speed_rpm": sg, "map_torque_nm": tg, "map_eta": eta, "envelope_speed_rpm": np.asarray(env_n),
            "envelope_torque_nm": np.asarray(env_t)}


def fit_dcdc_within(rec: Recording, *, steady: SteadyWindows | None = None, max_torque_nm: float = 1.0,
                    speed_std_rpm: float = 1.0, speed_std_frac: float = 0.002, rate_hz: float = 10.0,
                    min_points: int = 50) -> FitResult:
    """DC/DC efficiency from the 12 V load's own variation inside steady zero-torque motor windows.

    Inside a window where the motor's torque is zero and its speed steady, the motor's DC power is a constant
    (whatever the form of its loss: standby, friction, iron), so each change of the HV input power is the
    DC/DC's draw change ``dP_lv / eta_dcdc``. The fit regresses the HV power on the 12 V power, both less
    their window mean (one intercept per window), over every grid sample of those windows: ``1 / eta_dcdc``
    is the single unknown, observed independently of the motor's Willans line. The standard error allows
    for the serial correlation of the grid samples.

    Parameters
    ----------
    rec:
        Recording with ``em_speed_rpm``, ``em_torque_nm``, the DC input (:func:`dc_input_roles`) and
        ``dcdc_lv_current_a``, ``dcdc_lv_voltage_v``.
    steady:
        Steady windows over those channels (else found here over the whole Recording).
    max_torque_nm:
        Windows whose mean ``|T|`` exceeds this are left out.
    speed_std_rpm, speed_std_frac:
        Windows whose motor speed varies (standard deviation over the window) by more than
        ``speed_std_rpm + speed_std_frac |n|`` are left out: the steady search's speed tolerance lets a
        slow drift through (a launch, a creep near standstill), and the spin loss and standby draw change
        with it (measured on the high-fidelity paper campaign: such windows alone give eta_dcdc 0.5-0.8).
    rate_hz:
        Grid rate of the search.
    min_points:
        Fewest grid samples.

    Returns
    -------
    FitResult
        ``inv_eta_dcdc`` and derived ``eta_dcdc``; data ``dp_lv_w``, ``dp_hv_w`` (the demeaned samples).

    Raises
    ------
    InsufficientDataError
        Too few zero-torque samples.
    NoExcitationError
        The 12 V load did not vary inside them.
    """
    what = "motor.dcdc"
    dc = dc_input_roles(rec)
    if steady is None:
        steady = find_steady_windows(rec, ["em_speed_rpm", "em_torque_nm"],
                                     states=("gear_actual", "k0_closed", "lockup_closed", "hybrid_mode"),
                                     extra=(*dc, *_LV), kinds=None, rate_hz=rate_hz)
    g = steady.grid
    p_hv = g[dc[0]] * g[dc[1]]
    p_lv = g[_LV[0]] * g[_LV[1]]
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    segs: list[str] = []
    for w in steady.windows:
        if not abs(w.means.get("em_torque_nm", np.nan)) <= max_torque_nm:
            continue
        n_mean, n_std = abs(w.means.get("em_speed_rpm", np.nan)), w.stds.get("em_speed_rpm", np.nan)
        if not n_std <= speed_std_rpm + speed_std_frac * n_mean:
            continue
        y, x = p_hv[w.i0:w.i1], p_lv[w.i0:w.i1]
        ok = np.isfinite(y) & np.isfinite(x) & ~g.bad[w.i0:w.i1]
        if ok.sum() < 2:
            continue
        xs.append(x[ok] - x[ok].mean())
        ys.append(y[ok] - y[ok].mean())
        segs.append(w.segment)
    if not xs or sum(x.size for x in xs) < min_points:
        raise InsufficientDataError(f"{what}: {sum(x.size for x in xs)} samples in steady zero-torque windows; "
                                    f"need at least {min_points}")
    x, y = np.concatenate(xs), np.concatenate(ys)
    check_spread(x, 10.0, what, "12 V load (within windows)", "W")
    fit = linear_fit(x[:, None], y, ["inv_eta_dcdc"], units=["-"], segments=sorted({s for s in segs if s}),
                     min_points=min_points, n_excluded=steady.n_excluded, what=what, serial=True)
    derived(fit, "eta_dcdc", lambda v: 1.0 / v[0], unit="-")
    fit.data.update(dp_lv_w=x, dp_hv_w=y)
    lo, hi = ETA_DCDC_PLAUSIBLE
    if not lo <= fit.value("eta_dcdc") <= hi:
        fit.flag(f"eta_dcdc = {fit.value('eta_dcdc'):.3f} from the zero-torque windows is not physical")
    return fit


def _joint_eta_usable(fit: FitResult) -> tuple[bool, str]:
    """Whether a Willans fit's joint eta_dcdc is plausible and well determined (and why not)."""
    if "eta_dcdc" not in fit.params:
        return True, ""
    p = fit["eta_dcdc"]
    lo, hi = ETA_DCDC_PLAUSIBLE
    if not lo <= p.value <= hi:
        return False, f"outside {lo}..{hi}"
    if not p.std_error <= ETA_DCDC_MAX_SE:
        return False, f"standard error {p.std_error:.3f} > {ETA_DCDC_MAX_SE}"
    return True, ""


def side_points(pts: MotorPoints, min_torque_nm: float = 5.0
                ) -> list[tuple[str, np.ndarray, Callable[..., FitResult]]]:
    """``(side, mask of the points, Willans fit)`` for motoring and generating, as :func:`identify_motor` uses them.

    Finite points turning faster than 50 rpm with ``|T| > min_torque_nm`` (shared with the planner).
    """
    ok = np.isfinite(pts.torque_nm) & np.isfinite(pts.speed_rpm) & np.isfinite(pts.p_hpcu_w) & (pts.speed_rpm > 50)
    if pts.p_lv_w is not None:
        ok &= np.isfinite(pts.p_lv_w)
    return [("motoring", ok & (pts.torque_nm > min_torque_nm), fit_willans_motoring),
            ("generating", ok & (pts.torque_nm < -min_torque_nm), fit_willans_generating)]


def identify_motor(rec: Recording, specs: VehicleSpecs, *, points: MotorPoints | None = None,
                   eta_dcdc: float | None = None, min_torque_nm: float = 5.0, min_points: int = 5,
                   form: str = "normalised", **kwargs: object) -> IdentificationResult:
    """Willans lines of the motor (motoring and generating) and the efficiency map, from a Recording.

    Parameters
    ----------
    rec:
        The Recording: ``em_torque_nm``, ``em_speed_rpm``, ``hpcu_current_a``, ``hpcu_voltage_v`` (else
        ``battery_current_a``, ``battery_voltage_v``: the pack's power taken as the DC input, which then also
        holds the auxiliaries' draw) and (for eta_dcdc) ``dcdc_lv_current_a``, ``dcdc_lv_voltage_v``.
    specs:
        Rotor radius and volume.
    points:
        Steady points (else found here; ``kwargs`` go to :func:`motor_points`).
    eta_dcdc:
        A known DC/DC efficiency (else identified).
    min_torque_nm:
        Points with ``|T|`` below this are left out (neither motoring nor generating).
    form:
        ``"normalised"`` (the paper's eq. 20-22) or ``"power"`` (see :func:`fit_willans_motoring`).

    Returns
    -------
    IdentificationResult
        ``motor.motoring`` (e, W_loss, eta_dcdc, eta_peak, the map in ``data``),
        ``motor.generating`` (e_gen, W_loss_gen, eta_dcdc) and ``motor.loss`` (the loss model of
        :mod:`benchtwin.identification.motor_loss` over both sides' points); a fit that cannot be made is
        in ``errors``.

    Raises
    ------
    InsufficientDataError
        When neither side can be fitted.
    """
    pts = points if points is not None else motor_points(rec, **kwargs)  # type: ignore[arg-type]
    out = IdentificationResult()
    failures: dict[str, IdentificationError] = {}
    segs = np.asarray(pts.segments, dtype=object)
    for side, sel, func in side_points(pts, min_torque_nm):
        key = f"motor.{side}"
        try:
            fit = func(specs, pts.torque_nm[sel], pts.speed_rpm[sel], pts.p_hpcu_w[sel],
                       None if pts.p_lv_w is None else pts.p_lv_w[sel], eta_dcdc=eta_dcdc, min_points=min_points,
                       segments=list(segs[sel]), n_excluded=pts.n_flagged, form=form)
        except IdentificationError as exc:
            out.errors[key] = f"{type(exc).__name__}: {exc}"
            failures[key] = exc
            continue
        if dc_input_roles(rec) == _PACK and points is None:
            fit.reasons.append("HPCU current and voltage not recorded: the pack's power is taken as the motor's DC "
                               "input (auxiliaries other than the DC/DC are counted as motor losses)")
        out.fits[key] = fit
    if not out.fits:
        raise_all_failed("motor (motoring and generating)", failures)
    if eta_dcdc is None and pts.p_lv_w is not None:
        _refit_with_independent_eta(rec, specs, pts, out, segs, min_torque_nm, min_points, form)
    add_loss_fit(out, pts.torque_nm, pts.speed_rpm, pts.p_hpcu_w, pts.p_lv_w, eta_dcdc, list(segs), pts.n_flagged)
    return out


def _refit_with_independent_eta(rec: Recording, specs: VehicleSpecs, pts: MotorPoints, out: IdentificationResult,
                                segs: np.ndarray, min_torque_nm: float, min_points: int, form: str) -> None:
    """Refit the sides whose joint eta_dcdc is implausible or ill-determined with eta_dcdc fixed to
    :func:`fit_dcdc_within`'s (added as ``motor.dcdc``).

    The rule: a joint estimate outside :data:`ETA_DCDC_PLAUSIBLE` or with a standard error above
    :data:`ETA_DCDC_MAX_SE` is replaced when the zero-torque estimate is itself unflagged. The loss's curvature
    that is not affine in ``T omega`` leaks into the nearly collinear 12 V column of the joint regression
    (docs/fidelity.md); the zero-torque windows see the DC/DC alone.
    """
    unusable = {k: why for k, f in out.fits.items() if (why := _joint_eta_usable(f)[1])}
    if not unusable:
        return
    try:
        dcdc = fit_dcdc_within(rec)
        out.fits["motor.dcdc"] = dcdc
        problem = "; ".join(dcdc.reasons) if dcdc.status != "ok" else ""
    except IdentificationError as exc:
        problem = str(exc)
    if problem:
        for key, why in unusable.items():
            reason = f"joint eta_dcdc {why}; no independent estimate: {problem}"
            out.fits[key].reasons.append(reason)
            out.fits[key]["eta_dcdc"].status, out.fits[key]["eta_dcdc"].reason = "flagged", reason
        return
    eta = dcdc["eta_dcdc"]
    for side, sel, func in side_points(pts, min_torque_nm):
        key = f"motor.{side}"
        if key not in unusable:
            continue
        fit = func(specs, pts.torque_nm[sel], pts.speed_rpm[sel], pts.p_hpcu_w[sel], pts.p_lv_w[sel],
                   eta_dcdc=eta.value, min_points=min_points, segments=list(segs[sel]), n_excluded=pts.n_flagged,
                   form=form)
        reason = (f"joint eta_dcdc = {out.fits[key].value('eta_dcdc'):.3f} rejected ({unusable[key]}): refitted with "
                  f"eta_dcdc = {eta.value:.3f} +/- {eta.std_error:.3f} from the zero-torque windows (motor.dcdc)")
        fit.reasons.append(reason)
        fit.add(ParameterEstimate("eta_dcdc", eta.value, eta.std_error, eta.ci95, dcdc.r2, eta.n_points, unit="-",
                                  segments=list(dcdc.segments), reason=reason))
        fit.reasons.extend(r for r in out.fits[key].reasons if r.startswith("HPCU current"))
        out.fits[key] = fit
