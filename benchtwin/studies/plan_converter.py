"""Planned torque-converter standard errors: the sandwich of its two linear fits at the planned points.

The identification's own selection and regressors (:func:`~benchtwin.identification.torque_converter_points.
converter_points`, :func:`~benchtwin.identification.torque_converter.converter_design`) run on the noise-free
Recording, and its own fit (:func:`~benchtwin.identification.torque_converter.fit_torque_converter`) gives the
coupling point, the rows each mode keeps (outlier rejection) and the values. With those rows fixed, both fits
are linear in their right-hand sides:

- converter mode (eq. 37-38), stacked ``[t_p; t_t] = A x``: ``x = (A'A)^-1 A' b``, whose covariance is the
  sandwich with the variance of each row: the motor torque's grid sample for the pump rows, the shaft torque's
  over ``k_out^2`` (``k_out = i_g eta_m``) for the turbine rows (a grid sample interpolated between two readings
  at fraction ``a`` has ``(1-a)^2`` and ``a^2`` of their variances);
- coupling mode (eq. 39), ``t_p - J dw_p = q a_678``: the pump rows of the coupling points, and the pump inertia
  ``J`` of the converter fit through ``-(q'q)^-1 q' dw_p``;
- the transmission model each turbine torque goes through (``T_out / (i_g eta_m) + C0``) is itself estimated
  from the same seed's shaft torque: its planned ``eta_m`` and ``C0`` standard errors of each gear move all
  the turbine rows of that gear together (``-(t_t - C0) / eta_m`` and ``1``), taken as independent.

The derived parameters (``gamma_coupling``, ``k_at_gamma`` with its coupling point, ``sr_zero_torque``) follow
by the delta method on the joint covariance. What is not in it: rows that the outlier rejection keeps on one
seed and leaves out on another (the plan keeps those of the noise-free data).
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from benchtwin.config.vehicle import VehicleConfig
from benchtwin.errors import BenchtwinError
from benchtwin.identification.torque_converter import (
    _zero_torque_sr,
    converter_design,
    coupling_point,
    fit_torque_converter,
    identify_torque_converter,
    speed_products,
)
from benchtwin.identification.torque_converter_points import converter_points
from benchtwin.recording import Channel, Recording
from benchtwin.segments import Segment
from benchtwin.studies.plan_fits import PlannedParameter
from benchtwin.studies.plan_noise import ChannelNoise, grid_variance

__all__ = ["CONVERTER_RECORDED", "plan_converter"]

#: channels of the converter's points that the plan takes as recorded when they carry no random error: their
#: quantisation and latency are the same every seed, and the narrow coupling range's ``a6..a8`` (and the slope of
#: ``k_at_gamma`` along the coupling point) move with them; a noisy channel it reads keeps its truth with the
#: sensor's declared gain and offset (also the same every seed), so the derivatives are taken where a run is
CONVERTER_RECORDED = ("em_speed_rpm", "em_torque_nm", "vehicle_speed_kmh")

nan = float("nan")
_HINT = "add [[tests]] kind = \"acceleration\" (converter mode at the launch)"
_POINT_OPTS = ("rate_hz", "max_pump_accel_rpm_s", "min_pump_speed_rpm", "min_pump_torque_nm", "shift_hold_s",
               "derivative_window_s", "calibrate_turbine_speed", "min_calibration_points", "lockup_slip_tol")
_FIT_OPTS = ("gamma", "min_points", "outlier_sigma")


def _defaults() -> dict[str, object]:
    """The identification's own default options (one source of truth)."""
    return {k: p.default for k, p in inspect.signature(identify_torque_converter).parameters.items()
            if p.default is not inspect.Parameter.empty}


def _transmission_table(tx: Sequence[PlannedParameter]) -> dict[int, tuple[float, float, float, float]]:
    """Gear -> (eta_m, C0, se eta_m, se C0) of the identifiable drive fits of the transmission plan."""
    by = {p.name: p for p in tx}
    out = {}
    for name, p in by.items():
        if not (name.startswith("transmission.gear") and name.endswith(".eta_m") and "_coast" not in name):
            continue
        g = int(name[len("transmission.gear"):-len(".eta_m")])
        c0 = by.get(f"transmission.gear{g}.C0")
        if p.identifiable and c0 is not None and c0.identifiable:
            out[g] = (p.value, c0.value, p.se if math.isfinite(p.se) else 0.0, c0.se if math.isfinite(c0.se) else 0.0)
    return out


def _delta(func: Callable[[np.ndarray], float], z: np.ndarray, cov: np.ndarray) -> float:
    """Variance of ``func(z)`` by the delta method (central differences)."""
    grad = np.zeros(z.size)
    for i in range(z.size):
        h = 1e-6 * max(1.0, abs(float(z[i])))
        up, dn = z.copy(), z.copy()
        up[i] += h
        dn[i] -= h
        grad[i] = (func(up) - func(dn)) / (2 * h)
    return float(grad @ cov @ grad)


def plan_converter(rec: Recording, vehicle: VehicleConfig, noise: Mapping[str, ChannelNoise],
                   segments: list[Segment], tx: Sequence[PlannedParameter], *, seed: int = 0,
                   recorded: Mapping[str, Channel] | None = None) -> list[PlannedParameter]:
    """Predicted standard errors of ``a0..a8``, ``J_pump_kgm2``, the coupling point and its derived values.

    Parameters
    ----------
    rec:
        The noise-free truth Recording.
    vehicle:
        Gear ratios, final drive, wheel radius.
    noise:
        Role -> random error of its readings.
    segments:
        The campaign's tests.
    tx:
        The transmission plan (:func:`~benchtwin.studies.plan_fits.plan_transmission`): the table the turbine
        torque goes through, and its standard errors.
    recorded:
        Role -> the channel as the bench recorded it (:data:`CONVERTER_RECORDED`); a role without random error
        on the setup is taken from here instead of its truth.
    seed:
        Seed of the one noise draw that decides the rows the outlier rejection keeps (module docstring).

    Returns
    -------
    list of PlannedParameter
        ``torque_converter.converter.*`` and ``torque_converter.coupling.*``, or one row
        ``torque_converter.*`` flagged not identifiable with the test to add.
    """
    specs = vehicle.specs
    if not any(s.kind in ("acceleration", "deceleration") for s in segments):
        return [PlannedParameter("torque_converter.*", "", float("nan"), float("nan"), False,
                                 "missing: accelerations or decelerations (lock-up open)", _HINT)]
    opts = _defaults()
    swap = {n: ch for n, ch in (recorded or {}).items() if n not in noise and n in rec}
    for n in ("shaft_torque_nm", *CONVERTER_RECORDED):
        if n in noise and n in rec and (noise[n].gain or noise[n].offset):  # the same gain and offset every seed
            ch = rec[n]
            swap[n] = Channel(n, ch.unit, ch.timestamps, (1.0 + noise[n].gain) * ch.values + noise[n].offset,
                              ch.flags, ch.source)
    if swap:
        view = Recording(segments=list(rec.segments), meta=rec.meta)
        for name, ch in rec.channels.items():
            view.add(swap.get(name, ch))
        rec = view
    table = _transmission_table(tx)
    try:
        pts = converter_points(rec, specs, transmission={g: v[:2] for g, v in table.items()} or None,
                               **{k: opts[k] for k in _POINT_OPTS})  # type: ignore[arg-type]
        res = fit_torque_converter(pts.w_p, pts.w_t, pts.t_p, pts.t_t, dw_p=pts.dw_p,
                                   **{k: opts[k] for k in _FIT_OPTS})  # type: ignore[arg-type]
    except BenchtwinError as exc:
        return [PlannedParameter("torque_converter.*", "", float("nan"), float("nan"), False,
                                 f"no converter fit at the planned points: {exc}", _HINT)]
    # variance of each point's pump torque (motor torque) and turbine torque (shaft torque over k_out)
    v_tp = grid_variance(rec, noise, "em_torque_nm", pts.t)
    v_tt = grid_variance(rec, noise, "shaft_torque_nm", pts.t) / pts.k_out**2
    rows = res
    if np.any(v_tp > 0) or np.any(v_tt > 0):
        # the outlier rejection scales its bound by the residuals' spread: on noise-free points it would leave out
        # rows a noisy run keeps, and the coupling fit leans on the pump inertia of the converter fit. The rows,
        # the coupling point and the coefficients the derivatives are taken at come from one draw of the noise.
        rng = np.random.default_rng(seed)
        try:
            rows = fit_torque_converter(pts.w_p, pts.w_t, pts.t_p + rng.normal(0.0, np.sqrt(v_tp)),
                                        pts.t_t + rng.normal(0.0, np.sqrt(v_tt)), dw_p=pts.dw_p,
                                        **{k: opts[k] for k in _FIT_OPTS})  # type: ignore[arg-type]
        except BenchtwinError:
            rows = res
    conv = rows["converter"]
    data = rows["torque_ratio"].data
    g = float(data["gamma"][0])
    inlier = data["inlier"] > 0.5
    sr = pts.w_t / pts.w_p
    m1 = (sr < g) & inlier
    m2 = (sr >= g) & inlier
    A1 = converter_design(pts.w_p[m1], pts.w_t[m1], pts.dw_p[m1])
    B1 = np.linalg.inv(A1.T @ A1)
    L1 = B1 @ A1.T  # x_conv = L1 [t_p; t_t]
    n1 = int(m1.sum())
    cov1 = (L1 * np.r_[v_tp[m1], v_tt[m1]]) @ L1.T
    # the transmission model of each gear moves its turbine rows together
    for gear, (eta, c0, se_eta, se_c0) in table.items():
        sel = pts.gear[m1] == gear
        if not sel.any():
            continue
        d_eta = np.r_[np.zeros(n1), np.where(sel, -(pts.t_t[m1] - c0) / eta, 0.0)]
        d_c0 = np.r_[np.zeros(n1), sel.astype(float)]
        for d, se in ((d_eta, se_eta), (d_c0, se_c0)):
            u = L1 @ d
            cov1 += np.outer(u, u) * se**2
    names1 = [p for p in conv.params if p not in ("gamma_coupling", "turbine_speed_scale")]
    x1 = np.array([conv.value(p) for p in names1])
    k1 = len(names1)
    coup = rows.get("coupling")
    if coup is not None and int(m2.sum()) >= 3:
        q2 = speed_products(pts.w_p[m2], pts.w_t[m2])
        L2 = np.linalg.inv(q2.T @ q2) @ q2.T
        x2 = np.array([coup.value(f"a{k}") for k in (6, 7, 8)])
        j_idx = names1.index("J_pump_kgm2")
        dj = -L2 @ pts.dw_p[m2]  # d a678 / d J
        cov = np.zeros((k1 + 3, k1 + 3))
        cov[:k1, :k1] = cov1
        cov[k1:, k1:] = (L2 * v_tp[m2]) @ L2.T + np.outer(dj, dj) * cov1[j_idx, j_idx]
        cov[k1:, :k1] = np.outer(dj, cov1[j_idx])
        cov[:k1, k1:] = cov[k1:, :k1].T
        z = np.r_[x1, x2]
    else:
        x2, cov, z = None, cov1, x1

    def gamma_of(z: np.ndarray) -> float:
        return coupling_point(z[:6], lo=0.3, hi=1.0)

    n_pts = int(inlier.sum())
    why = f"{n1} converter-mode and {int(m2.sum())} coupling-mode points (SR 0..{sr.max():.2f}), Gamma {g:.3f}"
    v0 = {f"converter.{p}": q.value for p, q in res["converter"].params.items()}
    v0.update({f"coupling.{p}": q.value for p, q in res["coupling"].params.items()} if "coupling" in res else {})
    out = [PlannedParameter(f"torque_converter.converter.{p}", conv.params[p].unit, v0.get(f"converter.{p}", nan),
                            math.sqrt(max(float(cov[i, i]), 0.0)), True, why, "", n1) for i, p in enumerate(names1)]
    gv = v0.get("converter.gamma_coupling", nan)
    out.append(PlannedParameter("torque_converter.converter.gamma_coupling", "", gv,
                                math.sqrt(max(_delta(gamma_of, z, cov), 0.0)), True, why, "", n1))
    calib_noisy = any(r in noise for r in ("em_speed_rpm", "vehicle_speed_kmh"))
    out.append(PlannedParameter("torque_converter.converter.turbine_speed_scale", "", pts.scale,
                                float("nan") if calib_noisy else 0.0, True,
                                "SE not predicted (a median of noisy speed ratios)" if calib_noisy else
                                "the speeds it reads are free of random error on this setup", "", pts.n_cal))
    if x2 is None:
        out.append(PlannedParameter("torque_converter.coupling.*", "", float("nan"), float("nan"), False,
                                    f"{int(m2.sum())} coupling-mode points", "add [[tests]] kind = \"acceleration\" "
                                    "with the lock-up open up to a higher speed (SR above the coupling point)", n_pts))
        return out
    for i, k in enumerate((6, 7, 8)):
        out.append(PlannedParameter(f"torque_converter.coupling.a{k}", "Nm*s^2/rad^2", v0.get(f"coupling.a{k}", nan),
                                    math.sqrt(max(float(cov[k1 + i, k1 + i]), 0.0)), True, why, "", int(m2.sum())))

    def k_at_gamma(z: np.ndarray) -> float:
        gg = gamma_of(z)
        return float(z[k1] + z[k1 + 1] * gg + z[k1 + 2] * gg**2)

    def sr0(z: np.ndarray) -> float:
        return _zero_torque_sr(z[k1:k1 + 3])

    for name, func, unit in (("k_at_gamma", k_at_gamma, "Nm*s^2/rad^2"), ("sr_zero_torque", sr0, "")):
        out.append(PlannedParameter(f"torque_converter.coupling.{name}", unit, v0.get(f"coupling.{name}", nan),
                                    math.sqrt(max(_delta(func, z, cov), 0.0)), True, why, "", int(m2.sum())))
    return out
