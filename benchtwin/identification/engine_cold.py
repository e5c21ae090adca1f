"""Engine: the cold-start fuel factor over coolant temperature and the coolant's lumped warm-up.

A BSFC map identified on a warm engine under-predicts a cold one: friction of cold oil and enrichment raise the
fuel flow at the same speed and torque. Where the Recording has the engine coolant temperature
(``engine_coolant_out_degc``), the steady engine points are split by it:

- the **factor** ``engine.cold_fuel``: the ratio of the measured fuel to the warm map's over 10 s blocks of the
  firing engine (:func:`cold_blocks`; the map fitted on the warm steady points only) against the block's coolant
  temperature, fitted as
  ``ratio = a + b max(0, T_warm - T)`` (weighted least squares on ``[1, h]``, the hinge ``T_warm`` profiled over a
  1 K grid by the least residual sum of squares; its standard errors are those of the linear fit at that hinge);
  ``k = b / a`` per kelvin (delta method). ``data['use']`` is True only when the campaign has cold points
  (at least ``min_cold_points`` blocks ``min_cold_span_k`` below the warm level, the 90th percentile of
  the blocks' coolant temperature) and ``k``'s 95 % interval lies above zero; otherwise the fit is flagged
  ("no cold points", "no warm engine", "not significant") and the warm map is the map of all points.
- the **warm-up** ``engine.warmup``: the coolant as one lump heated by the engine's heat
  (fuel power less brake power) and losing heat to its surroundings below the thermostat,
  ``dT/dt = h P_heat - g (T - T_env)``, fitted as ``dT/dt = h P_heat - g T + c`` on 20 s blocks of the whole
  Recording below the regulated level (``T_env = c / g``); above it the thermostat holds the coolant at the
  regulated level ``T_reg`` (the 95th percentile of the recorded coolant temperature). The map-based model
  integrates it from a drive's first coolant reading, so the factor follows a coolant it predicts itself.

Both read the Recording's channels a run of whole blocks at a time (:func:`grid_runs`: ``gather``'s grid and its
numbers, each channel read around the run only) and keep per block only what the fits use, so their memory does
not grow with the campaign (the warm-up keeps the grid's coolant readings, 8 bytes a second at 1 Hz, for its 95th
percentile).

Reads only the Recording and the public specs (no truth).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import IdentificationError, InsufficientDataError
from benchtwin.identification._fit import FitResult, derived, linear_fit
from benchtwin.identification._signals import Grid
from benchtwin.identification._windows import gather_at, grid_bounds
from benchtwin.identification.fuel_map import fuel_map_gps, map_pmf
from benchtwin.recording import Recording

__all__ = ["COLD_KEY", "COOLANT_ROLE", "WARMUP_KEY", "cold_blocks", "cold_factor", "fit_cold_factor", "fit_warmup",
           "grid_runs", "identify_cold_fuel", "warm_mask"]

COLD_KEY = "engine.cold_fuel"
WARMUP_KEY = "engine.warmup"
COOLANT_ROLE = "engine_coolant_out_degc"

_RPM = math.pi / 30.0

#: grid points read at a time by :func:`grid_runs`, at most (rounded down to whole blocks)
GRID_RUN = 8192

#: seconds of the channels read at a time by :func:`grid_runs`, at most (a 100 Hz channel: 30 k samples)
RUN_S = 300.0


def grid_runs(rec: Recording, names: Sequence[str], rate_hz: float, per: int, *, optional: Iterable[str] = (),
              what: str = "identification") -> Iterator[Grid]:
    """``gather(rec, names, rate_hz, optional=optional)``'s grid, a run of whole ``per``-point blocks at a time.

    Parameters
    ----------
    rec, names, rate_hz, optional, what:
        As for :func:`~benchtwin.identification._signals.gather`.
    per:
        Points of one block: every run but the last holds a whole number of blocks (the last ends with the grid);
        a run is at most :data:`GRID_RUN` points and :data:`RUN_S` seconds long, unless one block is longer.

    Yields
    ------
    Grid
        Grid points ``a .. b - 1`` (``first_index`` ``a``): the times and values ``gather`` gives there, each channel
        read around the run only (``_windows.gather_at``); one run is let go before the next is read.

    Raises
    ------
    MissingChannelError, DataError
        As ``gather`` (checked before the first run).
    """
    lo, n, shifts = grid_bounds(rec, names, rate_hz, what=what)
    kept = rec.loaded()
    step = max(min(GRID_RUN, int(RUN_S * rate_hz)) // per, 1) * per
    optional = list(optional)
    ordered: dict[int, bool] = {}  # channels in memory checked for time order once
    try:
        for a in range(0, n, step):
            g = gather_at(rec, names, lo + np.arange(a, min(a + step, n)) / rate_hz, rate_hz, shifts,
                          optional=optional, ordered=ordered)
            g.first_index = a
            yield g
    finally:  # a lazy Recording's channel read whole here (no block reads) goes again, as after ``gather``
        rec.drop([c for c in [*names, *optional] if c in rec and c not in kept])


def cold_factor(k_per_k: float, t_warm_degc: float, coolant_degc: np.ndarray | float) -> np.ndarray:
    """Fuel multiplier ``1 + k max(0, T_warm - T)`` of a coolant temperature (1 when warm)."""
    return 1.0 + k_per_k * np.maximum(t_warm_degc - np.asarray(coolant_degc, float), 0.0)


def warm_mask(coolant_degc: np.ndarray, *, min_cold_span_k: float = 15.0) -> tuple[np.ndarray, float]:
    """Points warm enough for the warm map, and the warm level (90th percentile of the points' coolant).

    Points without a coolant reading count as warm.
    """
    t = np.asarray(coolant_degc, float)
    ok = np.isfinite(t)
    if not ok.any():
        return np.ones(t.size, bool), float("nan")
    level = float(np.percentile(t[ok], 90))
    return ~ok | (t >= level - min_cold_span_k), level


def fit_cold_factor(ratio: np.ndarray, coolant_degc: np.ndarray, *, weights: np.ndarray | None = None,
                    hinge_grid_degc: np.ndarray | None = None, min_cold_points: int = 3,
                    min_cold_span_k: float = 15.0, min_warm_degc: float = 60.0,
                    segments: list[str] | None = None) -> FitResult:
    """Fit ``ratio = a + b max(0, T_warm - T)`` over coolant temperature; ``k = b / a`` per K.

    Parameters
    ----------
    ratio:
        Measured fuel flow over the warm map's, per steady point.
    coolant_degc:
        The point's mean coolant temperature.
    weights:
        Least-squares weights (e.g. the fuel flow: a point near idle reads its ratio from a small flow).
    hinge_grid_degc:
        Candidate warm temperatures (default 40-100 degC by 1 K, kept within the points' span).
    min_cold_points, min_cold_span_k:
        "Cold" is ``min_cold_span_k`` below the warm level (:func:`warm_mask`); fewer cold points than
        ``min_cold_points`` flag the fit ("no cold points": the factor cannot be identified).
    min_warm_degc:
        A warm level below this flags the fit ("no warm engine": a campaign whose engine never warmed has no
        warm reference for the map).

    Returns
    -------
    FitResult
        Parameters ``a``, ``b`` (1/K) and derived ``k`` (1/K); data ``T_warm_degc``, ``use``, ``n_cold``, the
        points. ``use`` is True only when cold points exist and ``k``'s 95 % interval is above zero.

    Raises
    ------
    InsufficientDataError
        When fewer than 3 usable points are given.
    """
    r = np.asarray(ratio, float)
    t = np.asarray(coolant_degc, float)
    w = np.ones_like(r) if weights is None else np.asarray(weights, float)
    ok = np.isfinite(r) & np.isfinite(t) & np.isfinite(w) & (w > 0) & (r > 0)
    r, t, w = r[ok], t[ok], w[ok]
    if r.size < 3:
        raise InsufficientDataError(f"{COLD_KEY}: {r.size} steady points with a coolant temperature; need 3")
    warm, level = warm_mask(t, min_cold_span_k=min_cold_span_k)
    n_cold = int(np.sum(~warm))
    grid = np.arange(40.0, 100.5, 1.0) if hinge_grid_degc is None else np.asarray(hinge_grid_degc, float)
    grid = grid[(grid > np.min(t) + 1.0) & (grid <= np.max(t))]
    if n_cold < min_cold_points or grid.size == 0:
        # the factor is not identifiable: a flat fit (the ratio's mean) and a flag saying why
        fit = linear_fit(np.ones((r.size, 1)), r, ["a"], units=["-"], segments=segments or [], what=COLD_KEY,
                         weights=w)
        fit.data.update(T_warm_degc=np.array([level]), use=np.array([False]), n_cold=np.array([n_cold]),
                        ratio=r, coolant_degc=t)
        fit.flag(f"no cold points: {n_cold} block(s) of the firing engine more than {min_cold_span_k:.0f} K "
                 f"below the warm level ({level:.1f} degC; need {min_cold_points}): the factor is not identified")
        return fit
    if level < min_warm_degc:
        fit = linear_fit(np.ones((r.size, 1)), r, ["a"], units=["-"], segments=segments or [], what=COLD_KEY,
                         weights=w)
        fit.data.update(T_warm_degc=np.array([level]), use=np.array([False]), n_cold=np.array([n_cold]),
                        ratio=r, coolant_degc=t)
        fit.flag(f"no warm engine: the firing engine's warm level is {level:.1f} degC (below {min_warm_degc:.0f}): "
                 "no warm reference, the factor is not identified")
        return fit
    best: tuple[float, float] = (math.inf, float(grid[0]))
    sw = np.sqrt(w)
    for tw in grid:
        A = np.column_stack([np.ones_like(r), np.maximum(tw - t, 0.0)])
        coef, *_ = np.linalg.lstsq(A * sw[:, None], r * sw, rcond=None)
        sse = float(np.sum(w * (A @ coef - r) ** 2))
        if sse < best[0] * (1 - 1e-12):
            best = (sse, float(tw))
    tw = best[1]
    A = np.column_stack([np.ones_like(r), np.maximum(tw - t, 0.0)])
    fit = linear_fit(A, r, ["a", "b"], units=["-", "1/K"], segments=segments or [], what=COLD_KEY, weights=w,
                     cond_max=1e12)
    derived(fit, "k", lambda x: x[1] / x[0], unit="1/K")
    lo = fit.params["k"].ci95[0]
    use = bool(math.isfinite(lo) and lo > 0)
    fit.data.update(T_warm_degc=np.array([tw]), use=np.array([use]), n_cold=np.array([n_cold]), ratio=r,
                    coolant_degc=t)
    if not use:
        fit.flag(f"not significant: k = {fit.value('k'):.2e} /K, its 95 % interval reaches zero or below (the "
                 "engine burns no more fuel cold); the factor is not used")
    return fit


def fit_warmup(rec: Recording, specs: VehicleSpecs, *, block_s: float = 20.0, rate_hz: float = 1.0,
               min_blocks: int = 10) -> FitResult:
    """The coolant's lumped warm-up ``dT/dt = h P_heat - g T + c`` below the regulated level.

    Parameters
    ----------
    rec:
        The Recording: ``engine_coolant_out_degc``, ``fuel_mass_flow_gps``, ``engine_speed_rpm``,
        ``engine_torque_nm``.
    specs:
        The fuel's lower heating value.
    block_s, rate_hz:
        Block length over which ``dT/dt`` is taken (end minus start over the block) and the grid rate.

    Returns
    -------
    FitResult
        ``h`` (K/J), ``g`` (1/s), ``c`` (K/s) and derived ``T_env_degc``; data ``T_reg_degc`` (the regulated level).
    """
    names = [COOLANT_ROLE, "fuel_mass_flow_gps", "engine_speed_rpm", "engine_torque_nm"]
    n = max(round(block_s * rate_hz), 2)
    readings: list[np.ndarray] = []  # the grid's finite coolant readings, for the regulated level
    blocks: list[np.ndarray] = []  # per run, a row per complete block: max T, mean P_heat, -mean T, dT/dt
    for g in grid_runs(rec, names, rate_hz, n, what=WARMUP_KEY):
        t_c = g[COOLANT_ROLE]
        p_f = np.nan_to_num(g["fuel_mass_flow_gps"], nan=0.0) * 1e-3 * specs.fuel_lhv_j_per_kg
        p_b = np.nan_to_num(g["engine_torque_nm"] * g["engine_speed_rpm"] * _RPM, nan=0.0)
        p_heat = np.maximum(p_f - np.maximum(p_b, 0.0), 0.0)
        readings.append(t_c[np.isfinite(t_c)])
        run: list[tuple[float, float, float, float]] = []
        for k in range(t_c.size // n):  # the run holds whole blocks: these are the whole grid's blocks
            s = slice(k * n, (k + 1) * n)
            tb = t_c[s]
            if not np.all(np.isfinite(tb)):
                continue
            dt = (g.t[s][-1] - g.t[s][0])
            if dt <= 0:
                continue
            run.append((float(np.max(tb)), float(np.mean(p_heat[s])), -float(np.mean(tb)),
                        float((tb[-1] - tb[0]) / dt)))
        blocks.append(np.array(run).reshape(-1, 4))
    ok_t = np.concatenate(readings) if readings else np.zeros(0)
    del readings
    if ok_t.size < 10:
        raise InsufficientDataError(f"{WARMUP_KEY}: no coolant temperature readings")
    t_reg = float(np.percentile(ok_t, 95, overwrite_input=True))  # the same value; no third copy
    del ok_t
    stats = np.concatenate(blocks) if blocks else np.zeros((0, 4))
    below = ~(stats[:, 0] > t_reg - 5.0)
    if below.sum() < min_blocks:
        raise InsufficientDataError(f"{WARMUP_KEY}: {below.sum()} blocks below the regulated level; need {min_blocks}")
    A = np.column_stack([stats[below, 1], stats[below, 2], np.ones(below.sum())])
    y = stats[below, 3]
    heated = A[:, 0] > 0.0
    if heated.sum() < 3:
        raise InsufficientDataError(f"{WARMUP_KEY}: the engine never fires below the regulated coolant level")
    fit = linear_fit(A, y, ["h", "g", "c"], units=["K/J", "1/s", "K/s"], what=WARMUP_KEY, cond_max=1e14)
    derived(fit, "T_env_degc", lambda x: x[2] / x[1] if x[1] != 0 else float("nan"), unit="degC")
    fit.data.update(T_reg_degc=np.array([t_reg]))
    if not (fit.value("h") > 0 and fit.value("g") >= 0):
        fit.flag(f"h = {fit.value('h'):.3g} K/J, g = {fit.value('g'):.3g} 1/s: not a warming lump")
    return fit


def cold_blocks(rec: Recording, specs: VehicleSpecs, bsfc_data: dict, *, block_s: float = 10.0,
                rate_hz: float = 10.0, min_torque_nm: float = 5.0) -> dict[str, np.ndarray]:
    """Blocks of the firing engine over the whole Recording: measured fuel over the warm map's, coolant temperature.

    Each ``block_s`` block where the engine fires throughout (``engine_on``, speed above 300 rpm, mean torque above
    ``min_torque_nm``) gives the ratio of the block's fuel mass to the map's (read at every sample's speed and
    torque: the sums make the ratio robust to the fuel signal's lag in transients) and its mean coolant
    temperature. The campaign's steady engine points are all warm on a bench that warms the engine first; the
    firing engine of the take-offs and the first charging minutes is where the cold engine is seen.

    Raises
    ------
    IdentificationError
        When the map cannot be read or channels are missing.
    """
    m = map_pmf(bsfc_data, specs.fuel_lhv_j_per_kg)
    if m is None:
        raise IdentificationError(f"{COLD_KEY}: the BSFC map cannot be read")
    k = max(round(block_s * rate_hz), 2)
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # per run: fuel and map sums, mean coolant
    for g in grid_runs(rec, [COOLANT_ROLE, "fuel_mass_flow_gps", "engine_speed_rpm", "engine_torque_nm"], rate_hz,
                       k, optional=["engine_on"], what=COLD_KEY):
        parts.append(_cold_run(g, m, specs, k, min_torque_nm))
    f_b, p_b, c_b = (np.concatenate([p[j] for p in parts]) for j in range(3))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = f_b / p_b
    return {"ratio": ratio, "coolant_degc": c_b, "map_gps": p_b / k}


def _cold_run(g: Grid, m: tuple[np.ndarray, np.ndarray, np.ndarray], specs: VehicleSpecs, k: int,
              min_torque_nm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kept blocks of one run of whole ``k``-point blocks: fuel sums, the map's fuel sums, mean coolant."""
    n_rpm, tq, fuel, cool = g["engine_speed_rpm"], g["engine_torque_nm"], g["fuel_mass_flow_gps"], g[COOLANT_ROLE]
    on = (g["engine_on"] > 0.5) if "engine_on" in g.present else np.ones(n_rpm.size, bool)
    on &= np.isfinite(n_rpm) & np.isfinite(tq) & np.isfinite(fuel) & np.isfinite(cool) & (n_rpm > 300)
    pred = np.zeros_like(n_rpm)
    pred[on] = fuel_map_gps(*m, specs.engine_displacement_m3, specs.engine_strokes, specs.fuel_lhv_j_per_kg,
                            n_rpm[on], tq[on])
    nb = n_rpm.size // k
    shape = (nb, k)
    on_b = on[: nb * k].reshape(shape).all(axis=1)
    tq_b = np.where(on, tq, 0.0)[: nb * k].reshape(shape).mean(axis=1)
    keep = on_b & (tq_b > min_torque_nm)
    f_b = np.where(on, fuel, 0.0)[: nb * k].reshape(shape).sum(axis=1)[keep]
    p_b = pred[: nb * k].reshape(shape).sum(axis=1)[keep]
    c_b = np.where(on, cool, 0.0)[: nb * k].reshape(shape).mean(axis=1)[keep]
    return f_b, p_b, c_b


def identify_cold_fuel(rec: Recording, specs: VehicleSpecs, bsfc_data: dict, **kwargs: object) -> FitResult:
    """The factor (:func:`fit_cold_factor`) from the firing engine's blocks (:func:`cold_blocks`) against a warm
    map's data (``engine.bsfc``), weighted by the map's flow.

    Raises
    ------
    IdentificationError
        When the map cannot be read or too few blocks are found.
    """
    b = cold_blocks(rec, specs, bsfc_data)
    return fit_cold_factor(b["ratio"], b["coolant_degc"], weights=np.where(b["map_gps"] > 0, b["map_gps"], 0.0),
                           **kwargs)  # type: ignore[arg-type]
