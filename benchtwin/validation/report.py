"""The validation report: one :class:`Check` per comparison, and the :class:`ValidationReport` of a run."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from benchtwin.identification._fit import IdentificationResult

__all__ = ["Check", "ValidationReport", "by_family"]


@dataclass
class Check:
    """One comparison of the validation report.

    Attributes
    ----------
    group:
        Subsystem or ``chain``.
    name:
        What was checked (``transmission.gear5.eta_m``, ``chain.shaft_torque_nm``).
    identified, truth:
        The estimate (or measured quantity) and the true value.
    error:
        Error in the terms of the tolerance: relative for ``rel``, absolute for ``abs``, the R^2 for
        ``min``.
    tolerance:
        The bound; ``mode`` says how it applies.
    mode:
        ``rel`` (|error| <= tol, relative), ``abs`` (|error| <= tol, in ``unit``), ``min`` (value >= tol).
    unit:
        Unit of ``identified``/``truth`` (and of ``error`` in ``abs`` mode).
    passed:
        Whether the check holds.
    note:
        Why this tolerance, or why the check failed.
    """

    group: str
    name: str
    identified: float
    truth: float
    error: float
    tolerance: float
    mode: str
    unit: str = ""
    passed: bool = False
    note: str = ""

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        def clean(x: float) -> float | None:
            return float(x) if isinstance(x, (int, float)) and math.isfinite(x) else None

        return {"group": self.group, "name": self.name, "identified": clean(self.identified),
                "truth": clean(self.truth), "error": clean(self.error), "tolerance": self.tolerance,
                "mode": self.mode, "unit": self.unit, "passed": self.passed, "note": self.note}


@dataclass
class ValidationReport:
    """Everything a validation run found.

    Attributes
    ----------
    checks:
        Every check, parameters and chain.
    identification:
        The identification result (every fit with its statistics).
    chain:
        Chain summary: frames, bus load per bus, clock offsets, flagged samples per channel.
    timings_s:
        Wall time of each stage.
    meta:
        Vehicle, setup, campaign names, profile.
    prediction:
        The map-based model's prediction of held-out drives (``drives``: predicted, measured, errors per drive;
        ``notes``; ``series``/``series_measured``: time series of the held-out cycle for the figures).
    coverage:
        Every scalar parameter with a truth: its statistical and total 95 % intervals and whether they hold
        the truth (:func:`benchtwin.validation.coverage.interval_coverage`, as dicts).
    """

    checks: list[Check] = field(default_factory=list)
    identification: IdentificationResult | None = None
    chain: dict[str, Any] = field(default_factory=dict)
    timings_s: dict[str, float] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    prediction: dict[str, Any] = field(default_factory=dict)
    coverage: list[dict[str, Any]] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        """True when every check passed."""
        return all(c.passed for c in self.checks)

    def failures(self) -> list[Check]:
        """The checks that failed."""
        return [c for c in self.checks if not c.passed]

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (with the identification result)."""
        return {
            "passed": self.passed,
            "n_checks": len(self.checks),
            "n_failed": len(self.failures()),
            "meta": self.meta,
            "timings_s": self.timings_s,
            "chain": self.chain,
            "checks": [c.to_dict() for c in self.checks],
            "prediction": {k: v for k, v in self.prediction.items() if not k.startswith("series")},
            "interval_coverage": {"by_family": by_family(self.coverage), "parameters": self.coverage},
            "identification": self.identification.to_dict() if self.identification else None,
        }

    def format_table(self, *, only_failed: bool = False) -> str:
        """The checks as a fixed-width text table, grouped by subsystem."""
        rows = [c for c in self.checks if not (only_failed and c.passed)]
        out = [f"{'check':44s} {'identified':>12s} {'truth':>12s} {'error':>10s} {'tolerance':>11s}  result"]
        group = None
        for c in rows:
            if c.group != group:
                group = c.group
                out.append(f"-- {group}")
            if c.mode == "rel":
                err, tol = f"{100 * c.error:+.3f}%", f"{100 * c.tolerance:.2f}%"
            elif c.mode == "abs":
                err, tol = f"{c.error:+.4g}", f"{c.tolerance:.3g} {c.unit}".strip()
            else:
                err, tol = f"{c.error:.4f}", f">= {c.tolerance:g}"
            out.append(f"  {c.name:42s} {_fmt(c.identified):>12s} {_fmt(c.truth):>12s} {err:>10s} {tol:>11s}  "
                       f"{'pass' if c.passed else 'FAIL'}")
            if not c.passed and c.note:
                note = c.note if len(c.note) <= 160 else c.note[:157] + "..."
                out.append(f"      {note}")
        n_fail = len(self.failures())
        out.append(f"{len(self.checks)} checks, {len(self.checks) - n_fail} passed, {n_fail} failed")
        return "\n".join(out)


def by_family(rows: list[dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Coverage counts per family (and ``all``) of coverage rows (dicts with ``family``, ``inside_*``)."""
    out: dict[str, dict[str, int]] = {}
    for r in rows:
        for fam in (r["family"], "all"):
            d = out.setdefault(fam, {"n": 0, "inside_stat": 0, "inside_total": 0})
            d["n"] += 1
            d["inside_stat"] += int(r["inside_stat"])
            d["inside_total"] += int(r["inside_total"])
    return out


def _fmt(x: float) -> str:
    if not isinstance(x, (int, float)) or not math.isfinite(x):
        return "-"
    return f"{x:.6g}"
