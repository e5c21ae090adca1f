"""Flatten a :class:`~benchtwin.config.vehicle.VehicleConfig` into the float64 arrays the compiled loop uses.

The stepping loop is compiled with numba, so parameters travel as one flat vector ``p`` (scalars, indexed by
the ``P_*`` constants below) plus a few lookup tables (curves and maps). Units are SI inside the loop:
rad/s, Nm, W, m/s, kg/J for fuel.
"""

from __future__ import annotations

from importlib import resources
from typing import NamedTuple

import numpy as np

from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.lti import c2d

__all__ = ["PlantTables", "build_tables", "cell_maps"]

RPM = np.pi / 30.0
KMH = 1.0 / 3.6

# ---- scalar parameter indices (module constants: frozen into the compiled loop) ----
P_DT_S = 0
P_MASS_KG = 1
P_WHEEL_RADIUS_M = 2
P_FINAL_DRIVE_RATIO = 3
P_N_GEARS = 4
P_F0_N = 5
P_F1_N_PER_MPS = 6  # N per m/s
P_F2_N_PER_MPS2 = 7  # N per (m/s)^2
P_PARASITIC_F0_N = 8
P_PARASITIC_F1_N_PER_MPS = 9
P_PARASITIC_F2_N_PER_MPS2 = 10
P_SPEED_CTRL_MASS_KG = 11  # equivalent mass in speed-controlled mode (rollers + wheels)
P_ENGINE_IDLE_RADPS = 12
P_ENGINE_MAX_RADPS = 13
P_ENGINE_INERTIA_KGM2 = 14
P_ENGINE_FRICTION_NM = 15
P_ENGINE_FRICTION_NM_PER_RADPS = 16  # Nm per rad/s
P_ENGINE_START_FUEL_KG = 17
P_ENGINE_SPIN_RADPS2 = 18
P_DISPLACEMENT_M3 = 19
P_FUEL_LHV_J_PER_KG = 20
P_MOTOR_MAX_RADPS = 21
P_MOTOR_INERTIA_KGM2 = 22
P_WILLANS_E = 23
P_WILLANS_LOSS_W = 24
P_WILLANS_E_GEN = 25
P_WILLANS_LOSS_GEN_W = 26
P_MOTOR_IDLE_RADPS = 27
P_IDLE_GAIN_NM_PER_RADPS = 28
P_TC_COUPLING_SPEED_RATIO = 29
P_LOCKUP_MIN_GEAR = 30
P_LOCKUP_MIN_SPEED_MPS = 31
P_LOCKUP_CAPACITY_NM = 32
P_LOCKUP_ENGAGE_S = 33
P_SHIFT_DELAY_S = 34
P_BRAKE_GAIN_FRONT_NM_PER_BAR = 35  # Nm per bar
P_BRAKE_GAIN_REAR_NM_PER_BAR = 36
P_BRAKE_MAX_TORQUE_NM = 37
P_REGEN_CUTOFF_MPS = 38
P_BRAKE_FRONT_SHARE_BASE = 39
P_BRAKE_FRONT_SHARE_PER_MPS2 = 40
P_BRAKE_FRONT_SHARE_MAX = 41
P_COAST_REGEN_TORQUE_NM = 42
P_BATT_CAPACITY_AS = 43
P_BATT_ALPHA = 44
P_BATT_BETA_DISCHARGE = 45
P_BATT_BETA_CHARGE = 46
P_SOC_MIN_FRAC = 47
P_SOC_MAX_FRAC = 48
P_BATT_MAX_DISCHARGE_W = 49
P_BATT_MAX_CHARGE_W = 50
P_N_CELLS_SERIES = 51
P_DCDC_EFFICIENCY = 52
P_DCDC_SET_V = 53
P_LV_CAPACITY_AS = 54
P_LV_OCV_EMPTY_V = 55
P_LV_OCV_FULL_V = 56
P_LV_RESISTANCE_OHM = 57
P_DCDC_DROOP_OHM = 58
P_HYB_ENGINE_ON_W = 59
P_HYB_ENGINE_OFF_W = 60
P_HYB_ENGINE_ON_MPS = 61
P_HYB_MIN_ON_S = 62
P_HYB_SUSTAIN_SOC_PCT = 63
P_HYB_SUSTAIN_W_PER_PCT = 64
P_HYB_SUSTAIN_MAX_W = 65
P_HYB_KICKDOWN_PEDAL_PCT = 66
P_HYB_CHARGE_W = 67
P_HYB_ESAVE_ON_W = 68
P_DRIVER_B0_N_PER_MPS = 69
P_DRIVER_B1_N_PER_MPS = 70
P_DRIVER_PREVIEW_STEPS = 71
P_DRIVER_STOP_DECEL_MPS2 = 72
P_DYNO_B0_N_PER_MPS = 73
P_DYNO_B1_N_PER_MPS = 74
P_DYNO_MAX_FORCE_N = 75
P_DYNO_MAX_POWER_W = 76
P_DRIVER_FEEDBACK_MAX_N = 77
P_HYB_MAX_WHEEL_FORCE_N = 78
P_SHIFT_INERTIA_PHASE_S = 79
# high-fidelity plant (vehicle files with fidelity = "high"; all 0 for the paper form)
P_HIFI = 80  # 0 paper form, 1 high fidelity
P_AMBIENT_DEGC = 81
P_HF_R1_OHM = 82  # pack RC branches
P_HF_TAU1_S = 83
P_HF_R2_OHM = 84
P_HF_TAU2_S = 85
P_HF_R0_TEMP_PER_K = 86
P_HF_HYST_V = 87  # pack OCV hysteresis half-width
P_HF_HYST_AS = 88
P_HF_BATT_HEAT_J_PER_K = 89
P_HF_BATT_UA_W_PER_K = 90
P_HF_SPIN_PER_RADPS = 91
P_HF_OIL_VISC_PER_K = 92
P_HF_OIL_REF_DEGC = 93
P_HF_OIL_HEAT_J_PER_K = 94
P_HF_OIL_UA_W_PER_K = 95
P_HF_COLD_PENALTY = 96
P_HF_WARM_DEGC = 97
P_HF_ENGINE_HEAT_J_PER_K = 98
P_HF_ENGINE_HEAT_FRAC = 99
P_HF_RADIATOR_UA_W_PER_K = 100
P_HF_THERMOSTAT_DEGC = 101
P_HF_SLIP_STIFFNESS_N = 102  # driven axle's longitudinal slip stiffness, N per unit slip (0: no slip)
P_CONVENTIONAL = 103  # 1: conventional layout (no motor, no HV pack: the 12 V loads on an alternator), 0: P2 PHEV
P_BMS_DISCHARGE_BAND_PCT = 104  # displayed-SOC points above 0 % over which the discharge power derates to 0
P_BMS_CHARGE_BAND_PCT = 105  # displayed-SOC points below 100 % over which the charge power derates to 0
P_BMS_ENGINE_START_PCT = 106  # displayed SOC below which the BMS starts the engine (-1: never, no HV pack)
P_ENGINE_START_FUEL_S = 107  # an engine start's fuel is burnt at a constant rate over this time (0: one step)
NP = 108

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
O_T_BATT = 45  # high-fidelity thermal states fed back into the plant, degC (NaN for the paper form)
O_T_COOLANT = 46
O_T_OIL = 47
NO = 48

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
L_TYRE = 19  # driven tyres slipping on the rollers (high-fidelity plant)
L_ALTERNATOR = 20  # conventional layout: the alternator's drive, inside the engine's map (as its auxiliaries)
NL = 21

LEDGER_NAMES: tuple[str, ...] = (
    "fuel_chemical", "hv_battery_chemical", "lv_battery_chemical", "engine_loss", "motor_loss",
    "hv_battery_resistive", "lv_battery_resistive", "torque_converter_slip", "lockup_slip", "k0_slip",
    "transmission_loss", "brakes", "dcdc_loss", "lv_loads", "road_load_work", "dyno_absorbed",
    "kinetic_start", "kinetic_end", "shift_clutch_slip", "tyre_slip", "alternator_drive",
)
#: ledger entries that feed energy in; the stored kinetic energy is ``kinetic_end - kinetic_start``
LEDGER_INPUTS: tuple[str, ...] = ("fuel_chemical", "hv_battery_chemical", "lv_battery_chemical",
                                  "alternator_drive")


class PlantTables(NamedTuple):
    """The plant's parameter record: scalars ``p`` plus the lookup tables, all float64 arrays in SI units.

    A named tuple so that the compiled loop takes it as one argument and reads its fields by name
    (numba unboxes it once per call).
    """

    p: np.ndarray  # scalars, indexed by the P_* constants
    ratios: np.ndarray  # index 0 = neutral (0), 1..n
    eta_m: np.ndarray  # eq. 14 eta_m per gear (index 0 = neutral: 1)
    c0: np.ndarray  # eq. 14 C0 per gear, Nm
    up_v0: np.ndarray  # m/s, pair g -> g+1 at index g-1
    up_s: np.ndarray  # m/s per pedal %
    dn_v0: np.ndarray
    dn_s: np.ndarray
    e_fl_w: np.ndarray  # engine full load: rad/s
    e_fl_t: np.ndarray  # Nm
    bsfc_w: np.ndarray  # rad/s
    bsfc_b: np.ndarray  # Pa
    bsfc_kgpj: np.ndarray  # kg/J
    m_fl_w: np.ndarray  # motor full load: rad/s
    m_fl_t: np.ndarray  # Nm
    cell_soc: np.ndarray  # displayed SOC fraction 0..1
    cell_ocv: np.ndarray  # V
    cell_rd: np.ndarray  # ohm, discharge
    cell_rc: np.ndarray  # ohm, charge
    tc_a: np.ndarray  # torque converter a0..a8, Nm/(rad/s)^2
    tc_sr: np.ndarray  # high fidelity: converter speed-ratio axis (empty: eq. 35-36)
    tc_cap: np.ndarray  # capacity (30/pi)^2 / K^2, Nm/(rad/s)^2, negative in overrun
    tc_tr: np.ndarray  # torque ratio
    motor_loss: np.ndarray  # high fidelity: motor_loss_hifi_w coefficients (empty: Willans line)


def cell_maps() -> np.ndarray:
    """Return the literature NMC cell table (soc_pct, ocv_v, r_discharge_ohm, r_charge_ohm) as an array."""
    text = resources.files("benchtwin.data").joinpath("nmc_cell_literature.csv").read_text(encoding="utf-8")
    rows = [ln for ln in text.splitlines() if ln and not ln.startswith("#") and not ln.startswith("soc_pct")]
    return np.array([[float(x) for x in ln.split(",")] for ln in rows])


def _pi_coefficients(mass: float, bandwidth: float, damping: float, dt: float) -> tuple[float, float]:
    """PI for a pure mass (force -> speed), poles at ``bandwidth`` with ``damping``, discretised by c2d.

    Returns the coefficients (b0, b1) of ``u[k] = u[k-1] + b0 e[k] + b1 e[k-1]``.
    """
    kp = 2.0 * damping * bandwidth * mass
    ki = bandwidth**2 * mass
    num, den = c2d([kp, ki], [1.0, 0.0], dt, method="tustin")  # python-control's c2d (benchtwin.lti)
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
    p[P_DT_S] = dt
    p[P_MASS_KG] = s.test_mass_kg
    p[P_WHEEL_RADIUS_M] = s.wheel_radius_m
    p[P_FINAL_DRIVE_RATIO] = s.final_drive_ratio
    p[P_N_GEARS] = len(s.gear_ratios)
    p[P_F0_N], p[P_F1_N_PER_MPS], p[P_F2_N_PER_MPS2] = rl.f0_n, rl.f1_n_per_kmh * 3.6, rl.f2_n_per_kmh2 * 3.6**2
    p[P_PARASITIC_F0_N], p[P_PARASITIC_F1_N_PER_MPS] = rl.parasitic_f0_n, rl.parasitic_f1_n_per_kmh * 3.6
    p[P_PARASITIC_F2_N_PER_MPS2] = rl.parasitic_f2_n_per_kmh2 * 3.6**2
    p[P_SPEED_CTRL_MASS_KG] = campaign.dyno.roller_equivalent_mass_kg + rl.wheel_equivalent_mass_kg
    p[P_ENGINE_IDLE_RADPS] = en.idle_speed_rpm * RPM
    p[P_ENGINE_MAX_RADPS] = en.max_speed_rpm * RPM
    p[P_ENGINE_INERTIA_KGM2] = en.inertia_kgm2
    p[P_ENGINE_FRICTION_NM] = en.friction_torque_nm
    p[P_ENGINE_FRICTION_NM_PER_RADPS] = en.friction_torque_nm_per_krpm / (1000.0 * RPM)
    p[P_ENGINE_START_FUEL_KG] = en.start_fuel_g * 1e-3
    p[P_ENGINE_START_FUEL_S] = en.start_fuel_duration_s
    p[P_ENGINE_SPIN_RADPS2] = en.spin_rate_radps2
    p[P_DISPLACEMENT_M3] = s.engine_displacement_m3
    p[P_FUEL_LHV_J_PER_KG] = s.fuel_lhv_j_per_kg
    if mo is not None:
        p[P_MOTOR_MAX_RADPS] = mo.max_speed_rpm * RPM
        p[P_MOTOR_INERTIA_KGM2] = mo.inertia_kgm2
        p[P_WILLANS_E], p[P_WILLANS_LOSS_W] = mo.willans_e, mo.willans_w_loss_w
        p[P_WILLANS_E_GEN], p[P_WILLANS_LOSS_GEN_W] = mo.willans_e_gen, mo.willans_w_loss_gen_w
        p[P_MOTOR_IDLE_RADPS] = mo.idle_speed_rpm * RPM
        p[P_IDLE_GAIN_NM_PER_RADPS] = mo.idle_gain_nm_per_radps
    else:
        # conventional: no rotor, the converter's pump on the crankshaft; a lossless motor of zero torque (its
        # full-load curve is 0) draws exactly nothing, and the engine's idle controller keeps its gain
        p[P_CONVENTIONAL] = 1.0
        p[P_MOTOR_MAX_RADPS] = p[P_ENGINE_MAX_RADPS]
        p[P_MOTOR_INERTIA_KGM2] = tc.pump_inertia_kgm2
        p[P_WILLANS_E], p[P_WILLANS_E_GEN] = 1.0, 1.0
        p[P_IDLE_GAIN_NM_PER_RADPS] = en.idle_gain_nm_per_radps
    p[P_TC_COUPLING_SPEED_RATIO] = tc.coupling_speed_ratio
    p[P_LOCKUP_MIN_GEAR] = tc.lockup_min_gear
    p[P_LOCKUP_MIN_SPEED_MPS] = tc.lockup_min_speed_kmh * KMH
    p[P_LOCKUP_CAPACITY_NM] = tc.lockup_capacity_nm
    p[P_LOCKUP_ENGAGE_S] = tc.lockup_engage_time_s
    p[P_SHIFT_DELAY_S] = tr.shift_delay_s
    p[P_SHIFT_INERTIA_PHASE_S] = tr.shift_inertia_phase_s
    p[P_BRAKE_GAIN_FRONT_NM_PER_BAR] = br.gain_front_nm_per_bar
    p[P_BRAKE_GAIN_REAR_NM_PER_BAR] = br.gain_rear_nm_per_bar
    p[P_BRAKE_MAX_TORQUE_NM] = br.max_brake_torque_nm
    # conventional: no regeneration and no blending (the blending branch never runs: cut-off out of reach)
    p[P_REGEN_CUTOFF_MPS] = br.regen_cutoff_speed_kmh * KMH if mo is not None else 1e9
    p[P_BRAKE_FRONT_SHARE_BASE] = br.front_share_base
    p[P_BRAKE_FRONT_SHARE_PER_MPS2] = br.front_share_per_mps2
    p[P_BRAKE_FRONT_SHARE_MAX] = br.front_share_max
    p[P_COAST_REGEN_TORQUE_NM] = br.coast_regen_torque_nm
    if ba is not None:
        p[P_BATT_CAPACITY_AS] = ba.capacity_ah * 3600.0
        p[P_BATT_ALPHA], p[P_BATT_BETA_DISCHARGE], p[P_BATT_BETA_CHARGE] = ba.alpha, ba.beta_discharge, ba.beta_charge
        p[P_SOC_MIN_FRAC], p[P_SOC_MAX_FRAC] = ba.soc_min_frac, ba.soc_max_frac
        p[P_BATT_MAX_DISCHARGE_W], p[P_BATT_MAX_CHARGE_W] = ba.max_discharge_power_w, ba.max_charge_power_w
        p[P_BMS_DISCHARGE_BAND_PCT], p[P_BMS_CHARGE_BAND_PCT] = ba.discharge_derate_band_pct, ba.charge_derate_band_pct
        p[P_BMS_ENGINE_START_PCT] = ba.floor_engine_start_pct
    else:  # no HV pack: a placeholder the loop never draws on (its current is 0, its outputs are dropped)
        p[P_BATT_CAPACITY_AS], p[P_BATT_ALPHA], p[P_BATT_BETA_DISCHARGE], p[P_BATT_BETA_CHARGE] = 3600.0, 1, 1, 1
        p[P_SOC_MIN_FRAC], p[P_SOC_MAX_FRAC] = 0.0, 1.0
        p[P_BMS_ENGINE_START_PCT] = -1.0
    p[P_N_CELLS_SERIES] = s.n_cells_series or 1
    p[P_DCDC_EFFICIENCY], p[P_DCDC_SET_V] = lv.dcdc_efficiency, lv.dcdc_voltage_v
    p[P_LV_CAPACITY_AS] = lv.battery_capacity_ah * 3600.0
    p[P_LV_OCV_EMPTY_V], p[P_LV_OCV_FULL_V] = lv.battery_ocv_empty_v, lv.battery_ocv_full_v
    p[P_LV_RESISTANCE_OHM] = lv.battery_resistance_ohm
    p[P_DCDC_DROOP_OHM] = lv.dcdc_droop_ohm
    if hy is not None:
        p[P_HYB_ENGINE_ON_W] = hy.engine_on_power_w
        p[P_HYB_ENGINE_OFF_W] = hy.engine_off_power_w
        p[P_HYB_ENGINE_ON_MPS] = hy.engine_on_speed_kmh * KMH
        p[P_HYB_MIN_ON_S] = hy.engine_min_on_time_s
        p[P_HYB_SUSTAIN_SOC_PCT] = hy.sustain_soc_pct
        p[P_HYB_SUSTAIN_W_PER_PCT] = hy.sustain_gain_w_per_pct
        p[P_HYB_SUSTAIN_MAX_W] = hy.max_sustain_power_w
        p[P_HYB_KICKDOWN_PEDAL_PCT] = hy.electric_kickdown_pedal_pct
        p[P_HYB_CHARGE_W] = hy.charge_power_w
        p[P_HYB_ESAVE_ON_W] = hy.esave_on_power_w
        p[P_HYB_MAX_WHEEL_FORCE_N] = hy.max_wheel_force_n
    else:  # conventional: the engine runs all the time (commands forced), no sustain term; the limiter is the engine's
        p[P_HYB_SUSTAIN_SOC_PCT] = -1.0
        p[P_HYB_KICKDOWN_PEDAL_PCT] = 100.0
        p[P_HYB_MAX_WHEEL_FORCE_N] = en.max_wheel_force_n
    drv, dyn = campaign.driver, campaign.dyno
    p[P_DRIVER_B0_N_PER_MPS], p[P_DRIVER_B1_N_PER_MPS] = _pi_coefficients(s.test_mass_kg, drv.bandwidth_radps,
                                                                          drv.damping, dt)
    p[P_DRIVER_PREVIEW_STEPS] = round(drv.preview_s / dt)
    p[P_DRIVER_STOP_DECEL_MPS2] = drv.stop_decel_mps2
    p[P_DRIVER_FEEDBACK_MAX_N] = 0.5 * s.test_mass_kg * 9.81
    p[P_DYNO_B0_N_PER_MPS], p[P_DYNO_B1_N_PER_MPS] = _pi_coefficients(
        p[P_SPEED_CTRL_MASS_KG], dyn.speed_loop_bandwidth_radps, dyn.speed_loop_damping, dt)
    p[P_DYNO_MAX_FORCE_N], p[P_DYNO_MAX_POWER_W] = dyn.max_force_n, dyn.max_power_w

    empty = np.zeros(0)
    tc_sr, tc_cap, tc_tr, motor_loss = empty, empty, empty, empty
    hf = vehicle.high_fidelity
    if hf is not None:
        th = vehicle.thermal
        p[P_HIFI] = 1.0
        p[P_AMBIENT_DEGC] = campaign.ambient_degc
        n = s.n_cells_series
        p[P_HF_R1_OHM], p[P_HF_TAU1_S] = n * hf.battery.r1_ohm_per_cell, hf.battery.tau1_s
        p[P_HF_R2_OHM], p[P_HF_TAU2_S] = n * hf.battery.r2_ohm_per_cell, hf.battery.tau2_s
        p[P_HF_R0_TEMP_PER_K] = hf.battery.r0_temp_coeff_per_k
        p[P_HF_HYST_V] = n * hf.battery.hysteresis_v_per_cell
        p[P_HF_HYST_AS] = hf.battery.hysteresis_charge_ah * 3600.0
        p[P_HF_BATT_HEAT_J_PER_K], p[P_HF_BATT_UA_W_PER_K] = th.battery_heat_capacity_j_per_k, th.battery_ua_w_per_k
        p[P_HF_SPIN_PER_RADPS] = hf.transmission.spin_per_radps
        p[P_HF_OIL_VISC_PER_K] = hf.transmission.oil_viscosity_per_k
        p[P_HF_OIL_REF_DEGC] = hf.transmission.oil_reference_degc
        p[P_HF_OIL_HEAT_J_PER_K] = hf.transmission.oil_heat_capacity_j_per_k
        p[P_HF_OIL_UA_W_PER_K] = hf.transmission.oil_ua_w_per_k
        p[P_HF_COLD_PENALTY], p[P_HF_WARM_DEGC] = hf.engine.cold_penalty_frac, hf.engine.warm_degc
        p[P_HF_ENGINE_HEAT_J_PER_K] = th.engine_heat_capacity_j_per_k
        p[P_HF_ENGINE_HEAT_FRAC] = th.engine_heat_to_coolant_frac
        p[P_HF_RADIATOR_UA_W_PER_K] = th.engine_radiator_ua_w_per_k
        p[P_HF_THERMOSTAT_DEGC] = th.engine_thermostat_degc
        if hf.tyre is not None:
            p[P_HF_SLIP_STIFFNESS_N] = (hf.tyre.slip_stiffness_per_load * s.test_mass_kg * 9.81
                                        * hf.tyre.driven_axle_load_share)
        k = np.asarray(hf.torque_converter.k_factor_rpm_per_sqrt_nm, float)
        tc_sr = np.asarray(hf.torque_converter.speed_ratio, float)
        tc_cap = np.sign(k) * (30.0 / np.pi) ** 2 / (k * k)
        tc_tr = np.asarray(hf.torque_converter.torque_ratio, float)
        m = hf.motor
        motor_loss = np.array([m.copper_w_per_nm2, m.d_axis_w, m.base_speed_rpm * RPM, m.hysteresis_w_per_radps,
                               m.eddy_w_per_radps2, m.friction_w_per_radps, m.windage_w_per_radps3,
                               m.inverter_standby_w, m.inverter_switching_w_per_nm])

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
        m_fl_w=np.asarray(mo.full_load_speed_rpm, float) * RPM if mo is not None else np.array([0.0, 1.0]),
        m_fl_t=np.asarray(mo.full_load_torque_nm, float) if mo is not None else np.zeros(2),
        cell_soc=cells[:, 0] / 100.0,
        cell_ocv=cells[:, 1].copy(),
        cell_rd=cells[:, 2].copy(),
        cell_rc=cells[:, 3].copy(),
        tc_a=np.asarray(tc.a_nm_per_radps2, float),
        tc_sr=tc_sr,
        tc_cap=tc_cap,
        tc_tr=tc_tr,
        motor_loss=motor_loss,
    )
