"""The fault campaign: inject the setup's ``[[faults]]``, check the acquisition finds each one, and nothing else.

:func:`fault_campaign` runs the batch chain twice on one Trace: with the setup as written (its faults
injected) and with the same setup without faults (the clean run). Each injected fault is *detected* when
``Recording.meta["faults_detected"]`` holds a span of the same kind on the same device or bus (and channel,
for channel faults) overlapping the injected span (within :data:`TOLERANCE_S`, the devices' clocks are not
the plant's); a detected span that matches no injected fault is a *false alarm*, and so is every detection
of the clean run. Identification runs on both Recordings: the fits whose status changed, that lost points
or disappeared are listed (what lost support), and for each kind the flags found in its span say whether the
acquisition keeps those samples out of identification (:meth:`benchtwin.recording.Flag.bad`).
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.chain.batch import run_batch
from benchtwin.config.setup import FAULT_KINDS, FaultSpec, SetupConfig
from benchtwin.recording import Flag, Recording
from benchtwin.trace import Trace

__all__ = ["TOLERANCE_S", "VALUES_WRONG", "fault_campaign", "fault_table", "score_faults"]

#: a detected span may start or end this far from the injected one (device clocks, cycle times)
TOLERANCE_S = 1.0


def _target(d: dict[str, Any]) -> str:
    return str(d.get("device") or d.get("bus"))


def _matches(f: FaultSpec, d: dict[str, Any], tol_s: float = TOLERANCE_S) -> bool:
    return (d["kind"] == f.kind and _target(d) == f.target and (f.channel is None or d.get("channel") == f.channel)
            and d["start_s"] <= f.end_s + tol_s and d["end_s"] >= f.start_s - tol_s)


def score_faults(injected: list[FaultSpec], detected: list[dict[str, Any]], clean: list[dict[str, Any]] | None = None
                 ) -> dict[str, Any]:
    """Per kind: ``injected``, ``detected`` (injected faults found) and ``false_alarms`` (detections matching
    no injected fault, plus every detection of the clean run); and the list of each."""
    kinds: dict[str, dict[str, int]] = {k: {"injected": 0, "detected": 0, "false_alarms": 0} for k in FAULT_KINDS}
    per_fault = []
    for f in injected:
        hits = [d for d in detected if _matches(f, d)]
        kinds[f.kind]["injected"] += 1
        kinds[f.kind]["detected"] += bool(hits)
        per_fault.append({"kind": f.kind, "target": f.target, "channel": f.channel, "start_s": f.start_s,
                          "end_s": None if not np.isfinite(f.end_s) else f.end_s, "detected": bool(hits),
                          "spans": [[h["start_s"], h["end_s"]] for h in hits]})
    false = [d for d in detected if not any(_matches(f, d) for f in injected)]
    for d in [*false, *(clean or [])]:
        kinds.setdefault(d["kind"], {"injected": 0, "detected": 0, "false_alarms": 0})["false_alarms"] += 1
    return {"kinds": kinds, "faults": per_fault, "false_alarms": false, "clean_detections": list(clean or [])}


#: kinds whose samples in the span carry wrong values or times (the rest only lose samples)
VALUES_WRONG = frozenset({"corrupt_payload", "wrong_dlc", "ivt_error", "modbus_restart", "modbus_slow", "clock_drift",
                          "clock_step", "stuck", "clip", "open_circuit"})


def _flags_in_span(rec: Recording, f: FaultSpec, bus_of: dict[str, str | None]) -> dict[str, Any]:
    """The flags set on the fault's device (or the devices of its bus) inside its span; whether identification
    keeps them out (:meth:`Flag.bad`), which it must for every kind in :data:`VALUES_WRONG`."""
    bits = 0
    bad = 0
    for ch in rec.channels.values():
        if (ch.source != f.target) if f.bus is None else (bus_of.get(ch.source) != f.bus):
            continue
        if f.channel is not None and ch.name != f.channel:
            continue
        inside = (ch.timestamps >= f.start_s - TOLERANCE_S) & (ch.timestamps <= f.end_s + TOLERANCE_S)
        if inside.any():
            bits |= int(np.bitwise_or.reduce(ch.flags[inside]))
            bad |= int(np.any(ch.flags[inside] & int(Flag.bad())))
    return {"flags": [fl.name for fl in Flag if fl.value and bits & int(fl)],
            "excluded_from_identification": bool(bad),
            "identification_safe": bool(bad) or f.kind not in VALUES_WRONG}


def _fit_changes(clean: Any, faulty: Any) -> list[dict[str, Any]]:
    """Fits whose status changed, that lost (or gained) points, or that one run has and the other not."""
    out = []
    for key in sorted(set(clean.fits) | set(faulty.fits)):
        a, b = clean.fits.get(key), faulty.fits.get(key)
        if a is None or b is None:
            out.append({"fit": key, "clean": None if a is None else a.status, "faults": None if b is None else b.status,
                        "note": "no fit with faults" if b is None else "fit only with faults",
                        "error": faulty.errors.get(key)})
            continue
        if a.status != b.status or a.n_points != b.n_points:
            out.append({"fit": key, "clean": a.status, "faults": b.status, "points_clean": a.n_points,
                        "points_faults": b.n_points, "reasons": list(b.reasons)})
    return out


def fault_campaign(trace: Trace, setup: SetupConfig, *, seed: int = 0, out_dir: str | Path | None = None,
                   specs: Any = None, identify: bool = True) -> dict[str, Any]:
    """Run the fault campaign of ``setup`` on ``trace`` (see the module docstring); return the faults.json content.

    Parameters
    ----------
    trace:
        The truth.
    setup:
        The bench with its ``[[faults]]``.
    seed:
        Campaign seed (all random draws of the faults come from the devices' streams of it).
    out_dir:
        Where to write the raw logs of both runs (``faulty/``, ``clean/``), their Recordings and
        ``faults.json``; a temporary folder (deleted) when None (the logs are always written: a truncated
        log is a fault of the written files).
    specs:
        Public vehicle specs for identification.
    identify:
        Also run identification on both Recordings.
    """
    clean_setup = setup.model_copy(update={"faults": []})
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(out_dir) if out_dir is not None else Path(tmp)
        rec = run_batch(trace, setup, seed, base / "faulty")
        rec_clean = run_batch(trace, clean_setup, seed, base / "clean")
    detected = rec.meta.get("faults_detected", [])
    result = score_faults(list(setup.faults), detected, rec_clean.meta.get("faults_detected", []))
    result = {"setup": setup.name, "seed": seed, "plant_seconds": round(float(trace.duration_s), 2), **result}
    from benchtwin.sensors import devices

    bus_of = {d.poll_device or d.name: d.bus for d in devices(setup)}
    for entry, f in zip(result["faults"], setup.faults):
        entry.update(_flags_in_span(rec, f, bus_of))
    if identify:
        from benchtwin.identification.run import identify_all

        res_clean, res = identify_all(rec_clean, specs, type_b=False), identify_all(rec, specs, type_b=False)
        result["identification"] = {"fits_clean": len(res_clean.fits), "fits_faults": len(res.fits),
                                    "changed": _fit_changes(res_clean, res)}
    if out_dir is not None:
        Path(out_dir, "faults.json").write_text(json.dumps(result, indent=1, default=str), encoding="utf-8")
    return result


def fault_table(result: dict[str, Any]) -> str:
    """The per-kind table of a fault campaign (markdown)."""
    lines = ["| kind | injected | detected | false alarms |", "|---|---|---|---|"]
    for kind, row in result["kinds"].items():
        if row["injected"] or row["false_alarms"]:
            lines.append(f"| {kind} | {row['injected']} | {row['detected']} | {row['false_alarms']} |")
    tot = {k: sum(r[k] for r in result["kinds"].values()) for k in ("injected", "detected", "false_alarms")}
    lines.append(f"| **all** | {tot['injected']} | {tot['detected']} | {tot['false_alarms']} |")
    return "\n".join(lines)
