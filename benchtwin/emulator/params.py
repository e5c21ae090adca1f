"""Flatten a :class:`~benchtwin.config.vehicle.VehicleConfig` into the float64 arrays the compiled loop uses.

The stepping loop is compiled with numba, so parameters travel as one flat vector ``p`` (scalars, indexed by
the ``P_*`` constants below) plus a few lookup tables (curves and maps). Units are SI inside the loop:
rad/s, Nm, W, m/s, kg/J for fuel.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources

import numpy as np

from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.vehicle import VehicleConfig

__all__ = ["PlantTables", "build_tables", "cell_maps"]

RPM = np.pi / 30.0
KMH = 1.0 / 3.6

# ---- scalar parameter indices (module constants: frozen into the compiled loop) ----
P_DT = 0
P_MASS = 1
P_RW = 2
P_IFD = 3
P_NG = 4
P_F0 = 5
P_F1 = 6  # N per m/s
P_F2 = 7  # N per (m/s)^2
P_PF0 = 8
P_PF1 = 9
P_PF2 = 10
P_MSC = 11  # equivalent mass in speed-controlled mode (rollers + wheels)
P_E_IDLE = 12
P_E_MAX = 13
P_E_J = 14
P_E_FR0 = 15
P_E_FR1 = 16  # Nm per rad/s
P_E_START_KG = 17
P_E_SPIN = 18
P_VD = 19
P_LHV = 20
P_M_MAX = 21
P_M_J = 22
P_W_E = 23
P_W_LOSS = 24
P_W_EG = 25
P_W_LOSSG = 26
P_M_IDLE = 27
P_IDLE_K = 28
P_TC_GAMMA = 29
P_LU_GEAR = 30
P_LU_V = 31
P_LU_CAP = 32
P_LU_TENG = 33
P_SHIFT_DELAY = 34
P_B_GF = 35  # Nm per bar
P_B_GR = 36
P_B_TMAX = 37
P_B_VCUT = 38
P_B_FS0 = 39
P_B_FS1 = 40
P_B_FSMAX = 41
P_COAST_T = 42
P_CAP_AS = 43
P_ALPHA = 44
P_BETA_D = 45
P_BETA_C = 46
P_SOC_MIN = 47
P_SOC_MAX = 48
P_PDCH = 49
P_PCH = 50
P_NCELL = 51
P_DCDC_ETA = 52
P_DCDC_V = 53
P_LV_CAP_AS = 54
P_LV_OCV0 = 55
P_LV_OCV1 = 56
P_LV_R = 57
P_LV_DROOP = 58
P_H_PON = 59
P_H_POFF = 60
P_H_VON = 61
P_H_TMIN = 62
P_H_SUS = 63
P_H_SUSK = 64
P_H_SUSMAX = 65
P_H_KICK = 66
P_H_CHG = 67
P_H_ESAVE = 68
P_DRV_B0 = 69
P_DRV_B1 = 70
P_DRV_NPRE = 71
P_DRV_STOP = 72
P_DYN_B0 = 73
P_DYN_B1 = 74
P_DYN_FMAX = 75
P_DYN_PMAX = 76
P_DRV_FBMAX = 77
P_H_FMAX = 78
P_SHIFT_INERTIA = 79
NP = 80

# ---- command rows (one value per plant step) ----
C_DYNO_MODE = 0  # 0 road-load, 1 speed-controlled
C_DYNO_SET = 1  # m/s
C_DRV_MODE = 2  # 0 pedals from the protocol, 1 follow the target speed
C_PEDAL = 3
C_BRAKE = 4
C_VTGT = 5
C_GEAR = 6  # -1 automatic, 0 neutral, g held
C_HMODE = 7
C_K0 = 8  # -1 auto, 0 open, 1 closed
C_LU = 9
C_ENG = 10  # -1 auto, 0 off, 1 on
C_END_KIND = 11  # 0 none, 1 speed >=, 2 displayed SOC <=, 3 displayed SOC >=, 4 at once
C_END_VAL = 12
C_SEG = 13
C_LVLOAD = 14  # W
C_VPRE = 15  # target speed at the driver's preview (m/s)
C_AREF = 16  # reference acceleration around the preview (m/s^2)
NC = 17

# ---- loop outputs (columns) ----
O_V = 0
O_A = 1
O_X = 2
O_DSET = 3
O_FFRONT = 4
O_FREAR = 5
O_FRL = 6
O_PEDAL = 7
O_BRAKE = 8
O_HMODE = 9
O_WE = 10
O_TE = 11
O_EON = 12
O_FUEL = 13
O_K0 = 14
O_WP = 15
O_TM = 16
O_PEL = 17
O_TP = 18
O_WT = 19
O_TT = 20
O_LU = 21
O_GT = 22
O_GA = 23
O_TIN = 24
O_TOUT = 25
O_WS = 26
O_WW = 27
O_PF = 28
O_PR = 29
O_PMC = 30
O_TBF = 31
O_TBR = 32
O_IB = 33
O_VB = 34
O_OCV = 35
O_SOC = 36
O_DSOC = 37
O_ILV = 38
O_VLV = 39
O_ILVB = 40
O_Q_ENGINE = 41  # heat: fuel power minus brake power, W
O_Q_MOTOR = 42  # motor + inverter loss, W
O_Q_BATT = 43  # battery I^2 R, W
O_VDYN = 44
NO = 45

# ---- energy ledger entries (J) ----
L_FUEL = 0
L_HV_CHEM = 1
L_LV_CHEM = 2
L_ENGINE = 3
L_MOTOR = 4
L_HV_R = 5
L_LV_R = 6
L_TC = 7
L_LOCKUP = 8
L_K0 = 9
L_TRANS = 10
L_BRAKES = 11
L_DCDC = 12
L_LV_LOADS = 13
L_ROAD = 14
L_DYNO = 15
L_KE0 = 16  # stored kinetic energy at start
L_KE1 = 17  # at end
L_SHIFT = 18  # gearshift clutches synchronising the pump side
NL = 19

LEDGER_NAMES: tuple[str, ...] = (
    "fuel_chemical", "hv_battery_chemical", "lv_battery_chemical", "engine_loss", "motor_loss",
    "hv_battery_resistive", "lv_battery_resistive", "torque_converter_slip", "lockup_slip", "k0_slip",
    "transmission_loss", "brakes", "dcdc_loss", "lv_loads", "road_load_work", "dyno_absorbed",
    "kinetic_start", "kinetic_end", "shift_clutch_slip",
)
#: ledger entries that feed energy in; the stored kinetic energy is ``kinetic_end - kinetic_start``
LEDGER_INPUTS: tuple[str, ...] = ("fuel_chemical", "hv_battery_chemical", "lv_battery_chemical")


@dataclass
class PlantTables:
    """Everything the compiled loop needs about the vehicle and the bench, as float64 arrays."""

    p: np.ndarray
    ratios: np.ndarray  # index 0 = neutral (0), 1..n
    eta_m: np.ndarray
    c0: np.ndarray
    up_v0: np.ndarray  # m/s, pair g -> g+1 at index g-1
    up_s: np.ndarray  # m/s per pedal %
    dn_v0: np.ndarray
    dn_s: np.ndarray
    e_fl_w: np.ndarray
    e_fl_t: np.ndarray
    bsfc_w: np.ndarray  # rad/s
    bsfc_b: np.ndarray  # Pa
    bsfc_kgpj: np.ndarray  # kg/J
    m_fl_w: np.ndarray
    m_fl_t: np.ndarray
    cell_soc: np.ndarray  # displayed SOC fraction 0..1
    cell_ocv: np.ndarray
    cell_rd: np.ndarray
    cell_rc: np.ndarray
    tc_a: np.ndarray


def cell_maps() -> np.ndarray:
    """Return the literature NMC cell table (soc_pct, ocv_v, r_discharge_ohm, r_charge_ohm) as an array."""
    text = resources.files("benchtwin.data").joinpath("nmc_cell_literature.csv").read_text(encoding="utf-8")
    rows = [ln for ln in text.splitlines() if ln and not ln.startswith("#") and not ln.startswith("soc_pct")]
    return np.array([[float(x) for x in ln.split(",")] for ln in rows])


def _pi_coefficients(mass: float, bandwidth: float, damping: float, dt: float) -> tuple[float, float]:
    """PI for a pure mass (force -> speed), poles at ``bandwidth`` with ``damping``, discretised by c2d.

    Returns the coefficients (b0, b1) of ``u[k] = u[k-1] + b0 e[k] + b1 e[k-1]``.
    """
    import control

    kp = 2.0 * damping * bandwidth * mass
    ki = bandwidth**2 * mass
    pi_c = control.tf([kp, ki], [1.0, 0.0])
    pi_d = control.c2d(pi_c, dt, method="tustin")
    num = np.atleast_1d(np.squeeze(pi_d.num[0][0])).astype(float)
    den = np.atleast_1d(np.squeeze(pi_d.den[0][0])).astype(float)
    num = num / den[0]
    return float(num[0]), float(num[1])


def build_tables(vehicle: VehicleConfig, campaign: CampaignConfig) -> PlantTables:
    """Flatten vehicle and bench parameters for the compiled loop.

    Parameters
    ----------
    vehicle:
        The true vehicle parameters.
    campaign:
        The campaign (plant rate, dyno and driver settings).

    Returns
    -------
    PlantTables
        Scalars and lookup tables in SI units.
    """
    s, rl, en, mo = vehicle.specs, vehicle.road_load, vehicle.engine, vehicle.motor
    tc, tr, sh, br = vehicle.torque_converter, vehicle.transmission, vehicle.shift_schedule, vehicle.brakes
    ba, lv, hy = vehicle.battery, vehicle.low_voltage, vehicle.hybrid
    dt = 1.0 / campaign.plant_rate_hz
    p = np.zeros(NP)
    p[P_DT] = dt
    p[P_MASS] = s.test_mass_kg
    p[P_RW] = s.wheel_radius_m
    p[P_IFD] = s.final_drive_ratio
    p[P_NG] = len(s.gear_ratios)
    p[P_F0], p[P_F1], p[P_F2] = rl.f0_n, rl.f1_n_per_kmh * 3.6, rl.f2_n_per_kmh2 * 3.6**2
    p[P_PF0], p[P_PF1] = rl.parasitic_f0_n, rl.parasitic_f1_n_per_kmh * 3.6
    p[P_PF2] = rl.parasitic_f2_n_per_kmh2 * 3.6**2
    p[P_MSC] = campaign.dyno.roller_equivalent_mass_kg + rl.wheel_equivalent_mass_kg
    p[P_E_IDLE] = en.idle_speed_rpm * RPM
    p[P_E_MAX] = en.max_speed_rpm * RPM
    p[P_E_J] = en.inertia_kgm2
    p[P_E_FR0] = en.friction_torque_nm
    p[P_E_FR1] = en.friction_torque_nm_per_krpm / (1000.0 * RPM)
    p[P_E_START_KG] = en.start_fuel_g * 1e-3
    p[P_E_SPIN] = en.spin_rate_radps2
    p[P_VD] = s.engine_displacement_m3
    p[P_LHV] = s.fuel_lhv_j_per_kg
    p[P_M_MAX] = mo.max_speed_rpm * RPM
    p[P_M_J] = mo.inertia_kgm2
    p[P_W_E], p[P_W_LOSS] = mo.willans_e, mo.willans_w_loss_w
    p[P_W_EG], p[P_W_LOSSG] = mo.willans_e_gen, mo.willans_w_loss_gen_w
    p[P_M_IDLE] = mo.idle_speed_rpm * RPM
    p[P_IDLE_K] = mo.idle_gain_nm_per_radps
    p[P_TC_GAMMA] = tc.coupling_speed_ratio
    p[P_LU_GEAR] = tc.lockup_min_gear
    p[P_LU_V] = tc.lockup_min_speed_kmh * KMH
    p[P_LU_CAP] = tc.lockup_capacity_nm
    p[P_LU_TENG] = tc.lockup_engage_time_s
    p[P_SHIFT_DELAY] = tr.shift_delay_s
    p[P_SHIFT_INERTIA] = tr.shift_inertia_phase_s
    p[P_B_GF], p[P_B_GR] = br.gain_front_nm_per_bar, br.gain_rear_nm_per_bar
    p[P_B_TMAX] = br.max_brake_torque_nm
    p[P_B_VCUT] = br.regen_cutoff_speed_kmh * KMH
    p[P_B_FS0], p[P_B_FS1], p[P_B_FSMAX] = br.front_share_base, br.front_share_per_mps2, br.front_share_max
    p[P_COAST_T] = br.coast_regen_torque_nm
    p[P_CAP_AS] = ba.capacity_ah * 3600.0
    p[P_ALPHA], p[P_BETA_D], p[P_BETA_C] = ba.alpha, ba.beta_discharge, ba.beta_charge
    p[P_SOC_MIN], p[P_SOC_MAX] = ba.soc_min_frac, ba.soc_max_frac
    p[P_PDCH], p[P_PCH] = ba.max_discharge_power_w, ba.max_charge_power_w
    p[P_NCELL] = s.n_cells_series
    p[P_DCDC_ETA], p[P_DCDC_V] = lv.dcdc_efficiency, lv.dcdc_voltage_v
    p[P_LV_CAP_AS] = lv.battery_capacity_ah * 3600.0
    p[P_LV_OCV0], p[P_LV_OCV1] = lv.battery_ocv_empty_v, lv.battery_ocv_full_v
    p[P_LV_R] = lv.battery_resistance_ohm
    p[P_LV_DROOP] = lv.dcdc_droop_ohm
    p[P_H_PON], p[P_H_POFF], p[P_H_VON] = hy.engine_on_power_w, hy.engine_off_power_w, hy.engine_on_speed_kmh * KMH
    p[P_H_TMIN] = hy.engine_min_on_time_s
    p[P_H_SUS], p[P_H_SUSK], p[P_H_SUSMAX] = hy.sustain_soc_pct, hy.sustain_gain_w_per_pct, hy.max_sustain_power_w
    p[P_H_KICK] = hy.electric_kickdown_pedal_pct
    p[P_H_CHG] = hy.charge_power_w
    p[P_H_ESAVE] = hy.esave_on_power_w
    p[P_H_FMAX] = hy.max_wheel_force_n
    drv, dyn = campaign.driver, campaign.dyno
    p[P_DRV_B0], p[P_DRV_B1] = _pi_coefficients(s.test_mass_kg, drv.bandwidth_radps, drv.damping, dt)
    p[P_DRV_NPRE] = round(drv.preview_s / dt)
    p[P_DRV_STOP] = drv.stop_decel_mps2
    p[P_DRV_FBMAX] = 0.5 * s.test_mass_kg * 9.81
    p[P_DYN_B0], p[P_DYN_B1] = _pi_coefficients(p[P_MSC], dyn.speed_loop_bandwidth_radps, dyn.speed_loop_damping, dt)
    p[P_DYN_FMAX], p[P_DYN_PMAX] = dyn.max_force_n, dyn.max_power_w

    cells = cell_maps()
    bsfc = np.asarray(en.bsfc_g_per_kwh, dtype=np.float64) / 3.6e9  # g/kWh -> kg/J
    return PlantTables(
        p=p,
        ratios=np.concatenate([[0.0], np.asarray(s.gear_ratios, float)]),
        eta_m=np.concatenate([[1.0], np.asarray(tr.eta_m, float)]),
        c0=np.concatenate([[0.0], np.asarray(tr.c0_nm, float)]),
        up_v0=np.asarray(sh.up_v0_kmh, float) * KMH,
        up_s=np.asarray(sh.up_slope_kmh_per_pct, float) * KMH,
        dn_v0=np.asarray(sh.down_v0_kmh, float) * KMH,
        dn_s=np.asarray(sh.down_slope_kmh_per_pct, float) * KMH,
        e_fl_w=np.asarray(en.full_load_speed_rpm, float) * RPM,
        e_fl_t=np.asarray(en.full_load_torque_nm, float),
        bsfc_w=np.asarray(en.bsfc_speed_rpm, float) * RPM,
        bsfc_b=np.asarray(en.bsfc_bmep_bar, float) * 1e5,
        bsfc_kgpj=np.ascontiguousarray(bsfc),
        m_fl_w=np.asarray(mo.full_load_speed_rpm, float) * RPM,
        m_fl_t=np.asarray(mo.full_load_torque_nm, float),
        cell_soc=cells[:, 0] / 100.0,
        cell_ocv=cells[:, 1].copy(),
        cell_rd=cells[:, 2].copy(),
        cell_rc=cells[:, 3].copy(),
        tc_a=np.asarray(tc.a_nm_per_radps2, float),
    )
