"""Reading the identified BSFC map as a fuel mean effective pressure (the map-based model and the cold-start factor)."""

from __future__ import annotations

import numpy as np

_RPM = np.pi / 30.0


def fuel_map_gps(pmf_speed: np.ndarray, pmf_bmep: np.ndarray, pmf: np.ndarray, displacement_m3: float,
                 strokes: float, lhv_j_per_kg: float, speed_rpm: np.ndarray, torque_nm: np.ndarray) -> np.ndarray:
    """Fuel mass flow (g/s) of the firing engine from a fuel MEP map over speed x BMEP.

    The map is read bilinearly (speed clamped to the map); below its lowest BMEP row the fuel MEP goes on
    linearly to zero load (the Willans form of a diesel), and a motoring engine (torque <= 0) burns the
    zero-load flow.

    Parameters
    ----------
    pmf_speed, pmf_bmep:
        The map's speed nodes (rpm, increasing) and BMEP rows (bar, increasing, at least two).
    pmf:
        Fuel mean effective pressure (bar), rows BMEP, columns speed.
    displacement_m3, strokes, lhv_j_per_kg:
        Engine displacement, strokes per cycle and the fuel's lower heating value (public specs).
    speed_rpm, torque_nm:
        Engine speed and brake torque per sample.
    """
    n = np.asarray(speed_rpm, float)
    vd, k = displacement_m3, strokes
    # BMEP = pi k T / V_d (k strokes: 4 pi T / V_d for a four-stroke)
    b = np.maximum(np.asarray(torque_nm, float), 0.0) * (np.pi * k) / vd / 1e5
    sg, bg, P = pmf_speed, pmf_bmep, pmf
    nc = np.clip(n, sg[0], sg[-1])
    j = np.clip(np.searchsorted(sg, nc) - 1, 0, sg.size - 2)
    u = (nc - sg[j]) / (sg[j + 1] - sg[j])
    col = P[:, j] * (1 - u) + P[:, j + 1] * u  # (n_bmep, n_samples)
    bc = np.clip(b, bg[0], bg[-1])
    i = np.clip(np.searchsorted(bg, bc) - 1, 0, bg.size - 2)
    idx = np.arange(n.size)
    w = (bc - bg[i]) / (bg[i + 1] - bg[i])
    pm = col[i, idx] * (1 - w) + col[i + 1, idx] * w
    low = b < bg[0]
    if low.any():  # linear towards zero load with the slope of the two lowest rows
        slope = (col[1, idx] - col[0, idx]) / (bg[1] - bg[0])
        pm = np.where(low, col[0, idx] + slope * (b - bg[0]), pm)
    pm = np.maximum(pm, 0.0)
    p_fuel_w = pm * 1e5 * vd / (np.pi * k) * n * _RPM
    return p_fuel_w / lhv_j_per_kg * 1e3


def map_pmf(bsfc_data: dict, lhv_j_per_kg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The identified BSFC map (``engine.bsfc`` data) as fuel MEP: ``(speed nodes, BMEP rows, pmf)``.

    ``None`` when the map is missing or has fewer than two usable BMEP rows.
    """
    if not all(k in bsfc_data for k in ("map_speed_rpm", "map_bmep_bar", "map_bsfc")):
        return None
    sg = np.asarray(bsfc_data["map_speed_rpm"], float)
    bg = np.asarray(bsfc_data["map_bmep_bar"], float)
    z = np.asarray(bsfc_data["map_bsfc"], float)
    if z.shape != (bg.size, sg.size):
        z = z.T
    q = 3.6e9 / lhv_j_per_kg
    with np.errstate(invalid="ignore"):
        pmf = z * bg[:, None] / q  # fuel mean effective pressure, bar (rows BMEP, columns speed)
    keep = np.all(np.isfinite(pmf), axis=1) & (bg > 0)
    if keep.sum() < 2:
        return None
    return sg, bg[keep], pmf[keep]
