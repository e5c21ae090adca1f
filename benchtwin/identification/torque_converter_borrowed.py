"""A gear on a borrowed transmission model: its turbine-torque offset from its own coupling points.

The second half of the points' calibration of
:func:`~benchtwin.identification.torque_converter.identify_torque_converter`: a gear without a transmission model of
its own (:func:`~benchtwin.identification.torque_converter_points.converter_points` lends it the nearest gear's)
has its eq. 32 turbine torque offset to meet the pump torque on its coupling points
(:func:`borrowed_gear_offsets`, split at the gear's own coupling point, :func:`coupling_kink`), when the gear's
passes through the coupling mode refute the borrowed C0 (:func:`offset_significance`). When most of the points are
read through a gear left uncalibrated, the curves that read the turbine torque are not identified
(:func:`uncalibrated_share_reason`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from scipy import stats

from benchtwin.identification.torque_converter_points import ConverterPoints

__all__ = ["COUPLED_TR_TOL", "KINK_MIN_TOP", "KINK_WINDOW", "MAX_UNCALIBRATED_SHARE", "OFFSET_CONFIDENCE", "PASS_GAP_S",
           "TURBINE_UNIDENTIFIED", "UNCALIBRATED_SHARE_KEY", "UncalibratedShare", "borrowed_gear_offsets",
           "coupling_kink", "offset_significance", "uncalibrated_share", "uncalibrated_share_reason"]

#: a torque ratio this close to 1 counts as the coupling mode seen (:func:`borrowed_gear_offsets`): a few times the
#: torque ratio's scatter from the telemetry step (about 0.5 Nm at 20-80 Nm), well below a converter's TR - 1 short of
#: its coupling point (the TR curve falls by about 1 per unit SR there)
COUPLED_TR_TOL = 0.03
#: a borrowed gear's offset is applied only beyond this two-sided confidence of zero (the 3-sigma level of the
#: Student t of its passes, :func:`offset_significance`): the borrowed model's C0 is kept unless the gear's own
#: coupling points refute it
OFFSET_CONFIDENCE = 0.9973
#: the SR span below a gear's own coupling point whose converter-mode points calibrate its offset with it
#: (:func:`coupling_kink`): TR - 1 is about linear in Gamma - SR there (2.29 per unit SR 0.01 below Gamma and 2.13
#: on average over 0.06 below it, a drawn 9-speed's converter, Gamma 0.906), so the stick's slope holds within 7 %
KINK_WINDOW = 0.05
#: least points at or above a candidate kink (the coupling mode's plateau the offset is read from)
KINK_MIN_TOP = 3
#: coupling points further apart than this (s) are separate passes: 2.5 times the 0.4 s pump-acceleration window,
#: so no two passes share a sample of dw_p/dt, while the points of one pass share its operating point and errors
PASS_GAP_S = 1.0
#: the most of the converter's points that may be read through a borrowed gear model left uncalibrated: one half.
#: Their turbine torque may be off by the two gears' C0 difference (several Nm against 20-60 Nm), an error common to
#: all of them, not scatter. While the points through calibrated models are the majority, the robust fits (their
#: median-scaled outlier cut) and the coupling point (where the points' TR reaches 1) follow those; beyond half,
#: the breakdown point of a median, they follow the borrowed gear's, and nothing in the data says by how much
MAX_UNCALIBRATED_SHARE = 0.5
#: the words of the reason :func:`uncalibrated_share_reason` gives, by which the checks know the fit said so
TURBINE_UNIDENTIFIED = "the turbine torque's curves (TR, Gamma, coupling) not identified"
#: the converter fit's ``data`` key holding the :class:`UncalibratedShare` when its curves are not identified
UNCALIBRATED_SHARE_KEY = "uncalibrated_share"


def coupling_kink(sr: np.ndarray, d: np.ndarray, t_p: np.ndarray, *, window: float = KINK_WINDOW,
                  min_top: int = KINK_MIN_TOP) -> tuple[float, float]:
    """Where a gear's turbine-minus-pump torque turns flat: a broken stick ``d = c + s T_p max(G - SR, 0)``.

    Below the coupling point the turbine torque exceeds the pump torque by ``(TR - 1) T_p``, ``TR - 1`` falling
    about linearly to 0 at Gamma; above it the difference of eq. 32's turbine torque and the pump torque is the
    gear's offset ``c`` alone. Over each candidate ``G`` (the points' SRs with ``min_top`` points or more at or above
    it) the stick is fitted by least squares on the points within ``window`` below ``G`` and above; the kink is kept
    against the flat line (``s = 0`` over all those points) only when it lowers the Bayesian information criterion
    (two more parameters, ``G`` and ``s``). The kink is read from the gear's own points, not from the converter fit's
    Gamma: a Gamma fitted low (an offset taken too high lowers the torque ratios near it) would otherwise count
    converter-mode points as coupling points, which raises the offset and lowers Gamma further.

    Returns
    -------
    G, s
        The kink (the lowest SR when the flat line wins, NaN with too few points) and the slope (0: flat).
    """
    sr, d, t_p = (np.asarray(x, dtype=float) for x in (sr, d, t_p))
    if sr.size < min_top:
        return float("nan"), 0.0
    best = (np.inf, float(sr.min()), 0.0)
    for g in np.unique(np.round(sr, 3)):
        if int((sr >= g).sum()) < min_top:
            break
        m = sr >= g - window
        n = int(m.sum())
        x = t_p[m] * np.clip(g - sr[m], 0.0, None)
        r0 = d[m] - d[m].mean()
        sse0 = float(r0 @ r0)
        a = np.column_stack([np.ones(n), x])
        coef, *_ = np.linalg.lstsq(a, d[m], rcond=None)
        sse1 = float(np.sum((d[m] - a @ coef) ** 2))
        if not (coef[1] > 0 and n > 3) or (sse1 <= 0.0 and sse0 <= 0.0):
            continue
        # BIC of the kinked line against the flat one over the same points: n log(SSE / n) + k log(n)
        gain = n * (np.log(max(sse0, 1e-300) / n) - np.log(max(sse1, 1e-300) / n)) - 2.0 * np.log(n)
        if gain > 0 and sse1 / n < best[0]:
            best = (sse1 / n, float(g), float(coef[1]))
    return best[1], best[2]


def borrowed_gear_offsets(pts: ConverterPoints, gamma: float, j_pump: float, max_pump_accel_rads2: float,
                          min_points: int) -> tuple[dict[int, tuple[float, float, int]], dict[int, str]]:
    """Per gear on a borrowed transmission model, the offset of its eq. 32 turbine torque on its coupling points.

    A gear without a transmission model of its own (gear 1 never runs with the lock-up closed on most cars, so
    the steady lock-up-closed points of eq. 13-17 and the turbine-torque calibration have none) takes the
    nearest gear's ``eta_m`` and ``C0``, and its turbine torque is off by the difference of the two gears'
    drag, ``C0`` mostly (several Nm, against turbine torques of 20-60 Nm in a take-off). In coupling mode the
    turbine torque is the pump torque (eq. 36), i.e. the motor torque less the pump-side inertia torque: the
    difference ``T_t(eq. 32) - (T_motor - J dw_p/dt)`` over the gear's own coupling points (the pump nearly
    steady), taken with the pump steady (:func:`offset_significance`: its median, or
    the line through its passes at ``dw_p/dt = 0``), is that gear's offset. Only when the gears with a model of
    their own show the coupling mode (``COUPLED_TR_TOL``): else every borrowed gear is left as it is, with the
    reason. And only
    when the offset is significant (:func:`offset_significance`: beyond the ``OFFSET_CONFIDENCE`` Student-t bound
    of zero over the gear's passes through the coupling mode): else the borrowed C0 is consistent with the gear's
    own points and is kept, with the reason.

    Parameters
    ----------
    pts:
        The converter points (:func:`converter_points`), with ``borrowed``.
    gamma:
        The coupling point of the current converter fit (the split of a gear without a kink of its own).
    j_pump:
        The pump-side inertia of that fit (kg m^2; 0 without).
    max_pump_accel_rads2:
        Points with a larger ``|dw_p/dt|`` are left out (a tenth of the quasi-steady limit: the inertia torque
        stays about 1 % of the pump torque).
    min_points:
        Least coupling points of a gear.
    Returns
    -------
    offsets, reasons
        Gear -> (offset in Nm, its standard error over the passes, points used) for the gears with enough
        coupling points and a significant offset; gear -> the reason for the others (turbine torque left as it is).
    """
    out: dict[int, tuple[float, float, int]] = {}
    reasons: dict[int, str] = {}
    if not np.isfinite(gamma):
        gamma = 1.0
    with np.errstate(invalid="ignore", divide="ignore"):
        sr = pts.w_t / pts.w_p
    calm = np.abs(pts.dw_p) <= max_pump_accel_rads2
    # the anchor: the coupling mode seen in the gears with a model of their own (TR within ``COUPLED_TR_TOL`` of 1
    # on ``min_points`` points or more, the pump's inertia torque within that share of its torque). Without it, the
    # top of a borrowed gear's SR range may still be converter mode, where the turbine torque exceeds the pump
    # torque by (TR - 1) T_p: an "offset" taken there would pull the coupling point down with it
    own = ~np.isin(pts.gear, list(pts.borrowed))
    with np.errstate(invalid="ignore", divide="ignore"):
        tr = pts.t_t / (pts.t_p - j_pump * pts.dw_p)
    # and where the pump's inertia torque (J of a fit it is correlated with) is within that share of its torque
    coupled = own & (np.abs(tr - 1.0) <= COUPLED_TR_TOL) & (np.abs(j_pump * pts.dw_p) <= COUPLED_TR_TOL * pts.t_p)
    if int(coupled.sum()) < min_points:
        for k, near in sorted(pts.borrowed.items()):
            reasons[k] = (f"gear {k} on gear {near}'s transmission model: left uncalibrated, no coupling mode seen in "
                          f"the gears with a model of their own ({int(coupled.sum())} points with TR within "
                          f"{COUPLED_TR_TOL:g} of 1) to anchor it (too little excitation: its turbine torque may be "
                          "off by the two gears' C0 difference)")
        return out, reasons
    for k, near in sorted(pts.borrowed.items()):
        own = (pts.gear == k) & calm & np.isfinite(pts.t_t)
        d_all = pts.t_t - (pts.t_p - j_pump * pts.dw_p)
        g, slope = coupling_kink(sr[own], d_all[own], pts.t_p[own]) if own.any() else (float("nan"), 0.0)
        if slope > 0.0:  # the gear's own kink: its coupling points and, with the stick's slope, the window below it
            m = own & (sr >= g - KINK_WINDOW)
        else:  # no kink in the gear's points: its coupling points are those above the converter fit's Gamma
            g, m = gamma, own & (sr >= gamma)
        n = int(m.sum())
        if n < min_points:
            reasons[k] = (f"gear {k} on gear {near}'s transmission model: {n} coupling-mode points (SR >= "
                           f"{g:.3f}), need {min_points} to calibrate its turbine torque against the pump "
                           "torque: left uncalibrated (too little excitation, its turbine torque may be off by the "
                           "two gears' C0 difference)")
            continue
        # the converter-mode points of the window brought to the coupling mode by the stick's (TR - 1) T_p
        d = d_all[m] - slope * pts.t_p[m] * np.clip(g - sr[m], 0.0, None)
        off, se, n_pass, bound = offset_significance(pts.t[m], d, dw=pts.dw_p[m])
        if not abs(off) > bound:
            passes = f"{n_pass} pass" + ("es" if n_pass != 1 else "")
            reasons[k] = (f"gear {k} on gear {near}'s transmission model: left uncalibrated, its turbine torque on its "
                          f"{n} coupling-mode points ({passes}) is {off:+.2f} +- {se:.2f} Nm off the pump torque, "
                          f"within the {100 * OFFSET_CONFIDENCE:g} % bound {bound:.2f} Nm of zero (the borrowed C0 "
                          "not refuted)")
            continue
        out[k] = (off, se, n)
    return out, reasons


def offset_significance(t: np.ndarray, d: np.ndarray, *, dw: np.ndarray | None = None, gap_s: float = PASS_GAP_S,
                        confidence: float = OFFSET_CONFIDENCE) -> tuple[float, float, int, float]:
    """A borrowed gear's turbine-torque offset, its standard error over its passes, and the bound it must exceed.

    The points of one pass through the coupling mode (``t`` closer than ``gap_s``) share their operating point,
    the sensors' slow errors and the dw_p/dt window, so they are not independent samples: each pass counts
    once, by its median. Without ``dw`` (or without passes on both sides of a steady pump), the offset is the
    median of ``d``, its standard error that of a median over the passes, ``1.2533 s / sqrt(n_pass)`` with ``s``
    the spread of the passes' medians, and ``n_pass - 1`` degrees of freedom.

    With ``dw`` and at least three passes, some with the pump speeding up and some slowing down (the passes'
    median ``dw`` on both sides of 0), the offset is the intercept at ``dw = 0`` of the straight line through the
    passes' medians (``d`` against ``dw``, least squares), its standard error the intercept's (``n_pass - 2``
    degrees of freedom). In coupling mode ``d`` does not depend on the pump's acceleration when the pump-side
    inertia torque is taken out exactly; the ``J_pump`` of the converter fit is correlated with ``a0..a2`` and
    the motor torque lags the speed on the bus, so a pass that speeds the pump up and one that slows it down
    read ``d`` high and low by the part left in, and a median over a few passes lands on the side that has more
    of them. The intercept is the offset with the pump steady, whichever passes the campaign has.

    The offset differs from zero when ``|offset|`` exceeds Student's t at ``confidence`` (two-sided) times its
    standard error. A single pass gives no spread: the bound is infinite, the offset never significant.

    Parameters
    ----------
    t, d:
        Times (s) and ``T_t(eq. 32) - (T_p - J dw_p/dt)`` (Nm) of the gear's coupling points.
    dw:
        The pump acceleration ``dw_p/dt`` (rad/s^2) at those points; None: the median of ``d``.
    gap_s:
        Least time between two passes.
    confidence:
        Two-sided confidence of the bound (0.9973: 3 sigma).

    Returns
    -------
    offset, se, n_pass, bound
        The offset (Nm), its standard error over the passes (NaN for one pass), the number of passes and the
        bound on ``|offset|`` (Nm; inf for one pass).
    """
    order = np.argsort(t)
    t, d = np.asarray(t, dtype=float)[order], np.asarray(d, dtype=float)[order]
    cuts = np.flatnonzero(np.diff(t) > gap_s) + 1
    meds = np.array([np.median(p) for p in np.split(d, cuts)])
    off, n_pass = float(np.median(d)), int(meds.size)
    if n_pass < 2:
        return off, float("nan"), n_pass, float("inf")
    if dw is not None and n_pass >= 3:
        x = np.array([np.median(p) for p in np.split(np.asarray(dw, dtype=float)[order], cuts)])
        if x.min() < 0.0 < x.max():
            a = np.column_stack([np.ones(n_pass), x])
            coef, *_ = np.linalg.lstsq(a, meds, rcond=None)
            dof = n_pass - 2  # at least 1
            s2 = float(np.sum((meds - a @ coef) ** 2)) / dof
            se = float(np.sqrt(s2 * np.linalg.inv(a.T @ a)[0, 0]))
            return float(coef[0]), se, n_pass, float(stats.t.ppf(0.5 + confidence / 2.0, dof)) * se
    se = 1.2533 * float(np.std(meds, ddof=1)) / np.sqrt(n_pass)
    return off, se, n_pass, float(stats.t.ppf(0.5 + confidence / 2.0, n_pass - 1)) * se


@dataclass(frozen=True)
class UncalibratedShare:
    """The converter's turbine-torque curves not identified: most points through borrowed gear models left
    uncalibrated (:func:`uncalibrated_share`), as a structure a caller can judge, not only words.

    Attributes
    ----------
    n_points:
        The converter's usable points.
    points_by_gear:
        Uncalibrated borrowed gear -> its usable points.
    borrowed:
        Uncalibrated borrowed gear -> the gear whose transmission model it used.
    max_share:
        The largest share of such points that still identifies the curves.
    clipped:
        Gear -> why its own transmission model is missing when the telemetry's clipping is the cause
        (:class:`~benchtwin.identification.transmission_clip.ClipCause`; filled by the orchestrator's converter
        method, which holds the transmission result and the Recording). Empty: no clipping traced.
    """

    #: its key in the converter fit's ``data``
    KEY: ClassVar[str] = UNCALIBRATED_SHARE_KEY

    n_points: int
    points_by_gear: dict[int, int]
    borrowed: dict[int, int]
    max_share: float = MAX_UNCALIBRATED_SHARE
    clipped: dict[int, Any] = field(default_factory=dict)

    @property
    def n_uncalibrated(self) -> int:
        """Points through the uncalibrated borrowed models."""
        return sum(self.points_by_gear.values())

    @property
    def need(self) -> int:
        """Points through a model of their own the curves need (strictly more than ``1 - max_share`` of them)."""
        return int(np.floor((1.0 - self.max_share) * self.n_points)) + 1

    def clip_explains(self) -> bool:
        """Whether the clipping explains the verdict: some uncalibrated gear lost its model to clipped points, and
        without those gears' points the share left through uncalibrated models would be within ``max_share``."""
        left = self.n_uncalibrated - sum(self.points_by_gear.get(k, 0) for k in self.clipped)
        return bool(self.clipped) and not left > self.max_share * self.n_points

    def reason(self) -> str:
        """The verdict in words: the gears, the share, the count of well-modelled points against the need (and,
        when traced, the clipping that cost the gears their models)."""
        n, n_unc = self.n_points, self.n_uncalibrated
        gears = ", ".join(f"gear {k} on gear {self.borrowed[k]}'s" for k in sorted(self.points_by_gear))
        why = "; ".join(c.reason() for _k, c in sorted(self.clipped.items()))
        return (f"{n - n_unc} well-modelled points (of {n}: {n_unc}, {100.0 * n_unc / n:.0f} %, through {gears} "
                f"transmission model left uncalibrated, more than {100.0 * self.max_share:g} % allowed; need "
                f"{self.need}): {TURBINE_UNIDENTIFIED}, too little excitation of the gears with a model of their own"
                + (f"; {why}" if why else ""))


def uncalibrated_share(gear: np.ndarray, ok: np.ndarray, borrowed: dict[int, int], calibrated: set[int],
                       max_share: float = MAX_UNCALIBRATED_SHARE) -> UncalibratedShare | None:
    """Why the converter's turbine-torque curves are not identified, or None when they are.

    A gear on a borrowed transmission model whose turbine torque was not calibrated against the pump torque
    (:func:`borrowed_gear_offsets` found too few coupling points, no anchor, or no significant offset) may carry
    the two gears' C0 difference in every one of its points. When those points are more than ``max_share`` of the
    converter's points (``MAX_UNCALIBRATED_SHARE``: beyond half the fits follow them), the torque ratio curve, the
    coupling point and the coupling fit read that error (:class:`UncalibratedShare`: the gears, their points and,
    in words, the count of points through a model of their own against the count it needs).

    Parameters
    ----------
    gear, ok:
        Each point's gear and whether it is a usable point (finite speeds and torques).
    borrowed:
        Gear -> the gear whose model it borrowed.
    calibrated:
        The borrowed gears whose turbine torque was calibrated (an offset applied).
    max_share:
        The largest share of points through uncalibrated borrowed models that still identifies the curves.
    """
    gear, ok = np.asarray(gear), np.asarray(ok, dtype=bool)
    n = int(ok.sum())
    uncal = sorted(k for k in borrowed if k not in calibrated)
    if n == 0 or not uncal:
        return None
    by_gear = {k: int((ok & (gear == k)).sum()) for k in uncal}
    if not sum(by_gear.values()) > max_share * n:
        return None
    return UncalibratedShare(n, by_gear, {k: borrowed[k] for k in uncal}, max_share)


def uncalibrated_share_reason(gear: np.ndarray, ok: np.ndarray, borrowed: dict[int, int], calibrated: set[int],
                              max_share: float = MAX_UNCALIBRATED_SHARE) -> str:
    """:func:`uncalibrated_share` in words ('' when the curves are identified)."""
    share = uncalibrated_share(gear, ok, borrowed, calibrated, max_share)
    return "" if share is None else share.reason()
