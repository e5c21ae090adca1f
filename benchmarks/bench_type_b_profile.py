"""Where the type B re-runs of ``validate --out`` spend their CPU: per method and component kind, and the top functions.

Usage::

    python benchmarks/bench_type_b_profile.py [--campaign paper] [--setup paper] [--repeat 1] [--threads 2]
                                              [--profile] [--top 25] [--prof FILE]

The campaign is simulated and run through the chain into the acquisition's raw chunk files (``run_chunked(...,
keep_chunks=True)``, the Recording ``validate --out`` identifies from, read lazily by blocks). Then, ``--repeat``
times, :func:`~benchtwin.identification.run.identify_all` with ``type_b=True`` runs on it with the re-runs on
``--threads`` threads: the identify stage's wall and CPU seconds (``time.process_time``, all threads) and the type B
part's (``meta["seconds"]["type_b"]``, and its CPU). Each unit of re-runs (one method, one component) is timed on
its thread (``time.thread_time``; a rounding draw is a unit of its own once the draws run on the threads one by
one): the table lists per method and component kind the units, re-runs and CPU
seconds. ``--profile`` adds one run with the re-runs inline on the main thread under cProfile (its top functions
by own time and by cumulative time; ``--prof`` keeps the profile). A digest of every parameter's value and budget is
printed: two trees (``PYTHONPATH``) giving the same digest give the same type B budgets bit for bit.
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import io
import pstats
import statistics
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_scaling_profile import _InlineExecutor

from benchtwin.chain.stream import run_chunked, trace_pieces
from benchtwin.config._base import scenario_path
from benchtwin.config.campaign import load_campaign
from benchtwin.config.setup import load_setup
from benchtwin.config.vehicle import load_vehicle
from benchtwin.emulator import simulate_campaign
from benchtwin.identification import uncertainty
from benchtwin.identification.run import identify_all


def digest(result) -> str:
    """A digest of every parameter's value, standard error and type B contributions (bit for bit)."""
    h = hashlib.blake2b(digest_size=12)
    for fk in sorted(result.fits):
        for pk, p in sorted(result.fits[fk].params.items()):
            h.update(repr((fk, pk, p.value, p.std_error, p.ci95, p.u_type_b, p.u_total, p.ci95_total,
                           sorted(p.type_b.items()) if p.type_b else None)).encode())
        h.update(repr(result.fits[fk].reasons).encode())
    h.update(repr(result.meta.get("type_b")).encode())
    return h.hexdigest()


def timed_units(rows: list[tuple[str, str, int, float, float]]):
    """Wrap the units of re-runs (``uncertainty._propagate_step``: a gain or offset; ``uncertainty._one_draw``: one
    rounding draw; or, on a tree before draws were units of their own, ``uncertainty._propagate_one``) so that each
    unit's method, kind, re-runs, thread CPU and wall go to ``rows``; returns the function that undoes it."""
    lock = threading.Lock()
    saved = {}

    def wrap(name: str, kind: Callable[[tuple], str], reruns: Callable[[Any], int]) -> None:
        fn = saved[name] = getattr(uncertainty, name)

        def wrapped(recording, task, *rest):
            c0, w0 = time.thread_time(), time.perf_counter()
            out = fn(recording, task, *rest)
            c, w = time.thread_time() - c0, time.perf_counter() - w0
            with lock:
                rows.append((task[0][0].split(".")[0], kind(task), reruns(out), c, w))
            return out

        setattr(uncertainty, name, wrapped)

    if hasattr(uncertainty, "_one_draw"):
        wrap("_propagate_step", lambda t: t[2].kind, lambda out: out[1])
        wrap("_one_draw", lambda t: "resolution", lambda out: 1)
    else:
        wrap("_propagate_one", lambda t: t[2].kind, lambda out: out[1])

    def undo() -> None:
        for name, fn in saved.items():
            setattr(uncertainty, name, fn)
    return undo


def table(rows: list[tuple[str, str, int, float, float]]) -> str:
    """Per method and kind (resolution / gain-offset): units, re-runs, CPU s, wall s."""
    agg: dict[tuple[str, str], list[float]] = defaultdict(lambda: [0, 0, 0.0, 0.0])
    for method, kind, n, c, w in rows:
        a = agg[(method, "resolution" if kind == "resolution" else "gain/offset")]
        a[0] += 1
        a[1] += n
        a[2] += c
        a[3] += w
    out = ["| method | kind | units | re-runs | CPU s | CPU s per re-run |", "|---|---|---|---|---|---|"]
    tot = [0, 0, 0.0]
    for (m, k), (u, n, c, _w) in sorted(agg.items(), key=lambda kv: -kv[1][2]):
        out.append(f"| {m} | {k} | {u} | {n} | {c:.2f} | {c / max(n, 1):.3f} |")
        tot[0] += u
        tot[1] += n
        tot[2] += c
    out.append(f"| all | | {tot[0]} | {tot[1]} | {tot[2]:.2f} | |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--campaign", default="paper")
    ap.add_argument("--setup", default="paper")
    ap.add_argument("--vehicle", default="p2_phev_9at")
    ap.add_argument("--repeat", type=int, default=1, help="timed identify_all runs on the threads")
    ap.add_argument("--threads", type=int, default=2, help="threads of the re-runs")
    ap.add_argument("--profile", action="store_true", help="also one inline run under cProfile")
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--prof", type=Path, default=None, help="write the cProfile stats here")
    args = ap.parse_args()
    vehicle = load_vehicle(scenario_path("vehicles", f"{args.vehicle}.toml"))
    camp = load_campaign(scenario_path("campaigns", f"{args.campaign}.toml"))
    with tempfile.TemporaryDirectory() as tmp:
        trace = simulate_campaign(vehicle, camp)
        rec = run_chunked(trace_pieces(trace), load_setup(args.setup), seed=camp.seed, out_dir=Path(tmp) / "out",
                          keep_chunks=True)
        del trace
        uncertainty.WORKERS = args.threads
        walls, cpus, tb_walls, tb_cpus = [], [], [], []
        for k in range(args.repeat):
            rows: list = []
            undo = timed_units(rows)
            w0, c0 = time.perf_counter(), time.process_time()
            try:
                res = identify_all(rec, vehicle.specs, type_b=True)
            finally:
                undo()
            walls.append(time.perf_counter() - w0)
            cpus.append(time.process_time() - c0)
            tb_walls.append(res.meta["seconds"]["type_b"])
            tb_cpus.append(sum(r[3] for r in rows))
            print(f"run {k}: identify wall {walls[-1]:.2f} s CPU {cpus[-1]:.2f} s; type B wall {tb_walls[-1]:.2f} s, "
                  f"units' CPU {tb_cpus[-1]:.2f} s; digest {digest(res)}", flush=True)
        if args.repeat:
            print(f"\nmedians over {args.repeat}: identify wall {statistics.median(walls):.2f} s, CPU "
                  f"{statistics.median(cpus):.2f} s; type B wall {statistics.median(tb_walls):.2f} s, units' CPU "
                  f"{statistics.median(tb_cpus):.2f} s ({args.threads} threads)\n")
            print(table(rows))
        if args.profile:
            prof = cProfile.Profile()
            rows = []
            undo = timed_units(rows)
            saved, uncertainty.ThreadPoolExecutor = uncertainty.ThreadPoolExecutor, _InlineExecutor
            prof.enable()
            try:
                res = identify_all(rec, vehicle.specs, type_b=True)
            finally:
                prof.disable()
                uncertainty.ThreadPoolExecutor = saved
                undo()
            print(f"\ninline (cProfile): digest {digest(res)}\n")
            print(table(rows))
            if args.prof:
                prof.dump_stats(str(args.prof))
            for sort in ("tottime", "cumulative"):
                s = io.StringIO()
                pstats.Stats(prof, stream=s).sort_stats(sort).print_stats(args.top)
                print(s.getvalue())
        rec.close()


if __name__ == "__main__":
    main()
