"""The compiled plant loop: one ordered step per plant tick over preallocated arrays.

Order of a step (FASTSim-like run -> step -> ordered sub-steps):
driver -> hybrid strategy (engine on/off, K0) -> shift schedule and actual gear -> torque split, brakes and
blending -> driveline (rigid with lock-up closed, torque converter eq. 35-36 with it open, or neutral) ->
vehicle on the dyno (road-load or speed-controlled mode) -> HV battery (eq. 29-30) -> DC/DC and 12 V ->
energy ledger. Speeds in rad/s and m/s, torques in Nm, powers in W.

Every power term of the ledger is evaluated at the mid-point speeds of the step, the same rule that
advances the speed states, so that the ledger closes up to what the model really loses or stores.
"""

from __future__ import annotations

import numpy as np
from numba import njit

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
    L_BRAKES,
    L_DCDC,
    L_DYNO,
    L_ENGINE,
    L_FUEL,
    L_HV_CHEM,
    L_HV_R,
    L_K0,
    L_LOCKUP,
    L_LV_CHEM,
    L_LV_LOADS,
    L_LV_R,
    L_MOTOR,
    L_ROAD,
    L_SHIFT,
    L_TC,
    L_TRANS,
    O_A,
    O_BRAKE,
    O_DSET,
    O_DSOC,
    O_EON,
    O_FFRONT,
    O_FREAR,
    O_FRL,
    O_FUEL,
    O_GA,
    O_GT,
    O_HMODE,
    O_IB,
    O_ILV,
    O_ILVB,
    O_K0,
    O_LU,
    O_OCV,
    O_PEDAL,
    O_PEL,
    O_PF,
    O_PMC,
    O_PR,
    O_Q_BATT,
    O_Q_ENGINE,
    O_Q_MOTOR,
    O_SOC,
    O_TBF,
    O_TBR,
    O_TE,
    O_TIN,
    O_TM,
    O_TOUT,
    O_TP,
    O_TT,
    O_V,
    O_VB,
    O_VDYN,
    O_VLV,
    O_WE,
    O_WP,
    O_WS,
    O_WT,
    O_WW,
    O_X,
    P_ALPHA,
    P_B_FS0,
    P_B_FS1,
    P_B_FSMAX,
    P_B_GF,
    P_B_GR,
    P_B_TMAX,
    P_B_VCUT,
    P_BETA_C,
    P_BETA_D,
    P_CAP_AS,
    P_COAST_T,
    P_DCDC_ETA,
    P_DCDC_V,
    P_DRV_B0,
    P_DRV_B1,
    P_DRV_FBMAX,
    P_DRV_NPRE,
    P_DRV_STOP,
    P_DT,
    P_DYN_B0,
    P_DYN_B1,
    P_DYN_FMAX,
    P_DYN_PMAX,
    P_E_FR0,
    P_E_FR1,
    P_E_IDLE,
    P_E_J,
    P_E_SPIN,
    P_E_START_KG,
    P_F0,
    P_F1,
    P_F2,
    P_H_CHG,
    P_H_ESAVE,
    P_H_FMAX,
    P_H_KICK,
    P_H_POFF,
    P_H_PON,
    P_H_SUS,
    P_H_SUSK,
    P_H_SUSMAX,
    P_H_TMIN,
    P_H_VON,
    P_IDLE_K,
    P_IFD,
    P_LHV,
    P_LU_CAP,
    P_LU_GEAR,
    P_LU_TENG,
    P_LU_V,
    P_LV_CAP_AS,
    P_LV_DROOP,
    P_LV_OCV0,
    P_LV_OCV1,
    P_LV_R,
    P_M_IDLE,
    P_M_J,
    P_MASS,
    P_MSC,
    P_NCELL,
    P_NG,
    P_PCH,
    P_PDCH,
    P_PF0,
    P_PF1,
    P_PF2,
    P_RW,
    P_SHIFT_DELAY,
    P_SHIFT_INERTIA,
    P_SOC_MAX,
    P_SOC_MIN,
    P_TC_GAMMA,
    P_VD,
    P_W_E,
    P_W_EG,
    P_W_LOSS,
    P_W_LOSSG,
)

__all__ = ["N_STATE", "kinetic_energy", "run_plant", "tc_torques", "willans_power"]

#: state vector layout (carried between calls so a campaign may be run in pieces)
S_V, S_X, S_WP, S_WE, S_EON, S_K0, S_LU, S_GEAR, S_GT, S_SHT, S_SOC, S_SOCLV = range(12)
S_DRV_U, S_DRV_E, S_DYN_U, S_DYN_E, S_LATCH, S_LATCH_T, S_LATCH_V, S_SEG, S_EON_T, S_ESAVE, S_MEFF, S_T = range(12, 24)
S_STEP, S_LUT, S_RAMP, S_KOLD = 24, 25, 26, 27
N_STATE = 28


@njit(cache=True)
def tc_torques(a: np.ndarray, gamma: float, wp: float, wt: float) -> tuple[float, float, float]:
    """Pump and turbine torque (eq. 35-36) and dT_p/d(omega_p) at speeds ``wp``, ``wt`` (rad/s)."""
    sr = wt / wp if wp > 1e-6 else 0.0
    if sr < gamma:
        tp = a[0] * wp * wp + a[1] * wp * wt + a[2] * wt * wt
        tt = a[3] * wp * wp + a[4] * wp * wt + a[5] * wt * wt
        dtp = 2.0 * a[0] * wp + a[1] * wt
    else:
        tp = a[6] * wp * wp + a[7] * wp * wt + a[8] * wt * wt
        tt = tp
        dtp = 2.0 * a[6] * wp + a[7] * wt
    return tp, tt, max(dtp, 0.0)


@njit(cache=True)
def willans_power(p: np.ndarray, t: float, w: float) -> float:
    """Motor DC power from the Willans line (eq. 18-24), motoring for T >= 0, generating for T < 0."""
    if w < 1.0 and abs(t) < 0.5:
        return 0.0
    if t >= 0.0:
        return (t * w + p[P_W_LOSS]) / p[P_W_E]
    return p[P_W_EG] * t * w + p[P_W_LOSSG]


@njit(cache=True)
def _bsfc(w: np.ndarray, b: np.ndarray, tab: np.ndarray, ws: float, bmep: float) -> float:
    """Bilinear interpolation of the BSFC map (kg/J), clamped outside the grid."""
    nw = w.shape[0]
    nb = b.shape[0]
    x = min(max(ws, w[0]), w[nw - 1])
    y = min(max(bmep, b[0]), b[nb - 1])
    i = np.searchsorted(w, x) - 1
    i = min(max(i, 0), nw - 2)
    j = np.searchsorted(b, y) - 1
    j = min(max(j, 0), nb - 2)
    fx = (x - w[i]) / (w[i + 1] - w[i])
    fy = (y - b[j]) / (b[j + 1] - b[j])
    return ((1 - fx) * (1 - fy) * tab[i, j] + fx * (1 - fy) * tab[i + 1, j]
            + (1 - fx) * fy * tab[i, j + 1] + fx * fy * tab[i + 1, j + 1])


@njit(cache=True)
def _merge(j1: float, w1: float, j2: float, w2: float) -> tuple[float, float]:
    """Two inertias locked together by a clutch: common speed (momentum kept) and the energy lost, J."""
    w = (j1 * w1 + j2 * w2) / (j1 + j2)
    return w, 0.5 * j1 * w1 * w1 + 0.5 * j2 * w2 * w2 - 0.5 * (j1 + j2) * w * w


@njit(cache=True)
def jp_now(jm: float, je: float, k0: bool) -> float:
    """Inertia of the pump side: motor and converter pump, plus the engine when K0 is closed."""
    return jm + (je if k0 else 0.0)


@njit(cache=True)
def _ke(p: np.ndarray, st: np.ndarray) -> float:
    jp = p[P_M_J] + (p[P_E_J] if st[S_K0] > 0.5 else 0.0)
    ke = 0.5 * st[S_MEFF] * st[S_V] ** 2 + 0.5 * jp * st[S_WP] ** 2
    if st[S_K0] < 0.5:
        ke += 0.5 * p[P_E_J] * st[S_WE] ** 2
    return ke


@njit(cache=True)
def run_plant(p: np.ndarray, ratios: np.ndarray, eta_m: np.ndarray, c0: np.ndarray, up_v0: np.ndarray,
              up_s: np.ndarray, dn_v0: np.ndarray, dn_s: np.ndarray, e_fl_w: np.ndarray, e_fl_t: np.ndarray,
              bsfc_w: np.ndarray, bsfc_b: np.ndarray, bsfc_tab: np.ndarray, m_fl_w: np.ndarray, m_fl_t: np.ndarray,
              c_soc: np.ndarray, c_ocv: np.ndarray, c_rd: np.ndarray, c_rc: np.ndarray, tc_a: np.ndarray,
              cmd: np.ndarray, decim: int, st: np.ndarray, out: np.ndarray, row0: int,
              led: np.ndarray) -> tuple[int, int]:
    """Advance the plant over the steps of one test's commands.

    Parameters
    ----------
    p:
        Scalar parameters, indexed by the ``P_*`` constants of :mod:`benchtwin.emulator.params`.
    ratios, eta_m, c0:
        Per gear (index 0 = neutral): ratio, eq. 14 eta_m and C0 (Nm).
    up_v0, up_s, dn_v0, dn_s:
        Shift lines per gear pair (m/s, m/s per pedal %).
    e_fl_w, e_fl_t, m_fl_w, m_fl_t:
        Engine and motor full-load curves (rad/s, Nm).
    bsfc_w, bsfc_b, bsfc_tab:
        BSFC grid: speed (rad/s) x BMEP (Pa) -> kg/J.
    c_soc, c_ocv, c_rd, c_rc:
        Literature cell maps over the displayed SOC fraction (V, ohm).
    tc_a:
        Torque converter a0..a8 (Nm/(rad/s)^2).
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
    dt = p[P_DT]
    n = cmd.shape[1]
    ng = int(p[P_NG])
    rw = p[P_RW]
    ifd = p[P_IFD]
    mass = p[P_MASS]
    je = p[P_E_J]
    jm = p[P_M_J]
    gamma = p[P_TC_GAMMA]
    smin = p[P_SOC_MIN]
    smax = p[P_SOC_MAX]
    ncell = p[P_NCELL]
    widle_e = p[P_E_IDLE]
    widle_m = p[P_M_IDLE]
    kidle = p[P_IDLE_K]
    npre = int(p[P_DRV_NPRE])
    vramp = 0.5 / 3.6  # road load fades in below 0.5 km/h (no force at standstill)

    v = st[S_V]
    x = st[S_X]
    wp = st[S_WP]
    we = st[S_WE]
    eon = st[S_EON] > 0.5
    k0 = st[S_K0] > 0.5
    lu = st[S_LU] > 0.5
    gear = int(st[S_GEAR])
    gtgt = int(st[S_GT])
    sht = st[S_SHT]
    soc = st[S_SOC]
    soclv = st[S_SOCLV]
    drv_u = st[S_DRV_U]
    drv_e = st[S_DRV_E]
    dyn_u = st[S_DYN_U]
    dyn_e = st[S_DYN_E]
    latch = st[S_LATCH] > 0.5
    latch_t = st[S_LATCH_T]
    latch_v = st[S_LATCH_V]
    seg_prev = st[S_SEG]
    eon_t = st[S_EON_T]
    esave = st[S_ESAVE]
    meff = st[S_MEFF]
    t = st[S_T]
    kstep = int(st[S_STEP])
    lut = st[S_LUT]
    ramp = st[S_RAMP]
    kold = st[S_KOLD]
    t_inertia = p[P_SHIFT_INERTIA]
    iout = row0
    nrun = n

    for i in range(n):
        t = kstep * dt
        dmode = int(cmd[C_DYNO_MODE, i])
        seg = cmd[C_SEG, i]
        hm = int(cmd[C_HMODE, i])
        dsoc = 100.0 * (soc - smin) / (smax - smin)
        if seg != seg_prev:
            latch = False
            drv_u = 0.0
            drv_e = 0.0
            esave = dsoc
            seg_prev = seg
        # ---- dyno mode: simulated inertia (road-load) or rollers only (speed-controlled) ----
        m_new = mass if dmode == 0 else p[P_MSC]
        if m_new != meff:
            led[L_DYNO] -= 0.5 * (m_new - meff) * v * v  # the dyno supplies the change of simulated inertia
            meff = m_new
            dyn_u = 0.0
            dyn_e = 0.0

        # ---- end conditions of the protocol ----
        ek = int(cmd[C_END_KIND, i])
        if not latch and ek > 0:
            ev = cmd[C_END_VAL, i]
            if ((ek == 1 and v >= ev) or (ek == 2 and dsoc <= ev) or (ek == 3 and dsoc >= ev) or ek == 4):
                latch = True
                latch_t = t
                latch_v = v

        # ---- driver ----
        dm = int(cmd[C_DRV_MODE, i])
        pedal = cmd[C_PEDAL, i]
        brake = cmd[C_BRAKE, i]
        gh = int(cmd[C_GEAR, i])
        if latch or dm == 1:
            if latch:
                vt = max(latch_v - p[P_DRV_STOP] * (t - latch_t), 0.0)
                vt_pre = max(latch_v - p[P_DRV_STOP] * (t + npre * dt - latch_t), 0.0)
                aref = -p[P_DRV_STOP] if vt_pre > 0.0 else 0.0
            else:
                vt = cmd[C_VTGT, i]
                vt_pre = cmd[C_VPRE, i]  # previewed target and reference acceleration (protocols.py)
                aref = cmd[C_AREF, i]
            ff = mass * aref + (p[P_F0] + p[P_F1] * vt_pre + p[P_F2] * vt_pre * vt_pre) * min(vt_pre / vramp, 1.0)
            e = vt - v
            drv_u = drv_u + p[P_DRV_B0] * e + p[P_DRV_B1] * drv_e
            drv_u = min(max(drv_u, -p[P_DRV_FBMAX]), p[P_DRV_FBMAX])
            drv_e = e
            u = ff + drv_u
            # pedal map estimate: available force in the current gear
            gest = max(gear, 1)
            kk = ratios[gest] * ifd / rw
            west = max(kk * v, widle_e)
            tav = np.interp(west, m_fl_w, m_fl_t)
            if hm != 1:
                tav += np.interp(west, e_fl_w, e_fl_t)
            fav = max(tav * kk * 0.9, 500.0)
            if u >= 0.0:
                pedal = min(100.0 * u / fav, 100.0)
                brake = 0.0
            else:
                pedal = 0.0
                brake = min(100.0 * (-u) * rw / p[P_B_TMAX], 100.0)
            if vt <= 0.0 and vt_pre <= 0.0 and v < 0.3:
                pedal = 0.0
                brake = max(brake, 25.0)
                drv_u = 0.0
        vk = v * 3.6

        # ---- shift schedule: target gear, then actual gear after the actuation delay ----
        if gh >= 0:
            gtgt = gh
        else:
            if gtgt == 0:
                gtgt = 1
            if gtgt < ng and v >= up_v0[gtgt - 1] + up_s[gtgt - 1] * pedal:
                gtgt += 1
            elif gtgt > 1 and v <= dn_v0[gtgt - 2] + dn_s[gtgt - 2] * pedal:
                gtgt -= 1
        if gear != gtgt:
            sht += dt
            if sht >= p[P_SHIFT_DELAY] - 1e-9:
                g_old = gear
                if gtgt == 0 or gear == 0:
                    gear = gtgt
                elif gtgt > gear:
                    gear += 1
                else:
                    gear -= 1
                sht = 0.0
                if g_old > 0 and gear > 0:
                    # clutch-to-clutch shift: the lock-up opens (slip control), the turbine speed moves to the
                    # new ratio over the inertia phase while the motor takes the pump side's inertia torque
                    lu = False
                    lut = 0.0
                    ramp = t_inertia
                    kold = ratios[g_old] * ifd / rw
        else:
            sht = 0.0
        kg = ratios[gear] * ifd / rw if gear > 0 else 0.0
        if gear == 0:
            ramp = 0.0
        kge = kg + (kold - kg) * (ramp / t_inertia) if ramp > 0.0 else kg
        rge = kge * rw / ifd
        wt = kge * v if gear > 0 else wp

        # ---- machine limits ----
        wq = max(wp, 1.0)
        tm_max = np.interp(wp, m_fl_w, m_fl_t)
        tm_max = min(tm_max, max((p[P_PDCH] * p[P_W_E] - p[P_W_LOSS]) / wq, 0.0))
        tm_gen = np.interp(wp, m_fl_w, m_fl_t)
        tm_gen = min(tm_gen, (p[P_PCH] + p[P_W_LOSSG]) / (p[P_W_EG] * wq))
        te_max = np.interp(max(wp, widle_e), e_fl_w, e_fl_t)
        ef = int(cmd[C_ENG, i])
        t_avail = tm_max if (hm == 1 and ef != 1) else tm_max + te_max
        t_dem = pedal * 0.01 * t_avail
        if gear > 0:
            # traction / gearbox input torque limiter: wheel force at most P_H_FMAX through the converter's
            # present torque ratio (launches in low gears)
            tr_now = 1.0
            if not lu and wp > 1.0:
                tpn, ttn, _dn = tc_torques(tc_a, gamma, wp, wt)
                if tpn > 1e-3:
                    tr_now = max(ttn / tpn, 1.0)
            t_dem = min(t_dem, p[P_H_FMAX] * rw / (ratios[gear] * ifd * eta_m[gear] * tr_now) + c0[gear])
        lu_ok = lu and gear > 0
        if pedal <= 0.0 and lu_ok and v > p[P_B_VCUT]:
            t_dem = -p[P_COAST_T]
        p_dem = t_dem * wp

        # ---- hybrid strategy: engine on/off ----
        want = eon
        if ef == 1:
            want = True
        elif ef == 0:
            want = False
        elif hm == 1:
            want = pedal >= p[P_H_KICK] or (eon and pedal >= p[P_H_KICK] - 10.0) or dsoc < 0.5
        elif hm == 0:
            if not eon:
                want = p_dem > p[P_H_PON] or v > p[P_H_VON] or (dsoc < p[P_H_SUS] and vk > 15.0)
            else:
                want = not (p_dem < p[P_H_POFF] and v < p[P_H_VON] - 5.0 / 3.6
                            and (dsoc >= p[P_H_SUS] + 2.0 or vk < 5.0) and eon_t >= p[P_H_TMIN])
        elif hm == 2:
            if not eon:
                want = p_dem > p[P_H_ESAVE] or (dsoc < esave - 1.0 and vk > 10.0)
            else:
                want = not (p_dem < 0.5 * p[P_H_ESAVE] and (dsoc >= esave or vk < 5.0) and eon_t >= p[P_H_TMIN])
        else:
            want = vk > 3.0 or pedal > 0.0 or (eon and eon_t < p[P_H_TMIN])
        fuel_start = 0.0
        if want and not eon:
            eon = True
            eon_t = 0.0
            fuel_start = p[P_E_START_KG]
        elif not want and eon:
            eon = False
        if eon:
            eon_t += dt

        # ---- K0 clutch ----
        kf = int(cmd[C_K0, i])
        k0_req = (kf == 1) or (kf == -1 and eon)
        if k0 and not k0_req:
            k0 = False
            we = wp
        ke_e_self = 0.0
        if not k0:
            if k0_req and (eon or kf == 1):
                target = max(wp, 0.5 * widle_e) if eon else wp
            else:
                target = widle_e if eon else 0.0
            step = p[P_E_SPIN] * dt
            we_new = min(we + step, target) if we < target else max(we - step, target)
            ke_e_self = 0.5 * je * (we_new * we_new - we * we)
            we = we_new
            if k0_req and abs(we - wp) < 3.0:
                # the clutch locks: engine and pump side (with the vehicle if the lock-up is closed) share
                # their momentum; the small speed difference is lost as clutch slip energy
                rigid = lu and gear > 0 and kg > 0.0
                j2 = jm + (meff / (kg * kg) if rigid else 0.0)
                w, loss = _merge(je, we, j2, wp)
                led[L_K0] += loss
                wp = w
                we = w
                if rigid:
                    v = w / kg
                    wt = w
                k0 = True
        else:
            we = wp
        jp = jm + (je if k0 else 0.0)

        # ---- lock-up clutch command ----
        luf = int(cmd[C_LU, i])
        if luf == 1:
            lu_req = gear > 0 and vk >= 5.0
        elif luf == 0:
            lu_req = False
        else:
            # closed above its speed, and kept closed while braking down to the regen cut-off
            lu_req = gear >= p[P_LU_GEAR] and (v >= p[P_LU_V] or (brake > 0.0 and v > p[P_B_VCUT]))
        if not lu_req:
            lu = False
            lut = 0.0

        # ---- torque split ----
        sus = 0.0
        if hm == 0 and dsoc < p[P_H_SUS]:
            sus = min(p[P_H_SUSK] * (p[P_H_SUS] - dsoc), p[P_H_SUSMAX])
        elif hm == 2:
            sus = min(max(p[P_H_SUSK] * (esave - dsoc), -p[P_H_SUSMAX]), p[P_H_SUSMAX])
        te = 0.0
        tm = t_dem
        if k0 and eon:
            if hm == 3:
                tm = -min(p[P_H_CHG] / wq, tm_gen)
                te = min(max(t_dem - tm, 0.0), te_max)
                tm = min(t_dem - te, 0.0)
            elif hm == 1:
                low = min(p[P_H_SUSK] * (p[P_H_SUS] - dsoc), p[P_H_SUSMAX]) if dsoc < p[P_H_SUS] else 0.0
                te = min(max(t_dem - tm_max, 0.0) + low / wq, te_max)
                tm = t_dem - te
            else:
                te = min(max(t_dem + sus / wq, 0.0), te_max)
                tm = t_dem - te
        elif k0 and not eon:
            te = -(p[P_E_FR0] + p[P_E_FR1] * wp) if wp > 1.0 else 0.0
        # brakes and blending
        bdem = brake * 0.01 * p[P_B_TMAX]
        bhyd = bdem
        if bdem > 0.0 and gear > 0 and (lu or lu_req) and v > p[P_B_VCUT]:
            # regeneration first (also through a converter opened only for a shift), hydraulic for the rest
            kgr = ratios[gear] * ifd
            # the regenerative share fades out over the last 8 km/h above the cut-off speed
            fade = min((v - p[P_B_VCUT]) / (8.0 / 3.6), 1.0)
            t_in_need = eta_m[gear] * (c0[gear] - fade * bdem / kgr)
            tm_r = max(t_in_need - te, -tm_gen)
            tm = min(tm, tm_r)
            tm = max(tm, -tm_gen)
            t_in_real = tm + te
            breg = -kgr * (t_in_real / eta_m[gear] - c0[gear]) if t_in_real <= eta_m[gear] * c0[gear] else 0.0
            bhyd = max(bdem - breg, 0.0)
        if ramp > 0.0 and gear > 0 and not lu:
            # torque intervention during the inertia phase: the motor takes the pump side's inertia torque so
            # that the pump follows the turbine instead of dumping its energy into the driveline
            tm += jp_now(jm, je, k0) * (kg - kold) * v / t_inertia
        tm = min(max(tm, -tm_gen), tm_max)
        # idle speed holding when the pump side is free
        free = (not lu) or gear == 0
        d_idle = 0.0
        if free:
            if k0 and eon:
                if wp < widle_e:
                    te = min(te + kidle * (widle_e - wp), te_max)
                    d_idle = kidle
            elif gear == 0 and not (k0 and eon):
                # neutral: the motor holds the pump at idle (or lets it run down at standstill)
                wtarget = widle_m if (pedal > 0.0 or v > 0.3) else 0.0
                tm = min(max(tm + kidle * (wtarget - wp), -min(tm_gen, 30.0)), tm_max)
                d_idle = kidle
            elif (pedal > 0.0 or v > 0.3) and wp < widle_m:  # the motor stops at standstill, pedal released
                tm = min(tm + kidle * (widle_m - wp), tm_max)
                d_idle = kidle
        decel_dem = bdem / (rw * mass)
        fs = min(max(p[P_B_FS0] + p[P_B_FS1] * decel_dem, p[P_B_FS0]), p[P_B_FSMAX])
        tbf = fs * bhyd
        tbr = (1.0 - fs) * bhyd
        fb = (tbf + tbr) / rw

        # ---- engine fuel (BSFC map, eq. 26-28) ----
        fuel_flow = 0.0
        if eon:
            if k0 and te > 0.0:
                bmep = 4.0 * np.pi * te / p[P_VD]
                fuel_flow += _bsfc(bsfc_w, bsfc_b, bsfc_tab, wp, bmep) * te * wp
            else:
                wf = wp if k0 else we
                bmin = bsfc_b[0]
                tmin = bmin * p[P_VD] / (4.0 * np.pi)
                fuel_flow += _bsfc(bsfc_w, bsfc_b, bsfc_tab, wf, bmin) * tmin * wf
        fuel_e = (fuel_flow * dt + fuel_start) * p[P_LHV]
        fuel_flow += fuel_start / dt

        # ---- dyno forces ----
        rlf = min(v / vramp, 1.0)
        f_rl = (p[P_F0] + p[P_F1] * v + p[P_F2] * v * v) * rlf
        f_par = (p[P_PF0] + p[P_PF1] * v + p[P_PF2] * v * v) * rlf
        f_dyn = 0.0
        vset = np.nan
        if dmode == 1:
            vset = cmd[C_DYNO_SET, i]
            e = vset - v
            dyn_u = dyn_u + p[P_DYN_B0] * e + p[P_DYN_B1] * dyn_e
            flim = min(p[P_DYN_FMAX], p[P_DYN_PMAX] / max(v, 1.0))
            dyn_u = min(max(dyn_u, -flim), flim)
            dyn_e = e
            f_dyn = dyn_u
            f_ext = f_dyn - f_par
        else:
            f_ext = -f_rl

        # ---- lock-up engagement: capacity ramps up; it sticks once the torque to hold is within capacity ----
        tsrc = te + tm
        cap_now = 0.0
        if lu_req and not lu and gear > 0 and ramp <= 0.0:
            lut += dt
            cap_now = p[P_LU_CAP] * min(lut / p[P_LU_TENG], 1.0)
            tp0, _tt0, _d0 = tc_torques(tc_a, gamma, wp, wt)
            tneed = tsrc - tp0 - jp * (wt - wp) / dt
            if abs(tneed) <= cap_now:
                # the lock-up sticks: pump side and vehicle (seen through the gear) share their momentum
                w, loss = _merge(jp, wp, meff / (kg * kg), wt)
                led[L_LOCKUP] += loss
                wp = w
                v = w / kg
                wt = w
                if k0:
                    we = wp
                lu = True

        # ---- driveline and vehicle ----
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
        if gear > 0 and lu:
            eta = eta_m[gear]
            cc = c0[gear]
            ig = ratios[gear]
            fbd = fb if v > 0.0 else 0.0
            den = meff + eta * jp * kg * kg
            a = (kg * eta * (tsrc - cc) + f_ext - fbd) / den
            tin = tsrc - jp * kg * a
            if tin >= cc:
                tout = ig * eta * (tin - cc)
            else:
                den = meff + jp * kg * kg / eta
                a = (kg * (tsrc / eta - cc) + f_ext - fbd) / den
                tin = tsrc - jp * kg * a
                if tin <= eta * cc:
                    tout = ig * (tin / eta - cc)
                else:
                    a = (f_ext - fbd) / (meff + 0.0)
                    tin = tsrc - jp * kg * a
                    tout = 0.0
            if v <= 0.0 and a < 0.0:
                a = 0.0
        else:
            if gear > 0:
                tp, tt, dtp = tc_torques(tc_a, gamma, wp, wt)
                dlu = 0.0
                if cap_now > 0.0:
                    tlu = cap_now if wp > wt else -cap_now
                tin = tt + tlu
                eta = eta_m[gear]
                cc = c0[gear]
                # during the inertia phase the slipping shift clutch passes the torque at the lower ratio
                # (higher ratio in coast); the speed difference times torque is clutch slip energy
                reff = rge
                if ramp > 0.0:
                    rnew = ratios[gear]
                    rold = kold * rw / ifd
                    reff = min(rnew, rold) if tin >= 0.0 else max(rnew, rold)
                if tin >= cc:
                    tout = reff * eta * (tin - cc)
                elif tin <= eta * cc:
                    tout = reff * (tin / eta - cc)
                else:
                    tout = 0.0
                slip_w = (rge - reff) * ifd / rw  # turbine speed above the clutch's output side, per m/s
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
        fw = ifd * tout / rw
        v_new = v + a * dt
        stop_fix = 0.0
        if v_new < 0.0:
            a_stop = -v / dt
            stop_fix = meff * (a_stop - a)  # force the brakes/resistance did not need to deliver
            a = a_stop
            v_new = 0.0
        v_mid = 0.5 * (v + v_new)
        if gear > 0 and lu:
            wp_new = kg * v_new
            tp = tin
            tt = tin
        else:
            wp_new = max(wp + dw, 0.0)
        w_mid = 0.5 * (wp + wp_new)
        wt_mid = kge * v_mid if gear > 0 else w_mid
        ws_mid = ifd * v_mid / rw

        # ---- motor electrical power (Willans) and HV battery (eq. 29-30) ----
        pel = willans_power(p, tm, wp)
        # 12 V system: DC/DC with droop feeding loads and the 12 V battery
        ocv_lv = p[P_LV_OCV0] + (p[P_LV_OCV1] - p[P_LV_OCV0]) * soclv
        pload = cmd[C_LVLOAD, i]
        rd = p[P_LV_DROOP]
        rb = p[P_LV_R]
        vlv = p[P_DCDC_V]
        for _k in range(2):
            iload = pload / vlv
            vlv = (p[P_DCDC_V] - rd * iload + rd * ocv_lv / rb) / (1.0 + rd / rb)
        ilvb = (ocv_lv - vlv) / rb
        idc = pload / vlv - ilvb
        plv = vlv * idc
        pdc_in = plv / p[P_DCDC_ETA]
        php = pel + pdc_in
        sd = min(max((soc - smin) / (smax - smin), 0.0), 1.0)
        ocv_c = np.interp(sd, c_soc, c_ocv)
        uoc = ncell * p[P_ALPHA] * ocv_c
        if php >= 0.0:
            rpk = ncell * p[P_BETA_D] * np.interp(sd, c_soc, c_rd)
        else:
            rpk = ncell * p[P_BETA_C] * np.interp(sd, c_soc, c_rc)
        disc = uoc * uoc - 4.0 * rpk * php
        if disc < 0.0:
            disc = 0.0
        ib = (uoc - np.sqrt(disc)) / (2.0 * rpk)
        vb = uoc - ib * rpk

        # ---- ledger ----
        led[L_FUEL] += fuel_e
        led[L_HV_CHEM] += uoc * ib * dt
        led[L_HV_R] += rpk * ib * ib * dt
        led[L_LV_CHEM] += ocv_lv * ilvb * dt
        led[L_LV_R] += rb * ilvb * ilvb * dt
        led[L_DCDC] += (pdc_in - plv) * dt
        led[L_LV_LOADS] += pload * dt
        if gear > 0 and lu:
            p_in_src_e = te * w_mid
            p_in_src_m = tm * w_mid
        else:
            # pump node implicit: idle torque at the new speed goes to the machine that holds idle
            te_eff = te
            tm_eff = tm
            if d_idle > 0.0:
                if k0 and eon:
                    te_eff = te - d_idle * dw
                else:
                    tm_eff = tm - d_idle * dw
            p_in_src_e = te_eff * w_mid
            p_in_src_m = tm_eff * w_mid
        if k0:
            led[L_ENGINE] += fuel_e - p_in_src_e * dt
        else:
            led[L_ENGINE] += fuel_e - ke_e_self
            if p_in_src_e != 0.0:
                led[L_ENGINE] -= p_in_src_e * dt
        led[L_MOTOR] += pel * dt - p_in_src_m * dt
        if gear > 0 and not lu:
            led[L_TC] += (tp_eff * w_mid - tt * wt_mid) * dt
            led[L_LOCKUP] += (tlu_eff * w_mid - tlu * wt_mid) * dt
        if gear > 0:
            led[L_SHIFT] += tin * slip_w * v_mid * dt
            led[L_TRANS] += (tin * (wt_mid - slip_w * v_mid) - tout * ws_mid) * dt
        led[L_BRAKES] += (fb * v_mid - stop_fix * v_mid) * dt if v_mid > 0.0 else 0.0
        if dmode == 0:
            led[L_ROAD] += f_rl * v_mid * dt
        else:
            led[L_ROAD] += f_par * v_mid * dt
            led[L_DYNO] -= f_dyn * v_mid * dt

        # ---- outputs (state at the start of the step, actions over the step) ----
        if kstep % decim == 0:
            o = out[:, iout]
            o[O_V] = v
            o[O_A] = a
            o[O_X] = x
            o[O_DSET] = vset
            mv = 1.0 if v_mid > 0.0 else 0.0
            o[O_FFRONT] = -mv * tbf / rw - 0.5 * f_par
            o[O_FREAR] = fw - mv * tbr / rw - 0.5 * f_par
            o[O_FRL] = p[P_F0] + p[P_F1] * v + p[P_F2] * v * v
            o[O_PEDAL] = pedal
            o[O_BRAKE] = brake
            o[O_HMODE] = hm
            o[O_WE] = wp if k0 else we
            o[O_TE] = te
            o[O_EON] = 1.0 if eon else 0.0
            o[O_FUEL] = fuel_flow
            o[O_K0] = 1.0 if k0 else 0.0
            o[O_WP] = wp
            o[O_TM] = tm
            o[O_PEL] = pel
            o[O_TP] = tp
            o[O_WT] = wt
            o[O_TT] = tt
            o[O_LU] = 1.0 if (lu and gear > 0) else 0.0
            o[O_GT] = gtgt
            o[O_GA] = gear
            o[O_TIN] = tin
            o[O_TOUT] = tout
            o[O_WS] = ifd * v / rw
            o[O_WW] = v / rw
            o[O_PF] = tbf / p[P_B_GF] * 1e5
            o[O_PR] = tbr / p[P_B_GR] * 1e5
            o[O_PMC] = max(o[O_PF], o[O_PR])
            o[O_TBF] = tbf
            o[O_TBR] = tbr
            o[O_IB] = ib
            o[O_VB] = vb
            o[O_OCV] = uoc
            o[O_SOC] = soc
            o[O_DSOC] = dsoc
            o[O_ILV] = idc
            o[O_VLV] = vlv
            o[O_ILVB] = ilvb
            o[O_Q_ENGINE] = fuel_flow * p[P_LHV] - te * wp if eon else 0.0
            o[O_Q_MOTOR] = pel - tm * wp
            o[O_Q_BATT] = rpk * ib * ib
            o[O_VDYN] = v
            iout += 1

        # ---- advance states ----
        x += v_mid * dt
        v = v_new
        wp = wp_new
        if k0:
            we = wp
        soc -= ib * dt / p[P_CAP_AS]
        soclv -= ilvb * dt / p[P_LV_CAP_AS]
        t = (kstep + 1) * dt
        if ramp > 0.0:
            ramp = max(ramp - dt, 0.0)
        kstep += 1
        if latch and v <= 0.0 and t - latch_t > latch_v / p[P_DRV_STOP] + 3.0:
            nrun = i + 1
            break

    st[S_V] = v
    st[S_X] = x
    st[S_WP] = wp
    st[S_WE] = we
    st[S_EON] = 1.0 if eon else 0.0
    st[S_K0] = 1.0 if k0 else 0.0
    st[S_LU] = 1.0 if lu else 0.0
    st[S_GEAR] = gear
    st[S_GT] = gtgt
    st[S_SHT] = sht
    st[S_SOC] = soc
    st[S_SOCLV] = soclv
    st[S_DRV_U] = drv_u
    st[S_DRV_E] = drv_e
    st[S_DYN_U] = dyn_u
    st[S_DYN_E] = dyn_e
    st[S_LATCH] = 1.0 if latch else 0.0
    st[S_LATCH_T] = latch_t
    st[S_LATCH_V] = latch_v
    st[S_SEG] = seg_prev
    st[S_EON_T] = eon_t
    st[S_ESAVE] = esave
    st[S_MEFF] = meff
    st[S_T] = t
    st[S_STEP] = kstep
    st[S_LUT] = lut
    st[S_RAMP] = ramp
    st[S_KOLD] = kold
    return iout - row0, nrun


@njit(cache=True)
def kinetic_energy(p: np.ndarray, st: np.ndarray) -> float:
    """Stored kinetic energy (vehicle as the dyno sees it, pump side, free engine), J."""
    return _ke(p, st)

