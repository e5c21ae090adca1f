"""Sub-steps of a plant step, second half: K0 clutch, lock-up, torque split, brakes, driveline and vehicle.

Pure ``@njit`` functions like those of :mod:`benchtwin.emulator.steps_control` (same conventions: scalars
in and a tuple out, ``p`` the ``P_*`` parameter vector, ``tab`` the
:class:`~benchtwin.emulator.params.PlantTables` record, clutch slip energy booked into ``led``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from benchtwin.emulator.models import clutch_merge, converter_torques_nm, transmission_output_torque_nm
from benchtwin.emulator.params import (
    L_K0,
    L_LOCKUP,
    P_BRAKE_FRONT_SHARE_BASE,
    P_BRAKE_FRONT_SHARE_MAX,
    P_BRAKE_FRONT_SHARE_PER_MPS2,
    P_BRAKE_MAX_TORQUE_NM,
    P_CONVENTIONAL,
    P_DT_S,
    P_ENGINE_FRICTION_NM,
    P_ENGINE_FRICTION_NM_PER_RADPS,
    P_ENGINE_IDLE_RADPS,
    P_ENGINE_INERTIA_KGM2,
    P_ENGINE_SPIN_RADPS2,
    P_FINAL_DRIVE_RATIO,
    P_HYB_CHARGE_W,
    P_HYB_SUSTAIN_MAX_W,
    P_HYB_SUSTAIN_SOC_PCT,
    P_HYB_SUSTAIN_W_PER_PCT,
    P_IDLE_GAIN_NM_PER_RADPS,
    P_LOCKUP_CAPACITY_NM,
    P_LOCKUP_ENGAGE_S,
    P_LOCKUP_MIN_GEAR,
    P_LOCKUP_MIN_SPEED_MPS,
    P_MASS_KG,
    P_MOTOR_IDLE_RADPS,
    P_MOTOR_INERTIA_KGM2,
    P_REGEN_CUTOFF_MPS,
    P_SHIFT_DELAY_S,
    P_SHIFT_INERTIA_PHASE_S,
    P_TC_COUPLING_SPEED_RATIO,
    P_WHEEL_RADIUS_M,
    PlantTables,
)


@njit(cache=True, _nrt=False)
def k0_step(p: np.ndarray, led: np.ndarray, k0_cmd: int, engine_on: bool, k0_closed: bool,
            engine_speed_radps: float, pump_speed_radps: float, speed_mps: float, turbine_speed_radps: float,
            lockup_closed: bool, gear: int, gain_rad_per_m: float, eff_mass_kg: float) -> tuple:
    """K0 clutch between engine and motor: opens on request; while open the engine spins on its own towards
    its target (synchronous speed to close, idle or stop otherwise) and the clutch locks within 3 rad/s.

    Locking keeps the momentum of the engine and the pump side (with the vehicle, seen through the gear,
    when the lock-up is closed) and books the slip energy into ``led[L_K0]``.

    Returns
    -------
    tuple
        ``(k0_closed, engine_speed_radps, pump_speed_radps, speed_mps, turbine_speed_radps,
        engine_self_energy_j)``, the last the change of the free engine's kinetic energy (its own fuel).
    """
    je = p[P_ENGINE_INERTIA_KGM2]
    widle_e = p[P_ENGINE_IDLE_RADPS]
    k0 = k0_closed
    we = engine_speed_radps
    wp = pump_speed_radps
    v = speed_mps
    wt = turbine_speed_radps
    kg = gain_rad_per_m
    k0_req = (k0_cmd == 1) or (k0_cmd == -1 and engine_on)
    if k0 and not k0_req:
        k0 = False
        we = wp
    ke_e_self = 0.0
    if not k0:
        if k0_req and (engine_on or k0_cmd == 1):
            target = max(wp, 0.5 * widle_e) if engine_on else wp
        else:
            target = widle_e if engine_on else 0.0
        step = p[P_ENGINE_SPIN_RADPS2] * p[P_DT_S]
        we_new = min(we + step, target) if we < target else max(we - step, target)
        ke_e_self = 0.5 * je * (we_new * we_new - we * we)
        we = we_new
        if k0_req and abs(we - wp) < 3.0:
            # the clutch locks: engine and pump side (with the vehicle if the lock-up is closed) share
            # their momentum; the small speed difference is lost as clutch slip energy
            rigid = lockup_closed and gear > 0 and kg > 0.0
            j2 = p[P_MOTOR_INERTIA_KGM2] + (eff_mass_kg / (kg * kg) if rigid else 0.0)
            w, loss = clutch_merge(je, we, j2, wp)
            led[L_K0] += loss
            wp = w
            we = w
            if rigid:
                v = w / kg
                wt = w
            k0 = True
    else:
        we = wp
    return k0, we, wp, v, wt, ke_e_self


@njit(cache=True, _nrt=False)
def lockup_command(p: np.ndarray, lockup_cmd: int, gear: int, speed_mps: float, brake_pct: float,
                   lockup_closed: bool, lockup_engage_time_s: float) -> tuple[bool, bool, float]:
    """Lock-up clutch request: closed from ``P_LOCKUP_MIN_GEAR`` above ``P_LOCKUP_MIN_SPEED_MPS``, and kept
    closed while braking down to the regeneration cut-off (or forced by the protocol). No request opens it.

    Returns
    -------
    tuple
        ``(lockup_request, lockup_closed, lockup_engage_time_s)``.
    """
    v = speed_mps
    if lockup_cmd == 1:
        lu_req = gear > 0 and v * 3.6 >= 5.0
    elif lockup_cmd == 0:
        lu_req = False
    else:
        lu_req = gear >= p[P_LOCKUP_MIN_GEAR] and (v >= p[P_LOCKUP_MIN_SPEED_MPS]
                                                  or (brake_pct > 0.0 and v > p[P_REGEN_CUTOFF_MPS]))
    if not lu_req:
        lockup_closed = False
        lockup_engage_time_s = 0.0
    return lu_req, lockup_closed, lockup_engage_time_s


@njit(cache=True, _nrt=False)
def torque_split(p: np.ndarray, hybrid_mode: int, displayed_soc_pct: float, esave_soc_pct: float, k0_closed: bool,
                 engine_on: bool, pump_speed_radps: float, torque_demand_nm: float, motor_max_nm: float,
                 motor_gen_max_nm: float, engine_max_nm: float, limit_speed_radps: float) -> tuple[float, float]:
    """Hybrid strategy, torque split between engine and motor at the pump.

    The engine takes the demand plus a SOC-sustaining power (mode 0 below the sustain SOC, mode 2 around
    the e-save SOC), the motor the rest; mode 3 charges at ``P_HYB_CHARGE_W``; mode 1 uses the engine only
    above the motor's limit. With K0 closed and the engine off, the engine drags its friction torque.

    Returns
    -------
    tuple
        ``(engine_torque_nm, motor_torque_nm)``.
    """
    dsoc = displayed_soc_pct
    wq = limit_speed_radps
    t_dem = torque_demand_nm
    te_max = engine_max_nm
    sus_soc = p[P_HYB_SUSTAIN_SOC_PCT]
    sus_k = p[P_HYB_SUSTAIN_W_PER_PCT]
    sus_max = p[P_HYB_SUSTAIN_MAX_W]
    sus = 0.0
    if hybrid_mode == 0 and dsoc < sus_soc:
        sus = min(sus_k * (sus_soc - dsoc), sus_max)
    elif hybrid_mode == 2:
        sus = min(max(sus_k * (esave_soc_pct - dsoc), -sus_max), sus_max)
    te = 0.0
    tm = t_dem
    if k0_closed and engine_on:
        if hybrid_mode == 3:
            tm = -min(p[P_HYB_CHARGE_W] / wq, motor_gen_max_nm)
            te = min(max(t_dem - tm, 0.0), te_max)
            tm = min(t_dem - te, 0.0)
        elif hybrid_mode == 1:
            low = min(sus_k * (sus_soc - dsoc), sus_max) if dsoc < sus_soc else 0.0
            te = min(max(t_dem - motor_max_nm, 0.0) + low / wq, te_max)
            tm = t_dem - te
        else:
            te = min(max(t_dem + sus / wq, 0.0), te_max)
            tm = t_dem - te
    elif k0_closed and not engine_on:
        wp = pump_speed_radps
        te = -(p[P_ENGINE_FRICTION_NM] + p[P_ENGINE_FRICTION_NM_PER_RADPS] * wp) if wp > 1.0 else 0.0
    return te, tm


@njit(cache=True, _nrt=False)
def brake_blending(tab: PlantTables, brake_pct: float, gear: int, lockup_closed: bool, lockup_request: bool,
                   speed_mps: float, engine_torque_nm: float, motor_torque_nm: float,
                   motor_gen_max_nm: float, pump_speed_radps: float, turbine_speed_radps: float,
                   k0_closed: bool, engine_on: bool, lockup_time_s: float, shift_pending_s: float) -> tuple:
    """Brakes: pedal to demanded wheel torque; regeneration first (fading out over the last 8 km/h above the
    cut-off), through the gearbox (eq. 13-14 in coast), the hydraulic brakes for the rest.

    With the lock-up open (a shift's inertia phase, or the clutch still engaging) the regenerative torque is
    limited to what the open converter carries: the source torque may not fall below the pump torque
    ``T_p(w_p, w_t)`` plus ``k_idle (w_floor - w_p)``, ``w_floor`` the turbine speed (and at least the engine's
    idle speed when K0 is closed and the engine fires), so the free pump side follows the turbine instead
    of being dragged down by the motor; the hydraulic brakes take what regeneration cannot. Around a shift the
    regenerative torque beyond that floor is ramped, not stepped: out over the shift's actuation delay
    (``shift_pending_s`` of it elapsed, the lock-up still closed) and back in over ``P_LOCKUP_ENGAGE_S``
    after the lock-up closes (``lockup_time_s`` since the engagement began).

    Returns
    -------
    tuple
        ``(brake_demand_nm, hydraulic_brake_nm, motor_torque_nm)``.
    """
    p = tab.p
    v = speed_mps
    te = engine_torque_nm
    tm = motor_torque_nm
    tm_gen = motor_gen_max_nm
    bdem = brake_pct * 0.01 * p[P_BRAKE_MAX_TORQUE_NM]
    bhyd = bdem
    if bdem > 0.0 and gear > 0 and (lockup_closed or lockup_request) and v > p[P_REGEN_CUTOFF_MPS]:
        # regeneration first (also through a converter opened only for a shift), hydraulic for the rest
        kgr = tab.ratios[gear] * p[P_FINAL_DRIVE_RATIO]
        eta = tab.eta_m[gear]
        c0 = tab.c0[gear]
        fade = min((v - p[P_REGEN_CUTOFF_MPS]) / (8.0 / 3.6), 1.0)
        t_in_need = eta * (c0 - fade * bdem / kgr)
        tm_r = max(t_in_need - te, -tm_gen)
        tm = min(tm, tm_r)
        tm = max(tm, -tm_gen)
        tm_brake = tm
        base = motor_torque_nm  # what the torque split asked for before braking
        share = 1.0  # share of the regenerative torque beyond ``base`` that the controller allows
        if lockup_closed:
            share = (min(lockup_time_s / p[P_LOCKUP_ENGAGE_S], 1.0)
                     * min(max(1.0 - shift_pending_s / p[P_SHIFT_DELAY_S], 0.0), 1.0))
        else:
            # open converter: in overrun it carries only |T_p(w_p, w_t)|, which is ~0 near zero slip, so a
            # generating torque beyond it decelerates the free pump side (0.16-0.36 kg m^2) at hundreds of
            # rad/s^2 and stalls a firing engine within a few tenths of a second. A P2 controller limits
            # regeneration to what the converter carries and holds the pump near the turbine (at least at
            # the engine's idle); the intervention of the inertia phase (pump_torque_control) comes on top.
            # The floor never takes the motor above what the torque split asked for before braking.
            wp = pump_speed_radps
            wt = turbine_speed_radps
            tp_now, _tt, _dtp = converter_torques_nm(tab.tc_a, p[P_TC_COUPLING_SPEED_RATIO], tab.tc_sr, tab.tc_cap,
                                                     tab.tc_tr, wp, wt)
            w_floor = max(wt, p[P_ENGINE_IDLE_RADPS]) if (k0_closed and engine_on) else wt
            t_floor = tp_now + p[P_IDLE_GAIN_NM_PER_RADPS] * (w_floor - wp) - te
            base = max(tm_brake, min(motor_torque_nm, t_floor))
            share = 0.0
        tm = base + share * (tm_brake - base)
        t_in_real = tm + te
        breg = -kgr * (t_in_real / eta - c0) if t_in_real <= eta * c0 else 0.0
        bhyd = max(bdem - breg, 0.0)
    return bdem, bhyd, tm


@njit(cache=True, _nrt=False)
def pump_torque_control(p: np.ndarray, gear: int, lockup_closed: bool, k0_closed: bool, engine_on: bool,
                        speed_mps: float, pump_speed_radps: float, pedal_pct: float, pump_inertia_kgm2: float,
                        gain_rad_per_m: float, old_gain_rad_per_m: float, inertia_phase_left_s: float,
                        engine_torque_nm: float, motor_torque_nm: float, engine_max_nm: float, motor_max_nm: float,
                        motor_gen_max_nm: float) -> tuple[float, float, float]:
    """Torque intervention over a shift's inertia phase, machine limits, and idle-speed holding.

    During the inertia phase the motor takes the pump side's inertia torque J_p (k_new - k_old) v / t_phase.
    With the pump side free (lock-up open or neutral) a proportional idle controller holds the engine or
    motor at idle (the motor lets the pump run down at standstill with the pedal released). A conventional car
    (``P_CONVENTIONAL``) in overrun cuts the fuel: the engine drags its friction torque.

    Returns
    -------
    tuple
        ``(engine_torque_nm, motor_torque_nm, idle_gain_nm_per_radps)``, the last the gain of the active
        idle controller (0 if none), which the semi-implicit pump-speed update uses.
    """
    te = engine_torque_nm
    tm = motor_torque_nm
    tm_gen = motor_gen_max_nm
    tm_max = motor_max_nm
    wp = pump_speed_radps
    v = speed_mps
    kidle = p[P_IDLE_GAIN_NM_PER_RADPS]
    widle_e = p[P_ENGINE_IDLE_RADPS]
    widle_m = p[P_MOTOR_IDLE_RADPS]
    if inertia_phase_left_s > 0.0 and gear > 0 and not lockup_closed:
        # torque intervention during the inertia phase: the motor takes the pump side's inertia torque so
        # that the pump follows the turbine instead of dumping its energy into the driveline
        tm += pump_inertia_kgm2 * (gain_rad_per_m - old_gain_rad_per_m) * v / p[P_SHIFT_INERTIA_PHASE_S]
    tm = min(max(tm, -tm_gen), tm_max)
    # idle speed holding when the pump side is free
    free = (not lockup_closed) or gear == 0
    d_idle = 0.0
    if free:
        if k0_closed and engine_on:
            if wp < widle_e:
                te = min(te + kidle * (widle_e - wp), engine_max_nm)
                d_idle = kidle
        elif gear == 0 and not (k0_closed and engine_on):
            # neutral: the motor holds the pump at idle (or lets it run down at standstill)
            wtarget = widle_m if (pedal_pct > 0.0 or v > 0.3) else 0.0
            tm = min(max(tm + kidle * (wtarget - wp), -min(tm_gen, 30.0)), tm_max)
            d_idle = kidle
        elif (pedal_pct > 0.0 or v > 0.3) and wp < widle_m:  # the motor stops at standstill, pedal released
            tm = min(tm + kidle * (widle_m - wp), tm_max)
            d_idle = kidle
    elif p[P_CONVENTIONAL] > 0.5 and pedal_pct <= 0.0 and wp > 1.25 * widle_e:
        # a conventional car in overrun (lock-up closed, pedal released, above idle): fuel cut, the wheels drive
        # the engine against its friction (the P2 car recuperates with its motor instead)
        te = -(p[P_ENGINE_FRICTION_NM] + p[P_ENGINE_FRICTION_NM_PER_RADPS] * wp)
    return te, tm, d_idle


@njit(cache=True, _nrt=False)
def brake_split(p: np.ndarray, brake_demand_nm: float, hydraulic_brake_nm: float) -> tuple[float, float, float]:
    """Hydraulic brake torque per axle: the front share rises with the demanded deceleration, clamped.

    Returns
    -------
    tuple
        ``(front_brake_nm, rear_brake_nm, brake_force_n)`` (the total at the wheels' radius).
    """
    rw = p[P_WHEEL_RADIUS_M]
    decel_dem = brake_demand_nm / (rw * p[P_MASS_KG])
    fs = min(max(p[P_BRAKE_FRONT_SHARE_BASE] + p[P_BRAKE_FRONT_SHARE_PER_MPS2] * decel_dem,
                 p[P_BRAKE_FRONT_SHARE_BASE]), p[P_BRAKE_FRONT_SHARE_MAX])
    tbf = fs * hydraulic_brake_nm
    tbr = (1.0 - fs) * hydraulic_brake_nm
    fb = (tbf + tbr) / rw
    return tbf, tbr, fb


@njit(cache=True, _nrt=False)
def lockup_engagement(tab: PlantTables, led: np.ndarray, lockup_request: bool, lockup_closed: bool, gear: int,
                      inertia_phase_left_s: float, lockup_engage_time_s: float, k0_closed: bool,
                      source_torque_nm: float, pump_inertia_kgm2: float, gain_rad_per_m: float, eff_mass_kg: float,
                      speed_mps: float, pump_speed_radps: float, turbine_speed_radps: float,
                      engine_speed_radps: float) -> tuple:
    """Lock-up engagement: the capacity ramps up over ``P_LOCKUP_ENGAGE_S``; the clutch sticks once the torque
    needed to hold pump and turbine together (T_src - T_p(eq. 35) - J_p (omega_t - omega_p) / dt) is within
    capacity. Sticking keeps the momentum of pump side and vehicle (through the gear), slip energy to
    ``led[L_LOCKUP]``. Once closed, ``lockup_engage_time_s`` keeps counting (the regenerative torque ramps
    back in over ``P_LOCKUP_ENGAGE_S``, :func:`brake_blending`); it is reset when the lock-up opens.

    Returns
    -------
    tuple
        ``(lockup_closed, lockup_engage_time_s, lockup_capacity_nm, speed_mps, pump_speed_radps,
        turbine_speed_radps, engine_speed_radps)``; the capacity is that of this step while engaging, else 0.
    """
    p = tab.p
    dt = p[P_DT_S]
    lut = lockup_engage_time_s
    wp = pump_speed_radps
    wt = turbine_speed_radps
    v = speed_mps
    we = engine_speed_radps
    kg = gain_rad_per_m
    jp = pump_inertia_kgm2
    cap_now = 0.0
    if lockup_request and not lockup_closed and gear > 0 and inertia_phase_left_s <= 0.0:
        lut += dt
        cap_now = p[P_LOCKUP_CAPACITY_NM] * min(lut / p[P_LOCKUP_ENGAGE_S], 1.0)
        tp0, _tt0, _d0 = converter_torques_nm(tab.tc_a, p[P_TC_COUPLING_SPEED_RATIO], tab.tc_sr, tab.tc_cap,
                                              tab.tc_tr, wp, wt)
        tneed = source_torque_nm - tp0 - jp * (wt - wp) / dt
        if abs(tneed) <= cap_now:
            # the lock-up sticks: pump side and vehicle (seen through the gear) share their momentum
            w, loss = clutch_merge(jp, wp, eff_mass_kg / (kg * kg), wt)
            led[L_LOCKUP] += loss
            wp = w
            v = w / kg
            wt = w
            if k0_closed:
                we = wp
            lockup_closed = True
    elif lockup_closed:
        lut += dt  # time since the engagement began (the regenerative torque ramps back in over it)
    return lockup_closed, lut, cap_now, v, wp, wt, we


@njit(cache=True, _nrt=False)
def driveline_step(tab: PlantTables, gear: int, lockup_closed: bool, speed_mps: float, pump_speed_radps: float,
                   turbine_speed_radps: float, source_torque_nm: float, pump_inertia_kgm2: float,
                   gain_rad_per_m: float, eff_ratio: float, old_gain_rad_per_m: float, inertia_phase_left_s: float,
                   lockup_capacity_nm: float, idle_gain_nm_per_radps: float, eff_mass_kg: float,
                   external_force_n: float, brake_force_n: float, drag_torque_nm: float,
                   wheel_slip_gain: float = 1.0) -> tuple:
    """Driveline and vehicle acceleration over the step.

    - Lock-up closed (rigid): pump side and vehicle accelerate together; the gearbox is in drive
      (eq. 14, T_in >= C0), in coast (T_in <= eta_m C0) or in its dead band (T_out = 0), solved for the
      acceleration a = (k eta (T_src - C0) + F_ext - F_b) / (m + eta J_p k^2) in drive, and so on.
    - Lock-up open: converter torques (eq. 35-36, plus the slipping lock-up's capacity while engaging),
      gearbox output (eq. 13-14) through the effective ratio of a slipping shift clutch, and a
      semi-implicit pump-speed step dw = dt (T_src - T_p - T_lu) / (J_p + dt (dT_p/dw + k_idle)).
    - Neutral: the pump side alone.

    ``drag_torque_nm`` is the gear's C0 (eq. 14): the vehicle file's constant for the paper form, the spin
    loss at the present input speed and oil temperature for the high-fidelity plant.
    ``wheel_slip_gain`` is 1 + s, the driven wheels' speed over the roller speed (tyre slip, high-fidelity
    plant): the pump side turns with the wheels (``k (1 + s) v``) while the force reaches the rollers through
    ``k``, so only the inertia terms take it; exactly 1 for the paper form.

    Returns
    -------
    tuple
        ``(accel_mps2, pump_torque_nm, turbine_torque_nm, lockup_torque_nm, input_torque_nm, output_torque_nm,
        pump_torque_eff_nm, lockup_torque_eff_nm, slip_gain_rad_per_m, pump_speed_step_radps)``: with the
        converter, ``*_eff`` are the torques at the end-of-step pump speed (for the ledger) and
        ``slip_gain`` the turbine speed above the shift clutch's output side per m/s.
    """
    p = tab.p
    dt = p[P_DT_S]
    rw = p[P_WHEEL_RADIUS_M]
    ifd = p[P_FINAL_DRIVE_RATIO]
    v = speed_mps
    wp = pump_speed_radps
    wt = turbine_speed_radps
    tsrc = source_torque_nm
    jp = pump_inertia_kgm2
    kg = gain_rad_per_m
    kgk = kg * wheel_slip_gain  # kinematic gain: pump speed per roller speed
    meff = eff_mass_kg
    f_ext = external_force_n
    fb = brake_force_n
    d_idle = idle_gain_nm_per_radps
    tp = 0.0
    tt = 0.0
    tlu = 0.0
    tin = 0.0
    tout = 0.0
    tp_eff = 0.0
    tlu_eff = 0.0
    slip_w = 0.0
    dw = 0.0
    a = 0.0
    if gear > 0 and lockup_closed:
        eta = tab.eta_m[gear]
        cc = drag_torque_nm
        ig = tab.ratios[gear]
        fbd = fb if v > 0.0 else 0.0
        den = meff + eta * jp * kg * kgk
        a = (kg * eta * (tsrc - cc) + f_ext - fbd) / den
        tin = tsrc - jp * kgk * a
        if tin >= cc:
            tout = ig * eta * (tin - cc)
        else:
            den = meff + jp * kg * kgk / eta
            a = (kg * (tsrc / eta - cc) + f_ext - fbd) / den
            tin = tsrc - jp * kgk * a
            if tin <= eta * cc:
                tout = ig * (tin / eta - cc)
            else:
                a = (f_ext - fbd) / (meff + 0.0)
                tin = tsrc - jp * kgk * a
                tout = 0.0
        if v <= 0.0 and a < 0.0:
            a = 0.0
        tp = tin
        tt = tin
    else:
        if gear > 0:
            tp, tt, dtp = converter_torques_nm(tab.tc_a, p[P_TC_COUPLING_SPEED_RATIO], tab.tc_sr, tab.tc_cap,
                                               tab.tc_tr, wp, wt)
            dlu = 0.0
            if lockup_capacity_nm > 0.0:
                tlu = lockup_capacity_nm if wp > wt else -lockup_capacity_nm
            tin = tt + tlu
            # during the inertia phase the slipping shift clutch passes the torque at the lower ratio
            # (higher ratio in coast); the speed difference times torque is clutch slip energy
            reff = eff_ratio
            if inertia_phase_left_s > 0.0:
                rnew = tab.ratios[gear]
                rold = old_gain_rad_per_m * rw / ifd
                reff = min(rnew, rold) if tin >= 0.0 else max(rnew, rold)
            tout = transmission_output_torque_nm(reff, tab.eta_m[gear], drag_torque_nm, tin)
            slip_w = (eff_ratio - reff) * ifd / rw * wheel_slip_gain  # turbine above the clutch's output, per m/s
            num = tsrc - tp - tlu
            dw = dt * num / (jp + dt * (dtp + dlu + d_idle))
            tp_eff = tp + dtp * dw
            tlu_eff = tlu + dlu * dw
        else:
            dw = dt * tsrc / (jp + dt * d_idle)
        fw = ifd * tout / rw
        if v <= 0.0:
            a = (fw + f_ext) / meff
            if a <= 0.0:
                a = 0.0
            else:
                a = max((fw + f_ext - fb) / meff, 0.0)
        else:
            a = (fw + f_ext - fb) / meff
    return a, tp, tt, tlu, tin, tout, tp_eff, tlu_eff, slip_w, dw


@njit(cache=True, _nrt=False)
def vehicle_step(p: np.ndarray, gear: int, lockup_closed: bool, speed_mps: float, accel_mps2: float,
                 pump_speed_radps: float, pump_speed_step_radps: float, gain_rad_per_m: float,
                 eff_gain_rad_per_m: float, eff_mass_kg: float) -> tuple:
    """Advance vehicle and pump speed over the step (explicit in v, the vehicle stops at 0) and form the
    mid-point speeds at which every power of the ledger is evaluated.

    Returns
    -------
    tuple
        ``(accel_mps2, new_speed_mps, stop_force_n, mid_speed_mps, new_pump_speed_radps, mid_pump_speed_radps,
        mid_turbine_speed_radps, mid_shaft_speed_radps)``; ``stop_force_n`` is the force the brakes and
        resistances did not need to deliver to stop the car exactly.
    """
    dt = p[P_DT_S]
    v = speed_mps
    a = accel_mps2
    wp = pump_speed_radps
    v_new = v + a * dt
    stop_fix = 0.0
    if v_new < 0.0:
        a_stop = -v / dt
        stop_fix = eff_mass_kg * (a_stop - a)  # force the brakes/resistance did not need to deliver
        a = a_stop
        v_new = 0.0
    v_mid = 0.5 * (v + v_new)
    if gear > 0 and lockup_closed:
        wp_new = gain_rad_per_m * v_new
    else:
        wp_new = max(wp + pump_speed_step_radps, 0.0)
    w_mid = 0.5 * (wp + wp_new)
    wt_mid = eff_gain_rad_per_m * v_mid if gear > 0 else w_mid
    ws_mid = p[P_FINAL_DRIVE_RATIO] * v_mid / p[P_WHEEL_RADIUS_M]
    return a, v_new, stop_fix, v_mid, wp_new, w_mid, wt_mid, ws_mid
