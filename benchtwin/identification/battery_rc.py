"""Extension fit of the HV battery: eq. 30 plus one or two RC branches (``battery.rc``).

Eq. 30 is static: after a current step a real pack's terminal voltage relaxes for seconds (charge transfer)
and minutes (diffusion), which eq. 30 cannot follow, so its betas absorb part of that polarisation and a
drive's voltage is predicted with the wrong dynamics. The extension is a Thevenin model per cell

``V/n = alpha OCV_lit(s) - I beta R_lit(s) - u_1 - u_2``,  ``tau_k du_k/dt = R_k I - u_k``

(``beta_discharge`` for ``I > 0``, ``beta_charge`` for ``I < 0``, as eq. 30; with the pack temperature logged,
``beta`` becomes ``beta + beta_temp_per_k (25 degC - T)``: a pack's ``R_0`` falls a few % per K as it warms,
and a campaign warms the pack by 10-20 K). For given time constants the
model is linear in ``(alpha, beta_dch, beta_ch, R_1, R_2)``: ``u_k = R_k x_k`` with ``x_k`` the current
through a first-order filter (exact discretisation of a held current, ``x_k[j] = a x_k[j-1] + (1 - a) I[j]``,
``a = exp(-dt / tau_k)``). The time constants are found by a grid search over ``log tau`` (the sum of
squares profiled over the linear parameters), then refined by Nelder-Mead from the best grid point.

Intervals: the model is linearised in all its parameters (the time constants included) at the optimum and
the covariance ``s^2 (J^T J)^-1`` of that regression is inflated for the residuals' serial correlation
(:func:`benchtwin.identification._fit.linear_fit`), so each interval carries the time constants' uncertainty.

Branches that the data do not support (``R_k``'s interval reaching 0) or that are not material (``R_k`` times
the data's RMS current below the fit's residual RMS: the branch moves the voltage less than the model's own
scatter) are dropped, the last such one first, and the fit is redone; with no branch left the pack behaves as
eq. 30 (the paper-form truth has no RC branch), the result is flagged and
:class:`benchtwin.validation.predict.MapVehicle` keeps eq. 30.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import DataError, InsufficientDataError
from benchtwin.identification._fit import FitResult, ParameterEstimate, linear_fit
from benchtwin.identification._good_interp import count_good, interp_good
from benchtwin.identification.battery import CellMaps, eq30_design, identify_battery, load_literature_maps
from benchtwin.recording import Recording

__all__ = ["filtered_current", "fit_battery_rc", "identify_battery_rc"]

#: the pack temperature channel (optional)
TEMP_ROLE = "battery_temp_degc"
#: reference temperature of the linear temperature term of R_0, degC
T_REF_DEGC = 25.0
#: smallest span of the pack temperature over the data for a temperature term (below it the term is not separable
#: from beta: a 1 K span moves an Arrhenius-like R_0 by ~2.5 %)
MIN_TEMP_SPAN_K = 1.0
#: the eq. 30 fit's arrays the RC fit reads (its samples)
_EQ30_SAMPLES = ("t", "v_meas", "current", "soc")
#: a gap in the samples longer than this restarts the RC states (the current in the gap is unknown)
_MAX_GAP_S = 1.0


def filtered_current(t_s: np.ndarray, current_a: np.ndarray, tau_s: float, *, max_gap_s: float = _MAX_GAP_S
                     ) -> np.ndarray:
    """The current through a first-order filter of time constant ``tau_s`` (the RC branch's ``u / R``).

    ``x[j] = a x[j-1] + (1 - a) I[j]`` with ``a = exp(-(t[j] - t[j-1]) / tau)``: the exact response of the
    branch to a current held over each step. The state starts at 0 and restarts at 0 after a gap longer than
    ``max_gap_s``.

    Parameters
    ----------
    t_s, current_a:
        Increasing time (s) and current (A, positive discharge).
    tau_s:
        Time constant (s), positive.
    """
    if not tau_s > 0:
        raise DataError(f"tau_s must be positive, got {tau_s}")
    t = np.asarray(t_s, dtype=float)
    i = np.asarray(current_a, dtype=float)
    dt = np.diff(t, prepend=t[0] if t.size else 0.0)
    a = np.exp(-dt / tau_s)
    out = np.empty_like(i)
    starts = np.r_[0, np.flatnonzero(dt > max_gap_s)] if t.size else np.zeros(0, int)
    ends = np.r_[starts[1:], t.size]
    for s, e in zip(starts, ends):
        x = 0.0
        for j in range(s, e):  # a plain loop is fast enough on the fit's 10 Hz grid (tens of thousands of rows)
            aj = a[j] if j > s else 1.0
            x = aj * x + (1.0 - aj) * i[j]
            out[j] = x
    return out


def _filtered_blocks(t: np.ndarray, i: np.ndarray, tau: float) -> np.ndarray:
    """:func:`filtered_current` vectorised with scipy's ``lfilter`` on uniform blocks, for one time constant (the
    search uses :class:`_BranchFilter`, the same numbers with what does not depend on ``tau`` worked out once)."""
    from scipy.signal import lfilter

    dt = np.diff(t)
    if dt.size and np.allclose(dt[dt <= _MAX_GAP_S], np.median(dt), rtol=1e-6, atol=1e-9):
        h = float(np.median(dt))
        a = math.exp(-h / tau)
        cuts = np.r_[0, np.flatnonzero(dt > _MAX_GAP_S) + 1, t.size]
        out = np.empty_like(i)
        for s, e in itertools.pairwise(cuts):
            seg = i[s:e].copy()
            seg[0] = 0.0  # the state starts at 0: x[0] = 0, then x[j] = a x[j-1] + (1 - a) I[j]
            out[s:e] = lfilter([1.0 - a], [1.0, -a], seg)
        return out
    return filtered_current(t, i, tau)


class _BranchFilter:
    """:func:`_filtered_blocks` of one ``(t, i)`` for many time constants: the grid's uniformity check, its step, the
    gap cuts and each block's zero-started input are worked out once, not at every evaluation of the search (the
    same numbers: only ``a = exp(-h / tau)`` and the filter depend on ``tau``)."""

    def __init__(self, t: np.ndarray, i: np.ndarray) -> None:
        self.t, self.i = t, i
        self.h: float | None = None
        self.blocks: list[tuple[int, int, np.ndarray]] = []
        dt = np.diff(t)
        if dt.size and np.allclose(dt[dt <= _MAX_GAP_S], np.median(dt), rtol=1e-6, atol=1e-9):
            self.h = float(np.median(dt))
            cuts = np.r_[0, np.flatnonzero(dt > _MAX_GAP_S) + 1, t.size]
            for s, e in itertools.pairwise(cuts):
                seg = i[s:e].copy()
                seg[0] = 0.0  # the state starts at 0: x[0] = 0, then x[j] = a x[j-1] + (1 - a) I[j]
                self.blocks.append((int(s), int(e), seg))

    def __call__(self, tau: float) -> np.ndarray:
        if self.h is None:
            return filtered_current(self.t, self.i, tau)
        from scipy.signal import lfilter

        a = math.exp(-self.h / tau)
        out = np.empty_like(self.i)
        for s, e, seg in self.blocks:
            out[s:e] = lfilter([1.0 - a], [1.0, -a], seg)
        return out


def _sse(A: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
    x, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ x
    return float(r @ r), x


def identify_battery_rc(
    rec: Recording,
    specs: VehicleSpecs | None = None,
    *,
    n_cells: int | None = None,
    maps: CellMaps | None = None,
    rate_hz: float = 2.0,
    segment_kinds: tuple[str, ...] | None = None,
    n_branches: int = 2,
) -> FitResult:
    """``battery.rc`` from a Recording: eq. 30 with RC branches over every usable sample (:func:`fit_battery_rc`).

    The RC branches need current changes (steps, accelerations, regenerative braking), which the paper's two
    constant-speed tests hardly have; so, unlike eq. 30 (fitted on the constant drives), this fit takes every
    usable sample of the Recording by default (a driving cycle held out of identification is not in it). The
    samples and the refined SOC are those of :func:`benchtwin.identification.battery.identify_battery` on the
    same samples.

    Parameters
    ----------
    rec:
        Recording with ``battery_voltage_v``, ``battery_current_a`` and ``displayed_soc_pct``.
    specs, n_cells:
        Cells in series: ``n_cells`` or the specs' ``n_cells_series``.
    maps:
        Literature cell maps (default: the shipped NMC maps).
    rate_hz:
        Common time base; 2 Hz resolves time constants from about 1 s (the fast search range's lower end) and
        keeps a campaign's hours of samples to tens of thousands of rows.
    segment_kinds:
        Segment kinds whose samples are used; None: every usable sample.
    n_branches:
        1 or 2 RC branches to try.

    Raises
    ------
    MissingChannelError, InsufficientDataError, NoExcitationError
        As :func:`benchtwin.identification.battery.identify_battery`.
    """
    if n_cells is None:
        if specs is None:
            raise DataError("identify_battery_rc needs specs (n_cells_series) or n_cells")
        n_cells = specs.n_cells_series
    eq30 = identify_battery(rec, specs, n_cells=n_cells, maps=maps, rate_hz=rate_hz, segment_kinds=segment_kinds)
    # the fit below reads these four of eq. 30's arrays: its design matrix, fitted values and maps go now (a
    # campaign's rows each, not kept beside the RC search's)
    eq30.data = {k: eq30.data[k] for k in _EQ30_SAMPLES}
    temp = None
    if TEMP_ROLE in rec:
        ch = rec[TEMP_ROLE]
        if count_good(ch, 2) >= 2:  # read around the fit's times only (not the whole channel per type B re-run)
            temp = interp_good(ch, eq30.data["t"])
    return fit_battery_rc(eq30, n_cells, maps=maps, n_branches=n_branches, temp_degc=temp)


def fit_battery_rc(
    eq30: FitResult,
    n_cells: int,
    *,
    maps: CellMaps | None = None,
    temp_degc: np.ndarray | None = None,
    n_branches: int = 2,
    tau_fast_s: tuple[float, float] = (1.0, 40.0),
    tau_slow_s: tuple[float, float] = (40.0, 1500.0),
    grid: int = 9,
) -> FitResult:
    """Fit eq. 30 plus up to ``n_branches`` RC branches on the samples of the eq. 30 fit.

    Parameters
    ----------
    eq30:
        The eq. 30 fit (:func:`benchtwin.identification.battery.identify_battery`); its ``data`` gives the
        samples (``t``, ``v_meas`` pack voltage, ``current``, ``soc`` refined SOC) and its ``soc_per_ah``
        is carried over.
    n_cells:
        Cells in series.
    maps:
        The literature cell maps eq. 30 was fitted with (default: the shipped NMC maps).
    temp_degc:
        The pack temperature at the samples, or None. When it moves by :data:`MIN_TEMP_SPAN_K` or more,
        ``R_0`` takes a linear temperature term, ``R_0 = (beta + beta_temp_per_k (T_ref - T)) R_lit(s)``
        (``T_ref`` = :data:`T_REF_DEGC`; an Arrhenius-like resistance to first order).
    n_branches:
        1 or 2 RC branches to try (fewer are kept when the data do not support them).
    tau_fast_s, tau_slow_s:
        Search ranges of the fast and the slow time constant (s); the slow one is searched only above the
        fast one.
    grid:
        Grid points per time constant (log-spaced) of the coarse search.

    Returns
    -------
    FitResult
        ``alpha``, ``beta_discharge``, ``beta_charge`` (beta now scales ``R_0``, the instantaneous resistance),
        ``beta_temp_per_k`` with a temperature term, ``r1_ohm``/``tau1_s`` and, with two branches kept,
        ``r2_ohm``/``tau2_s`` (per cell), ``soc_per_ah``
        copied from ``eq30``; ``data`` holds ``v_model``, ``map_soc``, ``map_ocv``, ``map_r_dch``, ``map_r_ch``
        (``R_0`` maps, per cell) and ``n_branches``. Flagged, with ``n_branches`` 0, when no RC branch is
        supported by the data.

    Raises
    ------
    DataError
        ``n_branches`` not 1 or 2, or ``eq30`` without its samples.
    InsufficientDataError
        Too few samples.
    """
    if n_branches not in (1, 2):
        raise DataError(f"n_branches must be 1 or 2, got {n_branches}")
    if not all(k in eq30.data for k in _EQ30_SAMPLES):
        raise DataError("fit_battery_rc needs the eq. 30 fit's samples (t, v_meas, current, soc)")
    maps = maps or load_literature_maps()
    t = np.asarray(eq30.data["t"], float)
    i = np.asarray(eq30.data["current"], float)
    y = np.asarray(eq30.data["v_meas"], float) / n_cells
    s = np.asarray(eq30.data["soc"], float)
    if t.size < 50:
        raise InsufficientDataError(f"battery.rc: {t.size} samples, need 50")
    base = eq30_design(s, i, maps)
    base = {k: v for k, v in base.items() if k in eq30.params}  # a direction eq. 30 could not identify stays out
    reasons: list[str] = []
    temp = np.asarray(temp_degc, float) if temp_degc is not None else None
    if temp is not None and (temp.shape != t.shape or not np.all(np.isfinite(temp))):
        raise DataError(f"temp_degc must be finite with shape {t.shape}")
    if temp is not None and np.ptp(temp) < MIN_TEMP_SPAN_K:
        reasons.append(f"pack temperature spans {np.ptp(temp):.2g} K (< {MIN_TEMP_SPAN_K:g} K): no temperature term")
        temp = None
    if temp is not None:
        r_lit = np.where(i > 0, maps.r_discharge(s), maps.r_charge(s))
        base["beta_temp_per_k"] = -i * r_lit * (T_REF_DEGC - temp)
    for nb in range(n_branches, 0, -1):
        fit = _fit_taus(t, i, y, base, nb, tau_fast_s, tau_slow_s, grid, eq30.segments)
        i_rms = float(np.sqrt(np.mean(i * i)))
        why = {}
        for k in range(1, nb + 1):
            p = fit.params[f"r{k}_ohm"]
            if not p.ci95[0] > 0:
                why[k] = f"R{k}'s interval reaches 0 ({p.ci95[0]:.3g} ohm): the data do not support that branch"
            elif p.value * i_rms < fit.rmse:
                why[k] = (f"R{k} x the RMS current ({p.value * i_rms * n_cells * 1e3:.3g} mV on the pack) is below the "
                          f"fit's residual RMS ({fit.rmse * n_cells * 1e3:.3g} mV): the branch is not material")
        if not why:
            break
        weak = sorted(why)
        reasons.append(f"{nb} RC branch(es): {why[weak[-1]]}")
        del fit  # its design matrix and data go before the next search (a campaign's rows each)
    else:
        fit = linear_fit(np.column_stack(list(base.values())), y, list(base), units=_units(base),
                         segments=eq30.segments, what="battery eq. 30 (no RC branch supported)", serial=True)
        fit.flag("no RC branch is supported by the data: the pack behaves as eq. 30 (static)")
        nb = 0
    fit.reasons[:0] = reasons
    if "soc_per_ah" in eq30.params:
        fit.add(dataclasses.replace(eq30.params["soc_per_ah"]))
    fit.rmse *= n_cells
    alpha = fit.value("alpha")
    b_d = fit.value("beta_discharge") if "beta_discharge" in fit.params else float("nan")
    b_c = fit.value("beta_charge") if "beta_charge" in fit.params else float("nan")
    fit.data.update({
        "t": t, "v_meas": y * n_cells, "v_model": fit.data["y_fit"] * n_cells, "current": i, "soc": s,
        "map_soc": maps.soc_pct, "map_ocv": alpha * maps.ocv_v, "map_r_dch": b_d * maps.r_discharge_ohm,
        "map_r_ch": b_c * maps.r_charge_ohm, "n_branches": np.array(nb), "lit_r_dch": maps.r_discharge_ohm,
        "lit_r_ch": maps.r_charge_ohm, "t_ref_degc": np.array(T_REF_DEGC),
        "temp_mean_degc": np.array(float(np.mean(temp)) if temp is not None else T_REF_DEGC),
    })
    return fit


def _units(base: dict[str, np.ndarray]) -> list[str]:
    return ["1/K" if k == "beta_temp_per_k" else "" for k in base]


def _search_taus(B: np.ndarray, y: np.ndarray, filtered: _BranchFilter,
                 design: Callable[[tuple[float, ...]], np.ndarray], nb: int, fast: tuple[float, float],
                 slow: tuple[float, float], grid: int) -> tuple[float, ...]:
    """The time constants of least squares (coarse log grid, then Nelder-Mead on ``log tau``)."""
    from scipy.optimize import minimize

    # the base columns are the same for every pair of time constants: project them out once (QR), so that each
    # evaluation solves only for the branches' columns
    q, _r = np.linalg.qr(B)
    y_r = y - q @ (q.T @ y)
    yy = float(y_r @ y_r)

    def sse(taus: tuple[float, ...]) -> float:
        c = np.column_stack([-filtered(tau) for tau in taus])
        c_r = c - q @ (q.T @ c)
        g, h = c_r.T @ c_r, c_r.T @ y_r
        try:
            return yy - float(h @ np.linalg.solve(g, h))
        except np.linalg.LinAlgError:
            return _sse(design(taus), y)[0]

    gf, gs = np.geomspace(*fast, grid), np.geomspace(*slow, grid)
    pts = [(float(a),) for a in np.r_[gf, gs]] if nb == 1 else \
        [(float(a), float(b)) for a in gf for b in gs if b > 2.0 * a]
    best = min(pts, key=sse)
    lo, hi = np.log([fast[0]] + ([slow[0]] if nb == 2 else [])), np.log([fast[1] if nb == 2 else slow[1]]
                                                                       + ([slow[1]] if nb == 2 else []))
    opt = minimize(lambda z: sse(tuple(np.exp(np.clip(z, lo, hi)))), np.log(best), method="Nelder-Mead",
                   options={"xatol": 1e-3, "fatol": 0.0, "maxiter": 300})
    return tuple(float(v) for v in np.exp(np.clip(opt.x, lo, hi)))


def _fit_taus(t: np.ndarray, i: np.ndarray, y: np.ndarray, base: dict[str, np.ndarray], nb: int,
              fast: tuple[float, float], slow: tuple[float, float], grid: int, segments: list[str]) -> FitResult:
    """Best time constants (coarse log grid, then Nelder-Mead on ``log tau``); the fit there with joint intervals."""
    B = np.column_stack(list(base.values()))
    filtered = _BranchFilter(t, i)  # what does not depend on the time constants, once for the whole search

    def design(taus: tuple[float, ...]) -> np.ndarray:
        return np.column_stack([B] + [-filtered(tau) for tau in taus])

    # the search's projection goes with it: not beside the fits below (a campaign's rows times the base columns)
    taus = _search_taus(B, y, filtered, design, nb, fast, slow, grid)
    names = list(base) + [f"r{k + 1}_ohm" for k in range(nb)]
    A = design(taus)
    fit = linear_fit(A, y, names, units=_units(base) + ["ohm"] * nb, segments=segments,
                     what=f"battery eq. 30 + {nb} RC", serial=True)
    x = np.array([fit.value(n) for n in names])
    # joint intervals: the model linearised in all parameters (time constants included) at the optimum; the
    # regression of the linearised problem has the same residuals and the covariance s^2 (J^T J)^-1, inflated
    # for the residuals' serial correlation by linear_fit
    dcols = []
    for k, tau in enumerate(taus):
        h = 1e-4 * tau
        d = (-filtered(tau + h) + filtered(tau - h)) / (2.0 * h)
        dcols.append(x[len(base) + k] * d)
    J = np.column_stack([A, *dcols])
    y_lin = y - A @ x + J @ np.r_[x, taus]
    tnames = [f"tau{k + 1}_s" for k in range(nb)]
    joint = linear_fit(J, y_lin, names + tnames, units=_units(base) + ["ohm"] * nb + ["s"] * nb,
                       segments=segments, what=f"battery eq. 30 + {nb} RC (linearised)", serial=True, cond_max=1e9)
    for n in names:
        p, q = fit.params[n], joint.params[n]
        half = 0.5 * (q.ci95[1] - q.ci95[0])
        p.std_error, p.u_total = q.std_error, q.std_error
        p.ci95 = p.ci95_total = (p.value - half, p.value + half)
    for k, n in enumerate(tnames):
        q = joint.params[n]
        half = 0.5 * (q.ci95[1] - q.ci95[0])
        fit.add(ParameterEstimate(n, taus[k], q.std_error, (taus[k] - half, taus[k] + half), fit.r2, y.size, "s",
                                  list(segments)))
        rng = fast if k == 0 else slow
        if taus[k] <= rng[0] * 1.001 or taus[k] >= rng[1] * 0.999:
            fit.params[n].status = "flagged"
            fit.params[n].reason = f"at the end of its search range {rng[0]:g}..{rng[1]:g} s"
    return fit
