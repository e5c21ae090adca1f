"""Model layer: the pure equations of docs/models.md, one scalar function per model form.

Every function here is pure (no state, no ledger, no parameter vector): it takes plain floats and small
float64 arrays and returns floats. Each is compiled with numba (``@njit``), so the plant's sub-steps call
it at no cost, and it stays callable from plain Python (through the numba dispatcher, or its ``py_func``
attribute for the uncompiled Python body). Importing this module compiles nothing and has no side effects.

Units are SI throughout: rad/s, Nm, W, m/s, N, A, V, ohm, kg/J.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "battery_rc_update",
    "bms_power_limits_w",
    "bsfc_kg_per_j",
    "clutch_merge",
    "cold_start_factor",
    "converter_torques_nm",
    "interp_1d",
    "motor_elec_power_w",
    "motor_loss_hifi_w",
    "pack_current_a",
    "road_load_force_n",
    "spin_loss_torque_nm",
    "tabulated_converter_torques_nm",
    "torque_converter_curves_nm",
    "torque_converter_torques_nm",
    "transmission_output_torque_nm",
    "tyre_slip",
]


#: numba's np.interp looks a few points around its guess before bisecting
_LIKELY_IN_CACHE_SIZE = 8


@njit(cache=True)
def _search_with_guess(key: float, arr: np.ndarray, length: int, guess: int) -> int:
    """Index j with arr[j] <= key < arr[j + 1] (-1 below, ``length`` above): numba's np.interp search."""
    imin = 0
    imax = length
    if key > arr[length - 1]:
        return length
    elif key < arr[0]:
        return -1
    if length <= 4:
        i = 1
        while i < length and key >= arr[i]:
            i += 1
        return i - 1
    if guess > length - 3:
        guess = length - 3
    if guess < 1:
        guess = 1
    if key < arr[guess]:
        if key < arr[guess - 1]:
            imax = guess - 1
            if guess > _LIKELY_IN_CACHE_SIZE and key >= arr[guess - _LIKELY_IN_CACHE_SIZE]:
                imin = guess - _LIKELY_IN_CACHE_SIZE
        else:
            return guess - 1
    else:
        if key < arr[guess + 1]:
            return guess
        elif key < arr[guess + 2]:
            return guess + 1
        else:
            imin = guess + 2
            if guess < length - _LIKELY_IN_CACHE_SIZE - 1 and key < arr[guess + _LIKELY_IN_CACHE_SIZE]:
                imax = guess + _LIKELY_IN_CACHE_SIZE
    while imin < imax:
        imid = imin + ((imax - imin) >> 1)
        if key >= arr[imid]:
            imin = imid + 1
        else:
            imax = imid
    return imin - 1


@njit(cache=True)
def interp_1d(x: float, xp: np.ndarray, fp: np.ndarray) -> float:
    """Linear interpolation of one scalar, clamped outside ``xp``: the same result as ``np.interp(x, xp, fp)``.

    The scalar path of numba's ``np.interp`` (itself numpy's algorithm, step for step, so the results are
    bit-identical) without its temporary arrays, so that the plant's sub-steps, compiled without
    reference counting, allocate nothing.

    Parameters
    ----------
    x:
        Where to interpolate.
    xp, fp:
        Increasing sample points and their values (same length, at least 1).

    Returns
    -------
    float
        The interpolated value (``fp[0]`` below ``xp[0]``, ``fp[-1]`` above ``xp[-1]``, NaN for NaN).
    """
    n = xp.shape[0]
    if n == 1:
        return fp[0]
    if np.isnan(x):
        return x
    j = _search_with_guess(x, xp, n, 0)
    if j == -1:
        return fp[0]
    elif j == n:
        return fp[n - 1]
    elif j == n - 1 or xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    res = slope * (x - xp[j]) + fp[j]
    if np.isnan(res):
        res = slope * (x - xp[j + 1]) + fp[j + 1]
        if np.isnan(res) and fp[j] == fp[j + 1]:
            res = fp[j]
    return res


@njit(cache=True)
def torque_converter_torques_nm(a_nm_per_radps2: np.ndarray, coupling_speed_ratio: float, pump_speed_radps: float,
                                turbine_speed_radps: float) -> tuple[float, float, float]:
    """Pump and turbine torque of the torque converter (eq. 35-36) and dT_p/d(omega_p).

    Parameters
    ----------
    a_nm_per_radps2:
        Coefficients a0..a8, Nm/(rad/s)^2 (the vehicle file's ``a_nm_per_radps2``).
    coupling_speed_ratio:
        Gamma: converter mode below the speed ratio omega_t / omega_p = Gamma, coupling mode at and above.
    pump_speed_radps, turbine_speed_radps:
        omega_p and omega_t, rad/s. The speed ratio is taken as 0 when omega_p <= 1e-6 rad/s.

    Returns
    -------
    pump_torque_nm, turbine_torque_nm, dpump_torque_dspeed_nm_per_radps
        T_p and T_t (Nm), and the partial derivative of T_p with respect to omega_p, floored at 0
        (used by the semi-implicit pump-speed update).
    """
    a = a_nm_per_radps2
    wp = pump_speed_radps
    wt = turbine_speed_radps
    sr = wt / wp if wp > 1e-6 else 0.0
    if sr < coupling_speed_ratio:
        tp = a[0] * wp * wp + a[1] * wp * wt + a[2] * wt * wt
        tt = a[3] * wp * wp + a[4] * wp * wt + a[5] * wt * wt
        dtp = 2.0 * a[0] * wp + a[1] * wt
    else:
        tp = a[6] * wp * wp + a[7] * wp * wt + a[8] * wt * wt
        tt = tp
        dtp = 2.0 * a[6] * wp + a[7] * wt
    return tp, tt, max(dtp, 0.0)


@njit(cache=True)
def torque_converter_curves_nm(a_nm_per_radps2: np.ndarray, coupling_speed_ratio: float,
                               pump_speed_radps: np.ndarray,
                               turbine_speed_radps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 35-36 over arrays of operating points: :func:`torque_converter_torques_nm` point by point.

    Parameters
    ----------
    a_nm_per_radps2, coupling_speed_ratio:
        As for :func:`torque_converter_torques_nm`.
    pump_speed_radps, turbine_speed_radps:
        1-D arrays of the same length, rad/s. With ``pump_speed_radps = 1`` and ``turbine_speed_radps = SR``
        the results are the curves T_p / omega_p^2 and T_t / omega_p^2 over the speed ratio.

    Returns
    -------
    pump_torque_nm, turbine_torque_nm
        Arrays, Nm (the very numbers the plant computes at those points).
    """
    n = pump_speed_radps.shape[0]
    tp = np.empty(n)
    tt = np.empty(n)
    for k in range(n):
        tp_k, tt_k, _d = torque_converter_torques_nm(a_nm_per_radps2, coupling_speed_ratio, pump_speed_radps[k],
                                                     turbine_speed_radps[k])
        tp[k] = tp_k
        tt[k] = tt_k
    return tp, tt


@njit(cache=True)
def bms_power_limits_w(max_discharge_w: float, max_charge_w: float, displayed_soc_pct: float,
                       discharge_band_pct: float, charge_band_pct: float) -> tuple[float, float]:
    """BMS power limits of the HV pack, derated linearly towards the ends of its usable window.

    Discharge: full power from ``discharge_band_pct`` displayed-SOC points up, falling linearly to 0 at
    0 % (soc_min) and 0 below. Charge: the same towards 100 % (soc_max) over ``charge_band_pct`` points. A band of
    0 keeps full power up to the end of the window and none beyond it.

    Parameters
    ----------
    max_discharge_w, max_charge_w:
        Pack's rated discharge and charge power (W, both positive).
    displayed_soc_pct:
        Displayed SOC, % of the usable window (may lie outside 0..100).
    discharge_band_pct, charge_band_pct:
        Widths of the derating bands, displayed-SOC points (>= 0).

    Returns
    -------
    tuple of float
        ``(discharge_limit_w, charge_limit_w)``, both in 0..rated.
    """
    s = displayed_soc_pct
    if discharge_band_pct > 0.0:
        kd = min(max(s / discharge_band_pct, 0.0), 1.0)
    else:
        kd = 1.0 if s > 0.0 else 0.0
    if charge_band_pct > 0.0:
        kc = min(max((100.0 - s) / charge_band_pct, 0.0), 1.0)
    else:
        kc = 1.0 if s < 100.0 else 0.0
    return max_discharge_w * kd, max_charge_w * kc


@njit(cache=True)
def motor_elec_power_w(willans_e: float, willans_loss_w: float, willans_e_gen: float, willans_loss_gen_w: float,
                       torque_nm: float, speed_radps: float) -> float:
    """Motor inverter DC power from the Willans line (eq. 18-24).

    Motoring (T >= 0): P_el = (T omega + W_loss) / e; generating (T < 0): P_el = e_gen T omega + W_loss_gen.
    Zero when the machine is practically at rest and unloaded (omega < 1 rad/s and |T| < 0.5 Nm).

    Parameters
    ----------
    willans_e, willans_loss_w:
        Motoring efficiency e (-) and loss W_loss (W).
    willans_e_gen, willans_loss_gen_w:
        Generating slope e_gen (-) and loss W_loss_gen (W).
    torque_nm, speed_radps:
        Motor torque (Nm) and speed (rad/s).

    Returns
    -------
    float
        DC power, W (negative: power into the HV bus).
    """
    if speed_radps < 1.0 and abs(torque_nm) < 0.5:
        return 0.0
    if torque_nm >= 0.0:
        return (torque_nm * speed_radps + willans_loss_w) / willans_e
    return willans_e_gen * torque_nm * speed_radps + willans_loss_gen_w


@njit(cache=True)
def bsfc_kg_per_j(speed_grid_radps: np.ndarray, bmep_grid_pa: np.ndarray, bsfc_table_kg_per_j: np.ndarray,
                  speed_radps: float, bmep_pa: float) -> float:
    """Brake-specific fuel consumption (eq. 26-28), bilinear inside the grid and clamped outside.

    Parameters
    ----------
    speed_grid_radps, bmep_grid_pa:
        Grid axes: engine speed (rad/s) and BMEP (Pa), increasing.
    bsfc_table_kg_per_j:
        BSFC over the grid (speed x BMEP), kg/J.
    speed_radps, bmep_pa:
        Operating point.

    Returns
    -------
    float
        BSFC, kg/J.
    """
    w = speed_grid_radps
    b = bmep_grid_pa
    tab = bsfc_table_kg_per_j
    nw = w.shape[0]
    nb = b.shape[0]
    x = min(max(speed_radps, w[0]), w[nw - 1])
    y = min(max(bmep_pa, b[0]), b[nb - 1])
    i = np.searchsorted(w, x) - 1
    i = min(max(i, 0), nw - 2)
    j = np.searchsorted(b, y) - 1
    j = min(max(j, 0), nb - 2)
    fx = (x - w[i]) / (w[i + 1] - w[i])
    fy = (y - b[j]) / (b[j + 1] - b[j])
    return ((1 - fx) * (1 - fy) * tab[i, j] + fx * (1 - fy) * tab[i + 1, j]
            + (1 - fx) * fy * tab[i, j + 1] + fx * fy * tab[i + 1, j + 1])


@njit(cache=True)
def clutch_merge(inertia1_kgm2: float, speed1_radps: float, inertia2_kgm2: float,
                 speed2_radps: float) -> tuple[float, float]:
    """Two inertias locked together by a clutch: common speed (momentum kept) and the energy lost.

    Parameters
    ----------
    inertia1_kgm2, speed1_radps, inertia2_kgm2, speed2_radps:
        The two sides before the lock.

    Returns
    -------
    speed_radps, loss_j
        Common speed after the lock and the kinetic energy dissipated by the slip, J.
    """
    j1 = inertia1_kgm2
    w1 = speed1_radps
    j2 = inertia2_kgm2
    w2 = speed2_radps
    w = (j1 * w1 + j2 * w2) / (j1 + j2)
    return w, 0.5 * j1 * w1 * w1 + 0.5 * j2 * w2 * w2 - 0.5 * (j1 + j2) * w * w


@njit(cache=True)
def road_load_force_n(f0_n: float, f1_n_per_mps: float, f2_n_per_mps2: float, speed_mps: float) -> float:
    """Road-load force F0 + F1 v + F2 v^2 (v in m/s, coefficients converted to m/s), N."""
    return f0_n + f1_n_per_mps * speed_mps + f2_n_per_mps2 * speed_mps * speed_mps


@njit(cache=True)
def transmission_output_torque_nm(ratio: float, eta_m: float, c0_nm: float, input_torque_nm: float) -> float:
    """Gearbox output torque of eq. 14 (drive), eq. 13-14 (coast) and the dead band between.

    Parameters
    ----------
    ratio:
        Gear ratio i_g (or the effective ratio while a shift clutch slips).
    eta_m, c0_nm:
        eq. 14 efficiency and drag torque C0 (Nm) of the gear.
    input_torque_nm:
        T_in, Nm.

    Returns
    -------
    float
        T_out: i_g eta_m (T_in - C0) for T_in >= C0, i_g (T_in / eta_m - C0) for T_in <= eta_m C0, else 0.
    """
    if input_torque_nm >= c0_nm:
        return ratio * eta_m * (input_torque_nm - c0_nm)
    if input_torque_nm <= eta_m * c0_nm:
        return ratio * (input_torque_nm / eta_m - c0_nm)
    return 0.0


@njit(cache=True)
def pack_current_a(open_circuit_v: float, resistance_ohm: float, power_w: float) -> float:
    """HV pack current drawing ``power_w`` at the terminals of an OCV source with internal resistance (eq. 29-30).

    Solves P = (U_oc - R I) I for the smaller root, I = (U_oc - sqrt(U_oc^2 - 4 R P)) / (2 R); the
    discriminant is floored at 0 (the most power the pack can give).

    Parameters
    ----------
    open_circuit_v, resistance_ohm:
        Pack open-circuit voltage (V) and internal resistance (ohm).
    power_w:
        Terminal power, W (positive: discharge).

    Returns
    -------
    float
        Current, A (positive: discharge).
    """
    uoc = open_circuit_v
    rpk = resistance_ohm
    disc = uoc * uoc - 4.0 * rpk * power_w
    if disc < 0.0:
        disc = 0.0
    return (uoc - np.sqrt(disc)) / (2.0 * rpk)


# ---- high-fidelity model forms (vehicle files with fidelity = "high"; docs/fidelity.md) ----


@njit(cache=True)
def tabulated_converter_torques_nm(sr_grid: np.ndarray, capacity_grid: np.ndarray, torque_ratio_grid: np.ndarray,
                                   pump_speed_radps: float, turbine_speed_radps: float) -> tuple[float, float, float]:
    """Torque converter from tabulated curves: T_p = c(SR) omega_p^2, T_t = TR(SR) T_p, and dT_p/d(omega_p).

    The capacity c = (30 / pi)^2 / K^2 (K the K-factor in rpm/sqrt(Nm), negative c in overrun) and the
    torque ratio TR are interpolated linearly over the speed ratio SR = omega_t / omega_p (clamped).

    Parameters
    ----------
    sr_grid, capacity_grid, torque_ratio_grid:
        Increasing speed ratios, capacity c(SR) in Nm/(rad/s)^2 and torque ratio TR(SR).
    pump_speed_radps, turbine_speed_radps:
        omega_p and omega_t, rad/s (SR = 0 when omega_p <= 1e-6 rad/s).

    Returns
    -------
    pump_torque_nm, turbine_torque_nm, dpump_torque_dspeed_nm_per_radps
        T_p, T_t (Nm) and dT_p/d(omega_p) at fixed omega_t (2 c omega_p - c'(SR) omega_t), floored at 0.
    """
    wp = pump_speed_radps
    wt = turbine_speed_radps
    sr = wt / wp if wp > 1e-6 else 0.0
    c = interp_1d(sr, sr_grid, capacity_grid)
    tr = interp_1d(sr, sr_grid, torque_ratio_grid)
    n = sr_grid.shape[0]
    slope = 0.0
    if sr_grid[0] <= sr < sr_grid[n - 1]:
        j = np.searchsorted(sr_grid, sr, side="right") - 1
        slope = (capacity_grid[j + 1] - capacity_grid[j]) / (sr_grid[j + 1] - sr_grid[j])
    tp = c * wp * wp
    dtp = 2.0 * c * wp - slope * wt
    return tp, tr * tp, max(dtp, 0.0)


@njit(cache=True)
def converter_torques_nm(a_nm_per_radps2: np.ndarray, coupling_speed_ratio: float, sr_grid: np.ndarray,
                         capacity_grid: np.ndarray, torque_ratio_grid: np.ndarray, pump_speed_radps: float,
                         turbine_speed_radps: float) -> tuple[float, float, float]:
    """The plant's converter: the tabulated curves when ``sr_grid`` is not empty, else eq. 35-36.

    Returns
    -------
    pump_torque_nm, turbine_torque_nm, dpump_torque_dspeed_nm_per_radps
        As :func:`torque_converter_torques_nm` (the very same floats for an empty table).
    """
    if sr_grid.shape[0] > 0:
        return tabulated_converter_torques_nm(sr_grid, capacity_grid, torque_ratio_grid, pump_speed_radps,
                                              turbine_speed_radps)
    return torque_converter_torques_nm(a_nm_per_radps2, coupling_speed_ratio, pump_speed_radps, turbine_speed_radps)


@njit(cache=True)
def motor_loss_hifi_w(coeffs: np.ndarray, torque_nm: float, speed_radps: float) -> float:
    """Motor and inverter loss of the high-fidelity plant, W (docs/fidelity.md).

    P_loss = k_cu T^2 + k_d (1 - w_b/w)^2 [w > w_b] + (k_h w + k_e w^2) min(1, w_b/w)^2 + k_f w + k_w w^3
    + P_inv0 + k_sw |T|; the same loss motoring and generating (P_el = T w + P_loss).

    Parameters
    ----------
    coeffs:
        ``[k_cu, k_d, w_b, k_h, k_e, k_f, k_w, P_inv0, k_sw]`` in W/Nm^2, W, rad/s, W/(rad/s), W/(rad/s)^2,
        W/(rad/s), W/(rad/s)^3, W, W/Nm.
    torque_nm, speed_radps:
        Motor torque (Nm) and speed (rad/s, >= 0).

    Returns
    -------
    float
        Loss power, W.
    """
    w = max(speed_radps, 0.0)
    t = torque_nm
    wb = coeffs[2]
    phi = 1.0
    fw = 0.0
    if w > wb:
        phi = wb / w
        fw = 1.0 - phi
    return (coeffs[0] * t * t + coeffs[1] * fw * fw + (coeffs[3] * w + coeffs[4] * w * w) * phi * phi
            + coeffs[5] * w + coeffs[6] * w * w * w + coeffs[7] + coeffs[8] * abs(t))


@njit(cache=True)
def spin_loss_torque_nm(c0_nm: float, spin_per_radps: float, viscosity_per_k: float, oil_reference_degc: float,
                        input_speed_radps: float, oil_degc: float) -> float:
    """Load-independent gearbox drag at the input, Nm: C0 (1 + k_w |w_in|) exp(-k_T (T_oil - T_ref)).

    It takes the place of eq. 14's constant C0, so the gear's efficiency eta_m (1 - C / T_in) moves with
    input speed and oil temperature.
    """
    return c0_nm * (1.0 + spin_per_radps * abs(input_speed_radps)) * np.exp(
        -viscosity_per_k * (oil_degc - oil_reference_degc))


@njit(cache=True)
def battery_rc_update(voltage_v: float, resistance_ohm: float, tau_s: float, current_a: float, dt_s: float) -> float:
    """Voltage of an RC branch after ``dt_s`` at constant current (exact).

    u' = u e^(-dt/tau) + R I (1 - e^(-dt/tau)), V.
    """
    f = np.exp(-dt_s / tau_s)
    return voltage_v * f + resistance_ohm * current_a * (1.0 - f)


@njit(cache=True)
def cold_start_factor(penalty_frac: float, warm_degc: float, coolant_degc: float) -> float:
    """Fuel multiplier of a cold engine: 1 + penalty (T_warm - T) / (T_warm - 20 degC), none when warm."""
    if coolant_degc >= warm_degc:
        return 1.0
    return 1.0 + penalty_frac * (warm_degc - coolant_degc) / (warm_degc - 20.0)


@njit(cache=True)
def tyre_slip(force_n: float, slip_stiffness_n: float) -> float:
    """Longitudinal slip of the driven tyres on the rollers, s = (v_wheel - v_roller) / v_roller.

    Linear (brush-model) range of the slip curve: ``s = F_x / C_k``, with ``C_k`` the axle's slip stiffness
    (N per unit slip), positive under traction, negative under braking, limited to +/-0.1 (beyond, a tyre
    spins or locks; the plant's wheel-force limit keeps it below about 5 %). No slip when ``C_k <= 0``.

    Parameters
    ----------
    force_n:
        Longitudinal force of the driven axle on the rollers, N.
    slip_stiffness_n:
        Slip stiffness of the driven axle, N per unit slip.

    Returns
    -------
    float
        Slip, dimensionless.
    """
    if slip_stiffness_n <= 0.0:
        return 0.0
    return min(max(force_n / slip_stiffness_n, -0.1), 0.1)
