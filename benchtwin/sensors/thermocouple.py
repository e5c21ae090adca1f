"""Type K thermocouples on a CANopen thermo module with cold-junction compensation.

Per input: the probe's junction temperature ``T`` (with the probe's errors and time constant)
gives the thermoelectric voltage ``E(T) - E(T_cj)`` at the module terminals (ITS-90 type K reference
function, NIST Monograph 175, coefficients of the ``thermocouple-its90`` package evaluated with
numpy); the module quantises it (``emf_resolution_uv``), adds ``E(T_cj_measured)`` from its own
cold-junction sensor, inverts the reference function (NIST inverse polynomial refined by Newton
steps) and publishes ``T`` in 0.1 degC in object 0x9130 (INTEGER16; 0x7FFF above range,
-0x8000 below range or open). The cold-junction temperature goes to 0x2100.
"""

from __future__ import annotations

import numpy as np
from thermocouple_its90._data import TYPES as _ITS90

from benchtwin.chain.canopen_pdo import AI_OVERLOAD_NEG, AI_OVERLOAD_POS, pdo_layout
from benchtwin.chain.frames import ProcessImage
from benchtwin.config.setup import ThermoConfig
from benchtwin.sensors.imperfections import DeviceClock, measure
from benchtwin.trace import Trace

__all__ = ["emf_type_k", "encode_thermo", "seebeck_type_k", "temperature_type_k"]

_K = _ITS90["K"]
_T_MIN, _T_MAX = -270.0, 1372.0


def _forward(t: np.ndarray, derivative: bool = False) -> np.ndarray:
    out = np.full(t.shape, np.nan)
    for seg in _K["forward"]:
        lo, hi = seg["t_min_c"], seg["t_max_c"]
        m = (t >= lo) & (t <= hi) if lo < 0 else (t > lo) & (t <= hi)
        if not m.any():
            continue
        c = np.asarray(seg["coeffs"], dtype=np.float64)
        x = t[m]
        if derivative:
            v = np.polyval((c[1:] * np.arange(1, c.size))[::-1], x)
        else:
            v = np.polyval(c[::-1], x)
        ex = seg.get("exponential")
        if ex:
            g = ex["a0"] * np.exp(ex["a1"] * (x - ex["a2"]) ** 2)
            v = v + (g * 2.0 * ex["a1"] * (x - ex["a2"]) if derivative else g)
        out[m] = v
    return out


def emf_type_k(t_degc: np.ndarray) -> np.ndarray:
    """Type K thermoelectric voltage (mV, reference junction at 0 degC), -270..1372 degC; NaN outside."""
    return _forward(np.asarray(t_degc, dtype=np.float64))


def seebeck_type_k(t_degc: np.ndarray) -> np.ndarray:
    """dE/dT of the type K reference function, mV/degC."""
    return _forward(np.asarray(t_degc, dtype=np.float64), derivative=True)


def temperature_type_k(emf_mv: np.ndarray, newton_steps: int = 3) -> np.ndarray:
    """Invert the type K reference function: mV -> degC (inverse polynomial + Newton refinement)."""
    e = np.asarray(emf_mv, dtype=np.float64)
    t = np.full(e.shape, np.nan)
    for seg in _K["inverse"]:
        m = (e >= seg["mv_min"]) & (e <= seg["mv_max"])
        if m.any():
            t[m] = np.polyval(np.asarray(seg["coeffs"], dtype=np.float64)[::-1], e[m])
    # outside the inverse polynomials' span (below -200 degC): start from a linear guess
    rest = ~np.isfinite(t) & np.isfinite(e)
    t[rest] = np.clip(e[rest] / 0.0395, _T_MIN, _T_MAX)
    for _ in range(newton_steps):
        t = np.clip(t - (emf_type_k(t) - e) / seebeck_type_k(t), _T_MIN, _T_MAX)
    return t


def encode_thermo(trace: Trace, cfg: ThermoConfig, rng: np.random.Generator) -> ProcessImage:
    """The thermo module's object-dictionary values at each TPDO event (its own clock).

    Columns follow the EDS TPDO mapping (0x9130 sub 1..9, then 0x2100); inputs without a
    thermocouple read -0x8000 (open circuit).
    """
    layout = pdo_layout(cfg.node_id)
    clock = DeviceClock.of(cfg.link)
    t_dev = clock.ticks(float(trace.time_s[0]), float(trace.time_s[-1]) + 1e-9, cfg.pdo_period_ms / 1000.0)
    t = clock.to_plant(t_dev)
    n = t.shape[0]
    entries = layout.entries
    values = np.full((n, len(entries)), AI_OVERLOAD_NEG, dtype=np.int64)
    t_cj = cfg.cold_junction_degc
    e_cj_true = float(emf_type_k(np.array([t_cj]))[0])
    e_cj_meas = float(emf_type_k(np.array([t_cj + cfg.cold_junction_error_degc]))[0])
    for k, place in enumerate(cfg.places):
        temp = measure(trace.time_s, trace[place], t, cfg.errors, rng, latency_s=cfg.link.latency_s)
        v_term = emf_type_k(np.clip(temp, _T_MIN, _T_MAX)) - e_cj_true
        if cfg.emf_resolution_uv > 0:
            step = cfg.emf_resolution_uv * 1e-3
            v_term = np.rint(v_term / step) * step
        t_meas = temperature_type_k(v_term + e_cj_meas)
        col = entries.index((0x9130, k + 1))
        dec = 10.0 ** layout.decimals.get(k + 1, 1)
        raw = np.rint(t_meas * dec)
        raw = np.where(t_meas > cfg.range_max_degc, AI_OVERLOAD_POS, raw)
        raw = np.where((t_meas < cfg.range_min_degc) | ~np.isfinite(t_meas), AI_OVERLOAD_NEG, raw)
        values[:, col] = np.clip(raw, AI_OVERLOAD_NEG, AI_OVERLOAD_POS)
    if (0x2100, 0) in entries:
        values[:, entries.index((0x2100, 0))] = round((t_cj + cfg.cold_junction_error_degc) * 10.0)
    return ProcessImage("thermo", cfg.node_id, t_dev, entries, values)
