"""Sweep throughput: validation runs per minute on 1 and 2 local workers, and the Dask path's overhead.

Run with ``.venv/bin/python benchmarks/bench_sweep.py [--campaign quick] [--seeds 2] [--families ...]``.
Prints a Markdown section to append to benchmarks/RESULTS.md.

The sweep: the base vehicle and setup (paper), the campaign given, 2 axes x 2 values
(``setup.telemetry.k_tel`` 500/1000, ``setup.ivt.battery.current_errors.noise_std`` 0.1/0.3) x ``--seeds``
seeds; every run a whole validation (or only ``--families``). The Traces are put into a temporary cache
first (not timed), so the timing is what a sweep costs once its Traces exist. Timed: ``Sweep.run`` into a
fresh folder (worker start-up included, figures off) on a local process pool of 1 and of 2 workers, and
on a dask.distributed LocalCluster of 2 single-threaded worker processes on 127.0.0.1, started before the
timing as an existing cluster would be. The Dask overhead is its wall time against the 2-worker pool's.
Beside the wall time: the median wall of each worker's first run (imports, compilation and warm-up of a
fresh process) and of the later runs (the steady state of a long sweep).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import pandas as pd

from benchtwin.config import load_campaign, load_vehicle, scenario_path
from benchtwin.config.setup import load_setup
from benchtwin.studies.sweep import Sweep
from benchtwin.studies.sweep_file import SweepConfig


def _timed(sweep: Sweep, out: Path, n_workers: int, **kw) -> tuple[float, int, int, float, float]:
    """Wall time, runs done and failed, median wall of a worker's first run and of the later runs."""
    t0 = time.perf_counter()
    o = sweep.run(out, figures=False, **kw)
    wall = time.perf_counter() - t0
    walls = list(pd.read_csv(out / "runs.csv")["wall_s"])  # in the order the runs finished
    first, later = walls[:n_workers], walls[n_workers:] or [float("nan")]
    return wall, o.done, o.failed, statistics.median(first), statistics.median(later)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaign", default="quick", help="shipped campaign name (default quick)")
    ap.add_argument("--seeds", type=int, default=2, help="seeds per point (default 2: 8 runs)")
    ap.add_argument("--families", default=None, help="comma-separated families (default: the whole validation)")
    ap.add_argument("--no-dask", action="store_true", help="skip the Dask measurement")
    args = ap.parse_args()

    vehicle, setup = load_vehicle(), load_setup(scenario_path("setups", "paper.toml"))
    campaign = load_campaign(scenario_path("campaigns", f"{args.campaign}.toml"))
    cfg = SweepConfig(name="bench", campaign=campaign.name, seeds=[campaign.seed + k for k in range(args.seeds)],
                      families=args.families.split(",") if args.families else None,
                      axes={"setup.telemetry.k_tel": [500, 1000],
                            "setup.ivt.battery.current_errors.noise_std": [0.1, 0.3]})
    tmp = Path(tempfile.mkdtemp(prefix="benchtwin-sweep-"))
    sweep = Sweep(cfg, vehicle, setup, campaign, cache_dir=tmp / "cache")
    n = len(sweep.tasks)
    t0 = time.perf_counter()
    simulated = sweep.prefetch(workers=2)  # the Traces, not timed
    t_fill = time.perf_counter() - t0
    load0 = os.getloadavg()[0]
    res = {}
    for w in (1, 2):
        res[f"pool{w}"] = _timed(sweep, tmp / f"pool{w}", w, workers=w)
    if not args.no_dask:
        from distributed import LocalCluster

        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None) as cluster:
            res["dask2"] = _timed(sweep, tmp / "dask2", 2, scheduler=cluster.scheduler_address)
    load1 = os.getloadavg()[0]

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    what = f"families {args.families}" if args.families else "the whole validation"
    print("## Sweep throughput (benchmarks/bench_sweep.py)\n")
    print(f"- date {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, machine {platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}, commit {commit}")
    print(f"- campaign {campaign.name}, setup paper, {n} runs (2 axes x 2 values x {args.seeds} seeds), each {what}; "
          f"{simulated} Traces simulated into the cache first in {t_fill:.1f} s (not timed)\n")
    print("| executor | wall (s) | runs done / failed | runs per minute | a worker's first run (s) | later runs, "
          "median (s) |")
    print("|---|---|---|---|---|---|")
    names = {"pool1": "local pool, 1 worker", "pool2": "local pool, 2 workers",
             "dask2": "Dask LocalCluster, 2 workers (127.0.0.1)"}
    for k, (wall, done, failed, first, later) in res.items():
        print(f"| {names[k]} | {wall:.1f} | {done} / {failed} | {60.0 * n / wall:.1f} | {first:.2f} | {later:.2f} |")
    if "dask2" in res:
        d, p = res["dask2"][0], res["pool2"][0]
        print(f"\n- Dask overhead against the 2-worker pool: {d - p:+.1f} s over {n} runs "
              f"({100 * (d / p - 1):+.0f} %, {(d - p) / n:+.2f} s per run)")
    print(f"- speed-up of 2 workers over 1: {res['pool1'][0] / res['pool2'][0]:.2f}x")
    print(f"- load average {load0:.1f} before, {load1:.1f} after (the machine is shared)")


if __name__ == "__main__":
    main()
