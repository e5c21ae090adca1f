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

import json
import sys
import tempfile
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _repeated import chunked_recording, size_arguments

from benchtwin.identification.run import DEFAULT_METHODS, METHODS, IdentificationResult, _run_method


def measure(n: int, campaign: str, setup: str, vehicle_name: str) -> dict[str, float]:
    """Method -> peak traced MB on the campaign repeated ``n`` times."""
    with tempfile.TemporaryDirectory() as tmp:
        vehicle, rec = chunked_recording(n, Path(tmp), campaign, setup, vehicle_name)
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
    args = size_arguments(__doc__, "quick", "also write the results as JSON")
    sizes = args.sizes
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
