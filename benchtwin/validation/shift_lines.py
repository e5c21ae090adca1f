"""Gears from identified shift lines (the map-based model's ``gear_source="shift_lines"``)."""

from __future__ import annotations

import numpy as np


def shift_line_gears(shift_lines: dict[tuple[int, str], tuple[float, float]], n_gears: int, speed_kmh: np.ndarray,
                     pedal_pct: np.ndarray, recorded_gear: np.ndarray) -> np.ndarray:
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

    Returns
    -------
    numpy.ndarray
        Gear per sample (0 neutral; 1 below 1 km/h).
    """
    rec = np.asarray(recorded_gear).astype(int)
    g = max(int(rec[0]), 1)
    out = np.zeros(rec.size, dtype=int)
    for k in range(rec.size):
        v, p = speed_kmh[k], pedal_pct[k]
        if rec[k] == 0:
            out[k] = 0
            continue
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
    return out
