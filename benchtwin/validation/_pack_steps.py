"""The map-based vehicle model's pack, step by step, compiled (numba): each step's SOC is the last one's."""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

__all__ = ["battery_steps", "battery_steps_rc", "rc_model", "rc_model_note"]


def battery_steps(p_w: np.ndarray, dt_s: float, soc0_pct: float, nodes: np.ndarray, ocv_cell: np.ndarray,
                  r_dch: np.ndarray, r_ch: np.ndarray, n_cells: float, soc_per_ah: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The step-by-step pack of :meth:`benchtwin.validation.predict.MapVehicle.battery` (eq. 30): each step's SOC
    is the last one's. :func:`battery_steps_rc` without branches or temperature term, whose floating-point
    operations are then eq. 30's own. Returns the current, terminal voltage and SOC per step.
    """
    none = np.zeros(0)
    return battery_steps_rc(p_w, dt_s, soc0_pct, nodes, ocv_cell, r_dch, r_ch, n_cells, soc_per_ah, none, none,
                            r_dch, r_ch, 0.0, 0.0, np.zeros(p_w.size))


@numba.njit(cache=True, nogil=True)
def battery_steps_rc(p_w: np.ndarray, dt_s: float, soc0_pct: float, nodes: np.ndarray, ocv_cell: np.ndarray,
                     r_dch: np.ndarray, r_ch: np.ndarray, n_cells: float, soc_per_ah: float, r_rc: np.ndarray,
                     tau_rc: np.ndarray, r_lit_dch: np.ndarray, r_lit_ch: np.ndarray, beta_temp_per_k: float,
                     t_ref_degc: float, temp_degc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`battery_steps` with RC branches (``battery.rc``): ``V/n = OCV - I R_0 - sum u_k``.

    ``R_0 = R(s) + beta_temp_per_k (t_ref - T) R_lit(s)`` per direction, ``T`` the pack temperature per step
    (``beta_temp_per_k`` 0: no temperature term).

    Each branch's state is the current through a first-order filter, ``x_k = a x_k' + (1 - a) I``,
    ``a = exp(-dt / tau_k)``, ``u_k = R_k x_k`` (the discretisation the fit used); the step's current solves
    ``P / n = (OCV - sum R_k a x_k' - I (R_0 + sum R_k (1 - a))) I``. The states start at 0 (a rested pack).
    ``r_rc`` and ``tau_rc`` are per cell, one entry per branch.
    """
    n = p_w.size
    nb = r_rc.size
    i_out = np.zeros(n)
    v_out = np.zeros(n)
    s_out = np.zeros(n + 1)
    x = np.zeros(nb)
    a = np.zeros(nb)
    for b in range(nb):
        a[b] = math.exp(-dt_s / tau_rc[b])
    s = soc0_pct
    for k in range(n):
        p = p_w[k]
        ocv = np.interp(s, nodes, ocv_cell)
        r = np.interp(s, nodes, r_dch) if p > 0 else np.interp(s, nodes, r_ch)
        if beta_temp_per_k != 0.0:
            r_lit = np.interp(s, nodes, r_lit_dch) if p > 0 else np.interp(s, nodes, r_lit_ch)
            r += beta_temp_per_k * (t_ref_degc - temp_degc[k]) * r_lit
        off = 0.0
        r_eff = r
        for b in range(nb):
            off += r_rc[b] * a[b] * x[b]
            r_eff += r_rc[b] * (1.0 - a[b])
        e = ocv - off
        pc = p / n_cells
        disc = e * e - 4.0 * r_eff * pc
        i = (e - math.sqrt(disc)) / (2.0 * r_eff) if disc > 0 and r_eff > 0 else pc / e
        for b in range(nb):
            x[b] = a[b] * x[b] + (1.0 - a[b]) * i
        s_out[k] = s
        i_out[k] = i
        v_out[k] = (e - i * r_eff) * n_cells
        s -= soc_per_ah * i * dt_s / 3600.0
    s_out[n] = s
    return i_out, v_out, s_out[1:]


def rc_model(rc: Any) -> dict[str, Any] | None:
    """The pack of a ``battery.rc`` fit for :func:`battery_steps_rc`, or None to keep eq. 30.

    None when there is no such fit, it is flagged, or it kept no RC branch (a static pack). Otherwise the
    ``R_0`` maps (a direction that was not identified borrows the other's), the OCV map, ``r_rc`` and
    ``tau_rc`` per branch and a ``note`` for the prediction.
    """
    nb = int(rc.data.get("n_branches", 0)) if rc is not None else 0
    if rc is None or rc.status != "ok" or nb == 0:
        return None
    r_d, r_c = (np.asarray(rc.data[k], float) for k in ("map_r_dch", "map_r_ch"))
    r_rc = np.array([rc.value(f"r{k + 1}_ohm") for k in range(nb)])
    tau_rc = np.array([rc.value(f"tau{k + 1}_s") for k in range(nb)])
    k_t = rc.value("beta_temp_per_k") if "beta_temp_per_k" in rc.params else 0.0
    note = "battery: battery.rc, R_0" + (f" (with {k_t:.3g}/K x (25 degC - T) on beta, T the drive's pack temperature)"
                                         if k_t else "") + " and " + ", ".join(
        f"R {r * 1e3:.3g} mohm / tau {tau:.3g} s" for r, tau in zip(r_rc, tau_rc, strict=True)) + " per cell"
    ok_d = np.all(np.isfinite(r_d))
    ok_c = np.all(np.isfinite(r_c))
    lit_d, lit_c = (np.asarray(rc.data[k], float) for k in ("lit_r_dch", "lit_r_ch"))
    return {"ocv": np.asarray(rc.data["map_ocv"], float), "r_dch": r_d if ok_d else r_c, "r_ch": r_c if ok_c else r_d,
            "r_rc": r_rc, "tau_rc": tau_rc, "note": note, "r_lit_dch": lit_d if ok_d else lit_c,
            "r_lit_ch": lit_c if ok_c else lit_d, "beta_temp_per_k": float(k_t),
            "t_ref_degc": float(rc.data["t_ref_degc"]), "temp_mean_degc": float(rc.data["temp_mean_degc"])}


def rc_model_note(rc: Any) -> str:
    """The prediction's note when :func:`rc_model` keeps eq. 30."""
    if rc is None:
        return "battery: eq. 30 (static), battery.rc not identified"
    return "battery: eq. 30 (static), battery.rc not used: " + ("; ".join(rc.reasons) or "no RC branch kept")
