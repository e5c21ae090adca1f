"""Each compiled sub-step of the plant, called directly with hand-built state and parameters, against the
equations of docs/models.md computed independently here."""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.emulator.models import (
    interp_1d,
    motor_elec_power_w,
    pack_current_a,
    torque_converter_curves_nm,
    torque_converter_torques_nm,
    transmission_output_torque_nm,
)
from benchtwin.emulator.params import (
    L_ENGINE,
    L_K0,
    L_MOTOR,
    NL,
    NP,
    P_BATT_ALPHA,
    P_BATT_BETA_CHARGE,
    P_BATT_BETA_DISCHARGE,
    P_BRAKE_FRONT_SHARE_BASE,
    P_BRAKE_FRONT_SHARE_MAX,
    P_BRAKE_FRONT_SHARE_PER_MPS2,
    P_DCDC_DROOP_OHM,
    P_DCDC_EFFICIENCY,
    P_DCDC_SET_V,
    P_DISPLACEMENT_M3,
    P_DT_S,
    P_ENGINE_IDLE_RADPS,
    P_ENGINE_INERTIA_KGM2,
    P_ENGINE_SPIN_RADPS2,
    P_F0_N,
    P_F1_N_PER_MPS,
    P_F2_N_PER_MPS2,
    P_FINAL_DRIVE_RATIO,
    P_FUEL_LHV_J_PER_KG,
    P_LOCKUP_MIN_GEAR,
    P_LOCKUP_MIN_SPEED_MPS,
    P_LV_OCV_EMPTY_V,
    P_LV_OCV_FULL_V,
    P_LV_RESISTANCE_OHM,
    P_MASS_KG,
    P_MOTOR_INERTIA_KGM2,
    P_N_CELLS_SERIES,
    P_N_GEARS,
    P_PARASITIC_F0_N,
    P_PARASITIC_F1_N_PER_MPS,
    P_PARASITIC_F2_N_PER_MPS2,
    P_REGEN_CUTOFF_MPS,
    P_SHIFT_DELAY_S,
    P_SHIFT_INERTIA_PHASE_S,
    P_SOC_MAX_FRAC,
    P_SOC_MIN_FRAC,
    P_TC_COUPLING_SPEED_RATIO,
    P_WHEEL_RADIUS_M,
    P_WILLANS_E,
    P_WILLANS_E_GEN,
    P_WILLANS_LOSS_GEN_W,
    P_WILLANS_LOSS_W,
    PlantTables,
)
from benchtwin.emulator.steps_control import engine_on_off, shift_step
from benchtwin.emulator.steps_energy import dyno_forces, engine_fuel, hv_battery, ledger_machines, lv_system
from benchtwin.emulator.steps_powertrain import brake_split, driveline_step, k0_step, lockup_command, vehicle_step

# converter a0..a8 (Nm/(rad/s)^2) in the range of the shipped vehicle, Gamma 0.85
TC_A = np.array([2.0e-3, 1.0e-4, -1.5e-3, 4.0e-3, -1.0e-3, -2.5e-3, 3.0e-3, -1.0e-3, -1.6e-3])
GAMMA = 0.85


def _params() -> np.ndarray:
    p = np.zeros(NP)
    p[P_DT_S] = 0.01
    p[P_MASS_KG] = 2000.0
    p[P_WHEEL_RADIUS_M] = 0.33
    p[P_FINAL_DRIVE_RATIO] = 3.0
    p[P_N_GEARS] = 3
    p[P_F0_N], p[P_F1_N_PER_MPS], p[P_F2_N_PER_MPS2] = 150.0, 2.5, 0.45
    p[P_PARASITIC_F0_N], p[P_PARASITIC_F1_N_PER_MPS], p[P_PARASITIC_F2_N_PER_MPS2] = 40.0, 1.0, 0.02
    p[P_ENGINE_IDLE_RADPS] = 80.0
    p[P_ENGINE_INERTIA_KGM2] = 0.2
    p[P_ENGINE_SPIN_RADPS2] = 400.0
    p[P_MOTOR_INERTIA_KGM2] = 0.1
    p[P_DISPLACEMENT_M3] = 2.0e-3
    p[P_FUEL_LHV_J_PER_KG] = 43.0e6
    p[P_WILLANS_E], p[P_WILLANS_LOSS_W] = 0.93, 800.0
    p[P_WILLANS_E_GEN], p[P_WILLANS_LOSS_GEN_W] = 0.91, 700.0
    p[P_TC_COUPLING_SPEED_RATIO] = GAMMA
    p[P_LOCKUP_MIN_GEAR] = 2
    p[P_LOCKUP_MIN_SPEED_MPS] = 20.0 / 3.6
    p[P_SHIFT_DELAY_S] = 0.02
    p[P_SHIFT_INERTIA_PHASE_S] = 0.3
    p[P_REGEN_CUTOFF_MPS] = 10.0 / 3.6
    p[P_BRAKE_FRONT_SHARE_BASE], p[P_BRAKE_FRONT_SHARE_PER_MPS2], p[P_BRAKE_FRONT_SHARE_MAX] = 0.6, 0.02, 0.75
    p[P_BATT_ALPHA], p[P_BATT_BETA_DISCHARGE], p[P_BATT_BETA_CHARGE] = 1.02, 1.1, 0.9
    p[P_SOC_MIN_FRAC], p[P_SOC_MAX_FRAC] = 0.1, 0.9
    p[P_N_CELLS_SERIES] = 96
    p[P_DCDC_EFFICIENCY], p[P_DCDC_SET_V], p[P_DCDC_DROOP_OHM] = 0.92, 14.2, 0.01
    p[P_LV_OCV_EMPTY_V], p[P_LV_OCV_FULL_V], p[P_LV_RESISTANCE_OHM] = 11.8, 12.9, 0.02
    return p


def _tables(p: np.ndarray | None = None) -> PlantTables:
    p = _params() if p is None else p
    soc = np.linspace(0.0, 1.0, 11)
    return PlantTables(
        p=p,
        ratios=np.array([0.0, 4.0, 2.5, 1.5]),
        eta_m=np.array([1.0, 0.95, 0.96, 0.97]),
        c0=np.array([0.0, 6.0, 5.0, 4.0]),
        up_v0=np.array([15.0, 30.0]) / 3.6,
        up_s=np.array([0.3, 0.5]) / 3.6,
        dn_v0=np.array([8.0, 20.0]) / 3.6,
        dn_s=np.array([0.2, 0.3]) / 3.6,
        e_fl_w=np.array([80.0, 200.0, 450.0]),
        e_fl_t=np.array([200.0, 400.0, 300.0]),
        bsfc_w=np.array([80.0, 300.0, 500.0]),
        bsfc_b=np.array([1.0e5, 10.0e5, 20.0e5]),
        bsfc_kgpj=np.full((3, 3), 220.0 / 3.6e9),
        m_fl_w=np.array([0.0, 300.0, 700.0]),
        m_fl_t=np.array([300.0, 300.0, 120.0]),
        cell_soc=soc,
        cell_ocv=3.4 + 0.8 * soc,
        cell_rd=1.2e-3 + 0.4e-3 * (1.0 - soc),
        cell_rc=1.0e-3 + 0.3e-3 * soc,
        tc_a=TC_A.copy(),
        tc_sr=np.zeros(0),
        tc_cap=np.zeros(0),
        tc_tr=np.zeros(0),
        motor_loss=np.zeros(0),
    )


# ---- model layer ----

def test_interp_1d_is_np_interp_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 4, 5, 9, 30):
        xp = np.sort(rng.uniform(-5.0, 5.0, n))
        fp = rng.normal(size=n)
        for x in np.concatenate([rng.uniform(-7.0, 7.0, 200), xp, [np.nan, -np.inf, np.inf]]):
            got, want = interp_1d(x, xp, fp), np.interp(x, xp, fp)
            assert got == want or (np.isnan(got) and np.isnan(want))


@pytest.mark.parametrize(("t_nm", "w_radps"), [(120.0, 300.0), (-80.0, 250.0), (0.2, 0.5), (5.0, 0.5)])
def test_willans_line(t_nm: float, w_radps: float) -> None:
    p = _params()
    got = motor_elec_power_w(p[P_WILLANS_E], p[P_WILLANS_LOSS_W], p[P_WILLANS_E_GEN], p[P_WILLANS_LOSS_GEN_W],
                             t_nm, w_radps)
    p_mech = t_nm * w_radps
    if w_radps < 1.0 and abs(t_nm) < 0.5:
        want = 0.0
    elif t_nm >= 0.0:  # motoring: T w = e P_el - W_loss
        want = (p_mech + 800.0) / 0.93
    else:  # generating: P_el = e_gen T w + W_loss_gen
        want = 0.91 * p_mech + 700.0
    assert got == pytest.approx(want, rel=1e-12)


@pytest.mark.parametrize("sr", [0.0, 0.3, 0.84, 0.85, 0.95])
def test_converter_eq35_36(sr: float) -> None:
    wp = 180.0
    wt = sr * wp
    tp, tt, dtp = torque_converter_torques_nm(TC_A, GAMMA, wp, wt)
    q = np.array([wp * wp, wp * wt, wt * wt])
    if sr < GAMMA:  # converter mode
        assert tp == pytest.approx(TC_A[0:3] @ q, rel=1e-12)
        assert tt == pytest.approx(TC_A[3:6] @ q, rel=1e-12)
        d_num = (TC_A[0:3] @ [(wp + 1e-3) ** 2, (wp + 1e-3) * wt, wt * wt] - TC_A[0:3] @ q) / 1e-3
    else:  # coupling mode: T_p = T_t
        assert tp == pytest.approx(TC_A[6:9] @ q, rel=1e-12)
        assert tt == tp
        d_num = (TC_A[6:9] @ [(wp + 1e-3) ** 2, (wp + 1e-3) * wt, wt * wt] - TC_A[6:9] @ q) / 1e-3
    assert dtp == pytest.approx(max(d_num, 0.0), rel=1e-5, abs=1e-9)
    # plain-Python body gives the same numbers (shared with validation)
    assert torque_converter_torques_nm.py_func(TC_A, GAMMA, wp, wt) == (tp, tt, dtp)


def test_converter_curves_match_the_plant_pointwise() -> None:
    sr = np.linspace(0.0, 0.95, 40)
    ones = np.ones_like(sr)
    tp, tt = torque_converter_curves_nm(TC_A, GAMMA, ones, sr)
    for k in range(sr.size):
        tp_k, tt_k, _d = torque_converter_torques_nm(TC_A, GAMMA, 1.0, sr[k])
        assert (tp[k], tt[k]) == (tp_k, tt_k)
    conv = sr < GAMMA  # eq. 35 in the speed-ratio form: T / w_p^2 = a0 + a1 SR + a2 SR^2
    np.testing.assert_allclose(tp[conv], TC_A[0] + TC_A[1] * sr[conv] + TC_A[2] * sr[conv] ** 2, rtol=1e-12)
    np.testing.assert_allclose(tt[~conv], TC_A[6] + TC_A[7] * sr[~conv] + TC_A[8] * sr[~conv] ** 2, rtol=1e-12)


@pytest.mark.parametrize("t_in", [100.0, 6.0, 5.8, 5.5, -40.0])
def test_transmission_eq14(t_in: float) -> None:
    i_g, eta, c0 = 2.5, 0.95, 6.0
    got = transmission_output_torque_nm(i_g, eta, c0, t_in)
    if t_in >= c0:  # drive
        want = i_g * eta * (t_in - c0)
        assert (got / i_g) / t_in == pytest.approx(eta * (1.0 - c0 / t_in), rel=1e-12)  # eta = P_out / P_in
    elif t_in <= eta * c0:  # coast
        want = i_g * (t_in / eta - c0)
    else:  # dead band
        want = 0.0
    assert got == pytest.approx(want, rel=1e-12, abs=1e-12)


# ---- HV battery and 12 V ----

@pytest.mark.parametrize("power_w", [30_000.0, -20_000.0, 0.0])
def test_hv_battery_eq29_30(power_w: float) -> None:
    tab = _tables()
    soc = 0.5  # displayed 50 %
    uoc, rpk, ib, vb = hv_battery(tab, soc, power_w)
    s = (soc - 0.1) / 0.8
    ocv_lit = 3.4 + 0.8 * s
    if power_w >= 0.0:
        r_lit, beta = 1.2e-3 + 0.4e-3 * (1.0 - s), 1.1
    else:
        r_lit, beta = 1.0e-3 + 0.3e-3 * s, 0.9
    # V = (alpha OCV_lit - I beta R_lit) n_cells, and the terminals deliver the power asked for
    assert vb == pytest.approx((1.02 * ocv_lit - ib * beta * r_lit) * 96, rel=1e-12)
    assert uoc == pytest.approx(1.02 * ocv_lit * 96, rel=1e-12)
    assert rpk == pytest.approx(beta * r_lit * 96, rel=1e-12)
    assert vb * ib == pytest.approx(power_w, rel=1e-9, abs=1e-6)
    assert np.sign(ib) == np.sign(power_w)


def test_pack_current_limit() -> None:
    # more than U_oc^2 / (4 R) cannot be drawn: the current stops at U_oc / (2 R)
    assert pack_current_a(400.0, 0.1, 1e9) == pytest.approx(400.0 / 0.2)


def test_lv_system_balance() -> None:
    p = _params()
    ocv, vlv, ilvb, idc, plv, pdc_in = lv_system(p, 0.6, 300.0)
    assert ocv == pytest.approx(11.8 + 1.1 * 0.6)
    assert ilvb == pytest.approx((ocv - vlv) / 0.02, rel=1e-12)  # battery: internal resistance
    assert vlv * (idc + ilvb) == pytest.approx(300.0, rel=1e-12)  # the loads get their power
    assert plv == pytest.approx(vlv * idc, rel=1e-12)
    assert pdc_in == pytest.approx(plv / 0.92, rel=1e-12)  # DC/DC efficiency
    # droop: the bus sits below the set voltage by the droop times the DC/DC current (two fixed-point passes)
    assert vlv == pytest.approx(14.2 - 0.01 * idc, rel=1e-4)


# ---- road load and dyno ----

@pytest.mark.parametrize("v_mps", [0.05, 10.0, 30.0])
def test_road_load_mode(v_mps: float) -> None:
    p = _params()
    f_rl, f_par, f_dyn, f_ext, vset, _u, _e = dyno_forces(p, 0, np.nan, v_mps, 0.0, 0.0)
    fade = min(v_mps / (0.5 / 3.6), 1.0)
    assert f_rl == pytest.approx((150.0 + 2.5 * v_mps + 0.45 * v_mps**2) * fade, rel=1e-12)
    assert f_par == pytest.approx((40.0 + 1.0 * v_mps + 0.02 * v_mps**2) * fade, rel=1e-12)
    assert f_ext == -f_rl
    assert f_dyn == 0.0
    assert np.isnan(vset)


# ---- engine fuel ----

def test_engine_fuel_bsfc() -> None:
    tab = _tables()
    bsfc = 220.0 / 3.6e9  # kg/J, flat map
    flow, energy = engine_fuel(tab, True, True, 150.0, 200.0, 200.0, 0.0, 20.0)
    assert flow == pytest.approx(bsfc * 150.0 * 200.0, rel=1e-12)  # fuel = BSFC * T omega
    assert energy == pytest.approx(flow * 0.01 * 43.0e6, rel=1e-12)
    flow_off, energy_off = engine_fuel(tab, False, True, 150.0, 200.0, 200.0, 0.0, 20.0)
    assert flow_off == 0.0 and energy_off == 0.0
    # a start adds its fuel mass
    flow_s, energy_s = engine_fuel(tab, False, False, 0.0, 0.0, 0.0, 1e-3, 20.0)
    assert flow_s == pytest.approx(1e-3 / 0.01) and energy_s == pytest.approx(1e-3 * 43.0e6)


# ---- clutches ----

def test_k0_locks_within_3_radps_keeping_momentum() -> None:
    p = _params()
    p[P_ENGINE_SPIN_RADPS2] = 50.0
    led = np.zeros(NL)
    # engine free at 150 rad/s, pump at 152: K0 requested (auto, engine on); the engine first spins towards
    # the pump speed by P_ENGINE_SPIN_RADPS2 * dt, to 150.5 rad/s, within 3 rad/s: the clutch locks
    k0, we, wp, v, wt, _ke = k0_step(p, led, -1, True, False, 150.0, 152.0, 5.0, 100.0, False, 1, 20.0, 2000.0)
    assert k0
    we0 = 150.0 + 50.0 * 0.01
    je, jm = 0.2, 0.1
    w = (je * we0 + jm * 152.0) / (je + jm)
    assert wp == pytest.approx(w, rel=1e-12) and we == wp
    loss = 0.5 * je * we0**2 + 0.5 * jm * 152.0**2 - 0.5 * (je + jm) * w**2
    assert led[L_K0] == pytest.approx(loss, rel=1e-9)
    assert (v, wt) == (5.0, 100.0)  # lock-up open: the vehicle is not part of the merge
    # far from synchronous: stays open
    k0, we, wp, *_ = k0_step(p, np.zeros(NL), -1, True, False, 50.0, 152.0, 5.0, 100.0, False, 1, 20.0, 2000.0)
    assert not k0 and we == pytest.approx(50.5) and wp == 152.0
    # 3.5 rad/s apart after the spin step: still open
    k0, *_ = k0_step(p, np.zeros(NL), -1, True, False, 148.0, 152.0, 5.0, 100.0, False, 1, 20.0, 2000.0)
    assert not k0


@pytest.mark.parametrize(("gear", "v_kmh", "brake", "want"),
                         [(2, 25.0, 0.0, True), (1, 25.0, 0.0, False), (3, 15.0, 0.0, False),
                          (3, 15.0, 10.0, True), (3, 8.0, 10.0, False)])
def test_lockup_request(gear: int, v_kmh: float, brake: float, want: bool) -> None:
    p = _params()
    req, lu, lut = lockup_command(p, -1, gear, v_kmh / 3.6, brake, True, 0.1)
    assert req is want
    assert lu is want and lut == (0.1 if want else 0.0)  # no request opens the clutch


# ---- shift logic ----

def test_shift_lines_and_delay() -> None:
    tab = _tables()
    # 1 -> 2 above u0 + u1 * pedal (15 + 0.3 * 50 = 30 km/h); the actual gear follows after the delay
    out = shift_step(tab, 30.1 / 3.6, 50.0, -1, 1, 1, 0.0, True, 0.0, 0.0, 0.0)
    assert out[0] == 2 and out[1] == 1 and out[2] == pytest.approx(0.01)
    out = shift_step(tab, 30.1 / 3.6, 50.0, -1, 2, 1, 0.01, True, 0.0, 0.0, 0.0)
    gt, g, sht, lu, _lut, ramp, kold = out
    assert (gt, g, sht, lu, ramp) == (2, 2, 0.0, False, 0.3)
    assert kold == pytest.approx(4.0 * 3.0 / 0.33)  # the old gear's speed gain
    # below the line: stays in 1
    assert shift_step(tab, 29.9 / 3.6, 50.0, -1, 1, 1, 0.0, True, 0.0, 0.0, 0.0)[0] == 1
    # 2 -> 1 at or below d0 + d1 * pedal (8 + 0.2 * 10 = 10 km/h)
    assert shift_step(tab, 9.99 / 3.6, 10.0, -1, 2, 2, 0.0, True, 0.0, 0.0, 0.0)[0] == 1
    assert shift_step(tab, 10.01 / 3.6, 10.0, -1, 2, 2, 0.0, True, 0.0, 0.0, 0.0)[0] == 2


# ---- hybrid strategy ----

def test_engine_on_off_thresholds() -> None:
    p = _params()
    from benchtwin.emulator.params import P_ENGINE_START_FUEL_KG, P_HYB_ENGINE_ON_MPS, P_HYB_ENGINE_ON_W

    p[P_HYB_ENGINE_ON_W], p[P_HYB_ENGINE_ON_MPS], p[P_ENGINE_START_FUEL_KG] = 25_000.0, 30.0, 2e-4
    # hybrid mode 0, engine off: starts above the power threshold, paying the start fuel
    # (no start-fuel duration set: the start's fuel is burnt in its step, nothing left)
    assert engine_on_off(p, -1, 0, False, 0.0, 40.0, 50.0, 25_001.0, 10.0, 50.0, 0.0) == (True, 0.01, 2e-4, 0.0)
    assert engine_on_off(p, -1, 0, False, 0.0, 40.0, 50.0, 24_999.0, 10.0, 50.0, 0.0) == (False, 0.0, 0.0, 0.0)
    # forced off by the protocol
    assert engine_on_off(p, 0, 0, True, 5.0, 40.0, 50.0, 1e6, 40.0, 50.0, 0.0)[0] is False


# ---- brakes ----

def test_brake_front_share() -> None:
    p = _params()
    bdem = 3000.0
    tbf, tbr, fb = brake_split(p, bdem, 2000.0)
    decel = bdem / (0.33 * 2000.0)
    fs = min(max(0.6 + 0.02 * decel, 0.6), 0.75)
    assert tbf == pytest.approx(fs * 2000.0) and tbr == pytest.approx((1.0 - fs) * 2000.0)
    assert fb == pytest.approx(2000.0 / 0.33)


# ---- driveline and vehicle ----

def _rigid(tsrc: float, f_ext: float, fb: float, v: float = 20.0) -> tuple:
    tab = _tables()
    kg = 2.5 * 3.0 / 0.33
    jp = 0.3
    return driveline_step(tab, 2, True, v, kg * v, kg * v, tsrc, jp, kg, 2.5, 0.0, 0.0, 0.0, 0.0, 2000.0, f_ext, fb,
                          tab.c0[2])


@pytest.mark.parametrize(("tsrc", "f_ext", "fb"), [(200.0, -400.0, 0.0), (-150.0, -400.0, 500.0)])
def test_rigid_driveline_eq14(tsrc: float, f_ext: float, fb: float) -> None:
    a, tp, tt, _tlu, tin, tout, *_ = _rigid(tsrc, f_ext, fb)
    kg, jp, eta, c0, ig, m = 2.5 * 3.0 / 0.33, 0.3, 0.96, 5.0, 2.5, 2000.0
    # the pump side accelerates with the vehicle: T_in = T_src - J_p k a
    assert tin == pytest.approx(tsrc - jp * kg * a, rel=1e-12)
    if tin >= c0:
        assert tout == pytest.approx(ig * eta * (tin - c0), rel=1e-12)
    else:
        assert tin <= eta * c0
        assert tout == pytest.approx(ig * (tin / eta - c0), rel=1e-12)
    # Newton on the vehicle: m a = F_wheel + F_ext - F_b
    assert m * a == pytest.approx(3.0 * tout / 0.33 + f_ext - fb, rel=1e-9)
    assert tp == tin and tt == tin


def test_converter_driveline() -> None:
    tab = _tables()
    kg = 4.0 * 3.0 / 0.33
    v, wp, jp, tsrc = 3.0, 150.0, 0.3, 120.0
    wt = kg * v
    a, tp, tt, tlu, tin, tout, tp_eff, _tlu_eff, slip, dw = driveline_step(
        tab, 1, False, v, wp, wt, tsrc, jp, kg, 4.0, 0.0, 0.0, 0.0, 0.0, 2000.0, -200.0, 0.0, tab.c0[1])
    tp_w, tt_w, dtp = torque_converter_torques_nm(TC_A, GAMMA, wp, wt)
    assert (tp, tt, tlu) == (tp_w, tt_w, 0.0) and tin == tt_w
    assert tout == pytest.approx(4.0 * 0.95 * (tin - 6.0), rel=1e-12)  # eq. 14 drive
    # semi-implicit pump node: J dw/dt = T_src - T_p(w + dw)
    assert dw == pytest.approx(0.01 * (tsrc - tp) / (jp + 0.01 * dtp), rel=1e-12)
    assert tp_eff == pytest.approx(tp + dtp * dw, rel=1e-12)
    assert a == pytest.approx((3.0 * tout / 0.33 - 200.0) / 2000.0, rel=1e-12)
    assert slip == 0.0


def test_vehicle_stops_at_zero() -> None:
    p = _params()
    a, v_new, stop_fix, v_mid, *_ = vehicle_step(p, 2, True, 0.05, -10.0, 50.0, 0.0, 20.0, 20.0, 2000.0)
    assert v_new == 0.0 and a == pytest.approx(-5.0) and stop_fix == pytest.approx(2000.0 * 5.0)
    assert v_mid == pytest.approx(0.025)


# ---- ledger ----

def test_ledger_machines_losses() -> None:
    p = _params()
    led = np.zeros(NL)
    ledger_machines(p, led, 2, True, True, True, 100.0, 50.0, 9000.0, 5000.0, 0.0, 0.0, 0.0, 160.0)
    assert led[L_ENGINE] == pytest.approx(5000.0 - 100.0 * 160.0 * 0.01, rel=1e-12)  # fuel in - shaft out
    assert led[L_MOTOR] == pytest.approx(9000.0 * 0.01 - 50.0 * 160.0 * 0.01, rel=1e-12)  # P_el in - shaft out
