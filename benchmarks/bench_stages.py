"""The identify and predict stages of ``benchtwin validate``: identification with and without the type B
propagation, and the held-out prediction.

Run with ``.venv/bin/python benchmarks/bench_stages.py [--campaign paper] [--setup paper] [--runs 3]
[--cache FILE] [--label TEXT]``. Prints a Markdown table row set to put in benchmarks/RESULTS.md. The paper
campaign needs about 4 GB while its Recording is made: run it through the shared lock
(``flock /tmp/benchtwin-heavy.lock nice -n 5 ...``).

The Trace and the Recording are made as ``validate`` makes them (``simulate_campaign``, then the batch chain with
the campaign's seed), or read from ``--cache`` (a pickle this script wrote before: the same objects, so that a
comparison of two commits times the same input; run one commit with ``PYTHONPATH=<its tree>``). Timed, the median
of ``--runs`` runs of each, wall (``perf_counter``) and CPU of the process (``process_time``, all threads):

- ``identify_all(rec, specs, type_b=False)``: the estimates;
- ``identify_all(rec, specs, type_b=True)``: with the type B budget (``meta['seconds']['type_b']`` is its part);
- the prediction stage of ``validate`` (``benchtwin.validation.run._prediction``: identification without the
  campaign's cycle, the map-based model over it twice, and the further drives, the WLTC from a low SOC and the
  NEDC, each simulated, measured and predicted).

The machine is shared: the load average before and after is printed, and the CPU time is the steadier figure.
"""

from __future__ import annotations

import argparse
import os
import pickle
import platform
import statistics
import subprocess
import time
from pathlib import Path

from benchtwin.config import load_campaign, load_vehicle, scenario_path
from benchtwin.config.setup import load_setup


def _timed(fn, runs: int) -> tuple[float, float, float, object]:
    walls, cpus, out = [], [], None
    for _ in range(runs):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return statistics.median(walls), statistics.median(cpus), max(walls), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaign", default="paper")
    ap.add_argument("--setup", default="paper")
    ap.add_argument("--vehicle", default="p2_phev_9at")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--cache", type=Path, help="pickle of (Trace, Recording): read when present, else written")
    ap.add_argument("--label", default="", help="name of the code timed, for the table (e.g. before/after)")
    args = ap.parse_args()
    import benchtwin
    from benchtwin.identification.run import identify_all
    from benchtwin.validation.report import ValidationReport
    from benchtwin.validation.run import _prediction

    vehicle = load_vehicle(scenario_path("vehicles", f"{args.vehicle}.toml"))
    campaign = load_campaign(scenario_path("campaigns", f"{args.campaign}.toml"))
    setup = load_setup(scenario_path("setups", f"{args.setup}.toml"))
    if args.cache is not None and args.cache.exists():
        with args.cache.open("rb") as f:
            trace, rec = pickle.load(f)
    else:
        from benchtwin.chain.batch import run_batch
        from benchtwin.emulator import simulate_campaign

        trace = simulate_campaign(vehicle, campaign)
        rec = run_batch(trace, setup, seed=campaign.seed)
        if args.cache is not None:
            with args.cache.open("wb") as f:
                pickle.dump((trace, rec), f, protocol=5)
    identify_all(rec, vehicle.specs, type_b=False)  # warm-up (imports, compiled kernels)
    load0 = os.getloadavg()[0]
    plain = _timed(lambda: identify_all(rec, vehicle.specs, type_b=False), args.runs)
    with_b = _timed(lambda: identify_all(rec, vehicle.specs, type_b=True), args.runs)

    def predict() -> int:
        return len(_prediction(ValidationReport(meta={}), vehicle, setup, campaign, trace, rec, "realistic"))

    pred = _timed(predict, args.runs)
    load1 = os.getloadavg()[0]
    res = with_b[3]
    try:
        rev = subprocess.run(["git", "-C", str(Path(benchtwin.__file__).parent), "rev-parse", "--short", "HEAD"],
                             capture_output=True, text=True, check=False).stdout.strip()
    except OSError:
        rev = "?"
    print(f"- {args.label or 'run'}: benchtwin from {Path(benchtwin.__file__).parent} (commit {rev or '?'}), "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}; campaign {args.campaign} ({trace.duration_s:,.0f} s), setup "
          f"{args.setup}; median of {args.runs}; load average {load0:.1f} / {load1:.1f}; type B re-runs "
          f"{res.meta['type_b'].get('reruns')}; prediction checks {pred[3]}")
    print("")
    print("| code | identify, no type B: wall / CPU (s) | identify with type B: wall / CPU (s) | of which type B "
          "(s) | predict: wall / CPU (s) |")
    print("|---|---|---|---|---|")
    print(f"| {args.label or rev} | {plain[0]:.2f} / {plain[1]:.2f} | {with_b[0]:.2f} / {with_b[1]:.2f} | "
          f"{res.meta['seconds']['type_b']:.2f} | {pred[0]:.2f} / {pred[1]:.2f} |")


if __name__ == "__main__":
    main()
