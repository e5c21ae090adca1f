"""The CPU seconds of each stage of ``validate``'s side child (:mod:`benchtwin.validation.beside`): chain checks,
paper fits, the held-out prediction's identification, drives and predictions, recording.mf4, the report's figures.

Usage::

    python benchmarks/bench_side_stages.py [--campaign paper] [--setup paper] [--runs 3] [--root DIR ...]

Each source tree ``--root`` (put first on ``PYTHONPATH``; default: this one) runs ``validate --out`` ``--runs`` times,
the trees taking turns, in a process of its own with ``SIDE_MODE = "fork"``. In the forked child the stage functions
are wrapped to add up their CPU seconds (``time.process_time``: the child's threads) and their count, with the
child's garbage collection seconds (``gc.callbacks``, the collecting thread's CPU) and the child's whole CPU (and the
parent's garbage collection seconds and full collections: ``parent_gc``, ``parent_gc_full``); a stage nested in
another (the save and the figures run while the prediction waits) is counted in both. Prints each run and the
median per tree and stage (``--keep``: each tree's last outputs kept). A paper-campaign run takes about a minute of
CPU: run under the shared lock
(``flock /tmp/benchtwin-heavy.lock nice -n 5 python benchmarks/bench_side_stages.py ...``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

_CODE = r"""
import gc, json, os, sys, time
import benchtwin.validation.run as run
import benchtwin.validation.html as html
import benchtwin.validation.figures_beside as fb
import benchtwin.chain.deferred_save as ds
import benchtwin.identification.figures as idfig
run.SIDE_MODE = "fork"
parent = os.getpid()
acc = {}
gc_s = [0.0, None]

gc_parent = [0.0, None, 0]

def on_gc(phase, info):
    g = gc_parent if os.getpid() == parent else gc_s
    if phase == "start":
        g[1] = time.thread_time()
    elif g[1] is not None:
        g[0] += time.thread_time() - g[1]
        if g is gc_parent and info["generation"] == 2:
            gc_parent[2] += 1

def timed(owner, name, key):
    f = getattr(owner, name)
    def g(*a, **k):
        if os.getpid() == parent:
            return f(*a, **k)
        c = time.process_time()
        try:
            return f(*a, **k)
        finally:
            s, n = acc.get(key, (0.0, 0))
            acc[key] = (s + time.process_time() - c, n + 1)
    setattr(owner, name, g)

for owner, name in [(run, "chain_checks"), (run, "paper_estimation_fits"), (run, "identify_all"),
                    (run, "_held_out_drive"), (run, "predict_drive"), (run, "submodel_checks"),
                    (ds.DeferredSave, "run"), (html, "figure_images"), (idfig, "render_figures_png"),
                    (html, "_prediction_figure")]:
    timed(owner, name, "save_mf4" if owner is ds.DeferredSave else name)
side = run._side_stages

def child(*a, **k):
    c = time.process_time()
    try:
        return side(*a, **k)
    finally:
        acc["child_total"] = (time.process_time() - c, 1)
        acc["gc"] = (gc_s[0], 1)
        with open(os.environ["SIDE_STAGES_OUT"], "w") as fh:
            json.dump(acc, fh)

run._side_stages = child
gc.callbacks.append(on_gc)
from benchtwin.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
with open(os.environ["SIDE_STAGES_OUT"] + ".parent", "w") as fh:
    json.dump({"parent_gc": (gc_parent[0], 1), "parent_gc_full": (gc_parent[2], 1)}, fh)
"""


def _one(root: Path, campaign: str, setup: str, keep: Path | None) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "stages.json"
        env = dict(os.environ, PYTHONPATH=str(root), SIDE_STAGES_OUT=str(out))
        res = Path(tmp) / "out" if keep is None else keep
        if keep is not None:
            shutil.rmtree(keep, ignore_errors=True)
        subprocess.run([sys.executable, "-c", _CODE, "validate", "--campaign", campaign, "--setup", setup,
                        "--out", str(res)], env=env, check=True, cwd=tmp, stdout=subprocess.DEVNULL)
        got = json.loads(out.read_text())
        got.update(json.loads(Path(str(out) + ".parent").read_text()))
    return {k: v[0] for k, v in got.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaign", default="paper")
    ap.add_argument("--setup", default="paper")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--root", type=Path, action="append", help="a source tree (repeatable; default: this one)")
    ap.add_argument("--keep", type=Path, help="keep each tree's last --out folder as KEEP/<k> (k: the tree's place, "
                                              "from 0), e.g. for benchmarks/compare_validate_outputs.py")
    args = ap.parse_args()
    roots = args.root or [Path(__file__).resolve().parents[1]]
    runs: dict[Path, list[dict[str, float]]] = {r: [] for r in roots}
    for k in range(args.runs):
        for r in roots:
            got = _one(r, args.campaign, args.setup,
                       None if args.keep is None else args.keep / str(roots.index(r)))
            runs[r].append(got)
            print(f"run {k + 1} {r}: " + ", ".join(f"{n} {v:.2f}" for n, v in sorted(got.items())), flush=True)
    print(f"\nmedian CPU s over {args.runs} runs (os.getloadavg {os.getloadavg()[0]:.2f})")
    names = sorted({n for rs in runs.values() for g in rs for n in g})
    print("| stage | " + " | ".join(str(r) for r in roots) + " |")
    print("|---|" + "---|" * len(roots))
    for n in names:
        print(f"| {n} | " + " | ".join(f"{statistics.median(g.get(n, 0.0) for g in runs[r]):.2f}" for r in roots)
              + " |")


if __name__ == "__main__":
    main()
