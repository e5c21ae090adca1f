"""Clock alignment between sources of a Recording: offsets by cross-correlation, drifts from windowed offsets.

Two sources that measure one quantity (vehicle speed on the vehicle CAN and the dyno's roller speed; the
motor's mechanical power from the CAN torque and speed and the HPCU shunt's electrical power) are
cross-correlated: :func:`detect_lag` gives the time to add to one to line it up with the other. On
recordings of an hour or more the drift is the slope of the offsets found in consecutive 15-minute windows (a
Theil-Sen slope: a window whose correlation peak is a wrong one does not move it).

The vehicle's speed comes from its wheels, which slip on the rollers in proportion to the force they pass
(a fraction of a percent at cruise, 1-3 % in a hard acceleration): the difference to the roller speed then
follows the acceleration and a plain cross-correlation takes it for a time shift (65 ms on the quick
campaign's high-fidelity vehicle). :func:`slip_aware_lag` refines the lag with the slip in the model,
``v_wheel(t) = v_roller(t + lag) (g + k_f F_front + k_r F_rear) + c`` (forces on the dyno's clock), the lag
the one whose least-squares residual is smallest.

The shaft torque's telemetry carries no speed: its pair is the drive force the vehicle CAN's engine and motor
give, their power over the vehicle speed (:class:`_DriveForce`, the engine and motor torques times the gear
ratio as the speeds give it, up to the final drive and the converter's losses), which the shaft torque follows
within a few percent outside friction braking (the offsets are Pearson correlations: the scale does not matter).
Each drift comes with its standard error (from the scatter of the windows' offsets about the line) and the time on
``a``'s clock at which the offset holds (the centre of the span it was found on), so a reader can map times as
``offset + drift * (t - t_ref)``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from itertools import pairwise

import numpy as np

from benchtwin.chain.blocks import ChannelBlocks
from benchtwin.lag import _central_hour, _correlate, detect_lag
from benchtwin.recording import Recording

__all__ = ["DRIFT_WINDOW_S", "MIN_DRIVE_SPEED_KMH", "clock_offsets", "detect_lag", "slip_aware_lag"]



def slip_aware_lag(t_a: np.ndarray, x_a: np.ndarray, t_b: np.ndarray, x_b: np.ndarray,
                   forces: list[tuple[np.ndarray, np.ndarray]], lag0: float, *, rate_hz: float = 20.0,
                   search_s: float = 0.3, window: tuple[float, float] | None = None) -> float:
    """Lag of a wheel speed ``a`` against a roller speed ``b`` with the tyres' slip in the model.

    For each lag ``L`` within ``lag0 +- search_s`` (steps of ``1 / rate_hz``) the least-squares fit
    ``x_a(t) = x_b(t + L) (g + sum_i k_i F_i(t + L)) + c`` over the common span (or ``window``) is formed;
    the lag of the smallest residual, refined by a parabola, is returned (``lag0`` if the signals do not
    overlap enough). The slip term takes up the force-proportional difference that a plain
    cross-correlation (:func:`detect_lag`, which gives ``lag0``) reads as a time shift.

    Parameters
    ----------
    t_a, x_a:
        Wheel-based speed and its timestamps.
    t_b, x_b:
        Roller speed and its timestamps.
    forces:
        ``(timestamps, values)`` of the axle forces on ``b``'s clock (e.g. the dyno's front and rear force).
    lag0:
        Starting lag (the plain cross-correlation's), s.
    rate_hz, search_s, window:
        Grid rate, half-width of the search and an optional time window of ``a``.

    Returns
    -------
    float
        Time to add to ``a``'s timestamps to line it up with ``b``, s.
    """
    lo = max(t_a[0], t_b[0]) + abs(lag0) + search_s
    hi = min(t_a[-1], t_b[-1]) - abs(lag0) - search_s
    for tf, _ in forces:
        lo, hi = max(lo, tf[0] + abs(lag0) + search_s), min(hi, tf[-1] - abs(lag0) - search_s)
    if window is not None:
        lo, hi = max(lo, window[0]), min(hi, window[1])
    return _slip_fit(t_a, x_a, t_b, x_b, forces, lag0, lo, hi, rate_hz, search_s)


def _slip_fit(t_a: np.ndarray, x_a: np.ndarray, t_b: np.ndarray, x_b: np.ndarray,
              forces: list[tuple[np.ndarray, np.ndarray]], lag0: float, lo: float, hi: float, rate_hz: float,
              search_s: float) -> float:
    """:func:`slip_aware_lag` over the span ``lo..hi`` (its central hour): for each point of the grids only the
    samples either side of it matter (any run of them around the grids gives the same bits)."""
    lo, hi = _central_hour(lo, hi)
    if hi - lo < 20.0:
        return lag0
    grid = np.arange(lo, hi, 1.0 / rate_hz)
    a = np.interp(grid, t_a, x_a)
    lags = lag0 + np.arange(-round(search_s * rate_hz), round(search_s * rate_hz) + 1) / rate_hz
    ssr = np.empty(lags.size)
    finite_a = np.isfinite(a)
    for j, lag in enumerate(lags):
        at = grid + lag
        b = np.interp(at, t_b, x_b)
        cols = [b, np.ones_like(b)] + [b * np.interp(at, tf, f) for tf, f in forces]
        # column by column (a reduction along the rows of an n x k array is several times slower); the same
        # rows, scales and scaled design bit for bit, so the same normal equations
        good = finite_a.copy()
        for c in cols:
            good &= np.isfinite(c)
        if good.sum() < 10 * len(cols):
            return lag0
        kept = [c[good] for c in cols]
        ag = a[good]
        scale = np.maximum(np.array([np.abs(c).max() for c in kept]), 1e-300)  # normal equations, columns scaled
        dn = np.column_stack([c / s for c, s in zip(kept, scale)])
        coef = np.linalg.lstsq(dn.T @ dn, dn.T @ ag, rcond=None)[0]
        ssr[j] = float(np.sum((ag - dn @ coef) ** 2)) / ag.size
    k = int(np.argmin(ssr))
    frac = 0.0
    if 0 < k < ssr.size - 1:
        den = ssr[k - 1] - 2 * ssr[k] + ssr[k + 1]
        frac = 0.5 * (ssr[k - 1] - ssr[k + 1]) / den if den > 0 else 0.0
    return float(lags[k] + frac / rate_hz)


#: window (s) at each end of a long recording used to estimate the relative clock drift
DRIFT_WINDOW_S = 900.0


class _Series:
    """One channel's timestamps and values, read by runs of samples through a :class:`ChannelBlocks` view."""

    def __init__(self, view: ChannelBlocks, name: str) -> None:
        self.view, self.name, self.n = view, name, view.length(name)

    def read(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        t, v, _f = self.view.read(self.name, start, stop, "tv")
        return t, v

    def time(self, index: int) -> float:
        return self.view.sample(self.name, index)

    def search(self, time_s: float, side: str) -> int:
        """``np.searchsorted(timestamps, time_s, side)`` of the whole, time-ordered channel (a bisection over
        single samples)."""
        lo, hi = 0, self.n
        while lo < hi:
            mid = (lo + hi) // 2
            t = self.time(mid)
            if t < time_s or (side == "right" and t == time_s):
                lo = mid + 1
            else:
                hi = mid
        return lo


class _MotorPower(_Series):
    """The motor's mechanical power, torque times the speed interpolated at the torque's timestamps (rad/s)."""

    def __init__(self, torque: _Series, speed: _Series) -> None:
        self.torque, self.speed = torque, speed
        self.view, self.name, self.n = torque.view, torque.name, torque.n

    def read(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        t, q = self.torque.read(start, stop)
        if t.size == 0:
            return t, q
        return t, q * _interp_at(self.speed, t) * (2 * np.pi / 60.0)


def _interp_at(s: _Series, t: np.ndarray) -> np.ndarray:
    """``s`` interpolated at the increasing times ``t``, from its samples either side of them only (np.interp gives
    the bits of the whole channel)."""
    s0 = max(s.search(float(t[0]), "right") - 1, 0)
    s1 = min(s.search(float(t[-1]), "right") + 1, s.n)
    return np.interp(t, *s.read(s0, s1))


#: below this vehicle speed the drive force (power over speed) is left out (NaN): the converter's slip and a
#: near-zero divisor make the ratio of speeds no gear ratio there
MIN_DRIVE_SPEED_KMH = 10.0


class _DriveForce(_Series):
    """The drive force the engine and motor give at the wheels, ``(T_em w_em + T_e w_e) / v`` on the vehicle CAN
    (N, the speeds interpolated at the motor torque's timestamps; NaN below :data:`MIN_DRIVE_SPEED_KMH`)."""

    def __init__(self, torque: _Series, others: list[_Series]) -> None:
        # others: the motor speed (rpm), the engine torque (Nm), the engine speed (rpm), the vehicle speed (km/h)
        self.torque, self.others = torque, others
        self.view, self.name, self.n = torque.view, torque.name, torque.n

    def read(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        t, q = self.torque.read(start, stop)
        if t.size == 0:
            return t, q
        w_em, q_e, w_e, v = (_interp_at(s, t) for s in self.others)
        power = (q * w_em + q_e * w_e) * (2 * np.pi / 60.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return t, np.where(v >= MIN_DRIVE_SPEED_KMH, power / (v / 3.6), np.nan)


def _blocks_back(s: _Series, stop: int, size: int) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """Runs of samples before ``stop``, backwards: 64 samples first, doubling up to ``size`` (the finite sample
    looked for is most often the first one read)."""
    b, step = stop, min(64, size)
    while b > 0:
        a = max(b - step, 0)
        yield (a, *s.read(a, b))
        b, step = a, min(2 * step, size)


def _blocks_on(s: _Series, start: int, size: int) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """Runs of samples from ``start`` on: 64 samples first, doubling up to ``size``."""
    a, step = start, min(64, size)
    while a < s.n:
        b = min(a + step, s.n)
        yield (a, *s.read(a, b))
        a, step = b, min(2 * step, size)


def _finite_span(s: _Series, size: int) -> tuple[float, float] | None:
    """Timestamps of the first and last finite sample, None if fewer than ten (what :func:`detect_lag` needs)."""
    count, first = 0, math.nan
    for _a, t, x in _blocks_on(s, 0, size):
        good = np.flatnonzero(np.isfinite(x))
        if good.size and count == 0:
            first = float(t[good[0]])
        count += good.size
        if count >= 10:
            break
    if count < 10:
        return None
    for _a, t, x in _blocks_back(s, s.n, size):
        good = np.flatnonzero(np.isfinite(x))
        if good.size:
            return first, float(t[good[-1]])
    return None  # pragma: no cover (ten finite samples were found above)


def _around(s: _Series, lo: float, hi: float, size: int, *, finite: bool) -> tuple[np.ndarray, np.ndarray]:
    """The run of samples from the last one at or before ``lo`` to the first one after ``hi`` (with ``finite``:
    the last and first finite ones, the samples then filtered to the finite ones): what ``np.interp`` uses of
    the whole channel for points in ``lo..hi``."""
    start = s.search(lo, "right") - 1
    if finite:
        for a, _t, x in _blocks_back(s, start + 1, size):
            good = np.flatnonzero(np.isfinite(x))
            if good.size:
                start = a + int(good[-1])
                break
    stop = s.search(hi, "right")
    if finite:
        for a, _t, x in _blocks_on(s, stop, size):
            good = np.flatnonzero(np.isfinite(x))
            if good.size:
                stop = a + int(good[0])
                break
    t, x = s.read(max(start, 0), min(stop + 1, s.n))
    if finite:
        good = np.isfinite(x)
        t, x = t[good], x[good]
    return t, x


def _cut(s: _Series, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Samples with ``lo <= t < hi`` (the cut :func:`detect_lag` makes for a ``window``)."""
    return s.read(s.search(lo, "left"), s.search(hi, "left"))


def _pairs(view: ChannelBlocks) -> list[tuple[str, _Series, _Series, list[_Series]]]:
    """Signal pairs that measure one quantity on two sources: (key, a, b, forces), ``forces`` the axle forces on
    ``b``'s clock when ``a`` is a wheel speed that slips (else empty)."""
    rec = view.rec
    out: list[tuple[str, _Series, _Series, list[_Series]]] = []
    if "vehicle_speed_kmh" in rec and "dyno_speed_kmh" in rec:
        source = rec["dyno_speed_kmh"].source
        forces = [_Series(view, n) for n in ("dyno_force_front_n", "dyno_force_rear_n")
                  if n in rec and rec[n].source == source]
        out.append(("vehicle_can->dyno", _Series(view, "vehicle_speed_kmh"), _Series(view, "dyno_speed_kmh"),
                    forces))
    if "em_torque_nm" in rec and "em_speed_rpm" in rec:
        power_name = "hpcu_power_w" if "hpcu_power_w" in rec else "battery_power_w"
        if power_name in rec:
            mech = _MotorPower(_Series(view, "em_torque_nm"), _Series(view, "em_speed_rpm"))
            out.append((f"vehicle_can->{rec[power_name].source}", mech, _Series(view, power_name), []))
    drive = ("em_torque_nm", "em_speed_rpm", "engine_torque_nm", "engine_speed_rpm", "vehicle_speed_kmh")
    if "shaft_torque_nm" in rec and all(n in rec for n in drive):
        series = [_Series(view, n) for n in drive]
        out.append((f"vehicle_can->{rec['shaft_torque_nm'].source}", _DriveForce(series[0], series[1:]),
                    _Series(view, "shaft_torque_nm"), []))
    return [(key, a, b, forces) for key, a, b, forces in out
            if min([a.n, b.n] + [s.n for s in _parts(a)] + [f.n for f in forces]) > 0]


def _parts(s: _Series) -> list[_Series]:
    """The channels a composite series reads besides its own."""
    if isinstance(s, _MotorPower):
        return [s.speed]
    if isinstance(s, _DriveForce):
        return list(s.others)
    return []


def clock_offsets(rec: Recording | ChannelBlocks, detail: dict[str, dict[str, float]] | None = None
                  ) -> tuple[dict[str, float], dict[str, float]]:
    """Offsets (s) and, on recordings long enough, relative drifts (ppm) between sources.

    With ``detail`` (a dict), ``detail["clock_drift_se_ppm"]`` gets each drift's standard error (ppm) and
    ``detail["clock_offset_time_s"]`` the time on ``a``'s clock at which each offset holds (the centre of the span
    it was found on): the offset at time ``t`` is then ``offset + drift * 1e-6 * (t - t_ref)``.

    Only the time windows the work uses are read (the central hour of the common span, each 15-minute drift
    window, and the samples either side of them), a block of samples at a time through ``rec`` when it is a
    :class:`ChannelBlocks` view (channels in the store's files stay there); the offsets and drifts are those of
    :func:`detect_lag` and :func:`slip_aware_lag` on the whole channels, bit for bit.
    """
    view = rec if isinstance(rec, ChannelBlocks) else ChannelBlocks(rec)
    size, max_lag = view.size, 2.0
    offsets: dict[str, float] = {}
    drifts: dict[str, float] = {}
    drift_se: dict[str, float] = {}
    at_time: dict[str, float] = {}
    for key, a, b, forces in _pairs(view):
        span_a, span_b = _finite_span(a, size), _finite_span(b, size)
        if span_a is None or span_b is None:
            continue
        lo, hi = max(span_a[0], span_b[0]) + max_lag, min(span_a[1], span_b[1]) - max_lag
        if hi - lo < 4 * max_lag:  # too short a common span (as _correlate decides)
            continue
        g0, g1 = _central_hour(lo, hi)  # the grids: g0..g1 (a), g0 - max_lag..g1 + max_lag (b); a second to spare
        t_a, x_a = _around(a, g0 - 1.0, g1 + 1.0, size, finite=True)
        t_b, x_b = _around(b, g0 - max_lag - 1.0, g1 + max_lag + 1.0, size, finite=True)
        lag = _correlate(t_a, x_a, t_b, x_b, lo, hi, 100.0, max_lag, 0.6)
        del t_a, x_a, t_b, x_b
        if lag is None:
            continue
        centre = 0.5 * (g0 + g1)
        ends = [(s.time(0), s.time(-1)) for s in (a, b)]
        if forces:
            search = 0.3
            lo = max(ends[0][0], ends[1][0]) + abs(lag) + search
            hi = min(ends[0][1], ends[1][1]) - abs(lag) - search
            for f in forces:
                lo, hi = max(lo, f.time(0) + abs(lag) + search), min(hi, f.time(-1) - abs(lag) - search)
            g0, g1 = _central_hour(lo, hi)
            if g1 - g0 >= 20.0:  # else the plain lag stands (as _slip_fit decides)
                reach = abs(lag) + search + 1.0
                t_a, x_a = _around(a, g0 - 1.0, g1 + 1.0, size, finite=False)
                t_b, x_b = _around(b, g0 - reach, g1 + reach, size, finite=False)
                near = [_around(f, g0 - reach, g1 + reach, size, finite=False) for f in forces]
                lag = _slip_fit(t_a, x_a, t_b, x_b, near, lag, lo, hi, 20.0, search)
                centre = 0.5 * (g0 + g1)
                del t_a, x_a, t_b, x_b, near
        offsets[key] = lag
        at_time[key] = float(centre)
        t0, t1 = max(ends[0][0], ends[1][0]), min(ends[0][1], ends[1][1])
        n_win = int((t1 - t0) // DRIFT_WINDOW_S)
        if n_win >= 4:  # offset per window, drift = slope of a straight line through them
            edges = np.linspace(t0, t1, n_win + 1)
            pts = [(0.5 * (w0 + w1), detect_lag(*_cut(a, w0 - max_lag, w1 + max_lag),
                                                 *_cut(b, w0 - 2 * max_lag, w1 + 2 * max_lag),
                                                 window=(w0, w1), rate_hz=20.0))
                   for w0, w1 in pairwise(edges)]
            # a best lag at the search's edge is no peak (the quantity's lag lies outside, or none is found)
            pts = [(c, lag_w) for c, lag_w in pts if lag_w is not None and abs(lag_w) < max_lag - 0.5 / 20.0]
            if len(pts) >= 3 and pts[-1][0] - pts[0][0] >= 2 * DRIFT_WINDOW_S:
                c, lw = np.array(pts).T
                drifts[key], drift_se[key] = _drift_fit(c, lw)
    if detail is not None:
        detail["clock_drift_se_ppm"] = drift_se
        detail["clock_offset_time_s"] = at_time
    return offsets, drifts


def _drift_fit(centres: np.ndarray, lags: np.ndarray) -> tuple[float, float]:
    """Drift (ppm) through the windows' offsets and its standard error (ppm): the Theil-Sen slope (the median of
    the slopes between pairs of windows, unmoved by up to 29 % of windows whose correlation peak is a wrong one,
    e.g. on a steady cruise where the signals are flat and noisy) and half its 68.27 % confidence interval (one
    standard deviation)."""
    from scipy.stats import theilslopes

    res = theilslopes(lags, centres, alpha=0.6827)
    return float(res[0] * 1e6), float(0.5 * (res[3] - res[2]) * 1e6)
