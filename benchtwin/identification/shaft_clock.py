"""The shaft torque's clock against the dyno's rollers, test by test.

The telemetry carries the shaft torque alone. The acquisition puts its clock on the vehicle CAN's through the drive
force the CAN's engine and motor torques give (:mod:`benchtwin.chain.alignment`): a proxy that, through the
converter's torque multiplication, the pump's inertia and the driveline's dynamics, leads or lags the shaft by tens
of ms from one test to the next, and that finds a drift only on recordings of an hour or more (four 15-minute
windows). A converter campaign of 28 minutes on a telemetry clock 37 ppm slow (property draw, 2026-11-25: the
8-speed diesel of ``tests/properties/examples/converter_shaft_clock_drift.json``) was taken with a constant offset of
-0.05 ms, while its shaft torque read from 6 ms early at the start to 48 ms late at the end; in a take-off the
turbine torque changes by 0.3-1.4 times itself per second, so the late passes' torque ratios were 1-6 % off and the
torque-ratio curve 3.6 % (the same draw with the telemetry clock not drifting: 1.3 %).

The dyno's axle forces carry the same drive torque past the final drive and the wheels, without the converter in
between, and the dyno's clock is lined up with the CAN's by the acquisition (roller against vehicle speed). Per test
segment, the lag of the shaft torque against the sum of the axle forces, both on the reference clock through the
acquisition's shifts, is the residual of the shaft torque's clock there (:func:`roller_aligned_shifts`); on that
draw the tests' lags lie on a line within a few ms (113 ms at the start to 180 ms at 1,480 s with the dyno's 120 ms
offset). A Theil-Sen line through them (a test whose correlation peak is a wrong one, a braked deceleration, does
not move it) refines the telemetry's shift: its slope applied when significant (``|drift| > sqrt(2) se``, the rule
of :func:`~benchtwin.identification._clock.source_shifts`), else the tests' median lag as a constant.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from benchtwin.chain.alignment import detect_lag
from benchtwin.identification._clock import ClockShift, Shift, to_ref, to_source
from benchtwin.identification._windows import window_of
from benchtwin.recording import Recording

__all__ = ["MIN_TESTS", "ROLLER_FORCES", "roller_aligned_shifts"]

#: the dyno's axle-force channels whose sum the shaft torque is lined up with
ROLLER_FORCES = ("dyno_force_front_n", "dyno_force_rear_n")
#: least tests with a lag for a line through them (three: a slope and a spread about it)
MIN_TESTS = 3


def _window(rec: Recording, name: str, shift: Shift, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Finite samples of channel ``name`` around reference times ``lo..hi``, their times on the reference clock."""
    ch = rec[name]
    _, ts, vs, _fl = window_of(ch, float(to_source(lo, shift)), float(to_source(hi, shift)))
    good = np.isfinite(vs) & np.isfinite(ts)
    return np.asarray(to_ref(ts[good], shift), dtype=float), np.asarray(vs[good], dtype=float)


def _where(t: np.ndarray, x: np.ndarray, lo: float, hi: float, step_s: float = 0.1) -> float:
    """The time a test's lag holds: the mean of ``lo..hi`` weighted by the squared rate of change of ``x`` on a
    ``step_s`` grid (where the signal moves, the cross-correlation finds its lag; a drifting clock's lag differs
    across a 100 s test by the drift times the distance, 1.2 ms for 40 ppm over 30 s), the centre when flat."""
    grid = np.arange(lo, hi, step_s)
    if grid.size < 3:
        return 0.5 * (lo + hi)
    w = np.diff(np.interp(grid, t, x)) ** 2
    total = float(w.sum())
    return float(np.sum(0.5 * (grid[1:] + grid[:-1]) * w) / total) if total > 0 else 0.5 * (lo + hi)


def roller_aligned_shifts(rec: Recording, shifts: Mapping[str, Shift], *, rate_hz: float = 100.0,
                          max_lag_s: float = 0.5, min_correlation: float = 0.8, min_test_s: float = 5.0
                          ) -> tuple[dict[str, Shift], str]:
    """The shifts with the shaft torque's source lined up with the dyno's axle forces test by test (module docstring).

    Parameters
    ----------
    rec:
        The Recording (``shaft_torque_nm``, ``dyno_force_front_n`` and optionally ``dyno_force_rear_n``, its test
        segments).
    shifts:
        Time to add to each source's timestamps (:func:`~benchtwin.identification._clock.source_shifts`).
    rate_hz, max_lag_s, min_correlation:
        The cross-correlation of each test (:func:`~benchtwin.chain.alignment.detect_lag`); a lag at the search's
        edge is no peak and is left out.
    min_test_s:
        Shorter tests are left out.

    Returns
    -------
    shifts, note
        The refined shifts (a copy; unchanged without the channels, on one source, or with fewer than
        :data:`MIN_TESTS` tests lined up) and what was done ('' when nothing).
    """
    out = dict(shifts)
    if "shaft_torque_nm" not in rec or ROLLER_FORCES[0] not in rec:
        return out, ""
    tel, dyn = rec["shaft_torque_nm"].source, rec[ROLLER_FORCES[0]].source
    forces = [n for n in ROLLER_FORCES if n in rec and rec[n].source == dyn]
    if not tel or tel == dyn:
        return out, ""
    s_tel, s_dyn = shifts.get(tel, 0.0), shifts.get(dyn, 0.0)
    centres, lags = [], []
    margin = 2.0 * max_lag_s + 1.0
    for seg in rec.segments:
        lo, hi = float(seg.start_s), float(seg.end_s)
        if not hi - lo >= min_test_s:
            continue
        t_a, x_a = _window(rec, "shaft_torque_nm", s_tel, lo - margin, hi + margin)
        t_b, x_b = _window(rec, forces[0], s_dyn, lo - 2 * margin, hi + 2 * margin)
        for extra in forces[1:]:
            t_e, x_e = _window(rec, extra, s_dyn, lo - 2 * margin, hi + 2 * margin)
            if t_e.size < 2:
                t_b = t_b[:0]
                break
            x_b = x_b + np.interp(t_b, t_e, x_e)
        if t_a.size < 10 or t_b.size < 10:
            continue
        lag = detect_lag(t_a, x_a, t_b, x_b, rate_hz=rate_hz, max_lag_s=max_lag_s, min_correlation=min_correlation,
                         window=(lo, hi))
        if lag is not None and abs(lag) < max_lag_s - 1.0 / rate_hz:
            centres.append(_where(t_a, x_a, lo, hi))
            lags.append(lag)
    if len(lags) < MIN_TESTS:
        return out, ""
    from scipy.stats import theilslopes

    c, lg = np.asarray(centres), np.asarray(lags)
    res = theilslopes(lg, c, alpha=0.6827)
    slope, se = float(res[0]), float(0.5 * (res[3] - res[2]))
    c0, r0 = (s_tel.offset_s, s_tel.rate) if isinstance(s_tel, ClockShift) else (float(s_tel), 0.0)
    if abs(slope) > np.sqrt(2.0) * se:
        a = float(np.median(lg - slope * c))
        out[tel] = ClockShift(c0 + a, r0 + slope)
        how = f"{1e3 * a:+.1f} ms and {1e6 * slope:+.1f} +- {1e6 * se:.1f} ppm"
    else:
        a = float(np.median(lg))
        out[tel] = c0 + a if r0 == 0.0 else ClockShift(c0 + a, r0)
        how = f"{1e3 * a:+.1f} ms (its drift {1e6 * slope:+.1f} +- {1e6 * se:.1f} ppm not significant)"
    return out, (f"the shaft torque's clock ({tel}) lined up with the dyno's axle forces over {lg.size} tests: "
                 f"{how} added to the acquisition's shift (lags {1e3 * lg.min():+.0f}..{1e3 * lg.max():+.0f} ms)")
