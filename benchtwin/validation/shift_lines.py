"""Gears from identified shift lines (the map-based model's ``gear_source="shift_lines"``).

The lines give the *target* gear (they are fitted where ``gear_target`` changes, :mod:`~benchtwin.identification.
shifts`); the gearbox engages it one gear at a time, each after the actuation delay
(:mod:`~benchtwin.identification.shift_delay`). Without that delay every upshift of a drive comes early: on the
WLTC held out of the paper campaign (high-fidelity truth) 158 shifts x 0.34 s put ~7 s of firing engine into the
next gear up, at a lower speed, and the predicted fuel 1 % below the recorded-gear prediction.
"""

from __future__ import annotations

import numpy as np

__all__ = ["actuated_gears", "shift_line_gears"]


def actuated_gears(target: np.ndarray, dt_s: float, delay_s: float, change_s: np.ndarray | None = None) -> np.ndarray:
    """The engaged gear that follows a target gear one gear at a time, each step ``delay_s`` after the last.

    A target change happens at ``change_s`` (s, from -dt to 0) relative to the sample that first shows it; by
    default half a sample before it (somewhere in the interval). The gear steps at the first sample at or past that
    time plus ``delay_s``, and again ``delay_s`` after each step while the target is still elsewhere. Neutral (0)
    in the target is engaged at once and the gear leaving it is the target's (a recorded neutral is replayed, with
    its own timing).

    Parameters
    ----------
    target:
        Target gear per sample (0 neutral).
    dt_s:
        Sample interval, s (> 0).
    delay_s:
        Actuation delay, s (>= 0; 0: the target itself).
    change_s:
        Per sample, when the target's change it first shows happened, relative to the sample (s, clipped to
        ``[-dt_s, 0]``; NaN or None: ``-dt_s / 2``).

    Returns
    -------
    numpy.ndarray
        Engaged gear per sample.

    Raises
    ------
    ValueError
        ``dt_s`` not positive or ``delay_s`` negative or not finite.
    """
    if not (np.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"actuated_gears: dt_s must be > 0, got {dt_s}")
    if not (np.isfinite(delay_s) and delay_s >= 0):
        raise ValueError(f"actuated_gears: delay_s must be finite and >= 0, got {delay_s}")
    tg = np.asarray(target).astype(int)
    out = tg.copy()
    if delay_s == 0 or tg.size == 0:
        return out
    g = int(tg[0])
    due = float("nan")  # when the next one-gear step is due (s from the first sample)
    for k in range(tg.size):
        t = k * dt_s
        if tg[k] == 0 or g == 0:
            g, due = int(tg[k]), float("nan")
        elif tg[k] == g:
            due = float("nan")
        else:
            if not np.isfinite(due):
                c = float(change_s[k]) if change_s is not None and np.isfinite(change_s[k]) else -0.5 * dt_s
                due = t + min(max(c, -dt_s), 0.0) + delay_s
            if t >= due - 1e-9:
                g += 1 if tg[k] > g else -1
                due = due + delay_s if tg[k] != g else float("nan")
        out[k] = g
    return out


def shift_line_gears(shift_lines: dict[tuple[int, str], tuple[float, float]], n_gears: int, speed_kmh: np.ndarray,
                     pedal_pct: np.ndarray, recorded_gear: np.ndarray, *, delay_s: float = 0.0,
                     dt_s: float | None = None) -> np.ndarray:
    """Gears from shift lines ``v = c0 + c1 pedal`` with hysteresis between up and down lines.

    Parameters
    ----------
    shift_lines:
        ``(gear, "up" | "down") -> (c0_kmh, c1_kmh_per_pct)``; a missing line is never crossed.
    n_gears:
        Number of forward gears.
    speed_kmh, pedal_pct:
        The recorded vehicle speed and accelerator pedal per sample.
    recorded_gear:
        The recorded gear: neutral (0) is kept, and its first sample (at least 1) is the starting gear.
    delay_s:
        The gearbox's actuation delay (s): the engaged gear follows the lines' target gear by
        :func:`actuated_gears`; 0 (default): the target gear itself.
    dt_s:
        Sample interval (s); needed when ``delay_s > 0``. A line crossed between two samples is crossed at the
        time the speed and pedal, linear between them, reach it; the delay counts from there.

    Returns
    -------
    numpy.ndarray
        Gear per sample (0 neutral; the target is 1 below 1 km/h).

    Raises
    ------
    ValueError
        ``delay_s > 0`` without a positive ``dt_s``.
    """
    rec = np.asarray(recorded_gear).astype(int)
    g = max(int(rec[0]), 1)
    out = np.zeros(rec.size, dtype=int)
    change = np.full(rec.size, np.nan)  # when a line was crossed, relative to the sample that shows the new target
    for k in range(rec.size):
        v, p = speed_kmh[k], pedal_pct[k]
        if rec[k] == 0:
            out[k] = 0
            continue
        if k > 0 and dt_s is not None:
            change[k] = _crossing_s(shift_lines, g, n_gears, speed_kmh[k - 1:k + 1], pedal_pct[k - 1:k + 1], dt_s)
        for _ in range(n_gears):
            up = shift_lines.get((g, "up"))
            down = shift_lines.get((g, "down"))
            if g < n_gears and up is not None and v >= up[0] + up[1] * p:
                g += 1
            elif g > 1 and down is not None and v <= down[0] + down[1] * p:
                g -= 1
            else:
                break
        if v < 1.0:
            g = 1
        out[k] = g
    if delay_s > 0:
        if dt_s is None:
            raise ValueError("shift_line_gears: delay_s > 0 needs the sample interval dt_s")
        out = actuated_gears(out, dt_s, delay_s, change)
    return out


def _crossing_s(shift_lines: dict[tuple[int, str], tuple[float, float]], g: int, n_gears: int, v: np.ndarray,
                p: np.ndarray, dt_s: float) -> float:
    """When, relative to the second of two samples, the speed crossed gear ``g``'s up or down line (linear
    between the samples: the lines are identified at the crossing's time, :mod:`~benchtwin.identification.shifts`);
    NaN when neither line was crossed from the first sample to the second."""
    for direction, sign in (("up", 1.0), ("down", -1.0)):
        line = shift_lines.get((g, direction))
        if line is None or (direction == "up" and g >= n_gears) or (direction == "down" and g <= 1):
            continue
        s0 = sign * (v[0] - line[0] - line[1] * p[0])
        s1 = sign * (v[1] - line[0] - line[1] * p[1])
        if s0 < 0.0 <= s1:
            return -dt_s * s1 / (s1 - s0)
    return float("nan")
