"""Identification time on the Recording ``validate --out`` identifies from: the acquisition's chunk files.

Usage::

    python benchmarks/bench_identify_chunks.py [--sizes 1,3] [--campaign paper] [--setup paper] [--json FILE]

Per size, the campaign's tests are written that many times (as ``bench_stream.py`` does), simulated and run through
the chain test by test with the Recording kept in the acquisition's raw chunk files (``run_chunked(...,
keep_chunks=True)``); then :func:`~benchtwin.identification.run.identify_all` with the type B propagation (what
``validate`` runs) is timed once: wall and CPU seconds (``time.process_time``, all threads) and the load average.
``--json`` also writes every fit (``FitResult.to_dict``) to compare two trees' estimates. To measure another tree,
run this script with ``PYTHONPATH`` set to it. The paper campaign needs the shared heavy lock (about 4 GB at 3x).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_stream import repeated_campaign

from benchtwin.chain.stream import run_chunked, trace_pieces
from benchtwin.config._base import scenario_path
from benchtwin.config.campaign import load_campaign
from benchtwin.config.setup import load_setup
from benchtwin.config.vehicle import load_vehicle
from benchtwin.emulator import simulate_campaign
from benchtwin.identification.run import identify_all


def measure(n: int, campaign: str, setup: str, vehicle_name: str) -> tuple[dict[str, float], dict]:
    """Seconds of ``identify_all`` (type B on) on the campaign repeated ``n`` times, and the fits."""
    vehicle = load_vehicle(scenario_path("vehicles", f"{vehicle_name}.toml"))
    with tempfile.TemporaryDirectory() as tmp:
        camp = repeated_campaign(n, Path(tmp), scenario_path("campaigns", f"{campaign}.toml"))
        trace = simulate_campaign(vehicle, load_campaign(camp))
        rec = run_chunked(trace_pieces(trace), load_setup(setup), seed=1, keep_chunks=True)
        del trace
        load0 = os.getloadavg()[0]
        w0, c0 = time.perf_counter(), time.process_time()
        res = identify_all(rec, vehicle.specs, type_b=True)
        out = {"wall_s": time.perf_counter() - w0, "cpu_s": time.process_time() - c0, "load_before": load0,
               "load_after": os.getloadavg()[0]}
        fits = {k: f.to_dict() for k, f in res.fits.items()}
        rec.close()
    return out, fits


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="1,3", help="campaign repeats (default 1,3)")
    ap.add_argument("--campaign", default="paper", help="shipped campaign name (default paper)")
    ap.add_argument("--setup", default="paper", help="shipped setup name (default paper)")
    ap.add_argument("--vehicle", default="p2_phev_9at", help="shipped vehicle name")
    ap.add_argument("--json", type=Path, help="also write the times and every fit as JSON")
    args = ap.parse_args()
    results = {}
    print("| campaign | identify wall (s) | identify CPU (s) | load before / after |")
    print("|---|---|---|---|")
    for n in (int(s) for s in args.sizes.split(",")):
        t, fits = measure(n, args.campaign, args.setup, args.vehicle)
        results[n] = {"times": t, "fits": fits}
        print(f"| {args.campaign} x{n} | {t['wall_s']:.1f} | {t['cpu_s']:.1f} | "
              f"{t['load_before']:.1f} / {t['load_after']:.1f} |", flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=0, default=str))


if __name__ == "__main__":
    main()
