"""Peak traced allocation of each type B component's re-runs on a Recording read from the acquisition's chunk files,
for a campaign repeated 1x and 3x (which re-runs grow with the campaign).

Usage::

    python benchmarks/bench_type_b_memory.py [--sizes 1,3] [--campaign quick] [--setup paper] [--json FILE]

Per size, the campaign's tests are written that many times (as ``bench_stream.py`` does), simulated, run through the
chain test by test with the Recording kept in the acquisition's raw chunk files (``run_chunked(...,
keep_chunks=True)``, what ``validate --out`` identifies from), identified without type B, and then the re-runs of
every (method, component) pair of :func:`~benchtwin.identification.uncertainty.propagate_type_b` are run one pair at a
time under ``tracemalloc``: the peak of traced allocations beyond what was allocated before the pair, MB (the
Recording's channels dropped after each pair). A row whose peak at 3x is about 3x its peak at 1x holds something as
long as the campaign. The table lists, per method, the largest gain/offset pair and the resolution pair. To measure
another tree, run this script with ``PYTHONPATH`` set to it. About 1-2 min per size on the quick campaign.
"""

from __future__ import annotations

import json
import sys
import tempfile
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _repeated import chunked_recording, size_arguments

from benchtwin.identification.run import METHODS, _reads, _rerun, identify_all
from benchtwin.identification.uncertainty import _propagate_one, components


def measure(n: int, campaign: str, setup: str, vehicle_name: str) -> dict[str, float]:
    """``method / kind`` -> peak traced MB of that component's re-runs on the campaign repeated ``n`` times."""
    with tempfile.TemporaryDirectory() as tmp:
        vehicle, rec = chunked_recording(n, Path(tmp), campaign, setup, vehicle_name)
        result = identify_all(rec, vehicle.specs, type_b=False)
        rec.drop()
        out: dict[str, float] = {}
        tracemalloc.start()
        try:
            for m in METHODS:
                fits = sorted(k for k in result.fits if k == m.name or k.startswith(m.name + "."))
                nominal = {f"{fk}.{pk}": p for fk in fits for pk, p in result.fits[fk].params.items()}
                if not nominal:
                    continue
                run = _rerun(m.name, vehicle.specs, {})
                for comp in components(rec, _reads(m.name)):
                    tracemalloc.reset_peak()
                    base = tracemalloc.get_traced_memory()[0]
                    _propagate_one(rec, (fits, nominal, comp, run))
                    peak = round((tracemalloc.get_traced_memory()[1] - base) / 1e6, 1)
                    key = f"{m.name} / {'resolution' if comp.kind == 'resolution' else 'gain or offset (max)'}"
                    out[key] = max(out.get(key, 0.0), peak)
                    rec.drop()
        finally:
            tracemalloc.stop()
            rec.close()
    return out


def main() -> None:
    args = size_arguments(__doc__, "quick", "also write the results as JSON")
    sizes = args.sizes
    results = {n: measure(n, args.campaign, args.setup, args.vehicle) for n in sizes}
    rows = list(next(iter(results.values())))
    print("| method / component | " + " | ".join(f"{args.campaign} x{n} (MB)" for n in sizes) + " |")
    print("|---|" + "---|" * len(sizes))
    for r in rows:
        print(f"| {r} | " + " | ".join(f"{results[n].get(r, float('nan')):.1f}" for n in sizes) + " |")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
