"""The type B re-runs in line against shared with a forked worker (benchtwin.validation.type_b_worker), on their own.

Usage::

    python benchmarks/bench_type_b_worker.py [--campaign paper] [--setup paper] [--vehicle p2_phev_9at] [--runs 3]
                                             [--head 2 --head 1 ...]

The campaign is simulated and run through the chain into the acquisition's raw chunk files (``run_chunked(...,
keep_chunks=True)``: the lazy Recording ``validate --out`` identifies from). Then, ``--runs`` times, the variants
take turns (A B C A B C ...): :func:`~benchtwin.identification.run.identify_all` with ``type_b=True`` in line on the
default threads (``inline``), and with a :class:`~benchtwin.validation.type_b_worker.ForkedShare` whose parent runs
the head on ``--head`` threads (``worker/N``, one variant per ``--head``). Per run: the type B part's wall
(``meta["seconds"]["type_b"]``), the CPU seconds of the process and of the worker it waited for (``os.times``,
children included), the units the worker ran, and a digest of every parameter's value and budget (the variants must
print the same digest: the budgets bit for bit). No side stages run beside it: the gain measured is the most the
worker can give ``validate`` (whose side stages' child shares the cores during the first part of the re-runs).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from contextlib import nullcontext
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_type_b_profile import digest

from benchtwin.chain.stream import run_chunked, trace_pieces
from benchtwin.config._base import scenario_path
from benchtwin.config.campaign import load_campaign
from benchtwin.config.setup import load_setup
from benchtwin.config.vehicle import load_vehicle
from benchtwin.emulator import simulate_campaign
from benchtwin.identification.run import identify_all
from benchtwin.validation.type_b_worker import ForkedShare


def _cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--campaign", default="paper")
    ap.add_argument("--setup", default="paper")
    ap.add_argument("--vehicle", default="p2_phev_9at")
    ap.add_argument("--runs", type=int, default=3, help="runs per variant (default 3)")
    ap.add_argument("--head", type=int, action="append", default=None,
                    help="the parent's threads beside the worker, one variant each (repeat; default 2 and 1)")
    args = ap.parse_args()
    heads = args.head or [2, 1]
    vehicle = load_vehicle(scenario_path("vehicles", f"{args.vehicle}.toml"))
    camp = load_campaign(scenario_path("campaigns", f"{args.campaign}.toml"))
    variants: list[int | None] = [None, *heads]
    names = ["inline", *(f"worker/{h}" for h in heads)]
    rows: dict[str, list[tuple[float, float, int, str]]] = {n: [] for n in names}
    with tempfile.TemporaryDirectory() as tmp:
        trace = simulate_campaign(vehicle, camp)
        rec = run_chunked(trace_pieces(trace), load_setup(args.setup), seed=camp.seed, out_dir=Path(tmp) / "out",
                          keep_chunks=True)
        del trace
        for r in range(args.runs):
            for name, head in zip(names, variants, strict=True):
                ran: list[int] = []
                share = None
                if head is not None:
                    share = ForkedShare(head)
                    collect = share.collect
                    share.collect = lambda c=collect, ran=ran: (got := c(), ran.append(len(got)))[0]  # type: ignore
                c0 = _cpu()
                with share if share is not None else nullcontext():
                    res = identify_all(rec, vehicle.specs, type_b=True, type_b_share=share)
                cpu = _cpu() - c0
                tb = float(res.meta["seconds"]["type_b"])
                rows[name].append((tb, cpu, ran[0] if ran else 0, digest(res)))
                print(f"run {r} {name}: type B {tb:.2f} s, cpu {cpu:.1f} s (identify_all, worker included), "
                      f"worker units {ran[0] if ran else 0}, "
                      f"digest {digest(res)}", flush=True)
    print(f"\nmedians of {args.runs} (load average {os.getloadavg()[0]:.1f})\n"
          "| variant | type B wall s | identify_all CPU s | worker units | digest |\n|---|---|---|---|---|")
    for name in names:
        g = rows[name]
        print(f"| {name} | {statistics.median(x[0] for x in g):.2f} | {statistics.median(x[1] for x in g):.1f} | "
              f"{statistics.median(x[2] for x in g):.0f} | {', '.join(sorted({x[3] for x in g}))} |")


if __name__ == "__main__":
    main()
