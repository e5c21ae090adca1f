"""Map-free HV battery identification for real logs: OCV(SOC) and R(SOC) without literature maps.

For a pack whose chemistry differs from the paper's literature cell (:mod:`benchtwin.identification.battery`
holds eq. 29-30 and the sampling both ways share): :func:`identify_battery_map_free` fits ``OCV(s)``,
``R_dch(s)`` and ``R_ch(s)`` as continuous piecewise-linear functions of SOC (hat basis on SOC nodes)
by one linear least squares (``V = OCV(s) - I R(s)``); with one node (or no SOC signal) this is the plain
OCV/R fit. :func:`identify_battery_r0_steps` gives the ohmic resistance ``R0`` from current steps (HPPC
pulse edges, ``R0 = -dV/dI`` across one sample) and :func:`identify_battery_ocv_rest` the OCV at the end
of long rests (the HPPC definition of OCV). SOC is anchored by :mod:`benchtwin.identification.soc_reference`.
"""

from __future__ import annotations

import numpy as np

from benchtwin.errors import DataError, InsufficientDataError, MissingChannelError, NoExcitationError
from benchtwin.identification._fit import FitResult, ParameterEstimate, linear_fit
from benchtwin.identification.battery import battery_samples
from benchtwin.identification.soc_reference import SocReference, reference_soc
from benchtwin.recording import Recording

__all__ = ["identify_battery_map_free", "identify_battery_ocv_rest", "identify_battery_r0_steps"]


def _hat_basis(x: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Piecewise-linear (hat) basis: column k is 1 at node k, 0 at its neighbours; clamped outside."""
    x = np.clip(x, nodes[0], nodes[-1])
    eye = np.eye(nodes.size)
    return np.column_stack([np.interp(x, nodes, eye[k]) for k in range(nodes.size)])


def identify_battery_map_free(
    rec: Recording,
    *,
    n_cells: int = 1,
    soc_nodes_pct: np.ndarray | list[float] | None = None,
    capacity_ah: float | None = None,
    min_abs_current_a: float = 0.0,
    rate_hz: float | None = None,
    min_node_points: int = 10,
    segment_kinds: tuple[str, ...] | None = None,
    start_soc_pct: float | None = None,
) -> FitResult:
    """Identify OCV(SOC), R_dch(SOC) and R_ch(SOC) directly, without literature maps.

    ``V / n_cells = OCV(s) - I R_dch(s) [I > 0] - I R_ch(s) [I < 0]`` with each function
    piecewise linear in SOC between ``soc_nodes_pct`` (a hat basis), fitted at once by linear least
    squares. With a single node, or when the log has neither an SOC channel nor ``capacity_ah``,
    the functions are constants: the plain OCV/R fit.

    Parameters
    ----------
    rec:
        Recording with ``battery_voltage_v`` and ``battery_current_a`` (positive discharge), and
        optionally ``displayed_soc_pct``.
    n_cells:
        Divide the voltage by this (1: pack values; the cell count: per-cell values).
    soc_nodes_pct:
        SOC nodes; default one node (constant OCV and R).
    capacity_ah:
        When the log has no ``displayed_soc_pct``, SOC is coulomb-counted with this capacity, anchored by
        the rules of :func:`benchtwin.identification.soc_reference.reference_soc` (the rule used is in
        ``data['soc_reference']``).
    start_soc_pct:
        Declared SOC at the first sample (anchors the coulomb count instead of the data's rule).
    min_abs_current_a:
        Samples with ``0 < |I| <`` this are left out (near-zero current carries relaxation
        voltage, not OCV, on a dynamic trace); rest samples with ``I == 0`` exactly are kept.
    rate_hz:
        Common time base; default the voltage channel's own rate, at most 10 Hz.
    min_node_points:
        A node whose support has fewer samples of one direction loses that resistance (flagged).
    segment_kinds:
        Use only samples inside segments of these kinds (``None``: every sample).

    Returns
    -------
    FitResult
        Parameters ``ocv_v``, ``r_discharge_ohm``, ``r_charge_ohm`` (single node) or
        ``ocv_v_soc050`` etc. per node; ``data`` holds ``soc_nodes``, ``ocv_nodes``,
        ``r_dch_nodes``, ``r_ch_nodes`` (NaN where not identified), ``t``, ``v_meas``, ``v_model``.

    Raises
    ------
    MissingChannelError, InsufficientDataError, NoExcitationError, CollinearError
    """
    has_soc = "displayed_soc_pct" in rec
    d, use, segs, n_bad = battery_samples(rec, soc=has_soc, rate_hz=rate_hz, kinds=segment_kinds)
    t, i, v = d["t"], d["battery_current_a"], d["battery_voltage_v"]
    ref: SocReference | None = None
    if has_soc or capacity_ah is not None:
        ref = reference_soc(t, i, capacity_ah or 1.0, voltage_v=v, start_soc_pct=start_soc_pct,
                            soc_channel_pct=d["displayed_soc_pct"] if has_soc else None)
        s = ref.soc_pct
    else:
        s = np.full(t.shape, 50.0)
    nodes = np.array([50.0] if soc_nodes_pct is None else soc_nodes_pct, dtype=float)
    if not has_soc and capacity_ah is None:
        nodes = nodes[:1] * 0 + 50.0
    if nodes.ndim != 1 or nodes.size == 0 or np.any(np.diff(nodes) <= 0):
        raise DataError(f"soc_nodes_pct must be increasing, got {nodes.tolist()}")
    near_zero = (np.abs(i) < min_abs_current_a) & (i != 0)
    n_near_zero = int((use & near_zero).sum())
    use = use & ~near_zero
    t, i, v, s = t[use], i[use], v[use] / n_cells, s[use]
    if t.size < 3 * nodes.size + 1:
        raise InsufficientDataError(f"battery map-free: {t.size} usable samples for {nodes.size} SOC node(s)")
    H = np.ones((t.size, 1)) if nodes.size == 1 else _hat_basis(s, nodes)
    tag = (lambda k: "") if nodes.size == 1 else (lambda k: f"_soc{round(nodes[k]):03d}")
    dch, ch = i > 0, i < 0
    cols, names, units, reasons, keys = [], [], [], [], []
    for k in range(nodes.size):
        support = H[:, k] > 0.0
        if support.sum() < min_node_points:
            reasons.append(f"SOC node {nodes[k]:g} %: {int(support.sum())} samples, not identified")
            continue
        cols.append(H[:, k])
        names.append(f"ocv_v{tag(k)}")
        units.append("V")
        keys.append(("ocv", k))
        for nm, m, key in (("r_discharge_ohm", dch, "r_dch"), ("r_charge_ohm", ch, "r_ch")):
            if int((support & m).sum()) < min_node_points:
                reasons.append(f"SOC node {nodes[k]:g} %: {int((support & m).sum())} samples of "
                               f"{nm.split('_')[1]}, {nm} not identified")
                continue
            cols.append(-i * m * H[:, k])
            names.append(f"{nm}{tag(k)}")
            units.append("ohm")
            keys.append((key, k))
    if not cols:
        raise InsufficientDataError("battery map-free: no SOC node has enough samples")
    if not any(k[0] != "ocv" for k in keys):
        raise NoExcitationError("battery map-free: no current through the pack; R is not identifiable")
    fit = linear_fit(np.column_stack(cols), v, names, units=units, segments=segs, min_points=3 * nodes.size + 1,
                     n_excluded=n_bad + n_near_zero, what="battery OCV/R (map-free)")
    for r in reasons:
        fit.flag(r)
    out = {key: np.full(nodes.size, np.nan) for key in ("ocv", "r_dch", "r_ch")}
    for (key, k), nm in zip(keys, names):
        out[key][k] = fit.value(nm)
    neg = [nm for (key, _k), nm in zip(keys, names) if key != "ocv" and not fit.value(nm) > 0]
    if neg:
        fit.flag(f"non-positive resistance at {', '.join(neg)}: the static V = OCV - I R model does not describe "
                 "these data there (polarisation, relaxation, too few samples)")
    fit.data.update({"soc_nodes": nodes, "ocv_nodes": out["ocv"], "r_dch_nodes": out["r_dch"],
                     "r_ch_nodes": out["r_ch"], "t": t, "v_meas": v * n_cells,
                     "v_model": fit.data["y_fit"] * n_cells, "current": i, "soc": s})
    _note_soc_reference(fit, ref, nodes.size > 1)
    return fit


def _note_soc_reference(fit: FitResult, ref: SocReference | None, soc_used: bool) -> None:
    """Record how SOC was anchored (``data['soc_reference']``; a reason when the SOC axis is used)."""
    if ref is None:
        return
    fit.data["soc_reference"] = {"rule": ref.rule, "note": ref.note, "ambiguous": ref.ambiguous}
    if soc_used:
        fit.reasons.append(f"SOC reference ({ref.rule}): {ref.note}")


def identify_battery_r0_steps(
    rec: Recording,
    *,
    n_cells: int = 1,
    min_step_a: float = 5.0,
    max_prior_change_a: float = 0.5,
    capacity_ah: float | None = None,
    soc_nodes_pct: np.ndarray | list[float] | None = None,
    min_steps: int = 3,
    start_soc_pct: float | None = None,
) -> FitResult:
    """Ohmic resistance R0 from current steps (HPPC pulse edges): ``dV = -R0 dI`` across one sample.

    A step is a sample ``k`` where ``|I_k - I_(k-1)| >= min_step_a`` after a sample of nearly
    constant current (``|I_(k-1) - I_(k-2)| <= max_prior_change_a``). Over one sample interval the
    diffusion and charge-transfer voltages barely move, so the slope of ``dV`` on ``dI`` is the
    ohmic resistance (plus what the polarisation builds within one sample: the shorter the sample
    interval, the closer to R0).

    Parameters
    ----------
    rec:
        Recording with ``battery_voltage_v`` and ``battery_current_a`` sampled together (one source).
    n_cells:
        Divide the voltage by this.
    soc_nodes_pct, capacity_ah:
        When given (with an SOC channel or a capacity for coulomb counting), R0 is also reported
        per SOC bin centred on the nodes (``r0_ohm_soc050``...).
    start_soc_pct:
        Declared SOC at the first sample (anchors the coulomb count).
    min_steps:
        Minimum number of steps (per bin).

    Returns
    -------
    FitResult
        ``r0_ohm`` over all steps (no intercept) and per SOC bin; ``data`` holds ``di``, ``dv``,
        ``soc`` of each step.
    """
    for n in ("battery_voltage_v", "battery_current_a"):
        if n not in rec:
            raise MissingChannelError(f"R0 step identification needs channel {n!r}")
    ci, cv = rec["battery_current_a"], rec["battery_voltage_v"]
    t = ci.timestamps
    if cv.timestamps.shape == t.shape and np.array_equal(cv.timestamps, t):
        v = cv.values
    else:
        v = cv.at(t)
    i = ci.values
    good = ci.good & np.isfinite(v) & (cv.flags_at(t) == 0)
    di = np.diff(i)
    k = np.arange(2, i.size)
    step = (np.abs(di[1:]) >= min_step_a) & (np.abs(di[:-1]) <= max_prior_change_a) & good[k] & good[k - 1]
    k = k[step]
    if k.size < min_steps:
        raise InsufficientDataError(f"R0 steps: {k.size} current steps of at least {min_step_a} A, need {min_steps}")
    dI = i[k] - i[k - 1]
    dV = (v[k] - v[k - 1]) / n_cells
    fit = linear_fit(-dI[:, None], dV, ["r0_ohm"], units=["ohm"], min_points=min_steps, what="battery R0 steps")
    soc = None
    ref = None
    if "displayed_soc_pct" in rec:
        soc = rec["displayed_soc_pct"].at(t[k], hold=True)
    elif capacity_ah is not None:
        ref = reference_soc(t, i, capacity_ah, voltage_v=v, start_soc_pct=start_soc_pct)
        soc = ref.soc_pct[k]
    if soc is not None and soc_nodes_pct is not None:
        nodes = np.asarray(soc_nodes_pct, dtype=float)
        edges = np.r_[-np.inf, 0.5 * (nodes[1:] + nodes[:-1]), np.inf]
        r_nodes = np.full(nodes.size, np.nan)
        for j, node in enumerate(nodes):
            m = (soc >= edges[j]) & (soc < edges[j + 1])
            if m.sum() < min_steps:
                continue
            sub = linear_fit(-dI[m, None], dV[m], ["r0"], min_points=min_steps, what=f"R0 at {node:g} %")
            p = sub["r0"]
            fit.add(ParameterEstimate(f"r0_ohm_soc{round(node):03d}", p.value, p.std_error, p.ci95, sub.r2,
                                      sub.n_points, "ohm"))
            r_nodes[j] = p.value
        fit.data.update({"soc_nodes": nodes, "r0_nodes": r_nodes})
    fit.data.update({"di": dI, "dv": dV, "soc": soc if soc is not None else np.full(k.size, np.nan)})
    _note_soc_reference(fit, ref, soc_nodes_pct is not None)
    return fit


def identify_battery_ocv_rest(
    rec: Recording,
    *,
    n_cells: int = 1,
    capacity_ah: float | None = None,
    min_rest_s: float = 600.0,
    rest_current_a: float = 0.05,
    average_s: float = 10.0,
    start_soc_pct: float | None = None,
) -> FitResult:
    """OCV(SOC) from the ends of long rests (the HPPC definition of OCV).

    A rest is a run of samples with ``|I| <= rest_current_a`` lasting at least ``min_rest_s``;
    its OCV is the mean voltage over its last ``average_s`` seconds (the cell has relaxed), at the
    SOC of that moment (``displayed_soc_pct`` or coulomb counting with ``capacity_ah``).

    Parameters
    ----------
    rec:
        Recording with ``battery_voltage_v`` and ``battery_current_a`` (and ``displayed_soc_pct``).
    n_cells:
        Divide the voltage by this (1: pack values).
    capacity_ah, min_rest_s, rest_current_a, average_s:
        As above.
    start_soc_pct:
        Declared SOC at the first sample (anchors the coulomb count).

    Returns
    -------
    FitResult
        One parameter per rest, ``ocv_v_soc087`` (SOC rounded to 1 %), with the standard deviation
        of the averaged samples as its standard error; ``data`` holds ``soc`` and ``ocv`` sorted by SOC.

    Raises
    ------
    InsufficientDataError
        Fewer than two long rests.
    """
    for n in ("battery_voltage_v", "battery_current_a"):
        if n not in rec:
            raise MissingChannelError(f"OCV from rests needs channel {n!r}")
    ci, cv = rec["battery_current_a"], rec["battery_voltage_v"]
    t, i = ci.timestamps, ci.values
    v = cv.values if np.array_equal(cv.timestamps, t) else cv.at(t)
    ref = None
    if "displayed_soc_pct" in rec:
        soc = rec["displayed_soc_pct"].at(t, hold=True)
    elif capacity_ah is not None:
        ref = reference_soc(t, i, capacity_ah, voltage_v=v, start_soc_pct=start_soc_pct)
        soc = ref.soc_pct
    else:
        raise MissingChannelError("OCV from rests needs displayed_soc_pct or capacity_ah for coulomb counting")
    rest = (np.abs(i) <= rest_current_a) & ci.good & np.isfinite(v)
    edges = np.flatnonzero(np.diff(np.r_[0, rest.astype(np.int8), 0]))
    points = []
    for a, b in zip(edges[::2], edges[1::2]):
        if t[b - 1] - t[a] < min_rest_s:
            continue
        m = slice(a, b)
        last = t[m] >= t[b - 1] - average_s
        vv = v[m][last] / n_cells
        points.append((float(soc[b - 1]), float(vv.mean()), float(vv.std(ddof=1)) if vv.size > 1 else float("nan"),
                       int(vv.size)))
    if len(points) < 2:
        raise InsufficientDataError(f"OCV from rests: {len(points)} rest(s) of at least {min_rest_s:g} s, need 2")
    points.sort()
    s_arr = np.array([p[0] for p in points])
    o_arr = np.array([p[1] for p in points])
    params = {}
    for s_, o_, se, n in points:
        name = f"ocv_v_soc{round(s_):03d}"
        params[name] = ParameterEstimate(name, o_, se, (o_ - 2 * se, o_ + 2 * se), float("nan"), n, "V")
    fit = FitResult(params, float("nan"), float("nan"), float("nan"), sum(p[3] for p in points),
                    data={"soc": s_arr, "ocv": o_arr})
    _note_soc_reference(fit, ref, True)
    return fit
