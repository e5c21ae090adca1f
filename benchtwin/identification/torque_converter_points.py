"""The points the torque converter is fitted on: selection and regressors from a Recording.

:func:`converter_points` is the first half of
:func:`~benchtwin.identification.torque_converter.identify_torque_converter` (resampling, lock-up, shift
hold, quasi-steady and settled pump speed, turbine speed by eq. 31 and turbine torque through the
transmission model (eq. 32), each with its calibration where the lock-up is closed); the planner
(:mod:`benchtwin.studies.plan_converter`) runs the same function on the noise-free Recording of a campaign. A gear
on a borrowed transmission model is calibrated on its own coupling points in
:mod:`benchtwin.identification.torque_converter_borrowed`.

The 10 Hz grid is read a block of :data:`POINTS_BLOCK` points at a time (:class:`~benchtwin.identification.
_resample_blocks.StrictGrid`, with margins for the shift hold and the derivative window; the settle rule's state
carried from block to block): only the candidate points and the calibration ratios are gathered, so the memory does
not grow with the campaign, and the points are those of the whole grid bit for bit.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import MissingChannelError
from benchtwin.identification._fit import FitResult
from benchtwin.identification._resample_blocks import GRID_BLOCK, StrictGrid
from benchtwin.identification._signals import source_shifts
from benchtwin.identification.transmission_drag import drag_c0
from benchtwin.recording import Recording
from benchtwin.segments import touched

__all__ = ["RPM_PER_RADS", "ConverterPoints", "TorqueCalibration", "converter_points", "turbine_torque_scale",
           "unsettled"]

#: rpm per rad/s
RPM_PER_RADS = 60.0 / (2.0 * np.pi)

#: grid points of one block of :func:`converter_points` (its margins aside)
POINTS_BLOCK = GRID_BLOCK


def _central_derivative(x: np.ndarray, t: np.ndarray, window_s: float, h: int | None = None) -> np.ndarray:
    """Central difference ``(x[k+h] - x[k-h]) / (t[k+h] - t[k-h])`` over about ``window_s`` (``h`` given: that
    half window, for a block of a longer record whose own it is)."""
    if x.size < 3:
        return np.zeros_like(x)
    if h is None:
        dt = float(np.median(np.diff(t)))
        h = max(1, round(0.5 * window_s / dt)) if dt > 0 else 1
        h = min(h, (x.size - 1) // 2) or 1
    out = np.gradient(x, t)
    out[h:-h] = (x[2 * h:] - x[:-2 * h]) / (t[2 * h:] - t[:-2 * h])
    return out


def _half_window(t: np.ndarray, window_s: float) -> int:
    """Samples ``h`` either side of the central difference over ``window_s`` (as :func:`_central_derivative`)."""
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    h = max(1, round(0.5 * window_s / dt)) if dt > 0 else 1
    return min(h, (t.size - 1) // 2) or 1


def unsettled(n_p: np.ndarray, t: np.ndarray, max_rate: float, window_s: float) -> np.ndarray:
    """True where a pump speed step reaches the derivative window or the pump speed has not settled after it.

    A step is a change between two neighbouring samples larger than the quasi-steady limit ``max_rate``
    allows over the whole derivative window (``|n[j+1] - n[j]| > max_rate * window_s``): the central
    difference over the window cannot resolve it. The pump speed has settled at the first sample ``k``
    after the step from which every one-sample change over a whole derivative window (``2h`` changes,
    ``h`` the half window in samples) stays within the limit (``|n[i+1] - n[i]| <= max_rate * (t[i+1] -
    t[i])``). Left out: every sample whose derivative window reaches the step or the unsettled stretch
    after it, i.e. from ``j + 1 - h`` to ``k + h - 1``; the first sample kept after a step has its whole
    window in settled motion. A step with nothing unsettled after it costs the ``2h`` samples whose
    window holds it (they fail the quasi-steady limit anyway); no settling within the record leaves out
    the rest of it.

    Parameters
    ----------
    n_p, t:
        Pump speed (rpm) and its sample times (s).
    max_rate:
        The quasi-steady limit on ``|dn_p/dt|`` (rpm/s).
    window_s:
        Span of the central difference (s).
    """
    m = n_p.size
    out = np.zeros(m, dtype=bool)
    if m < 2:
        return out
    h = _half_window(t, window_s)
    d = np.abs(np.diff(n_p))
    jumps = np.flatnonzero(d > max_rate * window_s)
    if jumps.size == 0:
        return out
    settle_at = np.flatnonzero(_calm_run(d, t, max_rate, 2 * h))
    for j in jumps:
        i = np.searchsorted(settle_at, j + 1)
        k = int(settle_at[i]) if i < settle_at.size else m
        out[max(0, j + 1 - h): min(m, k + h)] = True
    return out


def _calm_run(d: np.ndarray, t: np.ndarray, max_rate: float, w: int) -> np.ndarray:
    """``[i]``: the one-sample changes ``d[i : i + w]`` all calm (``d <= max_rate`` times their time steps; a whole
    derivative window of ``w`` calm changes starts at ``i``)."""
    calm = d <= max_rate * np.diff(t)
    c = np.r_[0, np.cumsum(~calm)]
    run = np.zeros(d.size, dtype=bool)
    if d.size >= w:
        run[: d.size - w + 1] = (c[w:] - c[: d.size - w + 1]) == 0
    return run


def _hold_mask(gear_change: np.ndarray, n_hold: int) -> np.ndarray:
    """True where no gear change happened within ``n_hold`` samples either side."""
    if n_hold <= 0:
        return ~gear_change
    c = np.r_[0, np.cumsum(gear_change, dtype=np.int64)]
    i = np.arange(gear_change.size)
    return c[np.minimum(i + n_hold + 1, gear_change.size)] - c[np.maximum(i - n_hold, 0)] == 0


def _unsettled_block(n_p: np.ndarray, t: np.ndarray, max_rate: float, window_s: float, h: int, e0: int, a: int,
                     b: int, carry: tuple[int, int]) -> tuple[np.ndarray, tuple[int, int]]:
    """:func:`unsettled` of the grid points ``a .. b - 1`` of a record read a block at a time.

    ``n_p``, ``t``: the record's samples ``e0 ..`` (at least ``h`` either side of the block, or to its ends);
    ``h``: the whole record's half window; ``carry``: the last step and the last settle index (below) before
    ``a - h`` (-1: none), as this returns them for the next block (from ``b``). A sample is left out when there is a
    step ``j <= i + h - 1`` and no settle index in ``j + 1 .. i - h`` after the latest such step: the rule of
    :func:`unsettled` (the settle index is non-decreasing in the step)."""
    d = np.abs(np.diff(n_p))
    jump = d > max_rate * window_s
    calm_run = _calm_run(d, t, max_rate, 2 * h)
    idx = np.arange(d.size) + e0  # the steps' record indices
    last_jump = np.maximum.accumulate(np.where(jump, idx, -1)) if d.size else np.zeros(0, dtype=np.int64)
    last_settle = np.maximum.accumulate(np.where(calm_run, idx, -1)) if d.size else np.zeros(0, dtype=np.int64)
    i = np.arange(a, b)
    qj = np.minimum(i + h - 1, e0 + d.size - 1) - e0
    qs = i - h - e0
    jl = np.maximum(carry[0], np.where(qj >= 0, last_jump[np.clip(qj, 0, None)], -1))
    ls = np.maximum(carry[1], np.where(qs >= 0, last_settle[np.clip(qs, 0, None)], -1))
    out = (jl >= 0) & (ls < jl + 1)
    q = b - h - 1 - e0  # the next block's carry: before b - h
    if 0 <= q < d.size:
        carry = (max(carry[0], int(last_jump[q])), max(carry[1], int(last_settle[q])))
    return out, carry


@dataclass
class TorqueCalibration:
    """The samples the turbine torque of eq. 32 is calibrated on (lock-up closed, K0 open, nearly steady).

    ``t``, ``gear``, the motor torque ``t_p``, the turbine torque ``t_t`` of eq. 32 before the scale,
    ``k_out = i_g eta_m`` and ``c0`` of the transmission model each went through, and the least samples a gear
    needs (:func:`turbine_torque_scale`).
    """

    t: np.ndarray
    gear: np.ndarray
    t_p: np.ndarray
    t_t: np.ndarray
    k_out: np.ndarray
    c0: np.ndarray
    min_points: int


def turbine_torque_scale(gear: np.ndarray, t_p: np.ndarray, t_t: np.ndarray, min_points: int
                         ) -> tuple[float, float, int]:
    """The scale of eq. 32's turbine torque: the median over the gears of each gear's median ``t_p / t_t``.

    Per gear, because each gear's own eta_m and C0 errors differ and a gear with long steady drives must not
    outweigh the others; the median over the gears is the part common to all of them. A gear with fewer than
    ``min_points`` samples is left out.

    Parameters
    ----------
    gear, t_p, t_t:
        Gear, motor torque and turbine torque (eq. 32) of the calibration samples.
    min_points:
        Least samples of a gear.

    Returns
    -------
    scale, se, n
        The scale (1 without a gear), its standard error from the spread of the gear medians (NaN with fewer
        than two gears) and the samples used.
    """
    meds, n = [], 0
    for k in np.unique(gear):
        r = t_p[gear == k] / t_t[gear == k]
        if r.size >= min_points:
            meds.append(float(np.median(r)))
            n += int(r.size)
    if not meds:
        return 1.0, float("nan"), 0
    se = 1.2533 * float(np.std(meds, ddof=1)) / np.sqrt(len(meds)) if len(meds) > 1 else float("nan")
    return float(np.median(meds)), se, n


@dataclass
class ConverterPoints:
    """The points the converter is fitted on (:func:`converter_points`), on the grid of the identification.

    ``t`` grid times; ``w_p``, ``w_t`` pump and turbine speed (rad/s); ``t_p`` the motor torque; ``t_t`` the
    turbine torque ``T_out / k_out + C0`` with ``k_out = i_g eta_m`` per point; ``dw_p`` the pump acceleration
    (rad/s^2); ``gear``; ``n_excluded`` grid points left out; the turbine-speed calibration (``scale``,
    ``scale_se``, ``n_cal``), the turbine-torque calibration (``tscale``, ``tscale_se``, ``n_tcal``: eq. 32's
    torque against the motor torque where the lock-up is closed and K0 open; its samples in
    ``torque_calibration``), the reasons to flag and ``borrowed``: gear -> the gear whose transmission model (or
    drag model) it used for lack of its own, for the gears among the points.
    """

    t: np.ndarray
    w_p: np.ndarray
    w_t: np.ndarray
    t_p: np.ndarray
    t_t: np.ndarray
    dw_p: np.ndarray
    gear: np.ndarray
    k_out: np.ndarray
    segments: list[str]
    n_excluded: int
    scale: float
    scale_se: float
    n_cal: int
    reasons: list[str] = field(default_factory=list)
    tscale: float = 1.0
    tscale_se: float = float("nan")
    n_tcal: int = 0
    torque_calibration: TorqueCalibration | None = None
    borrowed: dict[int, int] = field(default_factory=dict)


def converter_points(rec: Recording, specs: VehicleSpecs, *, transmission: Mapping[int, tuple[float, float]] | None,
                     rate_hz: float, max_pump_accel_rpm_s: float, min_pump_speed_rpm: float,
                     min_pump_torque_nm: float, shift_hold_s: float, derivative_window_s: float,
                     calibrate_turbine_speed: bool, min_calibration_points: int, lockup_slip_tol: float,
                     calibrate_turbine_torque: bool = True, drag: FitResult | None = None) -> ConverterPoints:
    """The selection and regressors of :func:`identify_torque_converter`, shared with the planner.

    Parameters
    ----------
    rec, specs:
        The Recording and the vehicle's specs.
    transmission:
        Gear -> (eta_m, C0) of the identified transmission (None: losses ignored, said in the reasons).
    rate_hz, max_pump_accel_rpm_s, min_pump_speed_rpm, min_pump_torque_nm, shift_hold_s, derivative_window_s:
        Resampling rate and the quasi-steady selection, as :func:`identify_torque_converter` takes them
        (with the settle rule of :func:`unsettled` after a pump speed step).
    calibrate_turbine_speed, min_calibration_points, lockup_slip_tol:
        The turbine-speed calibration where the lock-up is closed, and the slip taken as closed without a
        lock-up channel.
    calibrate_turbine_torque:
        The turbine torque of eq. 32 scaled to the motor torque where the lock-up is closed and K0 open
        (:func:`identify_torque_converter`); needs the K0 or engine state of a hybrid's log.
    drag:
        The gearbox drag at the oil temperature (``transmission.drag``, to be used: the caller decides). With it and
        a ``gearbox_oil_degc`` channel, each point's ``eta_m`` and ``C0`` are the drag model's at that point's oil
        temperature and turbine speed (a gear without its own drag group: the nearest gear's, said in the
        reasons), instead of eq. 14's constant ``C0`` (identified at other oil temperatures).

    Raises
    ------
    MissingChannelError
    """
    engine_only = "em_speed_rpm" not in rec and "em_torque_nm" not in rec
    n_role, t_role = ("engine_speed_rpm", "engine_torque_nm") if engine_only else ("em_speed_rpm", "em_torque_nm")
    need = ["vehicle_speed_kmh", n_role, t_role, "shaft_torque_nm", "gear_actual"]
    missing = [n for n in need if n not in rec]
    if missing:
        raise MissingChannelError(f"torque converter identification needs channel(s) {', '.join(missing)}")
    opt = [n for n in ("lockup_closed", "gear_target", "k0_closed", "engine_on") if n in rec]
    drag_gears = sorted(int(k[4:]) for k in (drag.params if drag is not None else ()) if k[:4] == "C0_g"
                        and k[4:].isdigit())
    if drag_gears and "gearbox_oil_degc" in rec:
        opt.append("gearbox_oil_degc")
    states = {"gear_actual", "lockup_closed", "gear_target", "k0_closed", "engine_on"}
    # the shaft torque (telemetry clock) on the vehicle CAN's: offset, and drift where significant
    grid = StrictGrid(rec, need + opt, rate_hz, hold=tuple(states & set(need + opt)), shifts=source_shifts(rec))
    reasons = []
    if engine_only:
        reasons.append("no motor channels: the engine drives the pump alone (conventional layout), pump speed and "
                       "torque are the engine's")
    if "lockup_closed" not in opt:
        reasons.append(f"no lock-up state in the recording: closed where the slip is below {lockup_slip_tol:g} "
                       "(turbine speed not calibrated)")
        calibrate_turbine_speed = False
    k0_name = None if engine_only else "k0_closed" if "k0_closed" in opt else "engine_on" if "engine_on" in opt \
        else None
    if not engine_only and k0_name is None:
        reasons.append("no K0 or engine state in the recording: pump torque taken as motor torque everywhere")
    sel = _Selection(grid, specs, n_role=n_role, t_role=t_role, engine_only=engine_only, k0_name=k0_name,
                     rate_hz=rate_hz, max_pump_accel_rpm_s=max_pump_accel_rpm_s,
                     min_pump_speed_rpm=min_pump_speed_rpm, min_pump_torque_nm=min_pump_torque_nm,
                     shift_hold_s=shift_hold_s, derivative_window_s=derivative_window_s,
                     calibrate_turbine_speed=calibrate_turbine_speed, lockup_slip_tol=lockup_slip_tol)
    p = sel.points  # the candidates: points (use) and torque-calibration samples (tcal) before the torque model
    use, g, gear, ig, w_t = p["use"], p["g"], p["gear"], p["ig"], p["w_t"]
    segs = sorted({s.name for s, hit in zip(rec.segments, touched(rec.segments, p["t"][use]), strict=True) if hit})
    scale, scale_se, n_cal = 1.0, float("nan"), 0
    if calibrate_turbine_speed:
        n_cal = int(sel.ratio.size)
        if n_cal >= min_calibration_points:
            ratio = sel.ratio
            scale = float(np.median(ratio))
            scale_se = 1.2533 * float(np.std(ratio, ddof=1)) / np.sqrt(n_cal)
            w_t = w_t * scale
            if abs(scale - 1.0) > 0.1:
                reasons.append(f"turbine speed from eq. 31 is off by {100 * (scale - 1):+.1f} % against the motor "
                               "speed with the lock-up closed: check gear ratios, final drive and wheel radius")
    borrowed: dict[int, int] = {}
    if transmission:
        table = {int(k): (float(e), float(c)) for k, (e, c) in transmission.items()}
        lacking = sorted({int(k) for k in np.unique(g[use]) if int(k) not in table})
        for k in lacking:  # nearest identified gear (ties: the lower one)
            near = min(table, key=lambda j: (abs(j - k), j))
            borrowed[k] = near
            reasons.append(f"gear {k} has no transmission model: eta_m and C0 of gear {near} used")
        full = {k: table[k] if k in table else table[min(table, key=lambda j: (abs(j - k), j))]
                for k in range(1, len(specs.gear_ratios) + 1)}
        eta_tab = np.array([full[k][0] for k in range(1, len(specs.gear_ratios) + 1)])
        c0_tab = np.array([full[k][1] for k in range(1, len(specs.gear_ratios) + 1)])
        eta, c0 = eta_tab[g - 1], c0_tab[g - 1]
        own_model = np.isin(g, list(table))
    else:
        eta, c0 = np.ones_like(ig), np.zeros_like(ig)
        own_model = np.zeros(g.shape, dtype=bool)
        reasons.append("no transmission result: turbine torque with eta = 1, C0 = 0 (losses ignored)")
    if "gearbox_oil_degc" in opt and drag is not None:
        eta, c0 = np.array(eta, dtype=float), np.array(c0, dtype=float)
        oil = p["gearbox_oil_degc"]
        borrowed = {}
        for k in sel.gears:  # every gear of the grid (np.unique of the clipped gear)
            near = min(drag_gears, key=lambda j: (abs(j - k), j))
            m = g == k
            if near != k and np.any(m & use):
                borrowed[int(k)] = near
                reasons.append(f"gear {k} has no drag model: eta_m and C0(T_oil) of gear {near} used")
            eta[m] = drag.value(f"eta_m_g{near}")
            c0[m] = drag_c0(drag, f"g{near}", oil[m], w_t[m])
        use = use & np.isfinite(oil)
        own_model = np.isin(g, drag_gears)
    t_t = p["shaft_torque_nm"] / (ig * eta) + c0
    use = use & np.isfinite(t_t)
    tscale, tscale_se, n_tcal = 1.0, float("nan"), 0
    tcal_points = None
    if calibrate_turbine_torque and k0_name is not None:
        # lock-up closed, K0 open, nearly steady: the turbine torque of eq. 32 is the motor torque
        tcal = p["tcal"] & (t_t > 0) & own_model
        # only gears with a transmission model of their own: a borrowed model's efficiency error is the gear's,
        # not a torque gain common to all gears
        # per gear (each gear's own eta_m and C0 errors differ; a gear with long steady drives must not
        # outweigh the others), then the median over the gears: the part common to all gears
        tcal_points = TorqueCalibration(p["t"][tcal], gear[tcal], p["t_p"][tcal], t_t[tcal], (ig * eta)[tcal],
                                        c0[tcal], min_calibration_points)
        tscale, tscale_se, n_tcal = turbine_torque_scale(tcal_points.gear, tcal_points.t_p, tcal_points.t_t,
                                                         min_calibration_points)
        if n_tcal:
            t_t = t_t * tscale
            if abs(tscale - 1.0) > 0.05:
                reasons.append(f"turbine torque from eq. 32 is off by {100 * (1 / tscale - 1):+.1f} % against the "
                               "motor torque with the lock-up closed: check the torque channels' gains and the "
                               "transmission model")
    return ConverterPoints(p["t"][use], p["n_p"][use] / RPM_PER_RADS, w_t[use], p["t_p"][use], t_t[use],
                           p["dn"][use] / RPM_PER_RADS, gear[use], ig[use] * eta[use] / tscale, segs,
                           int(sel.size - use.sum()), scale, scale_se, n_cal, reasons, tscale, tscale_se, n_tcal,
                           tcal_points, borrowed)


def _median_step(grid: StrictGrid) -> float:
    """``np.median(np.diff(t))`` of the grid's times, a block at a time: the steps of a uniform grid take a few
    values (its rounding), counted block by block."""
    counts: dict[float, int] = {}
    for a in range(0, grid.size - 1, POINTS_BLOCK):
        vals, k = np.unique(np.diff(grid.times(a, min(a + POINTS_BLOCK, grid.size - 1) + 1)), return_counts=True)
        for v, c in zip(vals.tolist(), k.tolist(), strict=True):
            counts[v] = counts.get(v, 0) + c
    steps = sorted(counts)
    cum = np.cumsum([counts[v] for v in steps])
    m = int(cum[-1])
    lo, hi = (steps[int(np.searchsorted(cum, r, side="right"))] for r in ((m - 1) // 2, m // 2))
    return float(np.mean([lo, hi]))


class _Selection:
    """The grid's selection read a block at a time (:data:`POINTS_BLOCK` points with margins): what
    :func:`converter_points` needs of the grid, gathered, and nothing as long as the grid.

    ``points``: per candidate (a point before the torque model's checks, or a torque-calibration sample before
    them) its time, gear, clipped gear, gear ratio, pump speed and torque, shaft torque, turbine speed (eq. 31,
    unscaled), pump speed derivative, oil temperature (if read) and the two masks ``use`` and ``tcal``;
    ``ratio``: the turbine-speed calibration's ratios; ``gears``: the clipped gears met; ``size``: grid points.
    Every mask is the whole grid's: a block's margins hold the shift hold, the derivative window and the look-ahead
    of :func:`unsettled`, whose state is carried from block to block.
    """

    def __init__(self, grid: StrictGrid, specs: VehicleSpecs, *, n_role: str, t_role: str, engine_only: bool,
                 k0_name: str | None, rate_hz: float, max_pump_accel_rpm_s: float, min_pump_speed_rpm: float,
                 min_pump_torque_nm: float, shift_hold_s: float, derivative_window_s: float,
                 calibrate_turbine_speed: bool, lockup_slip_tol: float) -> None:
        self._grid, self._specs = grid, specs
        self._roles, self._engine_only, self._k0_name = (n_role, t_role), engine_only, k0_name
        self._limits = (max_pump_accel_rpm_s, min_pump_speed_rpm, min_pump_torque_nm)
        self._window_s, self._calibrate, self._slip_tol = derivative_window_s, calibrate_turbine_speed, lockup_slip_tol
        n = self.size = grid.size
        self._n_hold = round(shift_hold_s * rate_hz)
        h = 1
        if n > 1:  # the whole grid's (as _half_window of the whole grid), clipped to its size
            dt = _median_step(grid)
            h = min(max(1, round(0.5 * derivative_window_s / dt)) if dt > 0 else 1, (n - 1) // 2) or 1
        self._h = h
        self._carry = (-1, -1)
        cols: dict[str, list[np.ndarray]] = {}
        ratios: list[np.ndarray] = []
        gears: set[int] = set()
        for a in range(0, n, POINTS_BLOCK):
            part, ratio, met = self._block(a, min(a + POINTS_BLOCK, n))
            for k, v in part.items():
                cols.setdefault(k, []).append(v)
            ratios.append(ratio)
            gears |= met
        if not cols:
            raise ValueError("torque converter identification: no grid points")  # resample_strict raises first
        self.points = {k: np.concatenate(v) for k, v in cols.items()}
        self.ratio = np.concatenate(ratios) if ratios else np.zeros(0)
        self.gears = sorted(gears)

    def _block(self, a: int, b: int) -> tuple[dict[str, np.ndarray], np.ndarray, set[int]]:
        """The candidates of grid points ``a .. b - 1``, their calibration ratios and the clipped gears met."""
        n, h, n_hold, specs = self.size, self._h, self._n_hold, self._specs
        max_accel, min_speed, min_torque = self._limits
        margin = max(n_hold, 2 * h) + 2
        e0, e1 = max(0, a - margin), min(n, b + margin)
        t, d, bad = self._grid.block(e0, e1)
        gear = np.rint(np.nan_to_num(d["gear_actual"])).astype(int)
        change = np.r_[False, np.diff(gear) != 0]
        if "gear_target" in d:
            tgt = np.rint(np.nan_to_num(d["gear_target"])).astype(int)
            change |= np.r_[False, np.diff(tgt) != 0] | (tgt != gear)
        n_p, t_p = d[self._roles[0]], d[self._roles[1]]
        n_gears = len(specs.gear_ratios)
        g = np.clip(gear, 1, n_gears)
        ig = np.asarray(specs.gear_ratios)[g - 1]
        w_t = d["vehicle_speed_kmh"] / 3.6 / specs.wheel_radius_m * ig * specs.final_drive_ratio
        if "lockup_closed" not in d:
            # many cars do not broadcast the lock-up state: take it as closed where there is no slip
            with np.errstate(invalid="ignore", divide="ignore"):
                slip = np.abs(1.0 - w_t / (n_p / RPM_PER_RADS))
            d["lockup_closed"] = (slip < self._slip_tol).astype(float)
        held = ~bad & _hold_mask(change, n_hold) & (gear >= 1) & (gear <= n_gears)
        closed = np.nan_to_num(d["lockup_closed"]) >= 0.5
        use = held & ~closed
        k0_open = None  # where the motor alone drives the pump (the turbine-torque calibration's samples)
        if self._engine_only:
            if "engine_on" in d:
                use &= np.nan_to_num(d["engine_on"], nan=0.0) >= 0.5
        elif self._k0_name is not None:
            k0_open = np.nan_to_num(d[self._k0_name], nan=1.0) < 0.5
            use &= k0_open
        dn = _central_derivative(n_p, t, self._window_s, h) if n >= 3 else np.zeros_like(n_p)
        use &= np.abs(dn) <= max_accel
        i = slice(a - e0, b - e0)
        # a pump speed step the central difference cannot resolve: left out until the pump speed has settled
        unsteady = np.zeros(e1 - e0, dtype=bool)
        if n >= 2:
            unsteady[i], self._carry = _unsettled_block(n_p, t, max_accel, self._window_s, h, e0, a, b, self._carry)
        use &= ~unsteady & (n_p >= min_speed) & (t_p >= min_torque) & (d["shaft_torque_nm"] > 0)
        ratio = np.zeros(0)
        if self._calibrate:
            cal = (held & closed & (n_p >= min_speed) & (np.abs(dn) <= max_accel) & (d["vehicle_speed_kmh"] > 10.0))[i]
            ratio = n_p[i][cal] / RPM_PER_RADS / w_t[i][cal]
        tcal = np.zeros(e1 - e0, dtype=bool)
        if k0_open is not None:
            tcal = held & closed & k0_open & (n_p >= min_speed) & (np.abs(dn) <= 0.1 * max_accel) & ~unsteady \
                & (t_p >= min_torque) & (d["shaft_torque_nm"] > 0)
        keep = (use | tcal)[i]
        cols = {"t": t, "gear": gear, "g": g, "ig": ig, "n_p": n_p, "t_p": t_p, "w_t": w_t, "dn": dn,
                "shaft_torque_nm": d["shaft_torque_nm"], "use": use, "tcal": tcal}
        if "gearbox_oil_degc" in d:
            cols["gearbox_oil_degc"] = d["gearbox_oil_degc"]
        return {k: v[i][keep] for k, v in cols.items()}, ratio, {int(k) for k in np.unique(g[i])}
