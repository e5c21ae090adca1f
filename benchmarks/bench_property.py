"""The cost of one property example per identification family (tests/properties).

Run with ``.venv/bin/python benchmarks/bench_property.py [--runs 3] [--families transmission,battery]``.
Prints a Markdown section to append to benchmarks/RESULTS.md.

One example, as tests/properties/test_recovery.py runs it: the paper campaign's tests of the family moved to
the vehicle (``strategies.campaign_for`` with the family's ``FAMILY_PICKS``), simulated, then
``validate(..., trace=..., families=[f], profile="realistic")`` on the paper setup. Timed on the two shipped
vehicles (the cost follows the seconds of tests, not the vehicle), the median of ``--runs`` runs each, after
one warm-up example (numba and imports). ``--whole-bench`` times the same with every device of the setup
kept (the family runs before they carried only the devices the family reads); ``--chain-checks``,
``--per-test-chunks`` and ``--all-messages`` put back, one at a time, what the examples no longer do (the chain
checks, a chunk per test, the vehicle-CAN messages the family does not read).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "properties"))

import strategies

import benchtwin.validation.families as families
import benchtwin.validation.run as run
from benchtwin.config import load_vehicle, scenario_path
from benchtwin.emulator import simulate_campaign
from benchtwin.validation.families import FAMILIES


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="timed runs per family and vehicle (default 3)")
    ap.add_argument("--families", default=",".join(FAMILIES), help="comma-separated families (default: all)")
    ap.add_argument("--whole-bench", action="store_true", help="keep every device of the setup in family runs")
    ap.add_argument("--chain-checks", action="store_true",
                    help="also make the chain checks (the properties leave them out: chain_checks=False)")
    ap.add_argument("--per-test-chunks", action="store_true",
                    help="feed the chain one test at a time (as family runs did before FAMILY_CHUNK_S)")
    ap.add_argument("--all-messages", action="store_true",
                    help="send every vehicle-CAN message in family runs (as before they sent only the read ones)")
    args = ap.parse_args()
    if args.per_test_chunks:
        run.FAMILY_CHUNK_S = None  # type: ignore[assignment]
    if args.all_messages:
        _setup = families.family_setup

        def _all_messages(setup: object, roles: object) -> object:
            bench = _setup(setup, roles)
            if bench.vehicle_can is None:
                return bench
            return bench.model_copy(update={"vehicle_can": bench.vehicle_can.model_copy(update={"not_recorded": []})})

        run.family_setup = _all_messages  # type: ignore[assignment]
    if args.whole_bench:
        run.family_setup = lambda setup, roles: setup  # type: ignore[assignment]

    vehicles = [load_vehicle(), load_vehicle(scenario_path("vehicles", "p2_phev_alt.toml"))]
    setup = strategies.PAPER_SETUP

    def example(family: str, vehicle: object, seed: int) -> tuple[float, float, float, dict[str, float]]:
        w0, c0 = time.perf_counter(), time.process_time()
        camp = strategies.campaign_for(vehicle, FAMILIES[family].kinds, seed=seed,
                                       **strategies.FAMILY_PICKS.get(family, {}))
        trace = simulate_campaign(vehicle, camp)
        t_sim = time.perf_counter() - w0
        rep = run.validate(vehicle, setup, camp, trace=trace, families=[family], profile="realistic",
                           chain_checks=args.chain_checks)
        return time.perf_counter() - w0, time.process_time() - c0, trace.duration_s, {**rep.timings_s,
                                                                                       "simulate": t_sim}

    example("battery", vehicles[0], 1)  # warm-up: numba functions loaded, modules imported
    load0 = os.getloadavg()[0]
    rows = []
    for name in args.families.split(","):
        walls, cpus, parts, plant = [], [], [], []
        for v in vehicles:
            for k in range(args.runs):
                w, c, d, p = example(name, v, 100 + k)
                walls.append(w)
                cpus.append(c)
                parts.append(p)
                plant.append(d)
        med = {k: statistics.median(p[k] for p in parts) for k in ("simulate", "chain", "identify")}
        rows.append((name, statistics.median(plant), statistics.median(walls), min(walls), max(walls),
                     statistics.median(cpus), med))
    load1 = os.getloadavg()[0]

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    print("## One property example per family (benchmarks/bench_property.py)\n")
    print(f"- date {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, machine {platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}, commit {commit}")
    put_back = [f for f, on in (("whole bench in family runs", args.whole_bench), ("chain checks", args.chain_checks),
                                ("a chunk per test", args.per_test_chunks),
                                ("every vehicle-CAN message", args.all_messages)) if on]
    print(f"- setup paper{' (' + ', '.join(put_back) + ')' if put_back else ''}; vehicles p2_phev_9at "
          f"and p2_phev_alt, {args.runs} runs each (seeds 100..); after one warm-up example\n")
    print("| family | tests (s of plant) | wall median (s) | min..max (s) | CPU median (s) | simulate / chain / "
          "identify (s) |")
    print("|---|---|---|---|---|---|")
    for name, plant, med, lo, hi, cpu, part in rows:
        print(f"| {name} | {plant:.0f} | {med:.2f} | {lo:.2f}..{hi:.2f} | {cpu:.2f} | "
              f"{part['simulate']:.2f} / {part['chain']:.2f} / {part['identify']:.2f} |")
    print(f"\n- load average {load0:.1f} before, {load1:.1f} after")


if __name__ == "__main__":
    main()
