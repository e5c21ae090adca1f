"""Clock alignment between sources of a Recording: offsets by cross-correlation, drifts from windowed offsets.

Two sources that measure one quantity (vehicle speed on the vehicle CAN and the dyno's roller speed; the
motor's mechanical power from the CAN torque and speed and the HPCU shunt's electrical power) are
cross-correlated: :func:`detect_lag` gives the time to add to one to line it up with the other. On
recordings of an hour or more the drift is the slope of the offsets found in consecutive 15-minute windows.

The vehicle's speed comes from its wheels, which slip on the rollers in proportion to the force they pass
(a fraction of a percent at cruise, 1-3 % in a hard acceleration): the difference to the roller speed then
follows the acceleration and a plain cross-correlation takes it for a time shift (65 ms on the quick
campaign's high-fidelity vehicle). :func:`slip_aware_lag` refines the lag with the slip in the model,
``v_wheel(t) = v_roller(t + lag) (g + k_f F_front + k_r F_rear) + c`` (forces on the dyno's clock), the lag
the one whose least-squares residual is smallest.
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np

from benchtwin.recording import Recording

__all__ = ["DRIFT_WINDOW_S", "clock_offsets", "detect_lag", "slip_aware_lag"]



def detect_lag(t_a: np.ndarray, x_a: np.ndarray, t_b: np.ndarray, x_b: np.ndarray, *, rate_hz: float = 100.0,
               max_lag_s: float = 2.0, min_correlation: float = 0.6,
               window: tuple[float, float] | None = None) -> float | None:
    """Time to add to ``a``'s timestamps to line signal ``a`` up with ``b``.

    Normalised cross-correlation (Pearson coefficient per lag) of ``a`` over the common span
    (or ``window`` of ``a``'s time) against ``b`` shifted by up to ``+-max_lag_s`` on a ``rate_hz``
    grid, refined by a parabola through the peak. Returns None if the signals do not overlap
    enough, are flat, or the best correlation is below ``min_correlation`` (not the same quantity).
    """
    if window is not None:  # cut to the window first: the rest of the work is then small
        a0, a1 = np.searchsorted(t_a, [window[0] - max_lag_s, window[1] + max_lag_s])
        b0, b1 = np.searchsorted(t_b, [window[0] - 2 * max_lag_s, window[1] + 2 * max_lag_s])
        t_a, x_a, t_b, x_b = t_a[a0:a1], x_a[a0:a1], t_b[b0:b1], x_b[b0:b1]
    good_a, good_b = np.isfinite(x_a), np.isfinite(x_b)
    t_a, x_a, t_b, x_b = t_a[good_a], x_a[good_a], t_b[good_b], x_b[good_b]
    if t_a.size < 10 or t_b.size < 10:
        return None
    lo, hi = max(t_a[0], t_b[0]) + max_lag_s, min(t_a[-1], t_b[-1]) - max_lag_s
    if window is not None:
        lo, hi = max(lo, window[0]), min(hi, window[1])
    if hi - lo < 4 * max_lag_s:
        return None
    if hi - lo > 3600.0:  # the central hour of a long recording is plenty
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 1800.0, mid + 1800.0
    m = round(max_lag_s * rate_hz)
    grid = np.arange(lo, hi, 1.0 / rate_hz)
    a = np.interp(grid, t_a, x_a)
    a = a - a.mean()
    ext = np.concatenate([grid[0] - np.arange(m, 0, -1) / rate_hz, grid, grid[-1] + np.arange(1, m + 1) / rate_hz])
    b = np.interp(ext, t_b, x_b)
    n = a.size
    ea = float(np.dot(a, a))
    if ea == 0:
        return None
    from scipy.signal import correlate

    cov = correlate(b, a, mode="valid", method="fft")  # cov[j] = sum a[i] b[i + j], j = 0..2m
    cs, cs2 = np.concatenate([[0.0], np.cumsum(b)]), np.concatenate([[0.0], np.cumsum(b * b)])
    s1 = cs[n:n + 2 * m + 1] - cs[:2 * m + 1]
    s2 = cs2[n:n + 2 * m + 1] - cs2[:2 * m + 1]
    var = s2 - s1 * s1 / n
    with np.errstate(invalid="ignore", divide="ignore"):
        r = cov / np.sqrt(np.clip(var, 1e-300, None) * ea)
    k = int(np.nanargmax(r))
    if not r[k] >= min_correlation:
        return None
    frac = 0.0
    if 0 < k < r.size - 1:
        den = r[k - 1] - 2 * r[k] + r[k + 1]
        frac = 0.5 * (r[k - 1] - r[k + 1]) / den if den != 0 else 0.0
    return float((k - m + frac) / rate_hz)


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
    if hi - lo > 3600.0:
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 1800.0, mid + 1800.0
    if hi - lo < 20.0:
        return lag0
    grid = np.arange(lo, hi, 1.0 / rate_hz)
    a = np.interp(grid, t_a, x_a)
    lags = lag0 + np.arange(-round(search_s * rate_hz), round(search_s * rate_hz) + 1) / rate_hz
    ssr = np.empty(lags.size)
    for j, lag in enumerate(lags):
        b = np.interp(grid + lag, t_b, x_b)
        cols = [b, np.ones_like(b)] + [b * np.interp(grid + lag, tf, f) for tf, f in forces]
        design = np.column_stack(cols)
        good = np.isfinite(a) & np.all(np.isfinite(design), axis=1)
        if good.sum() < 10 * design.shape[1]:
            return lag0
        dg, ag = design[good], a[good]
        scale = np.maximum(np.abs(dg).max(axis=0), 1e-300)  # normal equations of the column-scaled design
        dn = dg / scale
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


def _pairs(rec: Recording) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray, list]]:
    """Signal pairs that measure one quantity on two sources: (key, t_a, x_a, t_b, x_b, forces), ``forces``
    the axle forces on ``b``'s clock when ``a`` is a wheel speed that slips (else empty)."""
    out = []
    if "vehicle_speed_kmh" in rec and "dyno_speed_kmh" in rec:
        a, b = rec["vehicle_speed_kmh"], rec["dyno_speed_kmh"]
        forces = [(rec[n].timestamps, rec[n].values) for n in ("dyno_force_front_n", "dyno_force_rear_n")
                  if n in rec and rec[n].source == b.source]
        out.append(("vehicle_can->dyno", a.timestamps, a.values, b.timestamps, b.values, forces))
    if "em_torque_nm" in rec and "em_speed_rpm" in rec:
        power_name = "hpcu_power_w" if "hpcu_power_w" in rec else "battery_power_w"
        if power_name in rec:
            tq, sp, p = rec["em_torque_nm"], rec["em_speed_rpm"], rec[power_name]
            mech = tq.values * np.interp(tq.timestamps, sp.timestamps, sp.values) * (2 * np.pi / 60.0)
            out.append((f"vehicle_can->{p.source}", tq.timestamps, mech, p.timestamps, p.values, []))
    return out


def clock_offsets(rec: Recording) -> tuple[dict[str, float], dict[str, float]]:
    """Offsets (s) and, on recordings long enough, relative drifts (ppm) between sources."""
    offsets: dict[str, float] = {}
    drifts: dict[str, float] = {}
    for key, t_a, x_a, t_b, x_b, forces in _pairs(rec):
        lag = detect_lag(t_a, x_a, t_b, x_b)
        if lag is None:
            continue
        if forces:
            lag = slip_aware_lag(t_a, x_a, t_b, x_b, forces, lag)
        offsets[key] = lag
        t0, t1 = max(t_a[0], t_b[0]), min(t_a[-1], t_b[-1])
        n_win = int((t1 - t0) // DRIFT_WINDOW_S)
        if n_win >= 4:  # offset per window, drift = slope of a straight line through them
            edges = np.linspace(t0, t1, n_win + 1)
            pts = [(0.5 * (a + b), detect_lag(t_a, x_a, t_b, x_b, window=(a, b), rate_hz=20.0))
                   for a, b in pairwise(edges)]
            pts = [(c, lag_w) for c, lag_w in pts if lag_w is not None]
            if len(pts) >= 3 and pts[-1][0] - pts[0][0] >= 2 * DRIFT_WINDOW_S:
                c, lw = np.array(pts).T
                drifts[key] = float(np.polyfit(c, lw, 1)[0] * 1e6)
    return offsets, drifts


