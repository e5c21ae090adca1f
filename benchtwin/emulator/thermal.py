"""Lumped thermal states for every thermocouple place of the Trace, driven by the loop's heat flows.

For the paper-form plant the thermal states do not feed back (no map of the vehicle file depends on
temperature), so they run after the loop over the output arrays. The high-fidelity plant (``fidelity =
"high"``) integrates the cell, engine-coolant and gearbox-oil temperatures inside the loop, where they feed
back (``steps_energy.hifi_thermal_step``), and its Trace takes the cell and coolant channels from there.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from benchtwin.config.vehicle import ThermalConfig

__all__ = ["simulate_thermal", "thermal_state"]

CP_COOLANT = 3600.0  # J/(kg K), water-glycol


@njit(cache=True)
def _thermal(dt, q_eng, q_mot, q_batt, q_trans, amb, state, th, c_eng, mdot_e, frac, ua_rad, c_b, ua_b, mdot_b, c_ed,
             ua_ed, mdot_ed, share, c_oil, ua_oil, out):
    n = q_eng.shape[0]
    te = state[0]
    tb = state[1]
    th_h = state[2]
    th_m = state[3]
    tloop = state[4]
    to = state[5]
    for i in range(n):
        # engine: block/coolant lump with a thermostat that opens over 8 K
        op = min(max((te - (th - 4.0)) / 8.0, 0.03), 1.0)
        q_rad = ua_rad * op * (te - amb)
        out[i, 0] = te - q_rad / (mdot_e * CP_COOLANT)  # coolant in (radiator return)
        out[i, 1] = te  # coolant out
        te += dt * (frac * max(q_eng[i], 0.0) - q_rad) / c_eng
        # HV battery: chiller keeps the coolant inlet a little above ambient
        tin_b = amb + 1.5
        qb = ua_b * (tb - tin_b)
        out[i, 2] = tb
        out[i, 3] = tin_b
        out[i, 4] = tin_b + qb / (mdot_b * CP_COOLANT)
        tb += dt * (q_batt[i] - qb) / c_b
        # e-drive loop: radiator -> HPCU -> motor
        q_h = ua_ed * (th_h - tloop)
        hout = tloop + q_h / (mdot_ed * CP_COOLANT)
        q_m = ua_ed * (th_m - hout)
        mout = hout + q_m / (mdot_ed * CP_COOLANT)
        out[i, 5] = tloop
        out[i, 6] = hout
        out[i, 7] = hout
        out[i, 8] = mout
        ql = max(q_mot[i], 0.0)
        th_h += dt * (share * ql - q_h) / (0.4 * c_ed)
        th_m += dt * ((1.0 - share) * ql - q_m) / (0.6 * c_ed)
        tloop += dt * (q_h + q_m - 4.0 * ua_ed * (tloop - amb)) / (0.3 * c_ed)
        # gearbox oil: heated by the gearbox loss, exchanging heat with the engine coolant
        out[i, 9] = to
        to += dt * (max(q_trans[i], 0.0) - ua_oil * (to - out[i, 1])) / c_oil
    state[0] = te
    state[1] = tb
    state[2] = th_h
    state[3] = th_m
    state[4] = tloop
    state[5] = to


def thermal_state(cfg: ThermalConfig, ambient_degc: float) -> np.ndarray:
    """The thermal lumps at the campaign start (engine below its thermostat, the rest at ambient)."""
    return np.array([cfg.engine_thermostat_degc - 8.0, ambient_degc, ambient_degc, ambient_degc, ambient_degc,
                     ambient_degc])


def simulate_thermal(cfg: ThermalConfig, dt: float, q_engine_w: np.ndarray, q_motor_w: np.ndarray,
                     q_battery_w: np.ndarray, ambient_degc: float, state: np.ndarray | None = None,
                     q_transmission_w: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Integrate the thermal lumps over the output time base.

    Parameters
    ----------
    cfg:
        Thermal parameters of the vehicle.
    dt:
        Output time step, s.
    q_engine_w, q_motor_w, q_battery_w:
        Heat released by the engine (fuel power minus brake power), the motor and inverter, the HV cells.
    ambient_degc:
        Test-cell temperature.
    state:
        The lumps' temperatures where the previous part of the campaign left them (:func:`thermal_state`),
        updated in place to where this part ends (a campaign run in parts equals it run whole); None: the
        campaign start.
    q_transmission_w:
        Gearbox loss (input power minus output power), heating the oil lump; None: no loss (the oil follows
        the engine coolant).

    Returns
    -------
    dict
        The thermocouple channels of the Trace (degC).
    """
    n = q_engine_w.shape[0]
    out = np.empty((n, 10))
    st = thermal_state(cfg, ambient_degc) if state is None else state
    q_trans = np.zeros(n) if q_transmission_w is None else np.ascontiguousarray(q_transmission_w, dtype=np.float64)
    _thermal(dt, np.ascontiguousarray(q_engine_w), np.ascontiguousarray(q_motor_w),
             np.ascontiguousarray(q_battery_w), q_trans, ambient_degc, st, cfg.engine_thermostat_degc,
             cfg.engine_heat_capacity_j_per_k, cfg.engine_coolant_flow_kgps, cfg.engine_heat_to_coolant_frac,
             cfg.engine_radiator_ua_w_per_k, cfg.battery_heat_capacity_j_per_k, cfg.battery_ua_w_per_k,
             cfg.battery_coolant_flow_kgps, cfg.edrive_heat_capacity_j_per_k, cfg.edrive_ua_w_per_k,
             cfg.edrive_coolant_flow_kgps, cfg.hpcu_share_of_motor_loss, cfg.gearbox_oil_heat_capacity_j_per_k,
             cfg.gearbox_oil_ua_w_per_k, out)
    names = ("engine_coolant_in_degc", "engine_coolant_out_degc", "battery_temp_degc", "battery_coolant_in_degc",
             "battery_coolant_out_degc", "hpcu_coolant_in_degc", "hpcu_coolant_out_degc", "motor_coolant_in_degc",
             "motor_coolant_out_degc", "gearbox_oil_degc")
    return {name: out[:, k] for k, name in enumerate(names)}
