"""The map-based vehicle model's pack, step by step, compiled (numba): each step's SOC is the last one's."""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["battery_steps"]


@numba.njit(cache=True, nogil=True)
def battery_steps(p_w: np.ndarray, dt_s: float, soc0_pct: float, nodes: np.ndarray, ocv_cell: np.ndarray,
                   r_dch: np.ndarray, r_ch: np.ndarray, n_cells: float, soc_per_ah: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The step-by-step pack of :meth:`benchtwin.validation.predict.MapVehicle.battery`.

    Each step's SOC is the last one's; compiled, with the same floating-point operations as the loop over
    ``np.interp`` it replaces, so the same numbers. Returns the current, terminal voltage and SOC per step.
    """
    n = p_w.size
    i_out = np.zeros(n)
    v_out = np.zeros(n)
    s_out = np.zeros(n + 1)
    s = soc0_pct
    for k in range(n):
        p = p_w[k]
        ocv = np.interp(s, nodes, ocv_cell)
        r = np.interp(s, nodes, r_dch) if p > 0 else np.interp(s, nodes, r_ch)
        pc = p / n_cells
        disc = ocv * ocv - 4.0 * r * pc
        i = (ocv - math.sqrt(disc)) / (2.0 * r) if disc > 0 and r > 0 else pc / ocv
        s_out[k] = s
        i_out[k] = i
        v_out[k] = (ocv - i * r) * n_cells
        s -= soc_per_ah * i * dt_s / 3600.0
    s_out[n] = s
    return i_out, v_out, s_out[1:]
