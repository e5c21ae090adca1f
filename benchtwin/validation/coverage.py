"""Interval coverage: does the truth lie inside the reported 95 % intervals?

Each scalar parameter of :func:`~benchtwin.validation.parameters.truth_expectations` is looked up in the
identification result; its statistical interval (``ci95``: the fit's scatter only, GUM type A) and its
total interval (``ci95_total``: type A combined with the setup's declared systematic uncertainties,
type B) are compared with the true value. A family's coverage is the share of its parameters whose
interval holds the truth; an honest 95 % interval holds it about 95 % of the time over many runs.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

from benchtwin.config.vehicle import VehicleConfig
from benchtwin.identification._fit import IdentificationResult
from benchtwin.identification.keys import split_param
from benchtwin.validation.parameters import truth_expectations
from benchtwin.validation.report import by_family

__all__ = ["CoverageRow", "coverage_by_family", "interval_coverage", "shift_line_coverage"]


@dataclass
class CoverageRow:
    """One scalar parameter against its truth.

    Attributes
    ----------
    family:
        Parameter family (``transmission.drive``, ``transmission.coast``, ``motor``, ``road_load``, ...).
    key:
        ``<fit>.<param>``.
    truth, value:
        True and identified value.
    u_stat, u_total:
        Standard uncertainty of the fit's scatter and the combined one (type A and B).
    inside_stat, inside_total:
        Whether the truth lies inside ``ci95`` and inside ``ci95_total``.
    ci95, ci95_total:
        The two intervals.
    """

    family: str
    key: str
    truth: float
    value: float
    u_stat: float
    u_total: float
    inside_stat: bool
    inside_total: bool
    ci95: tuple[float, float] = (math.nan, math.nan)
    ci95_total: tuple[float, float] = (math.nan, math.nan)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        def clean(v: Any) -> Any:
            if isinstance(v, tuple):
                return [clean(x) for x in v]
            return None if isinstance(v, float) and not math.isfinite(v) else v

        return {k: clean(v) for k, v in asdict(self).items()}


def _inside(ci: Iterable[float] | None, truth: float) -> bool:
    if ci is None:
        return False
    lo, hi = (float(x) for x in ci)
    return bool(math.isfinite(lo) and math.isfinite(hi) and lo <= truth <= hi)


def interval_coverage(result: IdentificationResult, vehicle: VehicleConfig) -> list[CoverageRow]:
    """Every identified scalar parameter with a truth, and whether its intervals hold it.

    Parameters
    ----------
    result:
        The identification result.
    vehicle:
        The truth.

    Returns
    -------
    list of CoverageRow
        Parameters not identified (or flagged) are left out: they report no interval to judge.
    """
    params = result.parameters()
    rows = []
    for e in truth_expectations(vehicle):
        p = params.get(e.key)
        if p is None or p.status != "ok" or not math.isfinite(p.value):
            continue
        fit_key, _ = split_param(e.key)
        family = e.group
        if family == "transmission":
            family = f"transmission.{fit_key.direction}"
        ci_total = getattr(p, "ci95_total", None) or p.ci95
        u_total = getattr(p, "u_total", p.std_error)
        rows.append(CoverageRow(family, e.key, float(e.truth), float(p.value), float(p.std_error), float(u_total),
                                _inside(p.ci95, e.truth), _inside(ci_total, e.truth),
                                (float(p.ci95[0]), float(p.ci95[1])), (float(ci_total[0]), float(ci_total[1]))))
    return rows


def shift_line_coverage(result: IdentificationResult, vehicle: VehicleConfig) -> list[CoverageRow]:
    """The shift lines' ``c0_kmh`` and ``c1_kmh_per_pct`` against the vehicle file's ``v0`` and ``slope`` (family
    ``shifts``): what validation compares each identified line ``c0 + c1 pedal`` with. Lines not identified, or
    flagged, are left out, as in :func:`interval_coverage` (which does not list them: its rows are
    :func:`~benchtwin.validation.parameters.truth_expectations`' scalars)."""
    s = vehicle.shift_schedule
    rows = []
    for g in range(vehicle.n_gears - 1):
        for key, truths in ((f"shifts.up_{g + 1}_{g + 2}", (s.up_v0_kmh[g], s.up_slope_kmh_per_pct[g])),
                            (f"shifts.down_{g + 2}_{g + 1}", (s.down_v0_kmh[g], s.down_slope_kmh_per_pct[g]))):
            fit = result.fits.get(key)
            if fit is None or fit.status != "ok":
                continue
            for name, truth in zip(("c0_kmh", "c1_kmh_per_pct"), truths, strict=True):
                p = fit.params.get(name)
                if p is None or not math.isfinite(p.value):
                    continue
                ci_total = getattr(p, "ci95_total", None) or p.ci95
                rows.append(CoverageRow("shifts", f"{key}.{name}", float(truth), float(p.value), float(p.std_error),
                                        float(getattr(p, "u_total", p.std_error)), _inside(p.ci95, truth),
                                        _inside(ci_total, truth), (float(p.ci95[0]), float(p.ci95[1])),
                                        (float(ci_total[0]), float(ci_total[1]))))
    return rows


def coverage_by_family(rows: Iterable[CoverageRow | dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Family -> ``{"n": ..., "inside_stat": ..., "inside_total": ...}`` (counts), plus ``all``."""
    return by_family([r.to_dict() if isinstance(r, CoverageRow) else r for r in rows])
