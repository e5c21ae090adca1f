"""``benchtwin faults [--setup S] [--campaign C] --out DIR``: the fault campaign.

Simulates the campaign (or loads ``--trace``), runs the batch chain with the setup's ``[[faults]]``
injected and again without them, and checks that the acquisition flags every injected fault (kind,
device or bus, time span) and nothing else. Writes ``DIR/faulty/`` and ``DIR/clean/`` (raw logs and
``recording.mf4`` of each run) and ``DIR/faults.json``: per kind ``injected``, ``detected`` and
``false_alarms`` (detections that match no injected fault, and every detection of the clean run), each
fault with the spans found and the flags in its span, and the identification fits that changed status
or lost points. The default setup is the shipped ``faults`` (the paper bench with one fault of every
kind), the default campaign ``quick.toml``. Exit status 1 when a fault was missed or a false alarm raised.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

__all__ = ["add_subparser", "run"]


def add_subparser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``faults`` subcommand."""
    p = subparsers.add_parser("faults", help="inject the setup's fault list and check the acquisition flags each "
                                             "fault and nothing else", description=__doc__.split("\n\n", 1)[1],
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--setup", default="faults", help="setup TOML with [[faults]] or a shipped name (default: faults)")
    p.add_argument("--campaign", default="quick.toml", help="campaign TOML or shipped name (default: quick.toml)")
    p.add_argument("--vehicle", default=None, help="vehicle TOML (default: the shipped P2 PHEV)")
    p.add_argument("--trace", type=Path, default=None, help="use this saved Trace instead of simulating")
    p.add_argument("--seed", type=int, default=None, help="campaign seed (default: the campaign's)")
    p.add_argument("--no-identify", action="store_true", help="skip identification of both runs")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Run the fault campaign and write faults.json; return the exit status."""
    from benchtwin.commands._common import check_writable
    from benchtwin.config.campaign import load_campaign
    from benchtwin.config.setup import load_setup
    from benchtwin.config.vehicle import load_vehicle
    from benchtwin.errors import ConfigError
    from benchtwin.trace import Trace
    from benchtwin.validation.faults import fault_campaign, fault_table

    check_writable(args.out, directory=True, what="--out")
    setup = load_setup(args.setup)
    if not setup.faults:
        raise ConfigError(f"setup {setup.name!r} has no [[faults]] to inject")
    vehicle = load_vehicle(args.vehicle)
    t0 = time.perf_counter()
    if args.trace is not None:
        trace = Trace.load(args.trace)
        seed = args.seed if args.seed is not None else int(trace.meta.get("seed", 0) or 0)
    else:
        from benchtwin.emulator import simulate_campaign

        campaign = load_campaign(args.campaign)
        seed = args.seed if args.seed is not None else campaign.seed
        trace = simulate_campaign(vehicle, campaign)
    t1 = time.perf_counter()
    args.out.mkdir(parents=True, exist_ok=True)
    result = fault_campaign(trace, setup, seed=seed, out_dir=args.out, specs=vehicle.specs,
                            identify=not args.no_identify)
    t2 = time.perf_counter()
    print(f"{setup.name}: {len(setup.faults)} faults over {trace.duration_s:.0f} s of trace "
          f"(trace {t1 - t0:.1f} s, two chain runs{'' if args.no_identify else ' and identifications'} "
          f"{t2 - t1:.1f} s)")
    print(fault_table(result))
    for f in result["faults"]:
        if not f["detected"]:
            print(f"  missed: {f['kind']} on {f['target']} at {f['start_s']:.1f} s")
    for d in result["false_alarms"] + result["clean_detections"]:
        print(f"  false alarm: {d['kind']} on {d.get('device') or d.get('bus')} {d['start_s']:.1f}..{d['end_s']:.1f} s")
    changed = result.get("identification", {}).get("changed", [])
    if changed:
        print(f"  identification: {len(changed)} fits changed status or lost points: "
              + ", ".join(c["fit"] for c in changed[:10]) + (" ..." if len(changed) > 10 else ""))
    print(f"wrote {args.out / 'faults.json'}")
    tot = result["kinds"].values()
    ok = all(r["detected"] == r["injected"] for r in tot) and not any(r["false_alarms"] for r in tot)
    return 0 if ok else 1
