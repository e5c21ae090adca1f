"""Sub-steps of a plant step, first half: protocol, driver, shift logic, hybrid strategy, clutches, brakes.

Each sub-step is a pure ``@njit`` function of scalars, the scalar parameter vector ``p`` (``P_*``
indices of :mod:`benchtwin.emulator.params`) and, where it needs lookup tables, the parameter record
``tab`` (:class:`~benchtwin.emulator.params.PlantTables`). It returns its results as a tuple; the only
side effect some have is booking clutch slip or dyno energy into the ledger ``led`` (``L_*``, J). The
order in which :func:`benchtwin.emulator.plant.plant_step` calls them is the order of the physics.

Names carry their units: ``_mps`` m/s, ``_radps`` rad/s, ``_nm`` Nm, ``_n`` N, ``_w`` W, ``_s`` s,
``_pct`` %, ``_rad_per_m`` rad/s of pump speed per m/s of vehicle speed, ``_kg`` kg.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from benchtwin.emulator.models import bms_power_limits_w, converter_torques_nm, interp_1d, road_load_force_n
from benchtwin.emulator.params import (
    L_DYNO,
    P_BATT_MAX_CHARGE_W,
    P_BATT_MAX_DISCHARGE_W,
    P_BMS_CHARGE_BAND_PCT,
    P_BMS_DISCHARGE_BAND_PCT,
    P_BMS_ENGINE_START_PCT,
    P_BRAKE_MAX_TORQUE_NM,
    P_COAST_REGEN_TORQUE_NM,
    P_DRIVER_B0_N_PER_MPS,
    P_DRIVER_B1_N_PER_MPS,
    P_DRIVER_FEEDBACK_MAX_N,
    P_DRIVER_PREVIEW_STEPS,
    P_DRIVER_STOP_DECEL_MPS2,
    P_DT_S,
    P_ENGINE_IDLE_RADPS,
    P_ENGINE_START_FUEL_KG,
    P_ENGINE_START_FUEL_S,
    P_F0_N,
    P_F1_N_PER_MPS,
    P_F2_N_PER_MPS2,
    P_FINAL_DRIVE_RATIO,
    P_HYB_ENGINE_OFF_W,
    P_HYB_ENGINE_ON_MPS,
    P_HYB_ENGINE_ON_W,
    P_HYB_ESAVE_ON_W,
    P_HYB_KICKDOWN_PEDAL_PCT,
    P_HYB_MAX_WHEEL_FORCE_N,
    P_HYB_MIN_ON_S,
    P_HYB_SUSTAIN_SOC_PCT,
    P_MASS_KG,
    P_N_GEARS,
    P_REGEN_CUTOFF_MPS,
    P_SHIFT_DELAY_S,
    P_SHIFT_INERTIA_PHASE_S,
    P_SPEED_CTRL_MASS_KG,
    P_TC_COUPLING_SPEED_RATIO,
    P_WHEEL_RADIUS_M,
    P_WILLANS_E,
    P_WILLANS_E_GEN,
    P_WILLANS_LOSS_GEN_W,
    P_WILLANS_LOSS_W,
    PlantTables,
)

#: road load (and the driver's feed-forward of it) fades in below 0.5 km/h: no force at standstill
ROAD_LOAD_FADE_MPS = 0.5 / 3.6


@njit(cache=True, _nrt=False)
def protocol_step(p: np.ndarray, led: np.ndarray, time_s: float, speed_mps: float, displayed_soc_pct: float,
                  segment_cmd: float, dyno_mode: int, end_kind: int, end_value: float, segment: float,
                  end_latched: bool, latch_time_s: float, latch_speed_mps: float, driver_force_n: float,
                  driver_error_mps: float, esave_soc_pct: float, eff_mass_kg: float, dyno_force_n: float,
                  dyno_error_mps: float) -> tuple:
    """Protocol bookkeeping: a new test resets the driver, a dyno mode change swaps the simulated mass,
    and the test's end condition latches (speed reached, displayed SOC reached, or at once).

    Returns
    -------
    tuple
        ``(segment, end_latched, latch_time_s, latch_speed_mps, driver_force_n, driver_error_mps,
        esave_soc_pct, eff_mass_kg, dyno_force_n, dyno_error_mps)``. A mass change books
        ``-0.5 (m_new - m_old) v^2`` into ``led[L_DYNO]`` (the dyno supplies the change of simulated inertia).
    """
    if segment_cmd != segment:
        end_latched = False
        driver_force_n = 0.0
        driver_error_mps = 0.0
        esave_soc_pct = displayed_soc_pct
        segment = segment_cmd
    # dyno mode: simulated inertia (road-load) or rollers only (speed-controlled)
    m_new = p[P_MASS_KG] if dyno_mode == 0 else p[P_SPEED_CTRL_MASS_KG]
    if m_new != eff_mass_kg:
        led[L_DYNO] -= 0.5 * (m_new - eff_mass_kg) * speed_mps * speed_mps
        eff_mass_kg = m_new
        dyno_force_n = 0.0
        dyno_error_mps = 0.0
    if not end_latched and end_kind > 0:
        ev = end_value
        if ((end_kind == 1 and speed_mps >= ev) or (end_kind == 2 and displayed_soc_pct <= ev)
                or (end_kind == 3 and displayed_soc_pct >= ev) or end_kind == 4):
            end_latched = True
            latch_time_s = time_s
            latch_speed_mps = speed_mps
    return (segment, end_latched, latch_time_s, latch_speed_mps, driver_force_n, driver_error_mps, esave_soc_pct,
            eff_mass_kg, dyno_force_n, dyno_error_mps)


@njit(cache=True, _nrt=False)
def driver_step(tab: PlantTables, time_s: float, speed_mps: float, gear: int, hybrid_mode: int, drive_mode: int,
                pedal_cmd_pct: float, brake_cmd_pct: float, target_mps: float, preview_mps: float,
                ref_accel_mps2: float, end_latched: bool, latch_time_s: float, latch_speed_mps: float,
                driver_force_n: float, driver_error_mps: float) -> tuple[float, float, float, float]:
    """Driver: pedals from the protocol, or a PI on force with feed-forward that follows the target speed.

    Feed-forward ``m a_ref + (F0 + F1 v + F2 v^2)`` at the previewed target; PI ``u[k] = u[k-1] + b0 e[k]
    + b1 e[k-1]`` clamped to +-``P_DRIVER_FEEDBACK_MAX_N``; the force becomes accelerator pedal through the
    force available in the current gear (90 % of the machines' full load, at least 500 N), or brake pedal
    through the maximum brake torque. After the end condition latched, the target is a stop at
    ``P_DRIVER_STOP_DECEL_MPS2``.

    Returns
    -------
    tuple
        ``(pedal_pct, brake_pct, driver_force_n, driver_error_mps)``.
    """
    p = tab.p
    dt = p[P_DT_S]
    rw = p[P_WHEEL_RADIUS_M]
    pedal = pedal_cmd_pct
    brake = brake_cmd_pct
    v = speed_mps
    if end_latched or drive_mode == 1:
        if end_latched:
            npre = int(p[P_DRIVER_PREVIEW_STEPS])
            vt = max(latch_speed_mps - p[P_DRIVER_STOP_DECEL_MPS2] * (time_s - latch_time_s), 0.0)
            vt_pre = max(latch_speed_mps - p[P_DRIVER_STOP_DECEL_MPS2] * (time_s + npre * dt - latch_time_s), 0.0)
            aref = -p[P_DRIVER_STOP_DECEL_MPS2] if vt_pre > 0.0 else 0.0
        else:
            vt = target_mps
            vt_pre = preview_mps  # previewed target and reference acceleration (protocols.py)
            aref = ref_accel_mps2
        ff = p[P_MASS_KG] * aref + road_load_force_n(p[P_F0_N], p[P_F1_N_PER_MPS], p[P_F2_N_PER_MPS2],
                                                     vt_pre) * min(vt_pre / ROAD_LOAD_FADE_MPS, 1.0)
        e = vt - v
        driver_force_n = driver_force_n + p[P_DRIVER_B0_N_PER_MPS] * e + p[P_DRIVER_B1_N_PER_MPS] * driver_error_mps
        driver_force_n = min(max(driver_force_n, -p[P_DRIVER_FEEDBACK_MAX_N]), p[P_DRIVER_FEEDBACK_MAX_N])
        driver_error_mps = e
        u = ff + driver_force_n
        # pedal map estimate: available force in the current gear
        gest = max(gear, 1)
        kk = tab.ratios[gest] * p[P_FINAL_DRIVE_RATIO] / rw
        west = max(kk * v, p[P_ENGINE_IDLE_RADPS])
        tav = interp_1d(west, tab.m_fl_w, tab.m_fl_t)
        if hybrid_mode != 1:
            tav += interp_1d(west, tab.e_fl_w, tab.e_fl_t)
        fav = max(tav * kk * 0.9, 500.0)
        if u >= 0.0:
            pedal = min(100.0 * u / fav, 100.0)
            brake = 0.0
        else:
            pedal = 0.0
            brake = min(100.0 * (-u) * rw / p[P_BRAKE_MAX_TORQUE_NM], 100.0)
        if vt <= 0.0 and vt_pre <= 0.0 and v < 0.3:
            pedal = 0.0
            brake = max(brake, 25.0)
            driver_force_n = 0.0
    return pedal, brake, driver_force_n, driver_error_mps


@njit(cache=True, _nrt=False)
def shift_step(tab: PlantTables, speed_mps: float, pedal_pct: float, gear_cmd: int, gear_target: int, gear: int,
               shift_timer_s: float, lockup_closed: bool, lockup_engage_time_s: float,
               inertia_phase_left_s: float, old_gain_rad_per_m: float) -> tuple:
    """Shift schedule and actuation: target gear from the shift lines, actual gear after the delay.

    Upshift from g when v >= u0_g + u1_g pedal, downshift when v <= d0_g + d1_g pedal (a held gear
    ``gear_cmd >= 0`` overrides). The actual gear follows one gear at a time after ``P_SHIFT_DELAY_S``;
    a clutch-to-clutch shift opens the lock-up and starts the inertia phase.

    Returns
    -------
    tuple
        ``(gear_target, gear, shift_timer_s, lockup_closed, lockup_engage_time_s, inertia_phase_left_s,
        old_gain_rad_per_m)``.
    """
    p = tab.p
    v = speed_mps
    if gear_cmd >= 0:
        gear_target = gear_cmd
    else:
        if gear_target == 0:
            gear_target = 1
        if gear_target < int(p[P_N_GEARS]) and v >= tab.up_v0[gear_target - 1] + tab.up_s[gear_target - 1] * pedal_pct:
            gear_target += 1
        elif gear_target > 1 and v <= tab.dn_v0[gear_target - 2] + tab.dn_s[gear_target - 2] * pedal_pct:
            gear_target -= 1
    if gear != gear_target:
        shift_timer_s += p[P_DT_S]
        if shift_timer_s >= p[P_SHIFT_DELAY_S] - 1e-9:
            g_old = gear
            if gear_target == 0 or gear == 0:
                gear = gear_target
            elif gear_target > gear:
                gear += 1
            else:
                gear -= 1
            shift_timer_s = 0.0
            if g_old > 0 and gear > 0:
                # clutch-to-clutch shift: the lock-up opens (slip control), the turbine speed moves to the
                # new ratio over the inertia phase while the motor takes the pump side's inertia torque
                lockup_closed = False
                lockup_engage_time_s = 0.0
                inertia_phase_left_s = p[P_SHIFT_INERTIA_PHASE_S]
                old_gain_rad_per_m = tab.ratios[g_old] * p[P_FINAL_DRIVE_RATIO] / p[P_WHEEL_RADIUS_M]
    else:
        shift_timer_s = 0.0
    return (gear_target, gear, shift_timer_s, lockup_closed, lockup_engage_time_s, inertia_phase_left_s,
            old_gain_rad_per_m)


@njit(cache=True, _nrt=False)
def gear_gains(tab: PlantTables, gear: int, inertia_phase_left_s: float, old_gain_rad_per_m: float, speed_mps: float,
               pump_speed_radps: float) -> tuple[float, float, float, float, float]:
    """Speed gains of the gear: turbine speed per vehicle speed, blended from the old gear over the inertia phase.

    Returns
    -------
    tuple
        ``(inertia_phase_left_s, gain_rad_per_m, eff_gain_rad_per_m, eff_ratio, turbine_speed_radps)``:
        the inertia phase ends in neutral; ``gain`` is i_g i_fd / r_w of the actual gear, ``eff_gain`` the
        gain blended from the old gear's over the inertia phase and ``eff_ratio`` its gear ratio; the
        turbine speed is the pump speed in neutral.
    """
    p = tab.p
    rw = p[P_WHEEL_RADIUS_M]
    ifd = p[P_FINAL_DRIVE_RATIO]
    kg = tab.ratios[gear] * ifd / rw if gear > 0 else 0.0
    if gear == 0:
        inertia_phase_left_s = 0.0
    t_inertia = p[P_SHIFT_INERTIA_PHASE_S]
    kge = kg + (old_gain_rad_per_m - kg) * (inertia_phase_left_s / t_inertia) if inertia_phase_left_s > 0.0 else kg
    rge = kge * rw / ifd
    wt = kge * speed_mps if gear > 0 else pump_speed_radps
    return inertia_phase_left_s, kg, kge, rge, wt


@njit(cache=True, _nrt=False)
def torque_demand(tab: PlantTables, pump_speed_radps: float, turbine_speed_radps: float, speed_mps: float,
                  pedal_pct: float, hybrid_mode: int, engine_cmd: int, gear: int, lockup_closed: bool,
                  displayed_soc_pct: float) -> tuple:
    """Machine limits and the driver's torque demand at the pump (eq. 18-24 power limits, eq. 35-36 limiter).

    The motor is limited by its full-load curve and the battery's discharge / charge power through the
    Willans line, both derated by the BMS towards the ends of the usable window
    (:func:`~benchtwin.emulator.models.bms_power_limits_w`); the demand is the pedal share of what is
    available, limited to ``P_HYB_MAX_WHEEL_FORCE_N`` at the wheels through the converter's present torque
    ratio, and a coast-regeneration torque (within the charge limit) with the pedal released and the lock-up
    closed.

    Returns
    -------
    tuple
        ``(motor_max_nm, motor_gen_max_nm, engine_max_nm, torque_demand_nm, power_demand_w,
        limit_speed_radps)`` with ``limit_speed_radps = max(omega_p, 1)``.
    """
    p = tab.p
    wp = pump_speed_radps
    wq = max(wp, 1.0)
    p_dis_w, p_chg_w = bms_power_limits_w(p[P_BATT_MAX_DISCHARGE_W], p[P_BATT_MAX_CHARGE_W], displayed_soc_pct,
                                          p[P_BMS_DISCHARGE_BAND_PCT], p[P_BMS_CHARGE_BAND_PCT])
    tm_max = interp_1d(wp, tab.m_fl_w, tab.m_fl_t)
    tm_max = min(tm_max, max((p_dis_w * p[P_WILLANS_E] - p[P_WILLANS_LOSS_W]) / wq, 0.0))
    tm_gen = interp_1d(wp, tab.m_fl_w, tab.m_fl_t)
    tm_gen = min(tm_gen, max((p_chg_w + p[P_WILLANS_LOSS_GEN_W]) / (p[P_WILLANS_E_GEN] * wq), 0.0))
    te_max = interp_1d(max(wp, p[P_ENGINE_IDLE_RADPS]), tab.e_fl_w, tab.e_fl_t)
    t_avail = tm_max if (hybrid_mode == 1 and engine_cmd != 1) else tm_max + te_max
    t_dem = pedal_pct * 0.01 * t_avail
    if gear > 0:
        # traction / gearbox input torque limiter: wheel force at most P_HYB_MAX_WHEEL_FORCE_N through the
        # converter's present torque ratio (launches in low gears)
        tr_now = 1.0
        if not lockup_closed and wp > 1.0:
            tpn, ttn, _dn = converter_torques_nm(tab.tc_a, p[P_TC_COUPLING_SPEED_RATIO], tab.tc_sr, tab.tc_cap,
                                                 tab.tc_tr, wp, turbine_speed_radps)
            if tpn > 1e-3:
                tr_now = max(ttn / tpn, 1.0)
        t_dem = min(t_dem, p[P_HYB_MAX_WHEEL_FORCE_N] * p[P_WHEEL_RADIUS_M]
                    / (tab.ratios[gear] * p[P_FINAL_DRIVE_RATIO] * tab.eta_m[gear] * tr_now) + tab.c0[gear])
    lu_ok = lockup_closed and gear > 0
    if pedal_pct <= 0.0 and lu_ok and speed_mps > p[P_REGEN_CUTOFF_MPS]:
        t_dem = -min(p[P_COAST_REGEN_TORQUE_NM], tm_gen)
    p_dem = t_dem * wp
    return tm_max, tm_gen, te_max, t_dem, p_dem, wq


@njit(cache=True, _nrt=False)
def bms_commands(p: np.ndarray, displayed_soc_pct: float, engine_on: bool, engine_cmd: int,
                 k0_cmd: int) -> tuple[int, int]:
    """BMS floor: the engine and K0 commands after the battery's own request.

    Below ``P_BMS_ENGINE_START_PCT`` displayed SOC the engine is started and K0 closed whatever the test
    commands (a forced-electric test then runs as a real car would: on the engine, which recharges through
    the motor by the hybrid strategy's SOC-sustaining term); with the engine running the request holds until
    the displayed SOC is back above the discharge derating band. A car without an HV pack (start -1) never
    requests.

    Returns
    -------
    tuple of int
        ``(engine_cmd, k0_cmd)``: the test's commands, or ``(1, 1)`` while the BMS requests the engine.
    """
    start = p[P_BMS_ENGINE_START_PCT]
    if start < 0.0:
        return engine_cmd, k0_cmd
    release = max(start, p[P_BMS_DISCHARGE_BAND_PCT])
    if displayed_soc_pct < start or (engine_on and displayed_soc_pct < release):
        return 1, 1
    return engine_cmd, k0_cmd


@njit(cache=True, _nrt=False)
def engine_on_off(p: np.ndarray, engine_cmd: int, hybrid_mode: int, engine_on: bool, engine_on_time_s: float,
                  pedal_pct: float, displayed_soc_pct: float, power_demand_w: float, speed_mps: float,
                  esave_soc_pct: float, start_left_kg: float) -> tuple[bool, float, float, float]:
    """Hybrid strategy, engine on/off: forced by the protocol, or by the mode's power / speed / SOC thresholds.

    Modes: 0 charge-depleting hybrid with a sustain floor, 1 electric (kick-down starts the engine),
    2 e-save (holds the SOC at entry), 3 charge. An engine start costs ``P_ENGINE_START_FUEL_KG``, burnt as a
    pulse over ``P_ENGINE_START_FUEL_S`` (:func:`start_fuel_pulse`); ``start_left_kg`` is what earlier starts
    have still to burn.

    Returns
    -------
    tuple
        ``(engine_on, engine_on_time_s, start_fuel_kg, start_left_kg)``: the start fuel burnt in this step and
        the rest still to burn.
    """
    eon = engine_on
    eon_t = engine_on_time_s
    pedal = pedal_pct
    dsoc = displayed_soc_pct
    p_dem = power_demand_w
    v = speed_mps
    esave = esave_soc_pct
    vk = v * 3.6
    want = eon
    if engine_cmd == 1:
        want = True
    elif engine_cmd == 0:
        want = False
    elif hybrid_mode == 1:
        kick = p[P_HYB_KICKDOWN_PEDAL_PCT]
        want = pedal >= kick or (eon and pedal >= kick - 10.0) or dsoc < 0.5
    elif hybrid_mode == 0:
        if not eon:
            want = (p_dem > p[P_HYB_ENGINE_ON_W] or v > p[P_HYB_ENGINE_ON_MPS]
                    or (dsoc < p[P_HYB_SUSTAIN_SOC_PCT] and vk > 15.0))
        else:
            want = not (p_dem < p[P_HYB_ENGINE_OFF_W] and v < p[P_HYB_ENGINE_ON_MPS] - 5.0 / 3.6
                        and (dsoc >= p[P_HYB_SUSTAIN_SOC_PCT] + 2.0 or vk < 5.0) and eon_t >= p[P_HYB_MIN_ON_S])
    elif hybrid_mode == 2:
        if not eon:
            want = p_dem > p[P_HYB_ESAVE_ON_W] or (dsoc < esave - 1.0 and vk > 10.0)
        else:
            want = not (p_dem < 0.5 * p[P_HYB_ESAVE_ON_W] and (dsoc >= esave or vk < 5.0)
                        and eon_t >= p[P_HYB_MIN_ON_S])
    else:
        want = vk > 3.0 or pedal > 0.0 or (eon and eon_t < p[P_HYB_MIN_ON_S])
    fuel_start = 0.0
    if want and not eon:
        eon = True
        eon_t = 0.0
        fuel_start = p[P_ENGINE_START_FUEL_KG]
    elif not want and eon:
        eon = False
    if eon:
        eon_t += p[P_DT_S]
    burn, left = start_fuel_pulse(p, start_left_kg, fuel_start)
    return eon, eon_t, burn, left


@njit(cache=True, _nrt=False)
def start_fuel_pulse(p: np.ndarray, left_kg: float, added_kg: float) -> tuple[float, float]:
    """The engine-start fuel burnt in this step, and the rest still to burn.

    Each start's ``P_ENGINE_START_FUEL_KG`` (m) is injected at the constant rate m / ``P_ENGINE_START_FUEL_S``
    (cranking and run-up), so over ``ceil(duration / dt)`` steps, the last one taking the remainder; a duration
    no longer than the plant step burns it in the start's step. The rest is burnt even when the engine stops
    before the pulse ends (the start's injection sequence is completed), so every start costs exactly m; a start
    within an unfinished pulse adds its m to the rest, which burns on at the same rate.

    Parameters
    ----------
    p:
        Plant scalars.
    left_kg:
        Start fuel still to burn from earlier steps.
    added_kg:
        The fuel of a start in this step (0 or m).

    Returns
    -------
    tuple of float
        ``(burn_kg, left_kg)``.
    """
    left = left_kg + added_kg
    if left <= 0.0:
        return 0.0, 0.0
    dt, dur = p[P_DT_S], p[P_ENGINE_START_FUEL_S]
    burn = left
    if dur > dt:
        per_step = p[P_ENGINE_START_FUEL_KG] * dt / dur
        if left > per_step * (1.0 + 1e-9):  # else the remainder (a rounding crumb is not left for a step more)
            burn = per_step
    return burn, left - burn

