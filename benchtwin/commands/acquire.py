"""``benchtwin acquire``: decode raw bench logs (batch) into a Recording MF4.

Two ways in:

* ``benchtwin acquire LOGDIR [--setup FILE] --out REC.mf4`` decodes the raw logs in LOGDIR
  (``<bus>.mf4`` MF4 bus logs, ``<device>.polls.npz`` Modbus poll logs, ``segments.json``); the
  setup defaults to ``LOGDIR/setup.json`` written with the logs.
* ``benchtwin acquire SPOOL_DIR --out REC.mf4`` recovers the Recording of a ``benchtwin record`` that
  was killed (or crashed) from its spool folder (``<out>.spool/``; setup and segments are in it): every
  frame and poll flushed before the kill, at most the last second received is lost.
* ``benchtwin acquire --trace TRACEDIR --setup FILE --logs LOGDIR --out REC.mf4 [--seed N] [--blf]``
  runs the whole batch chain on a saved Trace: the sensors encode it, the raw logs are written to
  LOGDIR (and BLF copies with ``--blf``), read back and decoded.

A setup may be a file or a shipped name (``paper``, ``ideal``). The summary lists the channels,
the flagged samples, protocol errors, Modbus timeouts and the clock offsets detected.

A damaged or truncated bus log (its own frame/object count, a file cut inside its data, or a time base
ending before the segment table or the other buses) is decoded up to the damage, reported on stderr
per bus and time span, listed in the Recording's ``meta["damaged_logs"]``, and its cut flagged
(TRANSPORT_DROP | LOST_FRAME); the exit status is then 1 (the Recording is written but incomplete).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from benchtwin.commands._common import add_seed_arg, load_setup_arg, writable_dir, writable_file
from benchtwin.errors import ConfigError, DataError

__all__ = ["add_subparser", "run"]


def add_subparser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``acquire`` subcommand."""
    p = subparsers.add_parser("acquire", help="decode raw bench logs (or a Trace through the sensors) into a "
                                              "Recording MF4", description=__doc__.split("\n\n", 1)[1],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("logdir", nargs="?", type=Path, default=None, help="folder of raw logs to decode")
    p.add_argument("--setup", default=None, help="setup TOML or shipped name (default: LOGDIR/setup.json)")
    p.add_argument("--trace", type=Path, default=None, help="encode this saved Trace first (folder of trace.mf4)")
    p.add_argument("--logs", type=Path, default=None, help="with --trace: where to write the raw logs")
    add_seed_arg(p, "with --trace: the trace's")
    p.add_argument("--blf", action="store_true", help="with --trace: also export BLF bus logs")
    p.add_argument("--out", type=Path, required=True, help="Recording MF4 to write (.mf4 is added or replaces "
                                                           "another suffix)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Decode (or encode and decode) and write the Recording; return the exit status."""
    from benchtwin.chain.acquisition import acquire
    from benchtwin.chain.batch import read_logs, run_batch
    from benchtwin.chain.live.bench import is_spool, read_spool
    from benchtwin.trace import Trace

    if args.trace is not None:
        if args.logdir is not None:
            raise ConfigError("give either LOGDIR (decode logs) or --trace (encode a trace), not both")
        if args.setup is None:
            raise ConfigError("--trace needs --setup (the bench to put on the trace)")
    elif args.logdir is None:
        raise ConfigError("give a LOGDIR of raw logs, or --trace TRACEDIR")
    elif args.seed is not None:
        raise ConfigError("--seed is for --trace (decoding logs draws nothing at random)")
    setup = load_setup_arg(args.setup) if args.setup else None
    # asammdf writes the MF4 under the name with its suffix made .mf4: check (and report) that file
    out = args.out if args.out.suffix.lower() == ".mf4" else args.out.with_suffix(".mf4")
    writable_file(out, "--out")
    t0 = time.perf_counter()
    if args.trace is not None and setup is not None:
        logs = args.logs if args.logs is not None else args.out.with_suffix("")
        writable_dir(logs, "--logs")
        trace = Trace.load(args.trace)
        seed = args.seed if args.seed is not None else int(trace.meta.get("seed", 0) or 0)
        rec = run_batch(trace, setup, seed, logs, blf=args.blf)
        print(f"encoded {trace.duration_s:.0f} s of trace with setup {setup.name!r}, raw logs in {logs}")
    else:
        if is_spool(args.logdir):
            received, setup = read_spool(args.logdir, setup)
            got = received.meta["recovered_spool"]
            print("recovering a recorder spool: " + ", ".join(f"{b} {n} frames" for b, n in got["frames"].items())
                  + "".join(f", {k} {n} polls" for k, n in got["polls"].items())
                  + ("" if got["recorder_stopped_cleanly"] else "; the recorder did not stop cleanly"), flush=True)
        else:
            received, setup = read_logs(args.logdir, setup)
        rec = acquire(received, setup)
    wall = time.perf_counter() - t0
    try:
        path = rec.save(out)
    except OSError as exc:
        raise DataError(f"{out}: cannot write the recording ({exc.strerror or exc})") from None
    n_frames = sum(rec.meta.get("frames", {}).values())
    n_samples = sum(len(c) for c in rec.channels.values())
    print(f"decoded {n_frames} frames and {sum(v['polls'] for v in rec.meta.get('modbus', {}).values())} polls "
          f"into {len(rec.channels)} channels ({n_samples} samples) in {wall:.1f} s")
    if rec.meta.get("bus_load"):
        print("  bus load: " + ", ".join(f"{b} {100 * v:.1f} %" for b, v in rec.meta["bus_load"].items()))
    for key in ("protocol_errors", "unknown_ids", "modbus", "clock_offsets_s", "clock_drift_ppm"):
        if rec.meta.get(key):
            print(f"  {key}: {rec.meta[key]}")
    flagged = rec.meta.get("flagged_samples", {})
    if flagged:
        print(f"  flagged samples in {len(flagged)} channels: " + ", ".join(
            f"{k} {sum(v.values())}" for k, v in sorted(flagged.items())[:12]) + (" ..." if len(flagged) > 12 else ""))
    print(f"wrote {path}")
    damaged = rec.meta.get("damaged_logs", [])
    for dmg in damaged:
        (a, b), (ea, eb) = dmg["covered_s"], dmg["expected_s"]
        print(f"benchtwin: warning: damaged log {dmg['file']} (bus {dmg['bus']}): {dmg['reason']}; it covers "
              f"{a:.3f} .. {b:.3f} s of {ea:.3f} .. {eb:.3f} s, nothing after {b:.3f} s on this bus",
              file=sys.stderr, flush=True)
    return 1 if damaged else 0
