"""One BSFC map fit (``fit_bsfc_map``): traced peak and CPU at n steady points, every point vs operating cells.

The paper campaign gives 144 steady engine points; a campaign repeated k times gives k x 144, each repeat within a
fraction of the sensors' step of its original (on paper_x3 the repeats of a point spread at most 0.106 rpm and
0.009 Nm; the CAN steps are 0.25 rpm and 0.1 Nm). ``before`` fits the thin plate through every point
(``cell=None``, today's fit without cells); ``after`` merges the points into operating cells by the declared steps
(``cell=(0.25, 0.1)``). Points: 144 scattered speed x torque points of a Willans-like engine (fuel power
``P_u / 0.42 + 3 kW (n / 1000 rpm)^1.5``), tiled n / 144 times with each repeat moved uniformly within a quarter step
and its fuel read with 0.5 % noise.

Each fit runs in this process under ``tracemalloc`` (peak of Python-traced allocations, numpy's included) with
``time.process_time`` around it; medians over ``--repeats`` runs. Not a test: numbers go to benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
import tracemalloc
from pathlib import Path

import numpy as np

from benchtwin.config import load_vehicle
from benchtwin.identification.engine import fit_bsfc_map

RPM = np.pi / 30
STEPS = (0.25, 0.1)


def points(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` steady points: 144 base points tiled ``n // 144`` times, repeats within a quarter step."""
    rng = np.random.default_rng(seed)
    base = 144
    s0 = rng.uniform(1200, 3600, base)
    t0 = rng.uniform(30, 350, base)
    f0 = (t0 * s0 * RPM / 0.42 + 3e3 * (s0 / 1000) ** 1.5) / 42.8e6 * 1e3
    reps = max(n // base, 1)
    m = base * reps
    s = np.tile(s0, reps) + (rng.uniform(-STEPS[0] / 4, STEPS[0] / 4, m) if reps > 1 else 0)
    t = np.tile(t0, reps) + (rng.uniform(-STEPS[1] / 4, STEPS[1] / 4, m) if reps > 1 else 0)
    f = np.tile(f0, reps) * (1 + rng.normal(0, 0.005, m))
    return s, t, f


def one_fit(n: int, cell: tuple[float, float] | None) -> dict[str, float]:
    """Traced peak (MB), CPU (s) and the fit's numbers of one fit."""
    specs = load_vehicle().specs
    s, t, f = points(n)
    tracemalloc.start()
    c0 = time.process_time()
    fit = fit_bsfc_map(specs, s, t, f, cell=cell)
    cpu = time.process_time() - c0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {"peak_mb": peak / 1e6, "cpu_s": cpu, "n_fitted": fit.n_points, "bsfc_min": fit.value("bsfc_min"),
            "bsfc_min_se": fit["bsfc_min"].std_error, "cv_rmse": fit.rmse}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="144,432,1440", help="steady points (default 144,432,1440)")
    ap.add_argument("--repeats", type=int, default=3, help="runs per size and method (medians; default 3)")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    args = ap.parse_args()
    rows = []
    for n in (int(x) for x in args.sizes.split(",")):
        for label, cell in (("before (every point)", None), ("after (cells)", STEPS)):
            runs = [one_fit(n, cell) for _ in range(args.repeats)]
            row = {"n": n, "method": label, **{k: statistics.median(r[k] for r in runs) for k in runs[0]}}
            rows.append(row)
            print(f"n={n:5d} {label:22s} fitted {row['n_fitted']:5.0f}  traced peak {row['peak_mb']:6.1f} MB  "
                  f"cpu {row['cpu_s']:6.2f} s  bsfc_min {row['bsfc_min']:.4f} (se {row['bsfc_min_se']:.4f})  "
                  f"cv rmse {row['cv_rmse']:.3f} g/kWh", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
