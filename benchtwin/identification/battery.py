"""HV battery identification (eq. 29-30 of the paper); the map-free OCV/R mode for real logs is in
:mod:`benchtwin.identification.battery_map_free`, which shares this module's sampling.

Two ways to describe a pack from a Recording of its terminal voltage ``V`` and current ``I``
(positive discharge, IVT-S), with the displayed SOC ``s`` from the vehicle CAN:

1. **Scaled literature maps** (:func:`identify_battery`, the paper's method). The cell maps
   ``OCV_lit(s)``, ``R_lit,dch(s)``, ``R_lit,ch(s)`` (benchtwin/data/nmc_cell_literature.csv) are
   scaled so that ``V = (alpha OCV_lit(s) - I beta R_lit(s)) n_cells`` (eq. 30), with ``beta_dch``
   and ``R_dch`` for ``I > 0`` and ``beta_ch``, ``R_ch`` for ``I < 0``. For given maps the model is
   linear in ``(alpha, beta_dch, beta_ch)``, so the RMSE minimisation of the paper is an ordinary
   least-squares problem solved exactly by :func:`benchtwin.identification._fit.linear_fit`.
2. **Map-free** (:mod:`benchtwin.identification.battery_map_free`), for a pack whose chemistry differs
   from the literature maps: ``OCV(s)``, ``R_dch(s)`` and ``R_ch(s)`` as piecewise-linear functions of
   SOC, ``R0`` from current steps and the OCV at the end of long rests.

A displayed SOC quantised on the CAN is refined by coulomb counting (:func:`refine_soc`) before
eq. 30 is fitted; logs without any SOC signal are coulomb-counted from a given capacity
(:func:`coulomb_soc`).

Every result is a :class:`~benchtwin.identification._fit.FitResult` whose ``data`` carries the
arrays the figures need (time, measured and modelled voltage, corrected maps).
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import DataError, InsufficientDataError, MissingChannelError, NoExcitationError
from benchtwin.identification._battery_used import used_samples
from benchtwin.identification._fit import FitResult, ParameterEstimate, linear_fit, serial_inflation
from benchtwin.identification._resample_blocks import rate_of, resample_strict
from benchtwin.identification._signals import segment_mask
from benchtwin.recording import Recording
from benchtwin.segments import touched

__all__ = [
    "CellMaps",
    "battery_samples",
    "coulomb_soc",
    "eq30_design",
    "identify_battery",
    "load_literature_maps",
    "refine_soc",
]

#: segment kinds that are depletion / charge tests (used when the Recording has a segment table)
BATTERY_SEGMENT_KINDS: tuple[str, ...] = ("constant_drive",)


@dataclass(frozen=True)
class CellMaps:
    """Cell maps over the displayed SOC axis.

    Attributes
    ----------
    soc_pct:
        SOC breakpoints, %, increasing.
    ocv_v, r_discharge_ohm, r_charge_ohm:
        Cell open-circuit voltage and internal resistances at the breakpoints.
    """

    soc_pct: np.ndarray
    ocv_v: np.ndarray
    r_discharge_ohm: np.ndarray
    r_charge_ohm: np.ndarray

    def ocv(self, soc_pct: np.ndarray) -> np.ndarray:
        """OCV at ``soc_pct`` (linear interpolation, clamped at the ends)."""
        return np.interp(soc_pct, self.soc_pct, self.ocv_v)

    def r_discharge(self, soc_pct: np.ndarray) -> np.ndarray:
        """Discharge resistance at ``soc_pct``."""
        return np.interp(soc_pct, self.soc_pct, self.r_discharge_ohm)

    def r_charge(self, soc_pct: np.ndarray) -> np.ndarray:
        """Charge resistance at ``soc_pct``."""
        return np.interp(soc_pct, self.soc_pct, self.r_charge_ohm)


def load_literature_maps(path: str | Path | None = None) -> CellMaps:
    """Read cell maps from a CSV with columns ``soc_pct, ocv_v, r_discharge_ohm, r_charge_ohm``.

    Parameters
    ----------
    path:
        CSV file; default the shipped generic NMC maps (``benchtwin/data/nmc_cell_literature.csv``).

    Raises
    ------
    DataError
        If the file is missing, malformed or its SOC axis is not increasing.
    """
    if path is None:
        text = resources.files("benchtwin.data").joinpath("nmc_cell_literature.csv").read_text(encoding="utf-8")
        src = "nmc_cell_literature.csv"
    else:
        try:
            text = Path(path).read_text(encoding="utf-8")
        except OSError as exc:
            raise DataError(f"{path}: cannot read cell maps ({exc.strerror})") from None
        src = str(path)
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise DataError(f"{src}: no data")
    header = [h.strip() for h in lines[0].split(",")]
    need = ("soc_pct", "ocv_v", "r_discharge_ohm", "r_charge_ohm")
    missing = [n for n in need if n not in header]
    if missing:
        raise DataError(f"{src}: missing column(s) {', '.join(missing)}")
    try:
        rows = np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]])
    except ValueError as exc:
        raise DataError(f"{src}: not numeric ({exc})") from None
    cols = {n: rows[:, header.index(n)] for n in need}
    if rows.shape[0] < 2 or np.any(np.diff(cols["soc_pct"]) <= 0):
        raise DataError(f"{src}: soc_pct must have at least two increasing breakpoints")
    return CellMaps(cols["soc_pct"], cols["ocv_v"], cols["r_discharge_ohm"], cols["r_charge_ohm"])


def coulomb_soc(t_s: np.ndarray, current_a: np.ndarray, capacity_ah: float, *, soc_at_max_charge_pct: float = 100.0
                ) -> np.ndarray:
    """SOC by coulomb counting when a log has no SOC signal.

    The charge content is integrated from the current (positive discharge, trapezoidal rule) and
    referenced so that its maximum over the log is ``soc_at_max_charge_pct`` (for an HPPC test that
    starts with a full charge, the fully charged cell is 100 %).

    Parameters
    ----------
    t_s, current_a:
        Time and current (A, positive discharge).
    capacity_ah:
        Capacity used to scale charge to percent.
    """
    if not capacity_ah > 0:
        raise DataError(f"capacity_ah must be positive, got {capacity_ah}")
    t_s = np.asarray(t_s, dtype=float)
    i = np.nan_to_num(np.asarray(current_a, dtype=float))
    dq = np.r_[0.0, -0.5 * (i[1:] + i[:-1]) * np.diff(t_s)] / 3600.0
    q = np.cumsum(dq)
    return soc_at_max_charge_pct + (q - q.max()) / capacity_ah * 100.0


def _native_rate(rec: Recording, name: str, cap_hz: float = 10.0) -> float:
    if len(rec[name]) < 3:
        raise InsufficientDataError(f"channel {name!r} has {len(rec[name])} samples")
    return rate_of(rec[name], max_hz=cap_hz)


def _segment_mask(rec: Recording, t: np.ndarray, kinds: tuple[str, ...] | None) -> tuple[np.ndarray, list[str]]:
    """Mask of samples inside segments of the given kinds; all samples when none match or no table."""
    mask = segment_mask(rec, t, kinds) if kinds else None
    searched = [s for s in rec.segments if s.kind in kinds] if mask is not None else []
    names = [s.name for s, hit in zip(searched, touched(searched, t), strict=True) if hit]
    if not names:
        return np.ones(t.shape, dtype=bool), []
    return mask, names


def battery_samples(rec: Recording, *, soc: bool, rate_hz: float | None, kinds: tuple[str, ...] | None
                    ) -> tuple[dict[str, np.ndarray], np.ndarray, list[str], int]:
    """V, I (and displayed SOC) on the fits' common grid, the usable mask, segment names and bad samples.

    Parameters
    ----------
    rec:
        The Recording (``battery_voltage_v``, ``battery_current_a``; ``displayed_soc_pct`` with ``soc``).
    soc:
        Also gather the displayed SOC.
    rate_hz:
        Rate of the common grid; None: the native rate of the pack voltage.
    kinds:
        Segment kinds whose samples are usable; None: every sample.
    """
    names = ["battery_voltage_v", "battery_current_a"] + (["displayed_soc_pct"] if soc else [])
    for n in names:
        if n not in rec:
            raise MissingChannelError(f"battery identification needs channel {n!r}")
    rate = rate_hz or _native_rate(rec, "battery_voltage_v")
    # displayed SOC is interpolated, not held: its CAN steps are a quantisation of a continuous SOC
    t, v, bad = resample_strict(rec, names, rate)
    seg_mask, segs = _segment_mask(rec, t, kinds)
    use = seg_mask & ~bad
    v["t"] = t
    return v, use, segs, int((seg_mask & bad).sum())


def eq30_design(soc_pct: np.ndarray, current_a: np.ndarray, maps: CellMaps) -> dict[str, np.ndarray]:
    """Columns of eq. 30 per cell at SOC ``soc_pct`` and current ``current_a`` (positive discharge).

    ``alpha``: ``OCV_lit(s)``; ``beta_discharge``: ``-I R_lit,dch(s)`` where ``I > 0`` (else 0);
    ``beta_charge``: ``-I R_lit,ch(s)`` where ``I < 0``. Shared by :func:`identify_battery` and the planner.

    Parameters
    ----------
    soc_pct, current_a:
        Cell state of charge (%) and pack current (A, positive discharge).
    maps:
        The literature cell's OCV and resistance maps.
    """
    s = np.asarray(soc_pct, dtype=float)
    i = np.asarray(current_a, dtype=float)
    return {"alpha": maps.ocv(s), "beta_discharge": -i * maps.r_discharge(s) * (i > 0),
            "beta_charge": -i * maps.r_charge(s) * (i < 0)}


def identify_battery(
    rec: Recording,
    specs: VehicleSpecs | None = None,
    *,
    n_cells: int | None = None,
    maps: CellMaps | None = None,
    rate_hz: float | None = None,
    segment_kinds: tuple[str, ...] | None = BATTERY_SEGMENT_KINDS,
    min_points: int = 20,
    min_direction_points: int = 10,
    refine_displayed_soc: bool = True,
    min_span_s: float = 60.0,
    min_current_span_a: float = 10.0,
    min_soc_span_pct: float = 2.0,
) -> FitResult:
    """Identify ``alpha``, ``beta_discharge`` and ``beta_charge`` of eq. 30.

    Parameters
    ----------
    rec:
        Recording with ``battery_voltage_v``, ``battery_current_a`` (positive discharge) and
        ``displayed_soc_pct``.
    specs:
        Public specs; ``n_cells_series`` is used unless ``n_cells`` is given.
    maps:
        Literature cell maps (default: the shipped NMC maps).
    rate_hz:
        Common time base for the channels; default the voltage channel's own rate, at most 10 Hz
        (the model is static: a higher rate adds correlated points, not information).
    segment_kinds:
        Segment kinds holding depletion and charge tests; all samples are used when the Recording
        has no such segment.
    min_points, min_direction_points:
        Minimum usable samples overall and per current direction.
    min_span_s, min_current_span_a, min_soc_span_pct:
        Excitation the fit needs before it is reported ``ok``: usable data spanning at least
        ``min_span_s``, the current of each direction spanning ``min_current_span_a`` (a beta rests on
        the voltage drop changing with the current), and the displayed SOC moving ``min_soc_span_pct``
        for ``soc_per_ah``. Less is fitted and flagged, with the reason.
    refine_displayed_soc:
        Use the displayed SOC refined by coulomb counting (:func:`refine_soc`) instead of its
        quantised values; the slope is reported as ``soc_per_ah`` (% per Ah, 100 / usable capacity).

    Returns
    -------
    FitResult
        Parameters ``alpha``, ``beta_discharge``, ``beta_charge`` with statistics; ``adj_r2`` of
        the voltage fit. ``data`` holds ``t``, ``v_meas``, ``v_model``, ``v_lit`` (the uncorrected
        literature model), ``current``, ``soc`` and the corrected maps on ``map_soc``:
        ``map_ocv`` (alpha OCV), ``map_r_dch`` (beta_dch R_dch), ``map_r_ch`` (beta_ch R_ch), all
        per cell. When one current direction has too few points its beta is not identified and the
        fit is flagged.

    Raises
    ------
    MissingChannelError
        A needed channel is absent.
    InsufficientDataError, NoExcitationError, CollinearError
        The data cannot support the fit.
    """
    if n_cells is None:
        if specs is None:
            raise DataError("identify_battery needs specs (n_cells_series) or n_cells")
        n_cells = specs.n_cells_series
    maps = maps or load_literature_maps()
    t_use, v, i, s, soc_disp, (k_soc, k_se, n_blocks), segs, n_bad = _eq30_samples(rec, rate_hz, segment_kinds,
                                                                                    refine_displayed_soc)
    if s.size < min_points:
        raise InsufficientDataError(f"battery: {s.size} usable samples, need {min_points}")
    v_cell = v / n_cells
    dch, ch = i > 0, i < 0
    cols = eq30_design(s, i, maps)
    reasons = []
    for name, m, what in (("beta_discharge", dch, "discharge"), ("beta_charge", ch, "charge")):
        if int(m.sum()) < min_direction_points:
            reasons.append(f"only {int(m.sum())} {what} samples: {name} not identified")
            cols.pop(name)
        elif np.ptp(i[m]) < min_current_span_a:
            reasons.append(f"{what} current spans {np.ptp(i[m]):.3g} A (< {min_current_span_a:g} A): {name} is not "
                           "separable from the OCV term on these data")
    span = float(t_use[-1] - t_use[0]) if t_use.size else 0.0
    if span < min_span_s:
        reasons.append(f"usable data span {span:.3g} s (< {min_span_s:g} s): too short to identify eq. 30")
    if "beta_discharge" not in cols and "beta_charge" not in cols:
        raise NoExcitationError("battery: no current through the pack in the data; alpha and beta are not separable")
    names = list(cols)
    A = np.column_stack([cols[n] for n in names])
    fit = linear_fit(A, v_cell, names, units=[""] * len(names), segments=segs, min_points=min_points,
                     n_excluded=n_bad, what="battery eq. 30", serial=True)
    for r in reasons:
        fit.flag(r)
    if refine_displayed_soc:
        est = ParameterEstimate("soc_per_ah", k_soc, k_se, (k_soc - 1.96 * k_se, k_soc + 1.96 * k_se),
                                float("nan"), n_blocks, "%/Ah", segs)
        fit.add(est)
        soc_span = float(np.ptp(soc_disp)) if soc_disp.size else 0.0
        if est.status == "ok" and np.isfinite(k_soc) and soc_span < min_soc_span_pct:
            est.status = "flagged"
            est.reason = (f"displayed SOC moved {soc_span:.3g} % (< {min_soc_span_pct:g} %): a few display steps do "
                          "not fix the capacity")
        if not np.isfinite(k_soc):
            fit.reasons.append("displayed SOC used as is: it does not change within any block of usable samples")
    # the paper's statistics are on the pack voltage (same R^2, RMSE in volts of the pack)
    fit.rmse *= n_cells
    alpha = fit.value("alpha")
    b_d = fit.value("beta_discharge") if "beta_discharge" in fit.params else float("nan")
    b_c = fit.value("beta_charge") if "beta_charge" in fit.params else float("nan")
    t = t_use
    lit = (maps.ocv(s) - i * np.where(dch, maps.r_discharge(s), maps.r_charge(s))) * n_cells
    fit.data.update({
        "t": t, "v_meas": v, "v_model": fit.data["y_fit"] * n_cells, "v_lit": lit, "current": i, "soc": s,
        "soc_displayed": soc_disp,
        "map_soc": maps.soc_pct, "map_ocv": alpha * maps.ocv_v, "map_r_dch": b_d * maps.r_discharge_ohm,
        "map_r_ch": b_c * maps.r_charge_ohm, "lit_ocv": maps.ocv_v, "lit_r_dch": maps.r_discharge_ohm,
        "lit_r_ch": maps.r_charge_ohm,
    })
    return fit


def _eq30_samples(rec: Recording, rate_hz: float | None, kinds: tuple[str, ...] | None, refine: bool
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[float, float, int],
                             list[str], int]:
    """Eq. 30's usable samples: time, V, I, the (refined) SOC, the displayed SOC, ``refine_soc``'s slope, its
    standard error and blocks, the segment names and the bad samples in them. The grid is walked a block at a time
    and only the usable points kept (:func:`~benchtwin.identification._battery_used.used_samples`): the numbers of
    :func:`battery_samples` and :func:`refine_soc` on the whole grid."""
    for n in ("battery_voltage_v", "battery_current_a", "displayed_soc_pct"):
        if n not in rec:
            raise MissingChannelError(f"battery identification needs channel {n!r}")
    u = used_samples(rec, rate_hz or _native_rate(rec, "battery_voltage_v"), kinds)
    if u is None:  # no segment of those kinds holds a point: every sample, on the whole grid
        d, use, segs, n_bad = battery_samples(rec, soc=True, rate_hz=rate_hz, kinds=kinds)
        soc_all, stats = d["displayed_soc_pct"], (float("nan"), float("nan"), 0)
        if refine:
            soc_all, *rest = refine_soc(d["t"], d["battery_current_a"], d["displayed_soc_pct"], use)
            stats = (rest[0], rest[1], rest[2])
        return (d["t"][use], d["battery_voltage_v"][use], d["battery_current_a"][use], soc_all[use],
                d["displayed_soc_pct"][use], stats, segs, n_bad)
    s, stats = u.soc, (float("nan"), float("nan"), 0)
    if refine:
        s, *rest = _refine_runs(u.q, u.soc, u.runs)
        stats = (rest[0], rest[1], rest[2])
    return u.t, u.v, u.i, s, u.soc, stats, u.segs, u.n_bad


def refine_soc(t_s: np.ndarray, current_a: np.ndarray, soc_pct: np.ndarray, use: np.ndarray
               ) -> tuple[np.ndarray, float, float, int]:
    """Displayed SOC refined by coulomb counting.

    A displayed SOC is quantised on the CAN (0.5 % steps are common): between steps it lags or leads
    the true SOC by up to half a step, which biases the OCV term of eq. 30. The IVT-S current is far
    finer, so ``s = s0_b + k Q(t)`` is fitted to the displayed values, with ``Q`` the charge counted
    from the current (Ah, positive when charging), one offset ``s0_b`` per contiguous block of usable
    samples and one slope ``k`` (% per Ah, i.e. 100 / usable capacity) shared by all blocks. A rounded
    staircase scatters evenly about the line, so the fitted SOC follows the true one.

    Parameters
    ----------
    t_s, current_a, soc_pct:
        Common time base, current (A, positive discharge) and displayed SOC.
    use:
        Usable samples; blocks are its runs.

    Returns
    -------
    soc, k, k_se, n_blocks
        Refined SOC on every sample (the displayed SOC where it could not be refined), the slope and
        its standard error (NaN when not refined) and the number of blocks that carried a slope.
    """
    i = np.nan_to_num(np.asarray(current_a, dtype=float))
    dq = np.r_[0.0, -0.5 * (i[1:] + i[:-1]) * np.diff(t_s)] / 3600.0
    q = np.cumsum(dq)
    edges = np.flatnonzero(np.diff(np.r_[0, use.astype(np.int8), 0]))
    return _refine_runs(q, soc_pct, list(zip(edges[::2], edges[1::2])))


def _refine_runs(q: np.ndarray, soc_pct: np.ndarray, runs: list[tuple[int, int]]
                 ) -> tuple[np.ndarray, float, float, int]:
    """:func:`refine_soc` from the counted charge ``q`` and the runs ``(a, b)`` of usable samples."""
    sxy = sxx = 0.0
    blocks = []
    for a, b in runs:
        qb, sb = q[a:b], soc_pct[a:b]
        if b - a < 3 or np.ptp(sb) <= 0:
            continue
        dqb, dsb = qb - qb.mean(), sb - sb.mean()
        sxy += float(dqb @ dsb)
        sxx += float(dqb @ dqb)
        blocks.append((a, b))
    if not blocks or not sxx > 0:
        return soc_pct, float("nan"), float("nan"), 0
    k = sxy / sxx
    if not k > 0:
        return soc_pct, float("nan"), float("nan"), 0
    out = np.asarray(soc_pct, dtype=float).copy()
    ss_res, n = 0.0, 0
    for a, b in runs:
        qb, sb = q[a:b], soc_pct[a:b]
        s0 = float(np.mean(sb - k * qb))
        out[a:b] = s0 + k * qb
        ss_res += float(np.sum((sb - out[a:b]) ** 2))
        n += b - a
    dof = max(n - len(blocks) - 1, 1)
    # the staircase residuals of one block follow each other: inflate for their serial correlation
    resid = np.concatenate([soc_pct[a:b] - out[a:b] for a, b in blocks])
    _rho, inflation = serial_inflation(resid)
    k_se = float(np.sqrt(ss_res / dof / sxx * inflation))
    return out, k, k_se, len(blocks)
