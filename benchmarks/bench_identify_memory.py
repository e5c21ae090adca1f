"""Peak traced allocation of each identification method on a Recording read from the acquisition's chunk files, for
a campaign repeated 1x and 3x (which methods grow with the campaign).

Usage::

    python benchmarks/bench_identify_memory.py [--sizes 1,3] [--campaign quick] [--setup paper] [--json FILE]

Per size, the campaign's tests are written that many times (as ``bench_stream.py`` does), simulated, run through the
chain test by test with the Recording kept in the acquisition's raw chunk files (``run_chunked(...,
keep_chunks=True)``, what ``validate --out`` identifies from), and each default method is run on its own (type B
off; ``torque_converter`` after ``transmission``, whose result it reads) under ``tracemalloc``: the peak of traced
allocations during the method beyond what was allocated before it, MB. The Recording's channels are dropped after
each method. A method whose peak at 3x is about 3x its peak at 1x holds something as long as the campaign; one
bounded by a test's worth of data stays flat. To measure another tree, run this script with ``PYTHONPATH`` set to it.
About 1 min per size on the quick campaign.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_stream import repeated_campaign

from benchtwin.chain.stream import run_chunked, trace_pieces
from benchtwin.config._base import scenario_path
from benchtwin.config.campaign import load_campaign
from benchtwin.config.setup import load_setup
from benchtwin.config.vehicle import load_vehicle
from benchtwin.emulator import simulate_campaign
from benchtwin.identification.run import DEFAULT_METHODS, METHODS, IdentificationResult, _run_method


def measure(n: int, campaign: str, setup: str, vehicle_name: str) -> dict[str, float]:
    """Method -> peak traced MB on the campaign repeated ``n`` times."""
    vehicle = load_vehicle(scenario_path("vehicles", f"{vehicle_name}.toml"))
    with tempfile.TemporaryDirectory() as tmp:
        camp = repeated_campaign(n, Path(tmp), scenario_path("campaigns", f"{campaign}.toml"))
        trace = simulate_campaign(vehicle, load_campaign(camp))
        rec = run_chunked(trace_pieces(trace), load_setup(setup), seed=1, keep_chunks=True)
        del trace
        known = {m.name: m for m in METHODS}
        res = IdentificationResult(meta={"ran": [], "skipped": {}, "seconds": {}})
        out: dict[str, float] = {}
        tracemalloc.start()
        try:
            for name in DEFAULT_METHODS:
                if name == "torque_converter" and "transmission" not in res.meta["ran"]:
                    _run_method(known["transmission"], rec, vehicle.specs, res, {})
                    rec.drop()
                tracemalloc.reset_peak()
                base = tracemalloc.get_traced_memory()[0]
                _run_method(known[name], rec, vehicle.specs, res, {})
                out[name] = round((tracemalloc.get_traced_memory()[1] - base) / 1e6, 1)
                rec.drop()
        finally:
            tracemalloc.stop()
            rec.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="1,3", help="campaign repeats (default 1,3)")
    ap.add_argument("--campaign", default="quick", help="shipped campaign name (default quick)")
    ap.add_argument("--setup", default="paper", help="shipped setup name (default paper)")
    ap.add_argument("--vehicle", default="p2_phev_9at", help="shipped vehicle name")
    ap.add_argument("--json", type=Path, help="also write the results as JSON")
    args = ap.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    results = {n: measure(n, args.campaign, args.setup, args.vehicle) for n in sizes}
    methods = list(next(iter(results.values())))
    print("| method | " + " | ".join(f"{args.campaign} x{n} (MB)" for n in sizes) + " |")
    print("|---|" + "---|" * len(sizes))
    for m in methods:
        print(f"| {m} | " + " | ".join(f"{results[n][m]:.1f}" for n in sizes) + " |")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
