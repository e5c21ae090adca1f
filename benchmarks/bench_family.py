"""The fast inner loop: one identification family on a cached Trace (sensors -> chain -> identification).

Run with ``.venv/bin/python benchmarks/bench_family.py [--campaign paper] [--setup paper] [--runs 3]``.
Prints a Markdown section to append to benchmarks/RESULTS.md.

The campaign's Trace is taken from the disk cache (simulated once into it when missing; that time is
printed, not part of the timing). Timed per family: ``validate(..., families=[name], cache=...)`` with the
Trace loaded from the cache each time, i.e. cache load + the chain over the family's tests + its
identification + its checks, the median of ``--runs`` runs; beside it one whole validation on the same
cached Trace. CPU time of the process is printed beside the wall time: the machine may be shared.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import tempfile
import time

from benchtwin.config import load_campaign, load_vehicle, scenario_path
from benchtwin.config.setup import load_setup
from benchtwin.emulator.cache import cached_campaign
from benchtwin.validation.families import FAMILIES, family_spans
from benchtwin.validation.run import validate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaign", default="paper", help="shipped campaign name (default paper)")
    ap.add_argument("--setup", default="paper", help="shipped setup name (default paper)")
    ap.add_argument("--runs", type=int, default=3, help="timed runs per family (default 3)")
    ap.add_argument("--cache", default=None, help="Trace cache directory (default: a temporary one)")
    ap.add_argument("--families", default=",".join(FAMILIES), help="comma-separated families (default: all)")
    args = ap.parse_args()

    vehicle = load_vehicle()
    setup = load_setup(scenario_path("setups", f"{args.setup}.toml"))
    campaign = load_campaign(scenario_path("campaigns", f"{args.campaign}.toml"))
    cache = args.cache or tempfile.mkdtemp(prefix="benchtwin-traces-")
    t0 = time.perf_counter()
    trace, hit = cached_campaign(vehicle, campaign, directory=cache)
    t_fill = time.perf_counter() - t0
    t0 = time.perf_counter()
    cached_campaign(vehicle, campaign, directory=cache)
    t_load = time.perf_counter() - t0
    load0 = os.getloadavg()[0]
    rows = []
    for name in args.families.split(","):
        fam = FAMILIES[name]
        spans = family_spans(trace.segments, fam.kinds)
        covered = sum(b - a for a, b in spans)
        walls, cpus, parts = [], [], []
        for _ in range(args.runs):
            w0, c0 = time.perf_counter(), time.process_time()
            rep = validate(vehicle, setup, campaign, families=[name], cache=cache)
            walls.append(time.perf_counter() - w0)
            cpus.append(time.process_time() - c0)
            parts.append(rep.timings_s)
        med = {k: statistics.median(p[k] for p in parts) for k in parts[0]}
        rows.append((name, len(spans), covered, statistics.median(walls), min(walls), max(walls),
                     statistics.median(cpus), med, len(rep.checks), len(rep.failures())))
    w0 = time.perf_counter()
    full = validate(vehicle, setup, campaign, cache=cache)
    t_full = time.perf_counter() - w0
    load1 = os.getloadavg()[0]

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    print("## One identification family on a cached Trace (benchmarks/bench_family.py)\n")
    print(f"- date {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, machine {platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}, commit {commit}")
    print(f"- campaign {campaign.name}: {trace.duration_s:.0f} s of tests; setup {setup.name}; Trace "
          f"{'from the cache' if hit else f'simulated into the cache in {t_fill:.1f} s'}, loaded from it in "
          f"{t_load:.2f} s")
    print(f"- timing: median of {args.runs} runs of validate(..., families=[f], cache=...) "
          f"(cache load + chain over the family's tests + identification + checks)\n")
    print("| family | spans | tests covered (s) | wall median (s) | min..max (s) | CPU median (s) | load / chain / "
          "identify (s) | checks (failed) |")
    print("|---|---|---|---|---|---|---|---|")
    for name, n_sp, cov, med, lo, hi, cpu, part, n_chk, n_fail in rows:
        print(f"| {name} | {n_sp} | {cov:.0f} | {med:.2f} | {lo:.2f}..{hi:.2f} | {cpu:.2f} | "
              f"{part['simulate']:.2f} / {part['chain']:.2f} / {part['identify']:.2f} | {n_chk} ({n_fail}) |")
    print(f"\n- the whole validation on the same cached Trace: {t_full:.1f} s (load / chain / identify "
          f"{full.timings_s['simulate']:.2f} / {full.timings_s['chain']:.2f} / {full.timings_s['identify']:.2f} s), "
          f"{len(full.checks)} checks")
    print(f"- load average {load0:.1f} before, {load1:.1f} after")


if __name__ == "__main__":
    main()
