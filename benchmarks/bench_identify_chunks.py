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

import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _repeated import chunked_recording, size_arguments

from benchtwin.identification.run import identify_all


def measure(n: int, campaign: str, setup: str, vehicle_name: str) -> tuple[dict[str, float], dict]:
    """Seconds of ``identify_all`` (type B on) on the campaign repeated ``n`` times, and the fits."""
    with tempfile.TemporaryDirectory() as tmp:
        vehicle, rec = chunked_recording(n, Path(tmp), campaign, setup, vehicle_name)
        load0 = os.getloadavg()[0]
        w0, c0 = time.perf_counter(), time.process_time()
        res = identify_all(rec, vehicle.specs, type_b=True)
        out = {"wall_s": time.perf_counter() - w0, "cpu_s": time.process_time() - c0, "load_before": load0,
               "load_after": os.getloadavg()[0]}
        fits = {k: f.to_dict() for k, f in res.fits.items()}
        rec.close()
    return out, fits


def main() -> None:
    args = size_arguments(__doc__, "paper", "also write the times and every fit as JSON")
    results = {}
    print("| campaign | identify wall (s) | identify CPU (s) | load before / after |")
    print("|---|---|---|---|")
    for n in args.sizes:
        t, fits = measure(n, args.campaign, args.setup, args.vehicle)
        results[n] = {"times": t, "fits": fits}
        print(f"| {args.campaign} x{n} | {t['wall_s']:.1f} | {t['cpu_s']:.1f} | "
              f"{t['load_before']:.1f} / {t['load_after']:.1f} |", flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=0, default=str))


if __name__ == "__main__":
    main()
