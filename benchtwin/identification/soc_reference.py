"""Where a coulomb-counted SOC is anchored, chosen by a stated rule and reported with the result.

Counting the current gives the charge content ``Q(t)`` up to a constant; SOC needs one point where it is
known. In order of precedence:

1. ``channel``: the log has the car's own SOC signal (``displayed_soc_pct``): it is used, nothing is counted.
2. ``declared_start``: the user declares the SOC at the first sample (``[battery] start_soc_pct`` of a signal
   map, ``benchtwin identify --start-soc``, or the method option ``start_soc_pct``).
3. ``max_charge``: 100 % at the highest charge content of the log. Right when the log starts full (an HPPC
   test after its initial charge) or ends with a full charge that began below full.
4. ``start_full_end_recharge``: the ambiguous case. The highest count is at the end, after a recharge that
   put back more ampere-hours than the test took out. Either the log started below full and the recharge
   filled the pack (then rule 3 is right), or it started full and the excess is charging loss and
   overcharge, not charge content (then 100 % belongs at the start). The data decide: when the pack rests
   at the end at no higher a voltage than at the start (within ``same_rest_v``), the start was full: 100 % at
   the start, SOC held at 100 % where the count climbs above it. When the end rests higher, the start was
   below full: rule 3. When the log has no rest at one of its ends, rule 3 is
   kept and the note says the reference is ambiguous.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from benchtwin.errors import DataError

__all__ = ["SocReference", "charge_counted_ah", "reference_soc"]


@dataclass(frozen=True)
class SocReference:
    """A SOC trace and how it was anchored.

    Attributes
    ----------
    soc_pct:
        SOC on every sample, %.
    rule:
        ``channel``, ``declared_start``, ``max_charge`` or ``start_full_end_recharge`` (module docstring).
    note:
        One sentence for the report: the rule and the numbers that chose it.
    ambiguous:
        True when the data could not decide between the rules (no rest at one end of the log).
    """

    soc_pct: np.ndarray
    rule: str
    note: str
    ambiguous: bool = False


def charge_counted_ah(t_s: np.ndarray, current_a: np.ndarray) -> np.ndarray:
    """Charge put into the pack since the first sample, Ah (trapezoidal rule).

    Parameters
    ----------
    t_s, current_a:
        Time (s) and current (A, positive discharging).
    """
    t_s = np.asarray(t_s, dtype=float)
    i = np.nan_to_num(np.asarray(current_a, dtype=float))
    dq = np.r_[0.0, -0.5 * (i[1:] + i[:-1]) * np.diff(t_s)] / 3600.0
    return np.cumsum(dq)


def _rest_voltage(t: np.ndarray, v: np.ndarray, rest: np.ndarray, at_end: bool, min_rest_s: float,
                  bound: int) -> float:
    """Mean voltage over the last 10 s of the first rest of at least ``min_rest_s`` ending by sample ``bound``
    (or the last one starting from it, ``at_end``); NaN if none."""
    edges = np.flatnonzero(np.diff(np.r_[0, rest.astype(np.int8), 0]))
    runs = [(a, b) for a, b in zip(edges[::2], edges[1::2]) if t[b - 1] - t[a] >= min_rest_s
            and (a >= bound if at_end else b <= bound)]
    if not runs:
        return float("nan")
    a, b = runs[-1] if at_end else runs[0]
    last = (t[a:b] >= t[b - 1] - 10.0) & np.isfinite(v[a:b])
    return float(np.mean(v[a:b][last])) if last.any() else float("nan")


def reference_soc(t_s: np.ndarray, current_a: np.ndarray, capacity_ah: float, *,
                  voltage_v: np.ndarray | None = None, start_soc_pct: float | None = None,
                  soc_channel_pct: np.ndarray | None = None, same_rest_v: float | None = None,
                  rest_current_a: float | None = None, min_rest_s: float = 60.0,
                  min_excess_pct: float = 1.0) -> SocReference:
    """SOC of a log by the rules of the module docstring.

    Parameters
    ----------
    t_s, current_a:
        Time and current (A, positive discharge).
    capacity_ah:
        Capacity that scales charge to percent.
    voltage_v:
        Terminal voltage on the same samples (for the rest-voltage comparison of rule 4).
    start_soc_pct:
        Declared SOC at the first sample (rule 2).
    soc_channel_pct:
        The log's own SOC on the same samples (rule 1).
    same_rest_v:
        Two rest voltages closer than this are one state; default 0.2 % of the start's rest voltage (a full
        pack relaxes to within a few millivolts per cell of its rest voltage; one percent of SOC moves a cell's
        OCV by several millivolts near full).
    rest_current_a:
        A rest is ``|I| <=`` this; default 1 % of the largest current of the log (at least 0.05 A).
    min_rest_s:
        Shortest rest whose voltage is compared.
    min_excess_pct:
        The recharge must put back more than this (% of capacity) beyond what was taken out for the case to
        count as ambiguous (below it, counting noise).
    """
    t_s = np.asarray(t_s, dtype=float)
    i = np.asarray(current_a, dtype=float)
    if soc_channel_pct is not None:
        return SocReference(np.asarray(soc_channel_pct, dtype=float), "channel",
                            "SOC from the log's own SOC channel (displayed_soc_pct)")
    if not capacity_ah > 0:
        raise DataError(f"capacity_ah must be positive, got {capacity_ah}")
    q = charge_counted_ah(t_s, i)
    pct = q / capacity_ah * 100.0
    if start_soc_pct is not None:
        if not 0.0 <= start_soc_pct <= 100.0:
            raise DataError(f"start_soc_pct must be within 0..100 %, got {start_soc_pct}")
        return SocReference(start_soc_pct + pct, "declared_start",
                            f"SOC counted from the declared start SOC of {start_soc_pct:g} % "
                            f"(capacity {capacity_ah:g} Ah)")
    by_max = 100.0 + pct - pct.max()
    k_max, k_min = int(np.argmax(pct)), int(np.argmin(pct))
    taken = -float(pct[: k_max + 1].min()) if k_max > 0 else 0.0
    excess = float(pct[-1])  # net charge in over the log, % of capacity
    # the highest count comes after the lowest and holds to the end (rests after the recharge are normal)
    held = float(pct.max() - pct[-1]) <= 0.1 * min_excess_pct
    ends_with_recharge = k_max > k_min and held and excess > min_excess_pct
    if not ends_with_recharge:
        where = "at the start" if k_max == 0 else f"at {t_s[k_max] - t_s[0]:.0f} s"
        return SocReference(by_max, "max_charge",
                            f"100 % at the highest charge content of the log ({where}; capacity {capacity_ah:g} Ah)")
    head = (f"the log ends with a recharge that puts back {taken + excess:.1f} % of capacity after {taken:.1f} % "
            f"was taken out ({excess:.1f} % more)")
    if voltage_v is None:
        return SocReference(by_max, "max_charge", f"{head}; no voltage to compare the rests at its ends: 100 % at "
                            "the end (ambiguous: if the log started full, every SOC is low by up to the excess)",
                            ambiguous=True)
    v = np.asarray(voltage_v, dtype=float)
    thr = rest_current_a if rest_current_a is not None else max(0.01 * float(np.nanmax(np.abs(i))), 0.05)
    rest = np.abs(np.nan_to_num(i, nan=np.inf)) <= thr
    # a rest "at the start" comes before the count has moved by min_excess_pct, one "at the end" after it has
    # settled within min_excess_pct of its final value
    moved = np.flatnonzero(np.abs(pct) > min_excess_pct)
    unsettled = np.flatnonzero(np.abs(pct - pct[-1]) > min_excess_pct)
    v_start = _rest_voltage(t_s, v, rest, False, min_rest_s, int(moved[0]) + 1 if moved.size else pct.size)
    v_end = _rest_voltage(t_s, v, rest, True, min_rest_s, int(unsettled[-1]) if unsettled.size else 0)
    if not (np.isfinite(v_start) and np.isfinite(v_end)):
        return SocReference(by_max, "max_charge", f"{head}; no rest of {min_rest_s:g} s at both ends to compare: "
                            "100 % at the end (ambiguous: if the log started full, every SOC is low by up to the "
                            "excess)", ambiguous=True)
    tol = same_rest_v if same_rest_v is not None else 0.002 * abs(v_start)
    if v_end - v_start <= tol:
        soc = np.minimum(100.0 + pct, 100.0)
        same = "the same, full state" if abs(v_end - v_start) <= tol else "the start is the fuller state"
        return SocReference(soc, "start_full_end_recharge",
                            f"{head}; the pack rests at {v_start:.4g} V at the start and {v_end:.4g} V at the end "
                            f"({same}, tolerance {tol:.3g} V), so 100 % at the start and the excess is charging "
                            "loss (SOC held at 100 % above it)")
    return SocReference(by_max, "max_charge",
                        f"{head}; the pack rests at {v_end:.4g} V at the end against {v_start:.4g} V at the start "
                        f"(more than {tol:.3g} V apart: it started below full), so 100 % at the end")
