"""Cost of rewriting a sweep's runs.parquet after each finished run (``benchtwin.studies.sweep.write_parquet``).

Run with ``.venv/bin/python benchmarks/bench_sweep_parquet.py [--rows 100,1000] [--figures 400] [--repeat 5]``.
Prints a Markdown table to add to benchmarks/RESULTS.md.

A sweep rewrites runs.parquet whole from runs.csv after every run (a Parquet file is readable only once its
footer is written, so an appending writer would leave nothing readable after a kill). This times that
rewrite on a synthetic runs.csv of N rows with F figures each (half ``value:``, a quarter each ``error:`` and
``pass:``, as a validation's row), the median of ``--repeat`` calls: the overhead per run at that sweep size,
to be set against a run's own seconds.
"""

from __future__ import annotations

import argparse
import csv
import json
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from benchtwin.studies.sweep import write_parquet

HEADER = ["run_key", "index", "seed", "vehicle", "status", "error", "passed", "n_checks", "n_failed",
          "trace_cached", "wall_s", "figures"]


def make_csv(folder: Path, rows: int, figures: int, seed: int = 0) -> None:
    """A runs.csv of ``rows`` rows with ``figures`` figures each."""
    rng = np.random.default_rng(seed)
    with (folder / "runs.csv").open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(HEADER)
        for i in range(rows):
            figs: dict[str, object] = {f"value:p{j}": float(rng.random()) for j in range(figures // 2)}
            figs |= {f"error:c{j}": float(rng.random()) for j in range(figures // 4)}
            figs |= {f"pass:c{j}": bool(rng.random() < 0.9) for j in range(figures // 4)}
            w.writerow([f"k{i:08d}", i, 7, f"random-{i % 10}", "ok", "", True, figures // 4, 0, True, 1.0,
                        json.dumps(figs, sort_keys=True)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", default="100,1000", help="comma-separated table sizes (rows)")
    ap.add_argument("--figures", type=int, default=400, help="figures per row")
    ap.add_argument("--repeat", type=int, default=5, help="timed calls per size (median)")
    args = ap.parse_args()
    print(f"machine: {platform.machine()}, {platform.python_version()}; figures per row: {args.figures}\n")
    print("| rows | write_parquet median (s) | min (s) | runs.parquet (MB) |\n|---:|---:|---:|---:|")
    for n in [int(x) for x in args.rows.split(",")]:
        with tempfile.TemporaryDirectory() as tmp:
            d = Path(tmp)
            make_csv(d, n, args.figures)
            walls = []
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                write_parquet(d)
                walls.append(time.perf_counter() - t0)
            size = (d / "runs.parquet").stat().st_size / 1e6
            print(f"| {n} | {statistics.median(walls):.3f} | {min(walls):.3f} | {size:.2f} |")


if __name__ == "__main__":
    main()
