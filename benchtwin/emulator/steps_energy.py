"""Sub-steps of a plant step, energy side: engine fuel, dyno forces, HV battery, 12 V system and the ledger.

Pure ``@njit`` functions with the conventions of :mod:`benchtwin.emulator.steps_control`; the ledger
sub-steps only add to the entries of ``led`` (``L_*``, J) they name.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from benchtwin.emulator.models import (
    battery_rc_update,
    bsfc_kg_per_j,
    cold_start_factor,
    interp_1d,
    pack_current_a,
    road_load_force_n,
)
from benchtwin.emulator.params import (
    L_ALTERNATOR,
    L_BRAKES,
    L_DCDC,
    L_DYNO,
    L_ENGINE,
    L_FUEL,
    L_HV_CHEM,
    L_HV_R,
    L_LOCKUP,
    L_LV_CHEM,
    L_LV_LOADS,
    L_LV_R,
    L_MOTOR,
    L_ROAD,
    L_SHIFT,
    L_TC,
    L_TRANS,
    P_AMBIENT_DEGC,
    P_BATT_ALPHA,
    P_BATT_BETA_CHARGE,
    P_BATT_BETA_DISCHARGE,
    P_CONVENTIONAL,
    P_DCDC_DROOP_OHM,
    P_DCDC_EFFICIENCY,
    P_DCDC_SET_V,
    P_DISPLACEMENT_M3,
    P_DT_S,
    P_DYNO_B0_N_PER_MPS,
    P_DYNO_B1_N_PER_MPS,
    P_DYNO_MAX_FORCE_N,
    P_DYNO_MAX_POWER_W,
    P_F0_N,
    P_F1_N_PER_MPS,
    P_F2_N_PER_MPS2,
    P_FUEL_LHV_J_PER_KG,
    P_HF_BATT_HEAT_J_PER_K,
    P_HF_BATT_UA_W_PER_K,
    P_HF_COLD_PENALTY,
    P_HF_ENGINE_HEAT_FRAC,
    P_HF_ENGINE_HEAT_J_PER_K,
    P_HF_HYST_AS,
    P_HF_HYST_V,
    P_HF_OIL_HEAT_J_PER_K,
    P_HF_OIL_UA_W_PER_K,
    P_HF_R0_TEMP_PER_K,
    P_HF_R1_OHM,
    P_HF_R2_OHM,
    P_HF_RADIATOR_UA_W_PER_K,
    P_HF_TAU1_S,
    P_HF_TAU2_S,
    P_HF_THERMOSTAT_DEGC,
    P_HF_WARM_DEGC,
    P_HIFI,
    P_LV_OCV_EMPTY_V,
    P_LV_OCV_FULL_V,
    P_LV_RESISTANCE_OHM,
    P_N_CELLS_SERIES,
    P_PARASITIC_F0_N,
    P_PARASITIC_F1_N_PER_MPS,
    P_PARASITIC_F2_N_PER_MPS2,
    P_SOC_MAX_FRAC,
    P_SOC_MIN_FRAC,
    PlantTables,
)
from benchtwin.emulator.steps_control import ROAD_LOAD_FADE_MPS


@njit(cache=True, _nrt=False)
def engine_fuel(tab: PlantTables, engine_on: bool, k0_closed: bool, engine_torque_nm: float, pump_speed_radps: float,
                engine_speed_radps: float, start_fuel_kg: float, coolant_degc: float) -> tuple[float, float]:
    """Engine fuel (eq. 26-28): BSFC(omega, BMEP = 4 pi T / V_d) T omega when driving through K0, the map's
    lowest-BMEP flow when motoring or idling free, nothing when off or (a conventional car) in overrun, plus the
    start's fuel mass. The high-fidelity plant multiplies the running flow by the cold-start factor of the
    coolant temperature.

    Returns
    -------
    tuple
        ``(fuel_flow_kgps, fuel_energy_j)``: mass flow over the step (start included) and the step's fuel
        chemical energy (LHV).
    """
    p = tab.p
    dt = p[P_DT_S]
    te = engine_torque_nm
    wp = pump_speed_radps
    fuel_flow = 0.0
    if engine_on:
        if k0_closed and te > 0.0:
            bmep = 4.0 * np.pi * te / p[P_DISPLACEMENT_M3]
            fuel_flow += bsfc_kg_per_j(tab.bsfc_w, tab.bsfc_b, tab.bsfc_kgpj, wp, bmep) * te * wp
        elif te < 0.0 and p[P_CONVENTIONAL] > 0.5:
            pass  # a conventional car's overrun: fuel cut
        else:
            wf = wp if k0_closed else engine_speed_radps
            bmin = tab.bsfc_b[0]
            tmin = bmin * p[P_DISPLACEMENT_M3] / (4.0 * np.pi)
            fuel_flow += bsfc_kg_per_j(tab.bsfc_w, tab.bsfc_b, tab.bsfc_kgpj, wf, bmin) * tmin * wf
        if p[P_HIFI] > 0.5:
            fuel_flow *= cold_start_factor(p[P_HF_COLD_PENALTY], p[P_HF_WARM_DEGC], coolant_degc)
    fuel_e = (fuel_flow * dt + start_fuel_kg) * p[P_FUEL_LHV_J_PER_KG]
    fuel_flow += start_fuel_kg / dt
    return fuel_flow, fuel_e


@njit(cache=True, _nrt=False)
def dyno_forces(p: np.ndarray, dyno_mode: int, dyno_set_mps: float, speed_mps: float, dyno_force_n: float,
                dyno_error_mps: float) -> tuple:
    """Roller forces. Road-load mode: F = -(F0 + F1 v + F2 v^2) (faded in below 0.5 km/h); speed-controlled
    mode: a PI on roller speed (force and power limited) against the vehicle's parasitic loss.

    Returns
    -------
    tuple
        ``(road_load_n, parasitic_n, dyno_force_n, external_force_n, set_speed_mps, dyno_force_state_n,
        dyno_error_mps)``; the set speed is NaN in road-load mode.
    """
    v = speed_mps
    rlf = min(v / ROAD_LOAD_FADE_MPS, 1.0)
    f_rl = road_load_force_n(p[P_F0_N], p[P_F1_N_PER_MPS], p[P_F2_N_PER_MPS2], v) * rlf
    f_par = road_load_force_n(p[P_PARASITIC_F0_N], p[P_PARASITIC_F1_N_PER_MPS], p[P_PARASITIC_F2_N_PER_MPS2], v) * rlf
    f_dyn = 0.0
    vset = np.nan
    if dyno_mode == 1:
        vset = dyno_set_mps
        e = vset - v
        dyno_force_n = dyno_force_n + p[P_DYNO_B0_N_PER_MPS] * e + p[P_DYNO_B1_N_PER_MPS] * dyno_error_mps
        flim = min(p[P_DYNO_MAX_FORCE_N], p[P_DYNO_MAX_POWER_W] / max(v, 1.0))
        dyno_force_n = min(max(dyno_force_n, -flim), flim)
        dyno_error_mps = e
        f_dyn = dyno_force_n
        f_ext = f_dyn - f_par
    else:
        f_ext = -f_rl
    return f_rl, f_par, f_dyn, f_ext, vset, dyno_force_n, dyno_error_mps


@njit(cache=True, _nrt=False)
def lv_system(p: np.ndarray, lv_soc_frac: float, lv_load_w: float) -> tuple:
    """12 V system: DC/DC with droop (set voltage minus droop times current) in parallel with the 12 V battery
    (linear OCV over SOC, internal resistance) feeding the loads; two fixed-point passes on the bus voltage.

    Returns
    -------
    tuple
        ``(lv_ocv_v, lv_bus_v, lv_battery_current_a, dcdc_lv_current_a, dcdc_lv_power_w, dcdc_hv_power_w)``;
        the DC/DC draws ``P_lv / eta_dcdc`` from the HV bus.
    """
    ocv_lv = p[P_LV_OCV_EMPTY_V] + (p[P_LV_OCV_FULL_V] - p[P_LV_OCV_EMPTY_V]) * lv_soc_frac
    pload = lv_load_w
    rd = p[P_DCDC_DROOP_OHM]
    rb = p[P_LV_RESISTANCE_OHM]
    vlv = p[P_DCDC_SET_V]
    for _k in range(2):
        iload = pload / vlv
        vlv = (p[P_DCDC_SET_V] - rd * iload + rd * ocv_lv / rb) / (1.0 + rd / rb)
    ilvb = (ocv_lv - vlv) / rb
    idc = pload / vlv - ilvb
    plv = vlv * idc
    pdc_in = plv / p[P_DCDC_EFFICIENCY]
    return ocv_lv, vlv, ilvb, idc, plv, pdc_in


@njit(cache=True, _nrt=False)
def hv_auxiliary_draw_w(p: np.ndarray, led: np.ndarray, dcdc_hv_power_w: float) -> float:
    """The 12 V system's draw on the HV pack: the DC/DC's input power, or 0 for a conventional car.

    A conventional car (``P_CONVENTIONAL``) has no pack: its "DC/DC" is the alternator, driven by the engine
    inside the engine's map (as the engine's own auxiliaries are, so its torque and fuel channels are those of
    the map); the drive is booked as the ledger's ``alternator_drive`` input.

    Returns
    -------
    float
        Power drawn from the HV pack, W.
    """
    if p[P_CONVENTIONAL] > 0.5:
        led[L_ALTERNATOR] += dcdc_hv_power_w * p[P_DT_S]
        return 0.0
    return dcdc_hv_power_w


@njit(cache=True, _nrt=False)
def hv_battery(tab: PlantTables, soc_frac: float, hv_power_w: float) -> tuple[float, float, float, float]:
    """HV pack (eq. 29-30): U_oc = n alpha OCV_lit(s), R = n beta R_lit(s) (discharge or charge map and beta
    by the sign of the power), current from the terminal power, terminal voltage U_oc - R I.

    Returns
    -------
    tuple
        ``(open_circuit_v, resistance_ohm, current_a, terminal_v)``.
    """
    p = tab.p
    smin = p[P_SOC_MIN_FRAC]
    smax = p[P_SOC_MAX_FRAC]
    ncell = p[P_N_CELLS_SERIES]
    sd = min(max((soc_frac - smin) / (smax - smin), 0.0), 1.0)
    ocv_c = interp_1d(sd, tab.cell_soc, tab.cell_ocv)
    uoc = ncell * p[P_BATT_ALPHA] * ocv_c
    if hv_power_w >= 0.0:
        rpk = ncell * p[P_BATT_BETA_DISCHARGE] * interp_1d(sd, tab.cell_soc, tab.cell_rd)
    else:
        rpk = ncell * p[P_BATT_BETA_CHARGE] * interp_1d(sd, tab.cell_soc, tab.cell_rc)
    ib = pack_current_a(uoc, rpk, hv_power_w)
    vb = uoc - ib * rpk
    return uoc, rpk, ib, vb


@njit(cache=True, _nrt=False)
def hv_battery_hifi(tab: PlantTables, soc_frac: float, hv_power_w: float, rc1_v: float, rc2_v: float,
                    hysteresis: float, battery_degc: float) -> tuple:
    """High-fidelity HV pack: OCV plus hysteresis h U_h, minus two RC branches, minus R0(T) I.

    R0 = n beta R_lit(s) exp(k_T (25 degC - T)); the current solves P = (U_oc + h U_h - u1 - u2 - R0 I) I.
    The branch voltages and the hysteresis state are advanced by :func:`hv_battery_dynamics`.

    Returns
    -------
    tuple
        ``(open_circuit_v, loss_resistance_ohm, current_a, terminal_v)``, the resistance being
        (U_oc - U) / I, so that R I^2 is every loss of the pack (R0, RC branches, hysteresis).
    """
    p = tab.p
    uoc, r0, _i, _v = hv_battery(tab, soc_frac, hv_power_w)
    r0 = r0 * np.exp(p[P_HF_R0_TEMP_PER_K] * (25.0 - battery_degc))
    src = uoc + hysteresis * p[P_HF_HYST_V] - rc1_v - rc2_v
    ib = pack_current_a(src, r0, hv_power_w)
    vb = src - ib * r0
    r_loss = (uoc - vb) / ib if abs(ib) > 1e-9 else 0.0
    return uoc, r_loss, ib, vb


@njit(cache=True, _nrt=False)
def hv_battery_dynamics(p: np.ndarray, current_a: float, rc1_v: float, rc2_v: float,
                        hysteresis: float) -> tuple[float, float, float]:
    """Advance the RC branch voltages (exact for a constant current over the step) and the hysteresis state,
    which moves towards -1 while discharging and +1 while charging by 1/e per ``P_HF_HYST_AS`` of charge.

    Returns
    -------
    tuple
        ``(rc1_v, rc2_v, hysteresis)`` at the end of the step.
    """
    dt = p[P_DT_S]
    u1 = battery_rc_update(rc1_v, p[P_HF_R1_OHM], p[P_HF_TAU1_S], current_a, dt)
    u2 = battery_rc_update(rc2_v, p[P_HF_R2_OHM], p[P_HF_TAU2_S], current_a, dt)
    h = hysteresis
    if current_a != 0.0:
        target = -1.0 if current_a > 0.0 else 1.0
        h += (target - h) * (1.0 - np.exp(-abs(current_a) * dt / p[P_HF_HYST_AS]))
    return u1, u2, h


@njit(cache=True, _nrt=False)
def hifi_thermal_step(p: np.ndarray, engine_heat_w: float, battery_heat_w: float, transmission_loss_w: float,
                      battery_degc: float, coolant_degc: float, oil_degc: float) -> tuple[float, float, float]:
    """Thermal states the high-fidelity plant feeds back (explicit Euler over the step), degC.

    - HV cells: C_b dT/dt = Q_batt - UA_b (T - (T_amb + 1.5)) (chiller inlet a little above ambient);
    - engine coolant: C_e dT/dt = f Q_eng - UA_rad o(T) (T - T_amb), thermostat opening o over 8 K
      (at least 3 %), the lumps of :mod:`benchtwin.emulator.thermal`;
    - gearbox oil: C_o dT/dt = P_trans_loss - UA_o (T - T_coolant) (oil-to-coolant heat exchanger).

    Returns
    -------
    tuple
        ``(battery_degc, coolant_degc, oil_degc)`` at the end of the step.
    """
    dt = p[P_DT_S]
    amb = p[P_AMBIENT_DEGC]
    tb = battery_degc + dt * (battery_heat_w - p[P_HF_BATT_UA_W_PER_K] * (battery_degc - (amb + 1.5))) / p[
        P_HF_BATT_HEAT_J_PER_K]
    op = min(max((coolant_degc - (p[P_HF_THERMOSTAT_DEGC] - 4.0)) / 8.0, 0.03), 1.0)
    q_rad = p[P_HF_RADIATOR_UA_W_PER_K] * op * (coolant_degc - amb)
    tc = coolant_degc + dt * (p[P_HF_ENGINE_HEAT_FRAC] * max(engine_heat_w, 0.0) - q_rad) / p[
        P_HF_ENGINE_HEAT_J_PER_K]
    to = oil_degc + dt * (transmission_loss_w - p[P_HF_OIL_UA_W_PER_K] * (oil_degc - coolant_degc)) / p[
        P_HF_OIL_HEAT_J_PER_K]
    return tb, tc, to


@njit(cache=True, _nrt=False)
def ledger_electrical(p: np.ndarray, led: np.ndarray, fuel_energy_j: float, open_circuit_v: float,
                      resistance_ohm: float, current_a: float, lv_ocv_v: float, lv_battery_current_a: float,
                      dcdc_hv_power_w: float, dcdc_lv_power_w: float, lv_load_w: float) -> None:
    """Ledger, sources and electrical losses: fuel, HV and 12 V chemical power and I^2 R, DC/DC loss, 12 V loads."""
    dt = p[P_DT_S]
    ib = current_a
    ilvb = lv_battery_current_a
    rb = p[P_LV_RESISTANCE_OHM]
    led[L_FUEL] += fuel_energy_j
    led[L_HV_CHEM] += open_circuit_v * ib * dt
    led[L_HV_R] += resistance_ohm * ib * ib * dt
    led[L_LV_CHEM] += lv_ocv_v * ilvb * dt
    led[L_LV_R] += rb * ilvb * ilvb * dt
    led[L_DCDC] += (dcdc_hv_power_w - dcdc_lv_power_w) * dt
    led[L_LV_LOADS] += lv_load_w * dt


@njit(cache=True, _nrt=False)
def ledger_machines(p: np.ndarray, led: np.ndarray, gear: int, lockup_closed: bool, k0_closed: bool,
                    engine_on: bool, engine_torque_nm: float, motor_torque_nm: float, motor_elec_power_w: float,
                    fuel_energy_j: float, engine_self_energy_j: float, idle_gain_nm_per_radps: float,
                    pump_speed_step_radps: float, mid_pump_speed_radps: float) -> None:
    """Ledger, engine and motor losses: fuel (or electrical) power in minus shaft power out at the mid-point
    pump speed; with the pump free, the idle controller's torque is taken at the end-of-step speed."""
    dt = p[P_DT_S]
    te = engine_torque_nm
    tm = motor_torque_nm
    w_mid = mid_pump_speed_radps
    if gear > 0 and lockup_closed:
        p_in_src_e = te * w_mid
        p_in_src_m = tm * w_mid
    else:
        # pump node implicit: idle torque at the new speed goes to the machine that holds idle
        te_eff = te
        tm_eff = tm
        if idle_gain_nm_per_radps > 0.0:
            if k0_closed and engine_on:
                te_eff = te - idle_gain_nm_per_radps * pump_speed_step_radps
            else:
                tm_eff = tm - idle_gain_nm_per_radps * pump_speed_step_radps
        p_in_src_e = te_eff * w_mid
        p_in_src_m = tm_eff * w_mid
    if k0_closed:
        led[L_ENGINE] += fuel_energy_j - p_in_src_e * dt
    else:
        led[L_ENGINE] += fuel_energy_j - engine_self_energy_j
        if p_in_src_e != 0.0:
            led[L_ENGINE] -= p_in_src_e * dt
    led[L_MOTOR] += motor_elec_power_w * dt - p_in_src_m * dt


@njit(cache=True, _nrt=False)
def ledger_driveline(p: np.ndarray, led: np.ndarray, gear: int, lockup_closed: bool, dyno_mode: int,
                     pump_torque_eff_nm: float, turbine_torque_nm: float, lockup_torque_eff_nm: float,
                     lockup_torque_nm: float, input_torque_nm: float, output_torque_nm: float,
                     slip_gain_rad_per_m: float, mid_pump_speed_radps: float, mid_turbine_speed_radps: float,
                     mid_speed_mps: float, mid_shaft_speed_radps: float, brake_force_n: float, stop_force_n: float,
                     road_load_n: float, parasitic_n: float, dyno_force_n: float) -> None:
    """Ledger, driveline and vehicle: converter and lock-up slip, shift-clutch slip, gearbox loss (eq. 13-14),
    brakes, road-load (or parasitic) work and the dyno's absorbed energy, at the mid-point speeds."""
    dt = p[P_DT_S]
    w_mid = mid_pump_speed_radps
    wt_mid = mid_turbine_speed_radps
    v_mid = mid_speed_mps
    tin = input_torque_nm
    slip_w = slip_gain_rad_per_m
    if gear > 0 and not lockup_closed:
        led[L_TC] += (pump_torque_eff_nm * w_mid - turbine_torque_nm * wt_mid) * dt
        led[L_LOCKUP] += (lockup_torque_eff_nm * w_mid - lockup_torque_nm * wt_mid) * dt
    if gear > 0:
        led[L_SHIFT] += tin * slip_w * v_mid * dt
        led[L_TRANS] += (tin * (wt_mid - slip_w * v_mid) - output_torque_nm * mid_shaft_speed_radps) * dt
    led[L_BRAKES] += (brake_force_n * v_mid - stop_force_n * v_mid) * dt if v_mid > 0.0 else 0.0
    if dyno_mode == 0:
        led[L_ROAD] += road_load_n * v_mid * dt
    else:
        led[L_ROAD] += parasitic_n * v_mid * dt
        led[L_DYNO] -= dyno_force_n * v_mid * dt
