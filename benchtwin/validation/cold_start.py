"""The map-based model's cold engine: the identified cold-start fuel factor on a coolant temperature it predicts.

The factor ``engine.cold_fuel`` (``1 + k max(0, T_warm - T)``) and the coolant's lumped warm-up ``engine.warmup``
(``dT/dt = h P_heat - g T + c`` below the regulated level ``T_reg``, held there above;
:mod:`benchtwin.identification.engine_cold`) are integrated together over the drive from its first coolant
reading (a boundary condition, as the drive's ambient): the recorded coolant trajectory is never read. The heat is
the fuel power (warm map x factor) less the brake power of the firing engine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from benchtwin.identification._fit import IdentificationResult
from benchtwin.identification.engine_cold import COLD_KEY, WARMUP_KEY
from benchtwin.identification.engine_start import START_KEY

__all__ = ["ColdStart", "cold_start_model", "start_fuel_model"]


@dataclass(frozen=True)
class ColdStart:
    """The identified factor and warm-up (see the module)."""

    k_per_k: float
    t_warm_degc: float
    h_k_per_j: float
    g_per_s: float
    c_k_per_s: float
    t_reg_degc: float

    def run(self, warm_fuel_gps: np.ndarray, brake_power_w: np.ndarray, firing: np.ndarray, dt_s: float,
            coolant0_degc: float, lhv_j_per_kg: float) -> tuple[np.ndarray, np.ndarray]:
        """Fuel flow with the factor (g/s) and the predicted coolant temperature (degC), per sample.

        Parameters
        ----------
        warm_fuel_gps:
            The warm map's fuel flow of the firing engine (0 when off).
        brake_power_w:
            The engine's brake power.
        firing:
            Engine on (bool per sample).
        dt_s, coolant0_degc, lhv_j_per_kg:
            Time step, the drive's first coolant reading, the fuel's lower heating value.
        """
        wf = np.asarray(warm_fuel_gps, float)
        pb = np.maximum(np.asarray(brake_power_w, float), 0.0)
        on = np.asarray(firing, bool)
        fuel = np.empty_like(wf)
        temp = np.empty_like(wf)
        t = float(coolant0_degc)
        for i in range(wf.size):
            temp[i] = t
            f = wf[i] * (1.0 + self.k_per_k * max(self.t_warm_degc - t, 0.0)) if on[i] else 0.0
            fuel[i] = f
            heat = max(f * 1e-3 * lhv_j_per_kg - pb[i], 0.0) if on[i] else 0.0
            t = min(t + dt_s * (self.h_k_per_j * heat - self.g_per_s * t + self.c_k_per_s), max(self.t_reg_degc, t))
        return fuel, temp


def cold_start_model(result: IdentificationResult) -> tuple[ColdStart | None, str]:
    """The cold-start model when the factor is significant and the warm-up identified, and a note saying which."""
    cf, wu = result.fits.get(COLD_KEY), result.fits.get(WARMUP_KEY)
    if cf is None or cf.status != "ok" or not bool(np.all(np.asarray(cf.data.get("use", [False])))):
        why = "not identified" if cf is None else ("; ".join(cf.reasons) or "not significant (k's 95 % interval "
                                                   "reaches zero)")
        return None, f"no cold-start fuel factor ({COLD_KEY}: {why}): the warm map at every coolant temperature"
    if wu is None or wu.status != "ok":
        return None, f"no cold-start fuel factor: {WARMUP_KEY} (the coolant's warm-up) not identified"
    vals = [cf.value("k"), float(np.asarray(cf.data["T_warm_degc"]).ravel()[0]), wu.value("h"), wu.value("g"),
            wu.value("c"), float(np.asarray(wu.data["T_reg_degc"]).ravel()[0])]
    if not all(math.isfinite(v) for v in vals):
        return None, f"no cold-start fuel factor: {COLD_KEY} or {WARMUP_KEY} not finite"
    m = ColdStart(*vals)
    return m, (f"cold-start fuel factor 1 + {m.k_per_k:.4f} max(0, {m.t_warm_degc:.0f} degC - T) ({COLD_KEY}) on "
               f"a coolant temperature predicted by the identified warm-up ({WARMUP_KEY}: T_env "
               f"{wu.value('T_env_degc'):.1f} degC, regulated at {m.t_reg_degc:.1f} degC) from the drive's first "
               "coolant reading")


def start_fuel_model(result: IdentificationResult) -> tuple[float | None, str]:
    """The fuel of one engine start (g) when ``engine.start_fuel`` is used (enough starts, significant), and a
    note saying which."""
    sf = result.fits.get(START_KEY)
    if sf is None or sf.status != "ok" or not bool(np.all(np.asarray(sf.data.get("use", [False])))):
        why = "not identified" if sf is None else ("; ".join(sf.reasons) or "not significant")
        return None, f"no engine-start fuel ({START_KEY}: {why}): an engine start burns no more than the map"
    m = sf.value("m_g")
    if not (math.isfinite(m) and m > 0):
        return None, f"no engine-start fuel: {START_KEY} = {m} g"
    se = sf.params["m_g"].std_error
    n = int(np.asarray(sf.data.get("n_starts", [0])).ravel()[0])
    return m, (f"engine-start fuel {m:.3f} +- {se:.3f} g per start of the replayed strategy ({START_KEY}, the mean "
               f"over {n} starts of the campaign)")
