"""``benchtwin sweep``: many validation runs over axes of the vehicle, setup and campaign, and seeds.

A sweep file names a base vehicle, setup and campaign (shipped names or paths), the axes to vary (dotted
paths into the models, each a list of values or a range; whole models as a list of files, or a random vehicle
family ``[axes.vehicle] random = {count, seed}``), the seeds and the figures to collect; see
scenarios/sweeps/telemetry_noise.toml. One row per run is appended to DIR/runs.csv as runs finish, and
DIR/runs.parquet (one column per figure) is rewritten from it after each (a killed sweep leaves both
readable); the summary PNGs are drawn at the end, also from what finished when the sweep is interrupted;
--resume then runs only the rest. A failed run records its
error in its row and the sweep goes on. Runs go to a local process pool (--workers) or to an existing
Dask cluster (--scheduler tcp://HOST:PORT); both give the same table.
"""

from __future__ import annotations

import argparse

__all__ = ["add_subparser", "run"]


def add_subparser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``sweep`` subcommand."""
    p = subparsers.add_parser("sweep", help="validation runs over axes of the vehicle, setup and campaign",
                              description=__doc__.split("\n\n", 1)[1] if __doc__ else None)
    p.add_argument("sweep_file", metavar="SWEEP.toml", help="the sweep file")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (runs.csv, runs.parquet, PNGs)")
    p.add_argument("--workers", type=int, default=2, help="local worker processes (default 2; 0: in this process)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="run on an existing Dask cluster at this scheduler address instead")
    p.add_argument("--resume", action="store_true", help="keep the rows already in DIR and run only the rest")
    p.add_argument("--max-runs", type=int, default=None, metavar="N", help="stop after N runs (resume later)")
    p.add_argument("--cache", metavar="DIR", default=None,
                   help="Trace cache directory (default $BENCHTWIN_CACHE or ~/.cache/benchtwin/traces)")
    p.add_argument("--no-figures", action="store_true", help="do not draw the summary PNGs")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Run the sweep; exit 0 when every run completed (failed checks included), 1 when a run failed."""
    from benchtwin.studies.sweep import Sweep

    sweep = Sweep.from_file(args.sweep_file, cache_dir=args.cache)
    print(f"benchtwin sweep: {sweep.config.name}, {len(sweep.tasks)} runs "
          f"({' x '.join(str(len(v)) for v in sweep.axes.values()) or '1'} x {len(sweep.seeds)} seeds), "
          + (f"Dask scheduler {args.scheduler}" if args.scheduler else f"{args.workers} local workers"))
    outcome = sweep.run(args.out, workers=args.workers, scheduler=args.scheduler, resume=args.resume,
                        max_runs=args.max_runs, progress=True, figures=not args.no_figures)
    print(f"{outcome.done} runs done, {outcome.failed} failed, {outcome.skipped} already in {args.out}, "
          f"{outcome.pending} pending; {outcome.simulated} Traces simulated (the rest from the cache)")
    for f in outcome.figures:
        print(f"  {f}")
    return 1 if outcome.failed else 0
