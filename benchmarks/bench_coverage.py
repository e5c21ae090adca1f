"""Coverage of the reported 95 % intervals: how often the truth lies inside them, per parameter family.

Run with ``.venv/bin/python benchmarks/bench_coverage.py [--campaigns quick,paper] [--setups ideal,paper]``.
Prints a Markdown section to append to benchmarks/RESULTS.md.

For each campaign and setup: one whole validation (the Trace from the disk cache, ``--cache``), then, per
parameter family, the share of its scalar parameters whose statistical interval (``ci95``, the fit's scatter)
and whose total interval (``ci95_total``, with the setup's declared systematic uncertainties, GUM type B)
hold the truth (the shift lines: c0 and c1 against the vehicle file's v0 and slope). Parameters a run could
not identify, or flagged, are not counted.
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import time

from benchtwin.config import load_campaign, load_vehicle, scenario_path
from benchtwin.config.setup import load_setup
from benchtwin.validation.coverage import coverage_by_family, interval_coverage, shift_line_coverage
from benchtwin.validation.run import validate


def _pct(k: int, n: int) -> str:
    return f"{k}/{n} ({100.0 * k / n:.0f} %)" if n else "-"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaigns", default="quick,paper", help="comma-separated campaigns (default quick,paper)")
    ap.add_argument("--setups", default="ideal,paper", help="comma-separated shipped setups (default ideal,paper)")
    ap.add_argument("--vehicle", default=None, help="vehicle file (default: the shipped p2_phev_9at)")
    ap.add_argument("--cache", default=None, help="Trace cache directory (default: $BENCHTWIN_CACHE or ~/.cache)")
    ap.add_argument("--misses", action="store_true", help="also list the parameters whose total interval misses")
    args = ap.parse_args()

    vehicle = load_vehicle(args.vehicle) if args.vehicle else load_vehicle()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    print("## Coverage of the 95 % intervals (benchmarks/bench_coverage.py)\n")
    print(f"- date {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, machine {platform.machine()}, "
          f"commit {commit}, vehicle {vehicle.name}")
    print("- cells: truth inside the interval / scalar parameters identified; stat = ci95 (fit scatter), "
          "total = ci95_total (plus the setup's declared systematics)\n")
    table: dict[tuple[str, str], dict[str, dict[str, int]]] = {}
    misses: list[str] = []
    for camp in args.campaigns.split(","):
        campaign = load_campaign(scenario_path("campaigns", f"{camp}.toml"))
        for st in args.setups.split(","):
            setup = load_setup(scenario_path("setups", f"{st}.toml"))
            rep = validate(vehicle, setup, campaign, cache=args.cache or True)
            rows = interval_coverage(rep.identification, vehicle) + shift_line_coverage(rep.identification, vehicle)
            table[(camp, st)] = coverage_by_family(rows)
            failed = [c.name for c in rep.checks if not c.passed]
            misses += [f"{camp}/{st}: {r.key} value {r.value:.6g} truth {r.truth:.6g} u_stat {r.u_stat:.3g} "
                       f"u_total {r.u_total:.3g}" for r in rows if not r.inside_total]
            sec = rep.identification.meta.get("seconds", {})
            tb = rep.identification.meta.get("type_b", {})
            print(f"- {camp}/{st}: {len(rep.checks)} checks, failed: {', '.join(failed) or 'none'}; identify "
                  f"{rep.timings_s.get('identify', float('nan')):.2f} s wall, of which type B "
                  f"{sec.get('type_b', 0.0):.2f} s ({tb.get('reruns', 0)} re-runs)")
    fams = [*sorted({f for d in table.values() for f in d if f != "all"}), "all"]
    cols = list(table)
    print("\n| family | " + " | ".join(f"{c}/{s} stat | {c}/{s} total" for c, s in cols) + " |")
    print("|---|" + "---|---|" * len(cols))
    for f in fams:
        cells = []
        for c in cols:
            d = table[c].get(f, {"n": 0, "inside_stat": 0, "inside_total": 0})
            cells += [_pct(d["inside_stat"], d["n"]), _pct(d["inside_total"], d["n"])]
        print(f"| {f} | " + " | ".join(cells) + " |")
    if args.misses and misses:
        print("\nTotal interval misses:\n")
        print("\n".join(f"- {m}" for m in misses))


if __name__ == "__main__":
    main()
