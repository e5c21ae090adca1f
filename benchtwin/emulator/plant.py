"""The compiled plant: ``run_plant`` -> ``plant_step`` -> ordered sub-steps, over preallocated arrays.

Order of a step (FASTSim-like run -> step -> ordered sub-steps), each sub-step a pure ``@njit`` function
of :mod:`benchtwin.emulator.steps_control`, :mod:`~benchtwin.emulator.steps_powertrain` or
:mod:`~benchtwin.emulator.steps_energy` over the model forms of :mod:`benchtwin.emulator.models`:

1. protocol (new test, dyno mode, end condition) -> driver -> shift logic (target and actual gear, gear gains);
2. torque demand and machine limits -> hybrid strategy (engine on/off) -> K0 clutch -> lock-up command ->
   torque split -> brakes and blending -> inertia-phase intervention and idle holding -> brake split;
3. engine fuel -> dyno forces -> lock-up engagement -> driveline (rigid with the lock-up closed, torque
   converter eq. 35-36 with it open, or neutral) -> vehicle (speed states, mid-point speeds);
4. motor power (Willans) -> 12 V system and DC/DC -> HV battery (eq. 29-30) -> energy ledger -> outputs ->
   advance the states.

A vehicle file with ``fidelity = "high"`` sets ``P_HIFI`` and the high-fidelity tables: the same sub-steps
take the motor loss model, the RC/hysteresis pack with R0(T), the spin-loss gear drag, the tabulated converter,
the cold-start fuel factor and the tyre slip (wheel speed = roller speed x (1 + s), s from the last step's axle
force); battery, coolant and oil temperatures are states (docs/fidelity.md). The paper form skips them all. A
conventional car is the record with the motor's terms zeroed and ``P_CONVENTIONAL`` set (docs/models.md).

Parameters travel as one record, :class:`~benchtwin.emulator.params.PlantTables` (scalars ``p`` with named ``P_*``
indices, lookup tables); the state between steps and calls is ``st`` (``S_*`` below). The step and its sub-steps are
compiled without numba's reference counting (``_nrt=False``): array arguments cost nothing per call, an allocation
inside a step is a compile error. Every power term of the ledger is taken at the step's mid-point speeds, the rule that
advances the speed states, so the ledger closes up to what the model loses or stores. Units: rad/s, m/s, Nm, N, W.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from benchtwin.emulator import params as out_rows
from benchtwin.emulator.models import (
    motor_elec_power_w,
    motor_loss_hifi_w,
    road_load_force_n,
    spin_loss_torque_nm,
    tyre_slip,
)
from benchtwin.emulator.params import (
    C_AREF,
    C_BRAKE,
    C_DRV_MODE,
    C_DYNO_MODE,
    C_DYNO_SET,
    C_END_KIND,
    C_END_VAL,
    C_ENG,
    C_GEAR,
    C_HMODE,
    C_K0,
    C_LU,
    C_LVLOAD,
    C_PEDAL,
    C_SEG,
    C_VPRE,
    C_VTGT,
    L_TYRE,
    P_BATT_CAPACITY_AS,
    P_BRAKE_GAIN_FRONT_NM_PER_BAR,
    P_BRAKE_GAIN_REAR_NM_PER_BAR,
    P_DRIVER_STOP_DECEL_MPS2,
    P_DT_S,
    P_ENGINE_INERTIA_KGM2,
    P_F0_N,
    P_F1_N_PER_MPS,
    P_F2_N_PER_MPS2,
    P_FINAL_DRIVE_RATIO,
    P_FUEL_LHV_J_PER_KG,
    P_HF_OIL_REF_DEGC,
    P_HF_OIL_VISC_PER_K,
    P_HF_SLIP_STIFFNESS_N,
    P_HF_SPIN_PER_RADPS,
    P_HIFI,
    P_LV_CAPACITY_AS,
    P_MOTOR_INERTIA_KGM2,
    P_SOC_MAX_FRAC,
    P_SOC_MIN_FRAC,
    P_WHEEL_RADIUS_M,
    P_WILLANS_E,
    P_WILLANS_E_GEN,
    P_WILLANS_LOSS_GEN_W,
    P_WILLANS_LOSS_W,
    PlantTables,
)
from benchtwin.emulator.steps_control import (
    bms_commands,
    driver_step,
    engine_on_off,
    gear_gains,
    protocol_step,
    shift_step,
    torque_demand,
)
from benchtwin.emulator.steps_energy import (
    dyno_forces,
    engine_fuel,
    hifi_thermal_step,
    hv_auxiliary_draw_w,
    hv_battery,
    hv_battery_dynamics,
    hv_battery_hifi,
    ledger_driveline,
    ledger_electrical,
    ledger_machines,
    lv_system,
)
from benchtwin.emulator.steps_powertrain import (
    brake_blending,
    brake_split,
    driveline_step,
    k0_step,
    lockup_command,
    lockup_engagement,
    pump_torque_control,
    torque_split,
    vehicle_step,
)

__all__ = ["N_STATE", "kinetic_energy", "plant_step", "run_plant"]

#: state vector layout (carried between steps and between calls so a campaign may be run in pieces)
S_SPEED_MPS = 0
S_DISTANCE_M = 1
S_PUMP_SPEED_RADPS = 2
S_ENGINE_SPEED_RADPS = 3
S_ENGINE_ON = 4  # 0/1
S_K0_CLOSED = 5  # 0/1
S_LOCKUP_CLOSED = 6  # 0/1
S_GEAR = 7  # actual gear, 0 = neutral
S_GEAR_TARGET = 8
S_SHIFT_TIMER_S = 9
S_SOC_FRAC = 10
S_LV_SOC_FRAC = 11
S_DRIVER_FORCE_N = 12  # driver PI output
S_DRIVER_ERROR_MPS = 13
S_DYNO_FORCE_N = 14  # dyno speed PI output
S_DYNO_ERROR_MPS = 15
S_END_LATCHED = 16  # 0/1: the test's end condition fired
S_LATCH_TIME_S = 17
S_LATCH_SPEED_MPS = 18
S_SEGMENT = 19  # segment index of the previous step
S_ENGINE_ON_TIME_S = 20
S_ESAVE_SOC_PCT = 21  # displayed SOC held in e-save mode
S_EFF_MASS_KG = 22  # mass the vehicle sees on the dyno
S_TIME_S = 23
S_STEP = 24  # plant steps run over the campaign
S_LOCKUP_ENGAGE_S = 25
S_INERTIA_PHASE_S = 26  # time left in a shift's inertia phase
S_OLD_GAIN_RAD_PER_M = 27  # pump speed per vehicle speed of the gear before the shift
# high-fidelity plant only (0 and unused for the paper form)
S_RC1_V = 28  # HV pack RC branch voltages
S_RC2_V = 29
S_HYSTERESIS = 30  # OCV hysteresis state, -1 (after discharge) .. +1 (after charge)
S_BATTERY_DEGC = 31
S_COOLANT_DEGC = 32
S_OIL_DEGC = 33
S_TYRE_SLIP = 34  # driven tyres' slip on the rollers, from the previous step's force
S_START_LEFT_KG = 35  # engine-start fuel still to burn (the start's pulse)
N_STATE = 36


@njit(cache=True)
def kinetic_energy(p: np.ndarray, st: np.ndarray) -> float:
    """Stored kinetic energy (vehicle as the dyno sees it, pump side, free engine), J.

    Parameters
    ----------
    p:
        Scalar parameters (``P_*``).
    st:
        State vector (``S_*``).

    Returns
    -------
    float
        0.5 m v^2 + 0.5 J_p omega_p^2 (+ 0.5 J_e omega_e^2 with K0 open), J.
    """
    k0 = st[S_K0_CLOSED] > 0.5
    jp = p[P_MOTOR_INERTIA_KGM2] + (p[P_ENGINE_INERTIA_KGM2] if k0 else 0.0)
    ke = 0.5 * st[S_EFF_MASS_KG] * st[S_SPEED_MPS] ** 2 + 0.5 * jp * st[S_PUMP_SPEED_RADPS] ** 2
    free = 0.0 if k0 else 0.5 * p[P_ENGINE_INERTIA_KGM2] * st[S_ENGINE_SPEED_RADPS] ** 2  # the free engine
    return ke + free


@njit(cache=True)
def run_plant(tab: PlantTables, cmd: np.ndarray, decim: int, st: np.ndarray, out: np.ndarray, row0: int,
              led: np.ndarray) -> tuple[int, int]:
    """Advance the plant over the steps of one test's commands.

    Parameters
    ----------
    tab:
        Parameter record: scalars ``tab.p`` (``P_*``) and lookup tables.
    cmd:
        Commands of the test, rows ``C_*`` x steps.
    decim:
        Write every ``decim``-th plant step (counted over the whole campaign in ``st``).
    st:
        State vector (``S_*``), updated in place.
    out:
        Outputs, one row per ``O_*`` channel and one column per written step, from column ``row0`` on.
    row0:
        First output column to write.
    led:
        Energy ledger (``L_*``, J), accumulated in place.

    Returns
    -------
    tuple of int
        Output rows written and plant steps run. The test ends before its last command once its end
        condition has fired and the car has come to rest.
    """
    n = cmd.shape[1]
    iout = row0
    nrun = n
    for i in range(n):
        wrote, stop = plant_step(tab, cmd, i, st, led, out, iout, decim)
        if wrote:
            iout += 1
        if stop:
            nrun = i + 1
            break
    return iout - row0, nrun


@njit(cache=True, _nrt=False)
def plant_step(tab: PlantTables, cmd: np.ndarray, i: int, st: np.ndarray, led: np.ndarray, out: np.ndarray,
               iout: int, decim: int) -> tuple[bool, bool]:
    """One plant step: read the state, run the sub-steps in order, book the ledger, write outputs, advance.

    Parameters
    ----------
    tab, cmd, st, led, out, decim:
        As for :func:`run_plant`.
    i:
        Column of ``cmd`` (this step's commands).
    iout:
        Output column, written when the campaign's step count is a multiple of ``decim``.

    Returns
    -------
    tuple of bool
        ``(wrote, stop)``: an output column was written; the test is over (end condition fired and the
        car at rest long enough).
    """
    p = tab.p
    dt = p[P_DT_S]
    wheel_radius_m = p[P_WHEEL_RADIUS_M]
    final_drive_ratio = p[P_FINAL_DRIVE_RATIO]
    smin = p[P_SOC_MIN_FRAC]
    smax = p[P_SOC_MAX_FRAC]

    speed_mps = st[S_SPEED_MPS]
    distance_m = st[S_DISTANCE_M]
    pump_speed_radps = st[S_PUMP_SPEED_RADPS]
    engine_speed_radps = st[S_ENGINE_SPEED_RADPS]
    engine_on = st[S_ENGINE_ON] > 0.5
    k0_closed = st[S_K0_CLOSED] > 0.5
    lockup_closed = st[S_LOCKUP_CLOSED] > 0.5
    gear = int(st[S_GEAR])
    gear_target = int(st[S_GEAR_TARGET])
    shift_timer_s = st[S_SHIFT_TIMER_S]
    soc_frac = st[S_SOC_FRAC]
    lv_soc_frac = st[S_LV_SOC_FRAC]
    driver_force_n = st[S_DRIVER_FORCE_N]
    driver_error_mps = st[S_DRIVER_ERROR_MPS]
    dyno_force_n = st[S_DYNO_FORCE_N]
    dyno_error_mps = st[S_DYNO_ERROR_MPS]
    end_latched = st[S_END_LATCHED] > 0.5
    latch_time_s = st[S_LATCH_TIME_S]
    latch_speed_mps = st[S_LATCH_SPEED_MPS]
    segment = st[S_SEGMENT]
    engine_on_time_s, start_left_kg = st[S_ENGINE_ON_TIME_S], st[S_START_LEFT_KG]
    esave_soc_pct = st[S_ESAVE_SOC_PCT]
    eff_mass_kg = st[S_EFF_MASS_KG]
    kstep = int(st[S_STEP])
    lockup_engage_time_s, inertia_phase_left_s = st[S_LOCKUP_ENGAGE_S], st[S_INERTIA_PHASE_S]
    old_gain_rad_per_m = st[S_OLD_GAIN_RAD_PER_M]
    hifi = p[P_HIFI] > 0.5
    rc1_v, rc2_v, hysteresis = st[S_RC1_V], st[S_RC2_V], st[S_HYSTERESIS]
    battery_degc, coolant_degc, oil_degc = st[S_BATTERY_DEGC], st[S_COOLANT_DEGC], st[S_OIL_DEGC]
    kin = 1.0 + st[S_TYRE_SLIP]  # wheel speed / roller speed (exactly 1 for the paper form)

    time_s = kstep * dt
    dyno_mode = int(cmd[C_DYNO_MODE, i])
    hybrid_mode = int(cmd[C_HMODE, i])
    displayed_soc_pct = 100.0 * (soc_frac - smin) / (smax - smin)
    engine_cmd, k0_cmd = bms_commands(p, displayed_soc_pct, engine_on, int(cmd[C_ENG, i]), int(cmd[C_K0, i]))

    # ---- protocol: new test, dyno mode, end condition ----
    (segment, end_latched, latch_time_s, latch_speed_mps, driver_force_n, driver_error_mps, esave_soc_pct,
     eff_mass_kg, dyno_force_n, dyno_error_mps) = protocol_step(
        p, led, time_s, speed_mps, displayed_soc_pct, cmd[C_SEG, i], dyno_mode, int(cmd[C_END_KIND, i]),
        cmd[C_END_VAL, i], segment, end_latched, latch_time_s, latch_speed_mps, driver_force_n, driver_error_mps,
        esave_soc_pct, eff_mass_kg, dyno_force_n, dyno_error_mps)

    # ---- driver ----
    pedal_pct, brake_pct, driver_force_n, driver_error_mps = driver_step(
        tab, time_s, speed_mps, gear, hybrid_mode, int(cmd[C_DRV_MODE, i]), cmd[C_PEDAL, i], cmd[C_BRAKE, i],
        cmd[C_VTGT, i], cmd[C_VPRE, i], cmd[C_AREF, i], end_latched, latch_time_s, latch_speed_mps,
        driver_force_n, driver_error_mps)

    # ---- shift logic: target gear, then actual gear after the actuation delay ----
    (gear_target, gear, shift_timer_s, lockup_closed, lockup_engage_time_s, inertia_phase_left_s,
     old_gain_rad_per_m) = shift_step(
        tab, speed_mps * kin, pedal_pct, int(cmd[C_GEAR, i]), gear_target, gear, shift_timer_s, lockup_closed,
        lockup_engage_time_s, inertia_phase_left_s, old_gain_rad_per_m)
    inertia_phase_left_s, gain_rad_per_m, eff_gain_rad_per_m, eff_ratio, turbine_speed_radps = gear_gains(
        tab, gear, inertia_phase_left_s, old_gain_rad_per_m, speed_mps * kin, pump_speed_radps)

    # ---- machine limits and torque demand ----
    motor_max_nm, motor_gen_max_nm, engine_max_nm, torque_demand_nm, power_demand_w, limit_speed_radps = \
        torque_demand(tab, pump_speed_radps, turbine_speed_radps, speed_mps, pedal_pct, hybrid_mode, engine_cmd,
                      gear, lockup_closed, displayed_soc_pct)

    # ---- hybrid strategy: engine on/off ----
    engine_on, engine_on_time_s, start_fuel_kg, start_left_kg = engine_on_off(
        p, engine_cmd, hybrid_mode, engine_on, engine_on_time_s, pedal_pct, displayed_soc_pct, power_demand_w,
        speed_mps, esave_soc_pct, start_left_kg)

    # ---- K0 clutch ----
    k0_closed, engine_speed_radps, pump_speed_radps, speed_mps, turbine_speed_radps, engine_self_energy_j = k0_step(
        p, led, k0_cmd, engine_on, k0_closed, engine_speed_radps, pump_speed_radps, speed_mps,
        turbine_speed_radps, lockup_closed, gear, gain_rad_per_m * kin, eff_mass_kg)
    pump_inertia_kgm2 = p[P_MOTOR_INERTIA_KGM2] + (p[P_ENGINE_INERTIA_KGM2] if k0_closed else 0.0)

    # ---- lock-up command, torque split, brakes and blending, pump-side torque control ----
    lockup_request, lockup_closed, lockup_engage_time_s = lockup_command(
        p, int(cmd[C_LU, i]), gear, speed_mps, brake_pct, lockup_closed, lockup_engage_time_s)
    engine_torque_nm, motor_torque_nm = torque_split(
        p, hybrid_mode, displayed_soc_pct, esave_soc_pct, k0_closed, engine_on, pump_speed_radps, torque_demand_nm,
        motor_max_nm, motor_gen_max_nm, engine_max_nm, limit_speed_radps)
    brake_demand_nm, hydraulic_brake_nm, motor_torque_nm = brake_blending(
        tab, brake_pct, gear, lockup_closed, lockup_request, speed_mps, engine_torque_nm, motor_torque_nm,
        motor_gen_max_nm, pump_speed_radps, turbine_speed_radps, k0_closed, engine_on, lockup_engage_time_s,
        shift_timer_s if gear != gear_target else 0.0)
    engine_torque_nm, motor_torque_nm, idle_gain_nm_per_radps = pump_torque_control(
        p, gear, lockup_closed, k0_closed, engine_on, speed_mps, pump_speed_radps, pedal_pct, pump_inertia_kgm2,
        gain_rad_per_m * kin, old_gain_rad_per_m * kin, inertia_phase_left_s, engine_torque_nm, motor_torque_nm,
        engine_max_nm, motor_max_nm, motor_gen_max_nm)
    front_brake_nm, rear_brake_nm, brake_force_n = brake_split(p, brake_demand_nm, hydraulic_brake_nm)

    # ---- engine fuel (BSFC map, eq. 26-28) ----
    fuel_flow_kgps, fuel_energy_j = engine_fuel(tab, engine_on, k0_closed, engine_torque_nm, pump_speed_radps,
                                                engine_speed_radps, start_fuel_kg, coolant_degc)

    # ---- dyno forces ----
    road_load_n, parasitic_n, dyno_applied_n, external_force_n, dyno_set_mps, dyno_force_n, dyno_error_mps = \
        dyno_forces(p, dyno_mode, cmd[C_DYNO_SET, i], speed_mps, dyno_force_n, dyno_error_mps)

    # ---- lock-up engagement ----
    source_torque_nm = engine_torque_nm + motor_torque_nm
    (lockup_closed, lockup_engage_time_s, lockup_capacity_nm, speed_mps, pump_speed_radps, turbine_speed_radps,
     engine_speed_radps) = lockup_engagement(
        tab, led, lockup_request, lockup_closed, gear, inertia_phase_left_s, lockup_engage_time_s, k0_closed,
        source_torque_nm, pump_inertia_kgm2, gain_rad_per_m * kin, eff_mass_kg, speed_mps, pump_speed_radps,
        turbine_speed_radps, engine_speed_radps)

    # ---- driveline and vehicle (gear drag: eq. 14's C0, or the high-fidelity spin loss) ----
    drag_torque_nm = tab.c0[gear]
    if hifi and gear > 0:
        drag_torque_nm = spin_loss_torque_nm(tab.c0[gear], p[P_HF_SPIN_PER_RADPS], p[P_HF_OIL_VISC_PER_K],
                                             p[P_HF_OIL_REF_DEGC], turbine_speed_radps, oil_degc)
    (accel_mps2, pump_torque_nm, turbine_torque_nm, lockup_torque_nm, input_torque_nm, output_torque_nm,
     pump_torque_eff_nm, lockup_torque_eff_nm, slip_gain_rad_per_m, pump_speed_step_radps) = driveline_step(
        tab, gear, lockup_closed, speed_mps, pump_speed_radps, turbine_speed_radps, source_torque_nm,
        pump_inertia_kgm2, gain_rad_per_m, eff_ratio, old_gain_rad_per_m, inertia_phase_left_s, lockup_capacity_nm,
        idle_gain_nm_per_radps, eff_mass_kg, external_force_n, brake_force_n, drag_torque_nm, kin)
    wheel_force_n = final_drive_ratio * output_torque_nm / wheel_radius_m
    (accel_mps2, new_speed_mps, stop_force_n, mid_speed_mps, new_pump_speed_radps, mid_pump_speed_radps,
     mid_turbine_speed_radps, mid_shaft_speed_radps) = vehicle_step(
        p, gear, lockup_closed, speed_mps, accel_mps2, pump_speed_radps, pump_speed_step_radps, gain_rad_per_m * kin,
        eff_gain_rad_per_m * kin, eff_mass_kg)
    mid_shaft_speed_radps *= kin  # the shaft turns with the slipping wheels

    # ---- motor electrical power (Willans, or the high-fidelity loss model), 12 V system, HV battery ----
    if hifi:
        motor_elec_w = 0.0
        if pump_speed_radps >= 1.0 or abs(motor_torque_nm) >= 0.5:
            motor_elec_w = (motor_torque_nm * pump_speed_radps
                            + motor_loss_hifi_w(tab.motor_loss, motor_torque_nm, pump_speed_radps))
    else:
        motor_elec_w = motor_elec_power_w(p[P_WILLANS_E], p[P_WILLANS_LOSS_W], p[P_WILLANS_E_GEN],
                                          p[P_WILLANS_LOSS_GEN_W], motor_torque_nm, pump_speed_radps)
    lv_load_w = cmd[C_LVLOAD, i]
    lv_ocv_v, lv_bus_v, lv_battery_current_a, dcdc_lv_current_a, dcdc_lv_power_w, dcdc_hv_power_w = lv_system(
        p, lv_soc_frac, lv_load_w)
    hv_aux_w = hv_auxiliary_draw_w(p, led, dcdc_hv_power_w)  # 0 for a conventional car (alternator)
    if hifi:
        hv_ocv_v, hv_resistance_ohm, hv_current_a, hv_terminal_v = hv_battery_hifi(
            tab, soc_frac, motor_elec_w + hv_aux_w, rc1_v, rc2_v, hysteresis, battery_degc)
    else:
        hv_ocv_v, hv_resistance_ohm, hv_current_a, hv_terminal_v = hv_battery(tab, soc_frac, motor_elec_w + hv_aux_w)

    # ---- ledger ----
    ledger_electrical(p, led, fuel_energy_j, hv_ocv_v, hv_resistance_ohm, hv_current_a, lv_ocv_v,
                      lv_battery_current_a, dcdc_hv_power_w, dcdc_lv_power_w, lv_load_w)
    ledger_machines(p, led, gear, lockup_closed, k0_closed, engine_on, engine_torque_nm, motor_torque_nm,
                    motor_elec_w, fuel_energy_j, engine_self_energy_j, idle_gain_nm_per_radps, pump_speed_step_radps,
                    mid_pump_speed_radps)
    ledger_driveline(p, led, gear, lockup_closed, dyno_mode, pump_torque_eff_nm, turbine_torque_nm,
                     lockup_torque_eff_nm, lockup_torque_nm, input_torque_nm, output_torque_nm, slip_gain_rad_per_m,
                     mid_pump_speed_radps, mid_turbine_speed_radps, mid_speed_mps, mid_shaft_speed_radps,
                     brake_force_n, stop_force_n, road_load_n, parasitic_n, dyno_applied_n)
    if hifi:  # shaft power at the wheel speed less the force at the roller speed: the tyres' slip loss
        led[L_TYRE] += (output_torque_nm * mid_shaft_speed_radps - wheel_force_n * mid_speed_mps) * dt

    # ---- outputs (state at the start of the step, actions over the step) ----
    wrote = False
    moving = 1.0 if mid_speed_mps > 0.0 else 0.0
    if kstep % decim == 0:
        o = out[:, iout]
        o[out_rows.O_V] = speed_mps * kin  # the car's speed from its driven wheels; the dyno's is O_VDYN
        o[out_rows.O_A] = accel_mps2
        o[out_rows.O_X] = distance_m
        o[out_rows.O_DSET] = dyno_set_mps
        o[out_rows.O_FFRONT] = -moving * front_brake_nm / wheel_radius_m - 0.5 * parasitic_n
        o[out_rows.O_FREAR] = wheel_force_n - moving * rear_brake_nm / wheel_radius_m - 0.5 * parasitic_n
        o[out_rows.O_FRL] = road_load_force_n(p[P_F0_N], p[P_F1_N_PER_MPS], p[P_F2_N_PER_MPS2], speed_mps)
        o[out_rows.O_PEDAL] = pedal_pct
        o[out_rows.O_BRAKE] = brake_pct
        o[out_rows.O_HMODE] = hybrid_mode
        o[out_rows.O_WE] = pump_speed_radps if k0_closed else engine_speed_radps
        o[out_rows.O_TE] = engine_torque_nm
        o[out_rows.O_EON] = 1.0 if engine_on else 0.0
        o[out_rows.O_FUEL] = fuel_flow_kgps
        o[out_rows.O_K0] = 1.0 if k0_closed else 0.0
        o[out_rows.O_WP] = pump_speed_radps
        o[out_rows.O_TM] = motor_torque_nm
        o[out_rows.O_PEL] = motor_elec_w
        o[out_rows.O_TP] = pump_torque_nm
        o[out_rows.O_WT] = turbine_speed_radps
        o[out_rows.O_TT] = turbine_torque_nm
        o[out_rows.O_LU] = 1.0 if (lockup_closed and gear > 0) else 0.0
        o[out_rows.O_GT] = gear_target
        o[out_rows.O_GA] = gear
        o[out_rows.O_TIN] = input_torque_nm
        o[out_rows.O_TOUT] = output_torque_nm
        o[out_rows.O_WS] = final_drive_ratio * speed_mps / wheel_radius_m * kin
        o[out_rows.O_WW] = speed_mps / wheel_radius_m * kin
        o[out_rows.O_PF] = front_brake_nm / p[P_BRAKE_GAIN_FRONT_NM_PER_BAR] * 1e5
        o[out_rows.O_PR] = rear_brake_nm / p[P_BRAKE_GAIN_REAR_NM_PER_BAR] * 1e5
        o[out_rows.O_PMC] = max(o[out_rows.O_PF], o[out_rows.O_PR])
        o[out_rows.O_TBF] = front_brake_nm
        o[out_rows.O_TBR] = rear_brake_nm
        o[out_rows.O_IB] = hv_current_a
        o[out_rows.O_VB] = hv_terminal_v
        o[out_rows.O_OCV] = hv_ocv_v
        o[out_rows.O_SOC] = soc_frac
        o[out_rows.O_DSOC] = displayed_soc_pct
        o[out_rows.O_ILV] = dcdc_lv_current_a
        o[out_rows.O_VLV] = lv_bus_v
        o[out_rows.O_ILVB] = lv_battery_current_a
        o[out_rows.O_Q_ENGINE] = (fuel_flow_kgps * p[P_FUEL_LHV_J_PER_KG] - engine_torque_nm * pump_speed_radps
                         if engine_on else 0.0)
        o[out_rows.O_Q_MOTOR] = motor_elec_w - motor_torque_nm * pump_speed_radps
        o[out_rows.O_Q_BATT] = hv_resistance_ohm * hv_current_a * hv_current_a
        o[out_rows.O_VDYN] = speed_mps
        o[out_rows.O_T_BATT] = battery_degc if hifi else np.nan
        o[out_rows.O_T_COOLANT] = coolant_degc if hifi else np.nan
        o[out_rows.O_T_OIL] = oil_degc if hifi else np.nan
        wrote = True

    # ---- advance states ----
    distance_m += mid_speed_mps * dt
    speed_mps = new_speed_mps
    pump_speed_radps = new_pump_speed_radps
    if k0_closed:
        engine_speed_radps = pump_speed_radps
    soc_frac -= hv_current_a * dt / p[P_BATT_CAPACITY_AS]
    lv_soc_frac -= lv_battery_current_a * dt / p[P_LV_CAPACITY_AS]
    time_s = (kstep + 1) * dt
    if inertia_phase_left_s > 0.0:
        inertia_phase_left_s = max(inertia_phase_left_s - dt, 0.0)
    kstep += 1
    if hifi:
        rc1_v, rc2_v, hysteresis = hv_battery_dynamics(p, hv_current_a, rc1_v, rc2_v, hysteresis)
        engine_heat_w = (fuel_flow_kgps * p[P_FUEL_LHV_J_PER_KG] - engine_torque_nm * pump_speed_radps
                         if engine_on else 0.0)
        trans_loss_w = 0.0
        if gear > 0:
            trans_loss_w = (input_torque_nm * (mid_turbine_speed_radps - slip_gain_rad_per_m * mid_speed_mps)
                            - output_torque_nm * mid_shaft_speed_radps)
        battery_degc, coolant_degc, oil_degc = hifi_thermal_step(
            p, engine_heat_w, hv_resistance_ohm * hv_current_a * hv_current_a, trans_loss_w, battery_degc,
            coolant_degc, oil_degc)
    slip = tyre_slip(wheel_force_n - moving * rear_brake_nm / wheel_radius_m, p[P_HF_SLIP_STIFFNESS_N])
    stop = (end_latched and speed_mps <= 0.0
            and time_s - latch_time_s > latch_speed_mps / p[P_DRIVER_STOP_DECEL_MPS2] + 3.0)

    st[S_SPEED_MPS] = speed_mps
    st[S_DISTANCE_M] = distance_m
    st[S_PUMP_SPEED_RADPS] = pump_speed_radps
    st[S_ENGINE_SPEED_RADPS] = engine_speed_radps
    st[S_ENGINE_ON] = 1.0 if engine_on else 0.0
    st[S_K0_CLOSED] = 1.0 if k0_closed else 0.0
    st[S_LOCKUP_CLOSED] = 1.0 if lockup_closed else 0.0
    st[S_GEAR], st[S_GEAR_TARGET] = gear, gear_target
    st[S_SHIFT_TIMER_S] = shift_timer_s
    st[S_SOC_FRAC], st[S_LV_SOC_FRAC] = soc_frac, lv_soc_frac
    st[S_DRIVER_FORCE_N] = driver_force_n
    st[S_DRIVER_ERROR_MPS] = driver_error_mps
    st[S_DYNO_FORCE_N] = dyno_force_n
    st[S_DYNO_ERROR_MPS] = dyno_error_mps
    st[S_END_LATCHED] = 1.0 if end_latched else 0.0
    st[S_LATCH_TIME_S] = latch_time_s
    st[S_LATCH_SPEED_MPS] = latch_speed_mps
    st[S_SEGMENT] = segment
    st[S_ENGINE_ON_TIME_S], st[S_START_LEFT_KG] = engine_on_time_s, start_left_kg
    st[S_ESAVE_SOC_PCT] = esave_soc_pct
    st[S_EFF_MASS_KG] = eff_mass_kg
    st[S_TIME_S] = time_s
    st[S_STEP] = kstep
    st[S_LOCKUP_ENGAGE_S], st[S_INERTIA_PHASE_S] = lockup_engage_time_s, inertia_phase_left_s
    st[S_OLD_GAIN_RAD_PER_M] = old_gain_rad_per_m
    st[S_RC1_V], st[S_RC2_V], st[S_HYSTERESIS] = rc1_v, rc2_v, hysteresis
    st[S_BATTERY_DEGC], st[S_COOLANT_DEGC], st[S_OIL_DEGC], st[S_TYRE_SLIP] = battery_degc, coolant_degc, oil_degc, slip
    return wrote, stop
