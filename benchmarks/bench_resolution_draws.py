"""The resolution term's Monte Carlo draws: coverage, the term's spread and the identify stage's cost against N.

Run with ``.venv/bin/python benchmarks/bench_resolution_draws.py [--campaign paper] [--setups ideal,paper]
[--draws 6,24,60] [--cache DIR]``, through the shared lock on a shared machine (``flock /tmp/benchtwin-heavy.lock
nice -n 5 ...``): the paper campaign's Recording needs about 4 GB while it is made. Prints Markdown rows for
benchmarks/RESULTS.md.

Per setup the Recording is made as ``validate`` makes it (the Trace from the disk cache, the batch chain with the
campaign's seed), then ``identify_all(rec, specs, type_b=True)`` is timed once per N with
``uncertainty.RESOLUTION_DRAWS = N`` (the draws of every method's resolution component), and the coverage cells of
``bench_coverage.py`` (``interval_coverage``) are counted. The last N is the reference of the spread: per parameter
with a resolution term, the term at each other N over the term at the last N (median and sd), and the total
interval's half-width likewise. The draws come from one seed, so a smaller N's draws are the first of a larger N's.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import time

import numpy as np

from benchtwin.config import load_campaign, load_vehicle, scenario_path
from benchtwin.config.setup import load_setup


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaign", default="paper")
    ap.add_argument("--setups", default="ideal,paper", help="comma-separated shipped setups")
    ap.add_argument("--draws", default="6,24,60", help="comma-separated draw counts; the last is the reference")
    ap.add_argument("--vehicle", default="p2_phev_9at")
    ap.add_argument("--cache", default=None, help="Trace cache directory (default: $BENCHTWIN_CACHE or ~/.cache)")
    args = ap.parse_args()
    from benchtwin.chain.batch import run_batch
    from benchtwin.emulator.cache import cached_campaign
    from benchtwin.identification import uncertainty
    from benchtwin.identification.run import identify_all
    from benchtwin.validation.coverage import coverage_by_family, interval_coverage

    draws = [int(n) for n in args.draws.split(",")]
    vehicle = load_vehicle(scenario_path("vehicles", f"{args.vehicle}.toml"))
    campaign = load_campaign(scenario_path("campaigns", f"{args.campaign}.toml"))
    trace, _hit = cached_campaign(vehicle, campaign, directory=args.cache)
    print(f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}; campaign {args.campaign}; load average {os.getloadavg()[0]:.1f}\n")
    print("| setup | N | identify wall / CPU (s) | of which type B (s) | re-runs | total inside | misses |")
    print("|---|---|---|---|---|---|---|")
    spreads = []
    for name in args.setups.split(","):
        rec = run_batch(trace, load_setup(scenario_path("setups", f"{name}.toml")), seed=campaign.seed)
        identify_all(rec, vehicle.specs, type_b=False)  # warm-up (compiled kernels)
        terms: dict[int, dict[str, tuple[float, float]]] = {}
        for n in draws:
            uncertainty.RESOLUTION_DRAWS = n
            t0, c0 = time.perf_counter(), time.process_time()
            res = identify_all(rec, vehicle.specs, type_b=True)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            rows = interval_coverage(res, vehicle)
            cell = coverage_by_family(rows)["all"]
            misses = ", ".join(f"{r.key} (u {r.u_total:.3g})" for r in rows if not r.inside_total) or "-"
            print(f"| {name} | {n} | {wall:.1f} / {cpu:.1f} | {res.meta['seconds']['type_b']:.1f} | "
                  f"{res.meta['type_b']['reruns']} | {cell['inside_total']}/{cell['n']} | {misses} |", flush=True)
            terms[n] = {k: (p.type_b.get("resolution", 0.0), 0.5 * (p.ci95_total[1] - p.ci95_total[0]))
                        for k, p in res.parameters().items()
                        if p.ci95_total is not None and math.isfinite(p.ci95_total[0])}
        ref = terms[draws[-1]]
        for n in draws[:-1]:
            keys = [k for k in ref if ref[k][0] > 0 and terms[n].get(k, (0.0, 0.0))[0] > 0]
            r = np.array([terms[n][k][0] / ref[k][0] for k in keys])
            w = np.array([terms[n][k][1] / ref[k][1] for k in keys])
            spreads.append(f"- {name}, N {n} against {draws[-1]}: {len(keys)} parameters; resolution term ratio median "
                           f"{statistics.median(r):.3f}, sd {r.std():.3f}; total half-width ratio median "
                           f"{statistics.median(w):.3f}, mean {w.mean():.3f}")
        del rec
    uncertainty.RESOLUTION_DRAWS = 6
    print("\n" + "\n".join(spreads))


if __name__ == "__main__":
    main()
