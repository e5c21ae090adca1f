"""``benchtwin simulate --campaign FILE [--vehicle FILE] --out DIR``: run a campaign, save the Trace.

Writes ``DIR/trace.mf4`` (every Trace channel, SI units, asammdf), ``DIR/segments.json`` (one segment per
test) and ``DIR/meta.json`` (vehicle, seed, rates, energy ledger). A bare campaign name such as
``quick`` or ``paper.toml`` is looked up among the shipped campaigns; ``--seed`` replaces the campaign's.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from benchtwin.commands._common import (
    add_seed_arg,
    campaign_for_vehicle,
    load_campaign_arg,
    load_vehicle_arg,
    writable_dir,
)
from benchtwin.errors import DataError

__all__ = ["add_subparser", "run"]


def add_subparser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``simulate`` subcommand."""
    p = subparsers.add_parser("simulate", help="run a test campaign on the emulated vehicle and save the Trace",
                              description=__doc__.split("\n\n", 1)[1] if __doc__ else None)
    p.add_argument("--campaign", required=True, help="campaign TOML or a shipped name: paper, quick, wltc")
    p.add_argument("--vehicle", default=None, help="vehicle TOML or a shipped name (default: p2_phev_9at)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    add_seed_arg(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Simulate the campaign test by test, writing the Trace as it goes; return the exit status."""
    from benchtwin.emulator import energy_balance, iter_campaign
    from benchtwin.emulator.protocols import lazy_protocol
    from benchtwin.trace import TraceWriter

    vehicle = load_vehicle_arg(args.vehicle)
    campaign = campaign_for_vehicle(vehicle, load_campaign_arg(args.campaign, args.seed))
    writable_dir(args.out, "--out")
    bar = None
    steps = lazy_protocol(campaign).steps
    dt = 1.0 / campaign.plant_rate_hz
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=round(sum(steps) * dt), unit="s sim", desc=campaign.name, leave=False)
    t0 = time.perf_counter()
    try:
        # one test in memory at a time: the Trace goes to the file's temporary blocks as each test ends
        with TraceWriter(args.out) as writer:
            done = 0
            for k, piece in enumerate(iter_campaign(vehicle, campaign)):
                writer.append(piece)
                done += steps[k]
                if bar is not None:  # a test's full block, even if it ended early: the total never moves
                    bar.update(round(done * dt) - bar.n)
    except OSError as exc:
        raise DataError(f"{args.out}: cannot write the trace ({exc.strerror or exc})") from None
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - t0
    duration = writer.span_s[1] - writer.span_s[0]
    bal = energy_balance(writer.meta["energy_ledger_j"])
    print(f"{campaign.name}: {len(writer.segments)} tests, {duration:.0f} s simulated in {wall:.1f} s "
          f"({duration / max(wall, 1e-9):.0f}x real time, Trace written), energy balance residual "
          f"{100 * bal['residual_frac']:.4f} %")
    print(f"wrote {writer.path} and {args.out / 'segments.json'} (seed {campaign.seed})")
    return 0
