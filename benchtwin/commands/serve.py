"""``benchtwin serve``: simulate (or load) a run, encode it with the bench's sensors, serve it live.

The CAN buses go on the chosen transport (``socketcand``: our endpoint on 127.0.0.1 that any
socketcand client reaches from another process; ``socketcan``: kernel interfaces such as vcan0;
``virtual``: in-process only), the pressure module on a Modbus TCP server, the thermo module as a
CANopen node, each IVT-S answers its command channel. The endpoints are printed first; at the end
the pacing statistics, the bus load per bus and whether the plan was kept.

Exit status: 0 when the plan was kept; 1 when it was not: a delivery failed (frames lost), the run
ended later than 5 % of its planned wall time (at least 0.25 s) after plan (the requested speed-up
was not held: the achieved speed-up and the lateness are printed), or a client that was receiving
left or was dropped before the end of the run (e.g. ``benchtwin record`` killed); 2 on a usage or
setup error.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
from pathlib import Path
from typing import Any

from benchtwin.commands._common import (
    add_seed_arg,
    load_campaign_arg,
    load_setup_arg,
    load_vehicle_arg,
    writable_file,
)
from benchtwin.errors import ConfigError

__all__ = ["add_subparser", "run"]


def add_subparser(subparsers: Any) -> None:
    """Register ``serve``."""
    p = subparsers.add_parser("serve", help="serve a run live on CAN transports, Modbus TCP and CANopen",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_argument_group("what to play (one of)")
    src.add_argument("--campaign", help="campaign file (simulated with --vehicle)")
    src.add_argument("--vehicle", help="vehicle file for --campaign (default: the shipped vehicle)")
    src.add_argument("--trace", help="a saved Trace directory (benchtwin simulate --out)")
    src.add_argument("--synthetic", type=float, metavar="SECONDS", help="a synthetic trace of this length")
    p.add_argument("--setup", required=True, help="bench setup file or shipped name (paper, ideal)")
    p.add_argument("--transport", default="socketcand", choices=["virtual", "socketcand", "socketcan"])
    p.add_argument("--speedup", type=float, default=1.0, help="plant seconds per wall second (default 1)")
    p.add_argument("--port", type=int, default=29536, help="socketcand endpoint port (0: a free one)")
    p.add_argument("--modbus-port", type=int, default=None, help="Modbus TCP port (default: the setup's)")
    p.add_argument("--channel-map", default="", help="socketcan: bus=iface,... (default vcan0, vcan1, ...)")
    p.add_argument("--start", type=float, default=None, help="plant time to start at, s")
    p.add_argument("--end", type=float, default=None, help="plant time to stop at, s")
    add_seed_arg(p, "the campaign's, else 0")
    p.add_argument("--wait-clients", type=int, default=0, metavar="N",
                   help="socketcand: wait for N clients in raw mode before playing")
    p.add_argument("--wait-timeout", type=float, default=30.0, help="seconds to wait for --wait-clients")
    p.add_argument("--linger", type=float, default=0.0, help="keep serving this many seconds after the end")
    p.add_argument("--realtime", type=int, default=None, metavar="PRIO",
                   help="run the pacing loop and servers under SCHED_FIFO at this priority (1..99; needs root or "
                        "CAP_SYS_NICE): keeps the pacing error below 1 ms on a loaded machine")
    p.add_argument("--record", metavar="OUT.mf4",
                   help="also record in this process (works with the embedded virtual transport): the same "
                        "Recording as benchtwin record")
    p.add_argument("--report", help="write the pacing report as JSON here")
    p.add_argument("--segments-out", help="write the run's segment table (JSON) here for benchtwin record")
    p.set_defaults(func=run)


def _load_trace(args: argparse.Namespace) -> tuple[Any, int]:
    chosen = [x for x in (args.campaign, args.trace, args.synthetic) if x is not None]
    if len(chosen) != 1:
        raise ConfigError("serve: give exactly one of --campaign, --trace, --synthetic")
    seed = 0
    if args.trace is not None:
        from benchtwin.trace import Trace

        try:
            return Trace.load(args.trace), seed
        except OSError as exc:
            raise ConfigError(f"--trace {args.trace}: cannot read the trace ({exc.strerror or exc})") from exc
    if args.synthetic is not None:
        from benchtwin.sensors.synthetic import synthetic_trace

        if not 0 < args.synthetic <= 86_400:
            raise ConfigError(f"serve: --synthetic {args.synthetic}: give a duration in seconds, > 0 and at most "
                              "86400 (a day)")
        return synthetic_trace(float(args.synthetic)), seed
    from benchtwin.emulator import simulate_campaign

    campaign = load_campaign_arg(args.campaign, args.seed)
    vehicle = load_vehicle_arg(args.vehicle)
    if not vehicle.has_motor:
        raise ConfigError(f"serve: vehicle {vehicle.name!r} is a conventional car; the live bench emulates the P2 "
                          "PHEV only (use benchtwin validate / acquire for a conventional car)")
    seed = int(campaign.seed)
    print(f"simulating {args.campaign} ...", flush=True)
    return simulate_campaign(vehicle, campaign), seed


def _channel_map(text: str) -> dict[str, str]:
    out = {}
    for part in filter(None, (s.strip() for s in text.split(","))):
        bus, sep, iface = part.partition("=")
        if not sep or not bus or not iface:
            raise ConfigError(f"--channel-map: {part!r} is not bus=interface")
        out[bus] = iface
    return out


def run(args: argparse.Namespace) -> int:
    """Run ``benchtwin serve``."""
    from benchtwin.chain.live.bench import session_from_setup
    from benchtwin.sensors import encode

    if not (args.speedup > 0 and math.isfinite(args.speedup)):
        raise ConfigError(f"--speedup must be a finite number > 0, got {args.speedup}")
    for opt, value in (("--start", args.start), ("--end", args.end), ("--linger", args.linger),
                       ("--wait-timeout", args.wait_timeout)):
        if value is not None and not math.isfinite(value):
            raise ConfigError(f"{opt} {value}: give a finite number of seconds")
    if args.record and Path(args.record).suffix.lower() != ".mf4":
        raise ConfigError(f"--record {args.record}: the Recording is written as MF4; use a .mf4 name")
    for opt, value in (("--record", args.record), ("--report", args.report), ("--segments-out", args.segments_out)):
        if value:  # before anything is simulated or served
            writable_file(value, opt)
    setup = load_setup_arg(args.setup)
    trace, seed = _load_trace(args)
    if args.seed is not None:
        seed = args.seed
    t0 = time.perf_counter()
    outputs = encode(trace, setup, seed=seed)
    print(f"encoded {outputs.n_frames()} CAN frames on {len(outputs.can)} buses, "
          f"{sum(len(s.times) for s in outputs.modbus.values())} Modbus updates, "
          f"{sum(len(i.times) for i in outputs.canopen.values())} CANopen updates "
          f"in {time.perf_counter() - t0:.1f} s", flush=True)
    if args.segments_out:
        from benchtwin.segments import save_segments

        try:
            save_segments(list(trace.segments), args.segments_out)
        except OSError as exc:
            raise ConfigError(f"--segments-out {args.segments_out}: {exc.strerror}") from exc
    recorder = capture = spool = None
    session = session_from_setup(outputs, setup, transport=args.transport, speedup=args.speedup,
                                 can_port=args.port, modbus_port=args.modbus_port,
                                 channel_map=_channel_map(args.channel_map), start_s=args.start, end_s=args.end,
                                 seed=seed, realtime_priority=args.realtime)
    previous = signal.getsignal(signal.SIGTERM)
    signal.signal(signal.SIGTERM, lambda *_: session.stop())
    try:
        session.start()
        print("endpoints:", flush=True)
        for line in session.endpoints():
            print(f"  {line}", flush=True)
        if args.record:
            from benchtwin.chain.live.bench import embedded_recorder

            if Path(args.record).suffix.lower() != ".mf4":
                raise ConfigError(f"--record {args.record}: the Recording is written as MF4; use a .mf4 name")
            spool = Path(args.record).with_name(Path(args.record).name + ".spool")
            recorder = embedded_recorder(session, setup, spool, segments=list(trace.segments)).start()
            print(f"  recording in this process to {args.record}", flush=True)
        elif args.transport == "virtual":
            print("  (virtual transport: only acquisitions in this process can connect; see --record)", flush=True)
        if args.wait_clients and not session.wait_for_clients(args.wait_clients, args.wait_timeout):
            print(f"benchtwin: warning: fewer than {args.wait_clients} clients after {args.wait_timeout} s; "
                  "playing anyway", file=sys.stderr, flush=True)
        sch = session.scheduler
        if args.realtime is not None and not session.realtime_active:
            print("benchtwin: warning: real-time priority unavailable; playing at normal priority",
                  file=sys.stderr, flush=True)
        print(f"playing {sch.start_s:.3f} .. {sch.end_s:.3f} s of plant time at speed-up {args.speedup:g} "
              f"({sch.n_deliveries} deliveries)", flush=True)
        before = dict(session.transport.stats()) if session.transport is not None else {}
        report = session.run(progress=lambda t: print(f"  t = {t:.1f} s", flush=True))
        after = dict(session.transport.stats()) if session.transport is not None else {}
        if args.linger > 0:
            time.sleep(args.linger)
        if recorder is not None:
            time.sleep(0.3)  # the last frames are on their way through the notifier threads
            capture = recorder.stop("end of run" if report.completed else "stopped")
        stats = session.stats()
    finally:
        if recorder is not None and capture is None:
            recorder.stop("error")  # flushes the spool: nothing received is lost
        session.close()
        signal.signal(signal.SIGTERM, previous)
    print(report.format(), flush=True)
    print("bus load per bus (emulated bus, nominal bit rate): " + ", ".join(
        f"{s.name[4:]} {100 * s.bus_load:.1f} %" for s in report.streams.values() if s.bus_load is not None),
        flush=True)
    if stats.get("transport"):
        print(f"transport: {stats['transport']}", flush=True)
    if recorder is not None:
        from benchtwin.chain.live.bench import save_capture

        rec = save_capture(capture, setup, args.record, segments=list(trace.segments),
                           meta={"transport": args.transport, "embedded": True, "seed": seed}, spool_dir=spool)
        print(f"wrote {args.record} ({len(rec.channels)} channels, "
              + ", ".join(f"{b} {len(t)} frames" for b, t in capture.can.items()) + ")", flush=True)
    problems = _plan_problems(report, before, after)
    if args.report:
        Path(args.report).write_text(json.dumps({"pacing": report.to_dict(), "stats": stats, "plan_kept": not problems,
                                                 "problems": problems}, indent=1, default=float))
    for text in problems:
        print(f"benchtwin: warning: plan not kept: {text}", file=sys.stderr, flush=True)
    print("plan kept" if not problems else f"PLAN NOT KEPT ({len(problems)} problem{'s' * (len(problems) > 1)})",
          flush=True)
    return 1 if problems else 0


def _plan_problems(report: Any, before: dict[str, Any], after: dict[str, Any]) -> list[str]:
    """Print what was achieved; return what of the plan was not kept (lost deliveries, the speed-up, receiving
    clients gone before the end of the run)."""
    out = []
    print(f"achieved speed-up {report.achieved_speedup:.3g} of {report.speedup:g} requested; ended "
          f"{report.late_s:.3f} s late, worst item {report.pacing_max_ms:.1f} ms late", flush=True)
    if report.lost:
        out.append(f"{report.lost} items could not be delivered")
    if not report.speedup_held():
        out.append(f"speed-up {report.speedup:g} not held: achieved {report.achieved_speedup:.3g}, the run ended "
                   f"{report.late_s:.3f} s late (worst item {report.pacing_max_ms / 1e3:.3f} s late)")
    left = int(after.get("raw_clients_left", 0)) - int(before.get("raw_clients_left", 0))
    dropped = int(after.get("clients_dropped", 0)) - int(before.get("clients_dropped", 0))
    if left > 0:
        out.append(f"{left} receiving client(s) left before the end of the run (a recorder died or stopped); "
                   f"{dropped} of them dropped by the endpoint for lagging")
    if after:
        print(f"clients: {int(after.get('clients_connected', 0))} connected at the end, {max(left, 0)} left during "
              f"the run, {max(dropped, 0)} dropped for lagging", flush=True)
    return out
