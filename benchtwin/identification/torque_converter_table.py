"""An empirical torque-converter map: binned, monotone-smoothed torque ratio and capacity over the speed ratio.

The paper's eq. 35-36 (:mod:`benchtwin.identification.torque_converter`) describe each mode's torques as
quadratic forms in ``(w_p, w_t)``, i.e. a torque ratio ``TR(SR)`` that is a ratio of two quadratics and a
capacity ``T_p / w_p^2`` that is a quadratic in ``SR``. A real converter's curves (e.g. the JDMA converter,
docs/fidelity.md: TR falling linearly to 1 at SR 0.9, the K-factor rising steeply above SR 0.85) are not of that
form, and a map-based vehicle model solving eq. 35-36 for the pump speed then misses the slip loss where a drive
runs the converter. This module fits the curves themselves on the same converter points
(:func:`fit_converter_table`, fit ``torque_converter.table``):

- the points (inliers of the eq. 35-36 fit, pump torque corrected for the pump-side inertia) are binned over
  ``SR`` (bins of ``bin_width``, at least ``min_bin`` points); each bin gives a node at its median ``SR`` with
  the median torque ratio ``TR = T_t / T_p`` and the median capacity ``c = T_p / w_p^2`` (Nm s^2/rad^2; the
  K-factor is ``(30/pi) / sqrt(c)`` rpm/sqrt(Nm));
- ``TR`` is made non-increasing and ``c`` non-increasing in ``SR`` (isotonic regression weighted by the bin
  counts: a converter's stator multiplies torque less, and its capacity falls, as the turbine catches up), ``TR``
  floored at 1 (the stator freewheels in the coupling zone);
- ``SR = 1`` carries no torque (``c = 0``, ``TR = 1``, as eq. 39's ``a6 + a7 + a8 = 0``); between the last node
  and ``SR = 1`` the capacity falls linearly; below the first node the curves follow the count-weighted line
  through the first :data:`STALL_NODES` nodes to a node at ``SR = 0`` (not below the first node's values). Held
  flat there instead, both curves (non-increasing) would be biased low at stall by their slope times the first
  node's SR: on the high-fidelity paper run (first node at SR 0.04, TR falling 1.2 per unit SR) 0.05 in TR, the
  ~9 Nm turbine-torque residuals that, in the score below, outweighed the table's better fit everywhere else.

The paper's eq. 35-36 stay the identified result (``torque_converter.converter``, ``.coupling``); the table is
reported beside them with its own torque-ratio R^2 and RMS torque residual, and ``better_than_eq35`` says whether
it is closer to the points than eq. 35-36 over the SR range (each SR bin weighing alike, residuals per degree of
freedom; the map-based model's rule for using it).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import isotonic_regression

from benchtwin.errors import InsufficientDataError
from benchtwin.identification._fit import FitResult, r_squared

__all__ = ["fit_converter_table", "table_pump", "table_torques"]

#: nodes whose line carries the curves from the first node to SR 0 (the stall)
STALL_NODES = 3

#: SR grid on which :func:`table_pump` inverts the table
_SR_GRID = np.linspace(0.0, 0.9995, 4000)


def _nodes(fit: FitResult | dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    d = fit.data if isinstance(fit, FitResult) else fit
    return (np.asarray(d["sr_nodes"], float), np.asarray(d["tr_nodes"], float), np.asarray(d["cap_nodes"], float))


def table_torques(fit: FitResult | dict[str, np.ndarray], w_p: np.ndarray,
                  w_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pump and turbine torque (Nm) of the table at pump and turbine speeds (rad/s, drive: ``0 <= w_t <= w_p``).

    Parameters
    ----------
    fit:
        The ``torque_converter.table`` fit (or its ``data``: ``sr_nodes``, ``tr_nodes``, ``cap_nodes``).
    w_p, w_t:
        Pump and turbine speeds, rad/s.
    """
    sr_n, tr_n, cap_n = _nodes(fit)
    w_p = np.asarray(w_p, float)
    w_t = np.asarray(w_t, float)
    sr = np.clip(np.divide(w_t, w_p, out=np.zeros_like(w_t), where=w_p > 0), 0.0, 1.0)
    t_p = np.interp(sr, sr_n, cap_n) * w_p**2
    return t_p, np.interp(sr, sr_n, tr_n) * t_p


def table_pump(fit: FitResult | dict[str, np.ndarray], w_t: np.ndarray,
               t_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pump speed (rad/s) and torque (Nm) that carry turbine torque ``t_t > 0`` at turbine speed ``w_t >= 0``.

    ``T_t = TR(SR) c(SR) w_p^2`` with ``w_p = w_t / SR``: ``SR^2 / (TR c)`` rises monotonically with ``SR`` (both
    curves non-increasing), so ``SR`` is read off it at ``w_t^2 / T_t`` and ``w_p = sqrt(T_t / (TR c))`` (which
    also holds at stall, ``w_t = 0``).

    Parameters
    ----------
    fit:
        As :func:`table_torques`.
    w_t, t_t:
        Turbine speed (rad/s) and torque (Nm); points with ``t_t <= 0`` are returned rigid (``w_p = w_t``,
        ``T_p = T_t``).
    """
    sr_n, tr_n, cap_n = _nodes(fit)
    w_t = np.asarray(w_t, float)
    t_t = np.asarray(t_t, float)
    g = np.maximum(np.interp(_SR_GRID, sr_n, tr_n) * np.interp(_SR_GRID, sr_n, cap_n), 1e-12)
    h = _SR_GRID**2 / g
    pos = t_t > 0
    x = np.where(pos, w_t**2 / np.where(pos, t_t, 1.0), 0.0)
    sr = np.interp(x, h, _SR_GRID)
    g_at = np.interp(sr, _SR_GRID, g)
    w_p = np.where(pos, np.sqrt(np.where(pos, t_t, 0.0) / g_at), w_t)
    w_p = np.maximum(w_p, w_t)
    t_p = np.where(pos, np.interp(sr, sr_n, cap_n) * w_p**2, t_t)
    return w_p, t_p


def _at_stall(s: np.ndarray, y: np.ndarray, w: np.ndarray) -> float:
    """The count-weighted least-squares line through the first nodes ``(s, y)`` at SR 0, not below the first
    node's ``y`` (the curves are non-increasing in SR)."""
    slope, icpt = np.polyfit(s, y, 1, w=np.sqrt(w))
    return float(max(icpt, y[0])) if slope <= 0 else float(y[0])


def fit_converter_table(w_p: np.ndarray, w_t: np.ndarray, t_p: np.ndarray, t_t: np.ndarray,
                        eq35_t_p: np.ndarray | None = None, eq35_t_t: np.ndarray | None = None, *,
                        bin_width: float = 0.025, min_bin: int = 5, segments: list[str] | None = None,
                        n_excluded: int = 0) -> FitResult:
    """Binned, monotone torque-ratio and capacity curves over the speed ratio (module docstring).

    Parameters
    ----------
    w_p, w_t, t_p, t_t:
        The converter points (drive: ``t_p > 0``, ``0 <= w_t <= w_p``), the pump torque without its inertia
        share; rad/s and Nm.
    eq35_t_p, eq35_t_t:
        Eq. 35-36's torques at the same points (the comparison ``better_than_eq35``); None: not compared.
    bin_width:
        Width of the SR bins.
    min_bin:
        Fewest points that make a node.
    segments, n_excluded:
        Carried into the result.

    Returns
    -------
    FitResult
        No parameters; ``r2`` the torque ratio's R^2 against the points, ``rmse`` the RMS of the stacked pump and
        turbine torque residuals (Nm); data ``sr_nodes``, ``tr_nodes``, ``cap_nodes``, ``k_nodes`` (rpm/sqrt(Nm)),
        ``n_nodes`` (points per node), ``rms_eq35``, and ``better_than_eq35``: ``score_table < score_eq35``, the RMS
        residuals with each SR bin weighted alike and per degree of freedom (``2 n / (2 n - p)``, ``p`` two per node
        for the table, 8 for eq. 35-36).

    Raises
    ------
    InsufficientDataError
        Fewer than two nodes.
    """
    w_p, w_t, t_p, t_t = (np.asarray(x, float) for x in (w_p, w_t, t_p, t_t))
    ok = np.isfinite(w_p) & np.isfinite(w_t) & np.isfinite(t_p) & np.isfinite(t_t) & (w_p > 0) & (t_p > 0)
    ok &= (w_t >= 0) & (w_t < w_p)
    sr = w_t[ok] / w_p[ok]
    tr = t_t[ok] / t_p[ok]
    cap = t_p[ok] / w_p[ok] ** 2
    edges = np.arange(0.0, 1.0 + bin_width, bin_width)
    idx = np.clip(np.digitize(sr, edges) - 1, 0, edges.size - 2)
    rows = []
    for k in range(edges.size - 1):
        m = idx == k
        if m.sum() >= min_bin:
            rows.append((float(np.median(sr[m])), float(np.median(tr[m])), float(np.median(cap[m])), int(m.sum())))
    if len(rows) < 2:
        raise InsufficientDataError(f"torque converter table: {len(rows)} SR bins with {min_bin} points or more, "
                                    "need 2")
    s_n, tr_n, cap_n, n_n = (np.array(c) for c in zip(*rows, strict=True))
    w = n_n.astype(float)
    tr_n = np.maximum(isotonic_regression(tr_n, weights=w, increasing=False).x, 1.0)
    cap_n = np.maximum(isotonic_regression(cap_n, weights=w, increasing=False).x, 0.0)
    if s_n[-1] < 1.0:  # no torque without slip
        s_n, tr_n, cap_n, n_n = np.r_[s_n, 1.0], np.r_[tr_n, 1.0], np.r_[cap_n, 0.0], np.r_[n_n, 0]
    if s_n[0] > 0.0 and len(rows) >= STALL_NODES:  # the stall: the curves' trend carried to SR 0 (not held)
        tr0, cap0 = _at_stall(s_n[:STALL_NODES], tr_n[:STALL_NODES], w[:STALL_NODES]), \
            _at_stall(s_n[:STALL_NODES], cap_n[:STALL_NODES], w[:STALL_NODES])
        s_n, tr_n, cap_n, n_n = np.r_[0.0, s_n], np.r_[tr0, tr_n], np.r_[cap0, cap_n], np.r_[0, n_n]
    nodes = {"sr_nodes": s_n, "tr_nodes": tr_n, "cap_nodes": cap_n}
    tp_m, tt_m = table_torques(nodes, w_p[ok], w_t[ok])
    res = np.r_[t_p[ok] - tp_m, t_t[ok] - tt_m]
    rms = float(np.sqrt(np.mean(res**2)))
    r2, _ = r_squared(tr, tt_m / tp_m)
    with np.errstate(divide="ignore"):
        k_n = (30.0 / np.pi) / np.sqrt(cap_n)
    data = {**nodes, "k_nodes": k_n, "n_nodes": n_n.astype(float), "rms_table": np.array([rms])}
    out = FitResult({}, r2, float("nan"), rms, int(ok.sum()), n_excluded=n_excluded + int((~ok).sum()),
                    segments=list(segments or []), data=data)
    if eq35_t_p is not None and eq35_t_t is not None:
        r35 = np.r_[np.asarray(eq35_t_p, float)[ok] - t_p[ok], np.asarray(eq35_t_t, float)[ok] - t_t[ok]]
        # judged over the SR range, not where the campaign dwelt: each SR bin weighs alike (a held-out drive
        # visits the range differently), and each model's residual variance per degree of freedom (the table has
        # two values per node, eq. 35-36 eight coefficients)
        wb = 1.0 / np.bincount(idx)[idx]
        wb = np.r_[wb, wb]
        dof = 2 * sr.size

        def score(r: np.ndarray, n_par: int) -> float:
            return float(np.sqrt(np.sum(wb * r**2) / np.sum(wb) * dof / max(dof - n_par, 1)))

        s_tab, s_35 = score(res, 2 * len(rows)), score(r35, 8)
        data["rms_eq35"] = np.array([float(np.sqrt(np.mean(r35**2)))])
        data["score_table"], data["score_eq35"] = np.array([s_tab]), np.array([s_35])
        data["better_than_eq35"] = np.array([s_tab < s_35])
    return out
