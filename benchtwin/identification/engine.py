"""Engine: BSFC map over speed x BMEP (eq. 26-28) and Willans lines per speed band.

BSFC of a steady point is ``fuel mass flow / P_u`` with ``P_u = T omega`` (eq. 27), in g/kWh; the
engine efficiency is ``eta_u = 1 / (BSFC Q_LHV)`` (eq. 28); BMEP = ``2 pi (strokes / 2) T / V_d``.
BSFC itself rises steeply towards low load, which no smooth surface through sparse points follows
well; the fuel mean effective pressure ``pmf = mdot Q_LHV / (omega V_d / (2 pi (strokes / 2)))``
(bar, the fuel energy per cycle and displacement) is nearly a plane in BMEP (the Willans line).
So the map is fitted on ``pmf(speed, BMEP)`` with a thin-plate-spline radial basis function with a
linear term (scipy ``RBFInterpolator``) over normalised coordinates, and
``BSFC = 3.6e9 / Q_LHV * pmf / BMEP``. Its smoothing is chosen by cross-validation unless given. Repeats of one
operating point are one weighted point (:mod:`~benchtwin.identification.engine_cells`): the fit grows with cells.
Grid nodes outside the convex hull of the data, or inside it but beyond the BMEP reach of the speed
bands on either side (:func:`_bracketed`), are marked extrapolated and never used for the
best-efficiency region (minimum BSFC and the area within ``+band`` g/kWh of it). Uncertainty of the
minimum comes from a wild bootstrap of the cross-validated prediction errors.

The Willans line of the engine, per speed band: fuel power ``P_f = mdot Q_LHV = P_u / e + W_loss``
(least squares on ``[P_u, 1]``); ``W_loss`` is on the fuel side, ``e W_loss`` the mechanical loss.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.spatial import Delaunay, QhullError

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import CollinearError, IdentificationError, InsufficientDataError
from benchtwin.identification._fit import (
    FitResult,
    IdentificationResult,
    ParameterEstimate,
    derived,
    linear_fit,
    r_squared,
)
from benchtwin.identification._reuse import only_values
from benchtwin.identification._signals import check_spread
from benchtwin.identification.engine_cells import declared_cell, operating_cells
from benchtwin.identification.engine_cold import (
    COLD_KEY,
    COOLANT_ROLE,
    WARMUP_KEY,
    fit_warmup,
    identify_cold_fuel,
    warm_mask,
)
from benchtwin.identification.engine_start import START_KEY, identify_start_fuel
from benchtwin.identification.steady import SteadyWindows, Tolerance, find_steady_windows
from benchtwin.recording import Recording

__all__ = ["EnginePoints", "bmep_bar", "engine_points", "fit_bsfc_map", "fit_engine_willans", "identify_engine",
           "speed_bands"]

RPM = 2.0 * math.pi / 60.0
#: bootstrap replicates whose maps on the fine grid are held at a time (each: 8 bytes a fine point, ~115 kB)
BOOT_BLOCK = 16
#: fine grid points of the minimum's search evaluated at a time (the operator's rows: 8 bytes a data point each)
FINE_BLOCK = 1024
_SMOOTHINGS = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)


def bmep_bar(torque_nm: np.ndarray, specs: VehicleSpecs) -> np.ndarray:
    """Brake mean effective pressure in bar: ``2 pi (strokes / 2) T / V_d``."""
    t = np.asarray(torque_nm, dtype=float)
    return 2 * np.pi * (specs.engine_strokes / 2) * t / specs.engine_displacement_m3 / 1e5


class EnginePoints:
    """Steady engine points: speed (rpm), torque (Nm), fuel mass flow (g/s), segments."""

    def __init__(self, speed_rpm: np.ndarray, torque_nm: np.ndarray, fuel_gps: np.ndarray,
                 segments: Sequence[str] = (), n_flagged: int = 0, coolant_degc: np.ndarray | None = None) -> None:
        self.speed_rpm = np.asarray(speed_rpm, dtype=float)
        self.torque_nm = np.asarray(torque_nm, dtype=float)
        self.fuel_gps = np.asarray(fuel_gps, dtype=float)
        self.segments = list(segments) if segments else [""] * self.speed_rpm.size
        self.n_flagged = n_flagged
        #: mean engine coolant temperature per point (NaN when not recorded)
        self.coolant_degc = (np.full(self.speed_rpm.size, np.nan) if coolant_degc is None
                             else np.asarray(coolant_degc, dtype=float))

    def subset(self, keep: np.ndarray) -> EnginePoints:
        """The points where ``keep`` is True."""
        return EnginePoints(self.speed_rpm[keep], self.torque_nm[keep], self.fuel_gps[keep],
                            [s for s, k in zip(self.segments, keep) if k], self.n_flagged, self.coolant_degc[keep])


def engine_points(rec: Recording, *, steady: SteadyWindows | None = None,
                  kinds: Iterable[str] | None = ("ramp_up", "constant_drive"), rate_hz: float = 10.0,
                  tolerances: Mapping[str, Tolerance] | None = None, min_torque_nm: float = 2.0,
                  max_duration_s: float | None = None) -> EnginePoints:
    """Steady points of the running engine (engine on, positive torque) from a Recording."""
    if steady is None:
        steady = find_steady_windows(rec, ["engine_speed_rpm", "engine_torque_nm"],
                                     states=("engine_on", "k0_closed", "gear_actual"), extra=("fuel_mass_flow_gps",),
                                     kinds=kinds, rate_hz=rate_hz, tolerances=tolerances, max_duration_s=max_duration_s)
    n = steady.raw_average(rec, "engine_speed_rpm")
    t = steady.raw_average(rec, "engine_torque_nm")
    f = steady.raw_average(rec, "fuel_mass_flow_gps")
    keep = np.isfinite(n) & np.isfinite(t) & np.isfinite(f) & (n > 300) & (t > min_torque_nm) & (f > 0)
    if "engine_on" in steady.grid:
        keep &= steady.state("engine_on") > 0.5
    segs = [w.segment for w, k in zip(steady.windows, keep) if k]
    cool = steady.raw_average(rec, COOLANT_ROLE)[keep] if COOLANT_ROLE in rec else None
    return EnginePoints(n[keep], t[keep], f[keep], segs, steady.n_excluded, cool)


def _scale(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return (x - lo) / (hi - lo if hi > lo else 1.0)


def _cv_residuals(P: np.ndarray, y: np.ndarray, smoothing: np.ndarray, folds: int) -> np.ndarray:
    """k-fold cross-validated prediction errors of the RBF at one smoothing (per point)."""
    idx = np.arange(y.size)
    err = np.empty(y.size)
    for k in range(folds):
        test = idx % folds == k
        try:
            f = RBFInterpolator(P[~test], y[~test], kernel="thin_plate_spline", smoothing=smoothing[~test], degree=1)
            err[test] = f(P[test]) - y[test]
        except (np.linalg.LinAlgError, ValueError):
            err[test] = np.inf
    return err


def _cv_smoothing(P: np.ndarray, y: np.ndarray, candidates: Sequence[float], folds: int, count: np.ndarray) -> float:
    """Smoothing with the least k-fold cross-validated RMSE (each point's smoothing that over its count)."""
    best = (float("inf"), candidates[0])
    for s in candidates:
        rmse = float(np.sqrt(np.mean(_cv_residuals(P, y, s / count, folds) ** 2)))
        if rmse < best[0] * (1 - 1e-6):
            best = (rmse, s)
    return best[1]


def fit_bsfc_map(specs: VehicleSpecs, speed_rpm: np.ndarray, torque_nm: np.ndarray, fuel_gps: np.ndarray, *,
                 speed_grid: np.ndarray | None = None, bmep_grid: np.ndarray | None = None,
                 smoothing: float | None = None, band_gpkwh: float = 8.0, n_boot: int = 200,
                 min_search_bmep_bar: float = 2.0,
                 segments: Sequence[str] = (), n_excluded: int = 0, min_points: int = 6, seed: int = 0,
                 cell: tuple[float, float] | None = None) -> FitResult:
    """BSFC map over speed x BMEP from steady points, with the best-efficiency region.

    Parameters
    ----------
    specs:
        Displacement, strokes and fuel LHV.
    speed_rpm, torque_nm, fuel_gps:
        Steady points (engine firing, positive torque).
    speed_grid, bmep_grid:
        Map axes (rpm, bar); default 25 nodes each over the span of the data.
    smoothing:
        RBF smoothing; None chooses it by cross-validation.
    band_gpkwh:
        Width of the best-efficiency region above the minimum.
    min_search_bmep_bar:
        The minimum is searched at BMEP at or above this (near zero load ``BSFC = pmf / BMEP`` turns
        every small error of the fuel MEP into a huge one, and the best point is never there).
    n_boot:
        Bootstrap replicates for the uncertainty of the minimum (each point's cross-validated
        prediction error added to the fitted fuel MEP with a random sign, map refitted); SE and
        percentile 95 % interval.
    cell:
        Speed (rpm) and torque (Nm) steps of the sensors: points closer than that in both are one operating
        cell, fitted as one point with the smoothing over its count (:mod:`~benchtwin.identification.engine_cells`);
        None merges nothing. ``min_points`` counts cells.

    Returns
    -------
    FitResult
        ``r2`` and ``rmse`` are cross-validated (k-fold, BSFC at the points); parameters
        ``bsfc_min`` (g/kWh), ``speed_at_min`` (rpm), ``bmep_at_min`` (bar), ``eta_max``;
        data ``speed_rpm``, ``bmep_bar``, ``bsfc`` (points), ``bsfc_fit``, ``map_speed_rpm``,
        ``map_bmep_bar``, ``map_bsfc`` (bmep x speed), ``map_extrapolated`` (bool, same shape),
        ``map_best_region`` (bool), ``map_eta``; per cell (the points above are cells) ``cell_count``.

    Raises
    ------
    InsufficientDataError, NoExcitationError, CollinearError
    """
    what = "engine.bsfc"
    n = np.asarray(speed_rpm, dtype=float)
    t = np.asarray(torque_nm, dtype=float)
    f = np.asarray(fuel_gps, dtype=float)
    ok = np.isfinite(n) & np.isfinite(t) & np.isfinite(f) & (t > 0) & (n > 0) & (f > 0)
    n_out = int((~ok).sum())
    cells = operating_cells(n[ok], t[ok], f[ok], cell)
    n, t, f, count = cells.speed_rpm, cells.torque_nm, cells.fuel_gps, cells.count
    if n.size < min_points:
        raise InsufficientDataError(f"{what}: {int(ok.sum())} usable steady points in {n.size} operating cells "
                                    f"(speed x torque steps {cell}); need at least {min_points} cells")
    b = bmep_bar(t, specs)
    check_spread(n, 200.0, what, "engine speed", "rpm")
    check_spread(b, 2.0, what, "BMEP", "bar")
    bsfc = f / (t * n * RPM / 1e3) * 3600.0
    q = 3.6e9 / specs.fuel_lhv_j_per_kg  # g/kWh per unit of 1/efficiency
    pmf = bsfc * b / q  # fuel mean effective pressure, bar
    nlo, nhi, blo, bhi = float(n.min()), float(n.max()), float(b.min()), float(b.max())
    P = np.column_stack([_scale(n, nlo, nhi), _scale(b, blo, bhi)])
    try:
        hull = Delaunay(P)
    except QhullError as exc:
        raise CollinearError(f"{what}: the points lie on a line in speed x BMEP; no map can be built ({exc})") from exc
    folds = min(n.size, 10)
    if smoothing is None:
        smoothing = _cv_smoothing(P, pmf, _SMOOTHINGS, folds, count)
    cv_all = _cv_residuals(P, pmf, smoothing / count, folds)
    cv_ok = np.isfinite(cv_all)
    cv_err = cv_all[cv_ok]
    cv_rmse = float(np.sqrt(np.mean(cv_err**2))) if cv_err.size else float("nan")
    rbf = RBFInterpolator(P, pmf, kernel="thin_plate_spline", smoothing=smoothing / count, degree=1)
    pmf_fit = rbf(P)
    fitted = q * pmf_fit / b
    # the map interpolates (or nearly): its in-sample R^2 says nothing, so the fit reports the
    # cross-validated R^2 of BSFC (each point predicted by the map built without its fold)
    r2_in, _ = r_squared(bsfc, fitted, 3)
    bsfc_cv = q * (pmf + cv_all) / b
    r2, adj = r_squared(bsfc[cv_ok], bsfc_cv[cv_ok], 3)
    rmse = float(np.sqrt(np.mean((bsfc[cv_ok] - bsfc_cv[cv_ok]) ** 2))) if cv_ok.any() else float("nan")
    sg = np.linspace(nlo, nhi, 25) if speed_grid is None else np.asarray(speed_grid, dtype=float)
    bg = np.linspace(max(blo, 0.0), bhi, 25) if bmep_grid is None else np.asarray(bmep_grid, dtype=float)
    S, B = np.meshgrid(sg, bg)
    nodes = np.column_stack([_scale(S.ravel(), nlo, nhi), _scale(B.ravel(), blo, bhi)])
    extrap = (hull.find_simplex(nodes) < 0).reshape(S.shape) | ~_bracketed(n, b, S, B)
    with np.errstate(divide="ignore", invalid="ignore"):
        mapv = np.where(B > 0, q * rbf(nodes).reshape(S.shape) / B, np.nan)
    # the minimum is searched on a fine grid inside the hull
    fs, fb = np.meshgrid(np.linspace(0, 1, 121), np.linspace(0, 1, 121))
    fine = np.column_stack([fs.ravel(), fb.ravel()])
    fine = fine[(hull.find_simplex(fine) >= 0) & (blo + fine[:, 1] * (bhi - blo) >= max(min_search_bmep_bar, 1e-6))]
    if fine.shape[0] == 0:
        raise InsufficientDataError(f"{what}: no point of the data's hull at BMEP >= {min_search_bmep_bar} bar")
    fine_b = blo + fine[:, 1] * (bhi - blo)

    # the map is linear in the data for a fixed smoothing: one fit with the identity as data gives the
    # operator from fuel MEP values at the points to the fine grid, so bootstrap refits are products
    # (evaluated a block of fine points at a time: the whole operator is fine points x data points)
    rbf_eye = RBFInterpolator(P, np.eye(n.size), kernel="thin_plate_spline", smoothing=smoothing / count, degree=1)

    def minima(y: np.ndarray) -> np.ndarray:
        # per column of y: the least BSFC over the fine grid (np.argmin's first least point), its speed and BMEP;
        # a block of fine points and a few replicates at a time (all at once: fine points x n_boot)
        best_v = np.full(y.shape[1], np.inf)
        best_k = np.zeros(y.shape[1], dtype=np.intp)
        for r0 in range(0, fine.shape[0], FINE_BLOCK):
            op = rbf_eye(fine[r0:r0 + FINE_BLOCK])
            fb = fine_b[r0:r0 + FINE_BLOCK, None]
            for j in range(0, y.shape[1], BOOT_BLOCK):
                v = q * (op @ y[:, j:j + BOOT_BLOCK]) / fb
                v[~(v > 0)] = np.inf  # a non-positive fuel MEP is no minimum
                k = np.argmin(v, axis=0)
                vk = v[k, np.arange(v.shape[1])]
                better = vk < best_v[j:j + BOOT_BLOCK]  # strictly: an earlier block keeps a tie, as argmin does
                best_v[j:j + BOOT_BLOCK][better] = vk[better]
                best_k[j:j + BOOT_BLOCK][better] = r0 + k[better]
        return np.column_stack([best_v, nlo + fine[best_k, 0] * (nhi - nlo), fine_b[best_k]])

    bmin, nmin, bmin_at = (float(x) for x in minima(pmf[:, None])[0])
    rng = np.random.default_rng(seed)
    # wild bootstrap of the cross-validated prediction errors: each point keeps its own error, with a
    # random sign. With an interpolating map the in-sample residuals are zero while the map between
    # the points is not exact; and the errors are heteroscedastic (points at the hull's edge are
    # extrapolated in cross-validation), so they are not swapped between points.
    resid = np.where(cv_ok, cv_all, 0.0) if cv_ok.any() else pmf - pmf_fit
    boots: list[np.ndarray] = []
    if np.any(resid != 0) and n_boot > 0 and not only_values():  # a type B re-run reads no standard error
        signs = rng.choice(np.array([-1.0, 1.0]), (resid.size, n_boot))
        boots = list(minima(pmf_fit[:, None] + resid[:, None] * signs))
    boots_a = np.asarray(boots) if boots else np.zeros((1, 3))

    def est(name: str, value: float, col: np.ndarray, unit: str) -> ParameterEstimate:
        se = float(np.std(col, ddof=1)) if col.size > 1 else 0.0
        lo, hi = (float(np.percentile(col, 2.5)), float(np.percentile(col, 97.5))) if col.size > 1 else (value, value)
        return ParameterEstimate(name, value, se, (min(lo, value), max(hi, value)), r2, int(n.size), unit,
                                 sorted({s for s in segments if s}))

    params = {
        "bsfc_min": est("bsfc_min", bmin, boots_a[:, 0], "g/kWh"),
        "speed_at_min": est("speed_at_min", nmin, boots_a[:, 1], "rpm"),
        "bmep_at_min": est("bmep_at_min", bmin_at, boots_a[:, 2], "bar"),
        "eta_max": est("eta_max", q / bmin, q / boots_a[:, 0] if boots else np.zeros(1), "-"),
    }
    region = (~extrap) & (mapv <= bmin + band_gpkwh)
    fit = FitResult(params, r2, adj, rmse, int(n.size), n_excluded + n_out, sorted({s for s in segments if s}))
    fit.data.update(speed_rpm=n, torque_nm=t, bmep_bar=b, bsfc=bsfc, bsfc_fit=fitted, y=bsfc, y_fit=fitted,
                    pmf_bar=pmf, pmf_fit_bar=pmf_fit, bsfc_cv=bsfc_cv, r2_in_sample=np.array([r2_in]),
                    map_speed_rpm=sg, map_bmep_bar=bg, map_bsfc=mapv, map_extrapolated=extrap,
                    map_best_region=region, map_eta=q / mapv, smoothing=np.array([smoothing]),
                    cv_rmse=np.array([cv_rmse]), band_gpkwh=np.array([band_gpkwh]), cell_count=count)
    if region.any():
        fit.data["best_region_speed_rpm"] = np.array([S[region].min(), S[region].max()])
        fit.data["best_region_bmep_bar"] = np.array([B[region].min(), B[region].max()])
    if n.size < 15:
        fit.reasons.append(f"only {n.size} points: the map between them is an interpolation, check the figure")
    return fit


def _bracketed(speed_rpm: np.ndarray, bmep: np.ndarray, node_speed: np.ndarray, node_bmep: np.ndarray, *,
               gap_rpm: float = 150.0) -> np.ndarray:
    """Whether each map node lies within the BMEP reach of the data's speed bands on both sides of it.

    Data at a few set speeds (ramp-ups) form speed bands (:func:`speed_bands`); the convex hull of
    such data holds triangles spanning from the top of one band to the top of a lower-reaching one,
    where the map only extrapolates the lower band along BMEP (a steep full-load corner of a BSFC map
    held by one point is missed there by several per cent). A node between two bands is bracketed when
    its BMEP is inside the BMEP range of the nearest band below and of the nearest band above (within
    a twentieth of the data's BMEP span); a node at a band's speed needs that band only. Scattered
    data (one band over the whole speed range) leave the hull as it is.
    """
    bands = speed_bands(speed_rpm, gap_rpm=gap_rpm)
    lo = np.array([speed_rpm[g].min() for g in bands])
    hi = np.array([speed_rpm[g].max() for g in bands])
    bmin = np.array([bmep[g].min() for g in bands])
    bmax = np.array([bmep[g].max() for g in bands])
    slack = 0.05 * float(np.ptp(bmep))
    ns, nb = np.ravel(node_speed), np.ravel(node_bmep)
    ok = np.ones(ns.shape, dtype=bool)
    for k in range(ns.size):
        inside = (lo <= ns[k]) & (ns[k] <= hi)
        below = np.flatnonzero(hi < ns[k])
        above = np.flatnonzero(lo > ns[k])
        if inside.any():
            near = np.flatnonzero(inside)
        else:
            sides = ([below[np.argmax(hi[below])]] if below.size else []) + \
                    ([above[np.argmin(lo[above])]] if above.size else [])
            near = np.array(sides, dtype=int)
        ok[k] = bool(near.size) and bool(np.all((bmin[near] - slack <= nb[k]) & (nb[k] <= bmax[near] + slack)))
    return ok.reshape(np.shape(node_speed))


def speed_bands(speed_rpm: np.ndarray, *, gap_rpm: float = 150.0, width_rpm: float | None = None
                ) -> list[np.ndarray]:
    """Group points into speed bands (index arrays).

    A new band starts where the sorted speeds jump by more than ``gap_rpm`` (engine-bench data at a
    few set speeds); a band that spans more than ``width_rpm`` (points spread over the whole speed
    range, as from a vehicle campaign) is cut into bands of that width.
    """
    n = np.asarray(speed_rpm, dtype=float)
    order = np.argsort(n)
    cuts = np.flatnonzero(np.diff(n[order]) > gap_rpm) + 1
    out = []
    for g in np.split(order, cuts):
        if width_rpm is None or g.size == 0 or n[g].max() - n[g].min() <= width_rpm:
            out.append(np.sort(g))
            continue
        lo = n[g].min()
        k = np.floor((n[g] - lo) / width_rpm).astype(int)
        out.extend(np.sort(g[k == j]) for j in np.unique(k))
    return out


def fit_engine_willans(speed_rpm: np.ndarray, torque_nm: np.ndarray, fuel_gps: np.ndarray, *,
                       lhv_j_per_kg: float = 42.8e6, bands: Sequence[tuple[float, float]] | None = None,
                       gap_rpm: float = 150.0, width_rpm: float | None = 500.0, min_points: int = 3,
                       segments: Sequence[str] | None = None,
                       n_excluded: int = 0) -> IdentificationResult:
    """Willans line per speed band: ``P_fuel = P_u / e + W_loss``.

    Parameters
    ----------
    speed_rpm, torque_nm, fuel_gps:
        Steady points.
    lhv_j_per_kg:
        Fuel lower heating value.
    bands:
        ``(low, high)`` rpm bands; default: :func:`speed_bands` with ``gap_rpm`` and ``width_rpm``.

    Returns
    -------
    IdentificationResult
        ``engine.willans_<rpm>rpm`` per band with ``inv_e``, ``W_loss`` (W, fuel side) and derived
        ``e`` and ``W_loss_mech`` (W); bands that cannot be fitted are in ``errors``.
    """
    n = np.asarray(speed_rpm, dtype=float)
    t = np.asarray(torque_nm, dtype=float)
    f = np.asarray(fuel_gps, dtype=float)
    segs = np.asarray(list(segments) if segments is not None else [""] * n.size, dtype=object)
    if bands is None:
        groups = speed_bands(n, gap_rpm=gap_rpm, width_rpm=width_rpm)
    else:
        groups = [np.flatnonzero((n >= lo) & (n < hi)) for lo, hi in bands]
    out = IdentificationResult()
    for g in groups:
        if g.size == 0:
            continue
        label = int(round(float(np.mean(n[g])) / 10.0) * 10)
        key = f"engine.willans_{label}rpm"
        p_u = t[g] * n[g] * RPM
        p_f = f[g] * 1e-3 * lhv_j_per_kg
        try:
            if g.size < min_points:
                raise InsufficientDataError(f"{key}: {g.size} points; need at least {min_points}")
            check_spread(p_u, 0.2 * float(np.max(np.abs(p_u))), key, "brake power", "W")
            fit = linear_fit(np.column_stack([p_u, np.ones_like(p_u)]), p_f, ["inv_e", "W_loss"], units=["-", "W"],
                             segments=sorted({s for s in segs[g] if s}), min_points=min_points,
                             n_excluded=n_excluded, what=key)
        except IdentificationError as exc:
            out.errors[key] = f"{type(exc).__name__}: {exc}"
            continue
        derived(fit, "e", lambda x: 1.0 / x[0], unit="-")
        derived(fit, "W_loss_mech", lambda x: x[1] / x[0], unit="W")
        fit.data.update(speed_rpm=n[g], p_u_w=p_u, p_fuel_w=p_f, p_fuel_fit_w=fit.data["y_fit"],
                        band_speed_rpm=np.array([float(np.mean(n[g]))]))
        if not 0.1 < fit.value("e") < 0.6:
            fit.flag(f"e = {fit.value('e'):.3f} is not plausible for a combustion engine")
        if not fit.r2 >= 0.9:
            fit.flag(f"R^2 = {fit.r2:.2f} < 0.9: fuel power is not linear in brake power in this band")
        out.fits[key] = fit
    if not out.fits:
        raise InsufficientDataError("engine Willans: no speed band could be fitted ("
                                    + "; ".join(f"{k}: {v}" for k, v in out.errors.items()) + ")")
    return out


def identify_engine(rec: Recording, specs: VehicleSpecs, *, points: EnginePoints | None = None,
                    willans: bool = True, map_kwargs: Mapping[str, object] | None = None, cold: bool = True,
                    start: bool = True, **kwargs: object) -> IdentificationResult:
    """BSFC map (``engine.bsfc``) and Willans lines per speed band (``engine.willans_*``) from a Recording.

    Parameters
    ----------
    rec:
        The Recording: ``engine_speed_rpm``, ``engine_torque_nm``, ``fuel_mass_flow_gps``
        (``engine_on`` used when present).
    specs:
        Displacement, strokes, fuel LHV.
    points:
        Steady points (else found here; ``kwargs`` go to :func:`engine_points`).
    willans:
        Also fit the Willans lines.
    map_kwargs:
        Options of :func:`fit_bsfc_map` (``cell`` defaults to the steps the Recording's budget declares).
    cold:
        With the coolant temperature recorded (``engine_coolant_out_degc``): the cold-start factor
        ``engine.cold_fuel`` and the coolant's warm-up ``engine.warmup``
        (:mod:`~benchtwin.identification.engine_cold`); when the factor is significant, ``engine.bsfc`` is the map
        of the warm points only (``data['warm_only']``).
    start:
        The fuel of one engine start ``engine.start_fuel`` over the campaign's starts, beyond the (warm) map
        (:mod:`~benchtwin.identification.engine_start`).

    Raises
    ------
    InsufficientDataError
        When neither the map nor any Willans line can be built.
    """
    pts = points if points is not None else engine_points(rec, **kwargs)  # type: ignore[arg-type]
    out = IdentificationResult()
    kw: dict[str, object] = {"cell": declared_cell(rec.meta), **dict(map_kwargs or {})}
    try:
        out.fits["engine.bsfc"] = fit_bsfc_map(specs, pts.speed_rpm, pts.torque_nm, pts.fuel_gps,
                                               segments=pts.segments, n_excluded=pts.n_flagged,
                                               **kw)  # type: ignore[arg-type]
    except IdentificationError as exc:
        out.errors["engine.bsfc"] = f"{type(exc).__name__}: {exc}"
    if cold and np.any(np.isfinite(pts.coolant_degc)):
        _cold_fuel(out, rec, specs, pts, kw)
    if start and "engine.bsfc" in out.fits:
        _start_fuel(out, rec, specs)
    if willans:
        try:
            w = fit_engine_willans(pts.speed_rpm, pts.torque_nm, pts.fuel_gps, lhv_j_per_kg=specs.fuel_lhv_j_per_kg,
                                   segments=pts.segments, n_excluded=pts.n_flagged)
            out.fits.update(w.fits)
            out.errors.update(w.errors)
        except IdentificationError as exc:
            out.errors["engine.willans"] = f"{type(exc).__name__}: {exc}"
    if not out.fits:
        raise InsufficientDataError("engine: no fit possible (" + "; ".join(f"{k}: {v}" for k, v in out.errors.items())
                                    + ")")
    return out


def _cold_fuel(out: IdentificationResult, rec: Recording, specs: VehicleSpecs, pts: EnginePoints,
               map_kwargs: dict[str, object]) -> None:
    """``engine.cold_fuel`` and ``engine.warmup`` into ``out``; ``engine.bsfc`` replaced by the warm points' map when
    the factor is significant (the map of all points stays otherwise, so a warm-only engine's map is unchanged)."""
    warm, _level = warm_mask(pts.coolant_degc)
    ref = out.fits.get("engine.bsfc")
    warm_fit = None
    if ref is not None and not warm.all() and warm.sum() >= 6:
        wp = pts.subset(warm)
        try:
            warm_fit = fit_bsfc_map(specs, wp.speed_rpm, wp.torque_nm, wp.fuel_gps, segments=wp.segments,
                                    n_excluded=wp.n_flagged, **map_kwargs)  # type: ignore[arg-type]
        except IdentificationError:
            warm_fit = None
    base = warm_fit if warm_fit is not None else ref
    if base is not None:
        try:
            cf = identify_cold_fuel(rec, specs, base.data)
            out.fits[COLD_KEY] = cf
            use = bool(np.all(np.asarray(cf.data.get("use", [False]))))
            if use and warm_fit is not None:
                warm_fit.data["warm_only"] = np.array([True])
                out.fits["engine.bsfc"] = warm_fit
        except IdentificationError as exc:
            out.errors[COLD_KEY] = f"{type(exc).__name__}: {exc}"
    try:
        out.fits[WARMUP_KEY] = fit_warmup(rec, specs)
    except IdentificationError as exc:
        out.errors[WARMUP_KEY] = f"{type(exc).__name__}: {exc}"


def _start_fuel(out: IdentificationResult, rec: Recording, specs: VehicleSpecs) -> None:
    """``engine.start_fuel`` into ``out``: beyond ``engine.bsfc`` x ``engine.cold_fuel`` (when used)."""
    cf = out.fits.get(COLD_KEY)
    cold = None
    if cf is not None and cf.status == "ok" and bool(np.all(np.asarray(cf.data.get("use", [False])))):
        cold = (cf.value("k"), float(np.asarray(cf.data["T_warm_degc"]).ravel()[0]))
    try:
        out.fits[START_KEY] = identify_start_fuel(rec, specs, out.fits["engine.bsfc"].data, cold=cold)
    except IdentificationError as exc:
        out.errors[START_KEY] = f"{type(exc).__name__}: {exc}"
