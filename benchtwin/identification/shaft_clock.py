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
not move it) refines the telemetry's shift when its slope is significant (``|drift| > sqrt(2) se``, the rule of
:func:`~benchtwin.identification._clock.source_shifts`): a drift the acquisition could not find. Without one the
acquisition's offset stands.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from benchtwin.identification._clock import ClockShift, Shift, to_ref, to_source
from benchtwin.identification._reuse import reused
from benchtwin.identification._windows import window_of
from benchtwin.lag import detect_lag
from benchtwin.recording import Recording

__all__ = ["MIN_TESTS", "ROLLER_FORCES", "roller_aligned_shifts"]

#: the dyno's axle-force channels whose sum the shaft torque is lined up with
ROLLER_FORCES = ("dyno_force_front_n", "dyno_force_rear_n")
#: least tests with a lag for a line through them (three: a slope and a spread about it)
MIN_TESTS = 3


def _window(rec: Recording, name: str, shift: Shift, lo: float, hi: float, ordered: dict[int, bool]
            ) -> tuple[np.ndarray, np.ndarray]:
    """Finite samples of channel ``name`` around reference times ``lo..hi``, their times on the reference clock
    (``ordered``: whether each channel is in time order, checked once for all the tests' windows, not per window)."""
    ch = rec[name]
    _, ts, vs, _fl = window_of(ch, float(to_source(lo, shift)), float(to_source(hi, shift)), ordered)
    good = np.isfinite(vs) & np.isfinite(ts)
    if not good.all():  # all finite (the usual case): the same samples without copying them first
        ts, vs = ts[good], vs[good]
    return np.asarray(to_ref(ts, shift), dtype=float), np.asarray(vs, dtype=float)


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


def _test_lags(rec: Recording, a: tuple[str, Shift], b: list[str], b_shift: Shift, rate_hz: float, max_lag_s: float,
               min_correlation: float, min_test_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Per test segment, where its lag holds (:func:`_where`) and the time to add to channel ``a`` (on the reference
    clock through its shift) to line it up with the sum of channels ``b`` (through ``b_shift``).

    A function of those channels, the shifts, the options and the segments' spans only: inside the type B re-runs
    (:func:`~benchtwin.identification._reuse.reusing`) it is computed once for the re-runs that do not move the
    channels (a gain of the engine torque moves neither the speeds nor the shaft torque nor the axle forces)."""
    key = (a, tuple(b), b_shift, rate_hz, max_lag_s, min_correlation, min_test_s,
           tuple((float(seg.start_s), float(seg.end_s)) for seg in rec.segments))
    return reused("test_lags", (rec[a[0]], *(rec[n] for n in b)), key,  # type: ignore[arg-type]
                  lambda: _test_lags_of(rec, a, b, b_shift, rate_hz, max_lag_s, min_correlation, min_test_s))


def _test_lags_of(rec: Recording, a: tuple[str, Shift], b: list[str], b_shift: Shift, rate_hz: float,
                  max_lag_s: float, min_correlation: float, min_test_s: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_test_lags` computed."""
    centres, lags = [], []
    margin = 2.0 * max_lag_s + 1.0
    ordered: dict[int, bool] = {}
    for seg in rec.segments:
        lo, hi = float(seg.start_s), float(seg.end_s)
        if not hi - lo >= min_test_s:
            continue
        t_a, x_a = _window(rec, a[0], a[1], lo - margin, hi + margin, ordered)
        t_b, x_b = _window(rec, b[0], b_shift, lo - 2 * margin, hi + 2 * margin, ordered)
        for extra in b[1:]:
            t_e, x_e = _window(rec, extra, b_shift, lo - 2 * margin, hi + 2 * margin, ordered)
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
    return np.asarray(centres, dtype=float), np.asarray(lags, dtype=float)


def _line(c: np.ndarray, lags: np.ndarray) -> tuple[float, float]:
    """Theil-Sen slope (s/s) of the tests' lags and half its 68.27 % interval (one standard deviation)."""
    from scipy.stats import theilslopes

    res = theilslopes(lags, c, alpha=0.6827)
    return float(res[0]), float(0.5 * (res[3] - res[2]))


def _affine(shift: Shift) -> tuple[float, float]:
    return (shift.offset_s, shift.rate) if isinstance(shift, ClockShift) else (float(shift), 0.0)


def roller_aligned_shifts(rec: Recording, shifts: Mapping[str, Shift], *, rate_hz: float = 100.0,
                          max_lag_s: float = 0.5, min_correlation: float = 0.8, min_test_s: float = 5.0
                          ) -> tuple[dict[str, Shift], str]:
    """The shifts with the shaft torque's source lined up with the dyno's axle forces test by test (module docstring).

    First the dyno's own clock: the acquisition's offset of the rollers against the vehicle CAN is slip-aware but
    finds a drift on an hour or more only, so per test the lag of the CAN's vehicle speed against the roller speed
    gives the dyno's drift (its Theil-Sen slope, applied when significant, about the time the acquisition's offset
    holds, ``meta["clock_offset_time_s"]``, so that offset stands there: a plain lag of a wheel speed carries the
    tyres' slip). Then the shaft torque against the axle forces on that clock.

    Parameters
    ----------
    rec:
        The Recording (``shaft_torque_nm``, ``dyno_force_front_n`` and optionally ``dyno_force_rear_n``, for the
        dyno's drift ``vehicle_speed_kmh`` and ``dyno_speed_kmh``; its test segments).
    shifts:
        Time to add to each source's timestamps (:func:`~benchtwin.identification._clock.source_shifts`).
    rate_hz, max_lag_s, min_correlation:
        The cross-correlation of each test (:func:`~benchtwin.lag.detect_lag`); a lag at the search's
        edge is no peak and is left out.
    min_test_s:
        Shorter tests are left out.

    Returns
    -------
    shifts, note
        The shifts with the shaft torque's source refined (a copy; unchanged without the channels, on one source,
        with fewer than :data:`MIN_TESTS` tests lined up, or when the tests' lags show no significant drift: the
        acquisition's offset then stands) and what was done ('' when nothing).
    """
    out = dict(shifts)
    if "shaft_torque_nm" not in rec or ROLLER_FORCES[0] not in rec:
        return out, ""
    tel, dyn = rec["shaft_torque_nm"].source, rec[ROLLER_FORCES[0]].source
    forces = [n for n in ROLLER_FORCES if n in rec and rec[n].source == dyn]
    if not tel or tel == dyn:
        return out, ""
    opts = (rate_hz, max_lag_s, min_correlation, min_test_s)
    s_dyn = shifts.get(dyn, 0.0)
    dyno_note = ""
    if "vehicle_speed_kmh" in rec and "dyno_speed_kmh" in rec and rec["dyno_speed_kmh"].source == dyn:
        v_src = rec["vehicle_speed_kmh"].source
        c, lg = _test_lags(rec, ("vehicle_speed_kmh", shifts.get(v_src, 0.0)), ["dyno_speed_kmh"], s_dyn, *opts)
        if lg.size >= MIN_TESTS:
            slope, se = _line(c, lg)
            if abs(slope) > np.sqrt(2.0) * se:
                times = rec.meta.get("clock_offset_time_s") if isinstance(rec.meta, dict) else None
                key = next((k for k in (times or {}) if k.endswith(f"->{dyn}") or k.startswith(f"{dyn}->")), None)
                t_ref = float(times[key]) if key is not None else float(np.median(c))
                c0, r0 = _affine(s_dyn)
                # the speed's lag against the rollers is the rollers' lag with the sign turned
                s_dyn = ClockShift(c0 + slope * t_ref, r0 - slope)
                dyno_note = (f"; the dyno's clock first: {-1e6 * slope:+.1f} +- {1e6 * se:.1f} ppm against the vehicle "
                             f"speed over {lg.size} tests")
    c, lg = _test_lags(rec, ("shaft_torque_nm", shifts.get(tel, 0.0)), forces, s_dyn, *opts)
    if lg.size < MIN_TESTS:
        return out, ""
    slope, se = _line(c, lg)
    if not abs(slope) > np.sqrt(2.0) * se:  # no drift the acquisition missed: its offset stands
        return out, ""
    c0, r0 = _affine(shifts.get(tel, 0.0))
    a = float(np.median(lg - slope * c))
    out[tel] = ClockShift(c0 + a, r0 + slope)
    return out, (f"the shaft torque's clock ({tel}) lined up with the dyno's axle forces over {lg.size} tests: "
                 f"{1e3 * a:+.1f} ms and {1e6 * slope:+.1f} +- {1e6 * se:.1f} ppm added to the acquisition's shift "
                 f"(lags {1e3 * lg.min():+.0f}..{1e3 * lg.max():+.0f} ms){dyno_note}")
