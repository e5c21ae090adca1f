"""The fault campaign: every fault kind of the setup injected, detected and false alarms per kind.

Usage::

    python benchmarks/bench_faults.py [--setup faults] [--campaign quick.toml] [--trace DIR] [--no-identify]
                                      [--append-results]

Simulates the campaign (or loads ``--trace``; the simulated Trace is cached there if the folder does not
hold one), runs the batch chain with the setup's ``[[faults]]`` and again without them
(:func:`benchtwin.validation.faults.fault_campaign`, raw logs written and read back), and prints per kind
the faults injected, detected and the false alarms (detections matching no injected fault plus every
detection of the clean run), the fits identification lost or changed, and the time of each part.
``--append-results`` appends the section to ``benchmarks/RESULTS.md``.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchtwin.config import load_setup
from benchtwin.config.campaign import load_campaign
from benchtwin.config.vehicle import load_vehicle
from benchtwin.trace import Trace
from benchtwin.validation.faults import fault_campaign, fault_table


def main(argv: list[str] | None = None) -> int:
    """Run the fault campaign and print (and optionally record) the table."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n", 1)[0], epilog=__doc__.split("\n\n", 1)[1],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--setup", default="faults", help="setup with [[faults]] (default: the shipped faults)")
    p.add_argument("--campaign", default="quick.toml", help="campaign (default: quick.toml)")
    p.add_argument("--trace", type=Path, default=None, help="Trace folder (cache of the simulated campaign)")
    p.add_argument("--no-identify", action="store_true", help="skip identification of both runs")
    p.add_argument("--append-results", action="store_true", help="append the section to benchmarks/RESULTS.md")
    args = p.parse_args(argv)
    setup = load_setup(args.setup)
    vehicle = load_vehicle()
    campaign = load_campaign(args.campaign)
    t0 = time.perf_counter()
    if args.trace is not None and (args.trace / "trace.mf4").exists():
        trace = Trace.load(args.trace)
    else:
        from benchtwin.emulator import simulate_campaign

        trace = simulate_campaign(vehicle, campaign)
        if args.trace is not None:
            trace.save(args.trace)
    t1 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        result = fault_campaign(trace, setup, seed=campaign.seed, out_dir=tmp, specs=vehicle.specs,
                                identify=not args.no_identify)
    t2 = time.perf_counter()
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).parent, check=False).stdout.strip()
    except OSError:
        commit = "?"
    lines = [
        "## Fault campaign (benchmarks/bench_faults.py)",
        "",
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, machine {platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}, commit {commit}",
        f"- setup {setup.name} ({len(setup.faults)} faults), campaign {campaign.name}: {trace.duration_s:.0f} s "
        f"simulated (trace {t1 - t0:.1f} s), faulted + clean chain runs with raw logs"
        f"{'' if args.no_identify else ' and identification of both'}: {t2 - t1:.1f} s",
        "",
        fault_table(result),
        "",
    ]
    for f in result["faults"]:
        spans = ", ".join(f"{a:.1f}..{b:.1f}" for a, b in f["spans"]) or "none"
        end = "end" if f["end_s"] is None else f"{f['end_s']:.1f}"
        lines.append(f"- {f['kind']} on {f['target']}{'/' + f['channel'] if f['channel'] else ''} "
                     f"{f['start_s']:.1f}..{end} s: detected {spans}; flags {'|'.join(f['flags']) or '-'}"
                     f"{'' if f['identification_safe'] else ' (NOT kept out of identification)'}")
    ident = result.get("identification")
    if ident:
        lines.append(f"- identification: {ident['fits_clean']} fits clean, {ident['fits_faults']} with faults; "
                     "changed: " + ("; ".join(
                         f"{c['fit']} {c.get('clean')} -> {c.get('faults')}"
                         + (f" ({c['points_clean']} -> {c['points_faults']} points)" if "points_clean" in c else "")
                         for c in ident["changed"]) or "none"))
    text = "\n".join(lines)
    print(text)
    if args.append_results:
        res = Path(__file__).with_name("RESULTS.md")
        res.write_text(res.read_text(encoding="utf-8").rstrip("\n") + "\n\n" + text + "\n", encoding="utf-8")
    tot = result["kinds"].values()
    return 0 if all(r["detected"] == r["injected"] and not r["false_alarms"] for r in tot) else 1


if __name__ == "__main__":
    sys.exit(main())
