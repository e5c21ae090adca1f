"""Which plan row covers an estimate: the check of the plan against a seed sweep (benchmarks/bench_plan.py).

A plan row is either one parameter (``transmission.gear5.eta_m``, the name identification gives it) or a family
row ending in ``.*`` (``engine.*``: every estimate under that prefix, predicted alike). A sweep's estimate that no
row covers (a fit added to identification after its plan, e.g. ``battery.rc``) is *not planned*: the check says so
instead of leaving the estimate out unseen. A family that runs another family's method first (the torque converter
runs the transmission's) also reports that method's estimates; they are planned in the other family's plan by name,
for the other family's own tests, so they are *planned elsewhere*, not compared here. Another family's ``.*`` row
does not count there: it speaks for that family's own estimates only (``engine.*`` with a predicted 0 says nothing
of the CAN torque calibration the transmission family fits, ``engine.can_torque``).
"""

from __future__ import annotations

from collections.abc import Iterable

__all__ = ["plan_row_of", "planned_elsewhere", "unplanned_keys"]


def plan_row_of(key: str, names: Iterable[str]) -> str | None:
    """The plan row that covers the estimate ``key``.

    Parameters
    ----------
    key:
        ``fit.parameter`` as the identification names the estimate (e.g. ``battery.rc.R0``).
    names:
        The plan's row names: parameters, or family rows ending in ``.*``.

    Returns
    -------
    str or None
        The row of the same name; else the longest ``.*`` row whose prefix (with its dot) starts ``key``;
        None when no row covers it (not planned).
    """
    best: str | None = None
    for name in names:
        if name == key:
            return name
        if name.endswith(".*") and key.startswith(name[:-1]) and (best is None or len(name) > len(best)):
            best = name
    return best


def unplanned_keys(names: Iterable[str], keys: Iterable[str], others: Iterable[str] = ()) -> list[str]:
    """The estimates no plan row covers (:func:`plan_row_of` is None, nor :func:`planned_elsewhere`), sorted.

    Parameters
    ----------
    names:
        The plan's row names.
    keys:
        The sweep's estimate keys of the same family.
    others:
        The other families' plan row names (their exact names only count).

    Returns
    -------
    list of str
        The keys not planned.
    """
    names, others = list(names), list(others)
    return sorted(k for k in keys if plan_row_of(k, names) is None and planned_elsewhere(k, others) is None)


def planned_elsewhere(key: str, others: Iterable[str]) -> str | None:
    """The other family's row that plans ``key`` by its exact name (``.*`` rows do not count), or None.

    Parameters
    ----------
    key:
        An estimate its own family's plan does not cover.
    others:
        The row names of the other families' plans.

    Returns
    -------
    str or None
        ``key`` when another plan has a row of that name, else None.
    """
    return key if key in set(others) else None
