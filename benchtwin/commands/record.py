"""``benchtwin record``: the live acquisition of a served (or real) bench, decoded into a Recording.

Connects to every CAN bus of the setup (python-can over socketcand, or socketcan interfaces),
polls the pressure module over Modbus TCP at the setup's rate, receives the thermo module's PDOs
with a canopen RemoteNode. Raw frames and polls are flushed to ``<out>.spool/`` while recording (at
least every second; the setup and segment table are in the spool from the start), so killing the
recorder at any moment (even ``kill -9``) loses at most the last second received:
``benchtwin acquire <out>.spool --out REC.mf4`` turns the spool into the Recording.
On stop (``--duration``, the stream going idle, Ctrl-C, or every bus connection dropped) everything
received is decoded by the same decoder as batch mode and saved as MF4; the raw logs go to
``<out stem>_raw/`` with the DBC of every bus, the EDS and ``setup.json``, so ``benchtwin acquire
<out stem>_raw`` or cantools decode them on their own.

Where to connect follows python-can's configuration when no flag says otherwise (``can.util.load_config``:
CAN_INTERFACE, CAN_CHANNEL, CAN_CONFIG, ~/can.conf, /etc/can.conf): the interface (socketcand or
socketcan) gives ``--transport``, ``host``/``port`` the socketcand endpoint, and the channel the interface
of a single recorded bus. A flag always wins; without flags or configuration: socketcand on
127.0.0.1:29536.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from benchtwin.commands._common import load_setup_arg, writable_dir, writable_file
from benchtwin.errors import ConfigError

__all__ = ["add_subparser", "run"]


def add_subparser(subparsers: Any) -> None:
    """Register ``record``."""
    p = subparsers.add_parser("record", help="record a live bench into a Recording (MF4)", description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--setup", required=True, help="bench setup file or shipped name (paper, ideal)")
    p.add_argument("--transport", default=None, choices=["socketcand", "socketcan"],
                   help="default: python-can's configured interface, else socketcand")
    p.add_argument("--host", default=None, help="socketcand endpoint host (default: python-can's config, else "
                                                "127.0.0.1)")
    p.add_argument("--port", type=int, default=None, help="socketcand endpoint port (default: python-can's "
                                                          "config, else 29536)")
    p.add_argument("--connect-timeout", type=float, default=10.0,
                   help="seconds to keep trying to reach the endpoint (it may still be starting)")
    p.add_argument("--channel-map", default="", help="socketcan: bus=iface,... (default: the bus names)")
    p.add_argument("--modbus-host", default=None, help="pressure module host (default: --host)")
    p.add_argument("--modbus-port", type=int, default=None, help="pressure module port (default: the setup's)")
    p.add_argument("--no-modbus", action="store_true", help="do not poll the pressure module")
    p.add_argument("--buses", default=None, help="comma-separated buses to record (default: all of the setup)")
    p.add_argument("--speedup", type=float, default=1.0, help="the server's speed-up (acquisition clock scale)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many acquisition seconds")
    p.add_argument("--idle", type=float, default=2.0, help="stop when no frame came for this many wall seconds")
    p.add_argument("--segments", default=None, help="segment table (JSON, from benchtwin serve --segments-out)")
    p.add_argument("--out", required=True, help="Recording to write (.mf4)")
    p.add_argument("--spool", default=None, help="incremental raw logs (default: <out>.spool/)")
    p.set_defaults(func=run)


_DEFAULTS = {"transport": "socketcand", "host": "127.0.0.1", "port": 29536}


def python_can_defaults(args: argparse.Namespace, buses: list[str]) -> tuple[str, str, int, dict[str, str]]:
    """Transport, host, port and channel map: the flags, else python-can's configuration, else the defaults.

    Raises
    ------
    ConfigError
        python-can's configuration names an interface ``record`` cannot use.
    """
    import can

    try:
        cfg = dict(can.util.load_config())
    except (can.CanInterfaceNotImplementedError, ValueError, TypeError):
        cfg = {}  # nothing (or nothing usable) configured
    transport = args.transport
    cmap = {}
    if transport is None and cfg.get("interface"):
        transport = str(cfg["interface"])
        if transport not in ("socketcand", "socketcan"):
            raise ConfigError(f"python-can's configuration selects interface {transport!r}; record reads "
                              "socketcand or socketcan (pass --transport)")
        if cfg.get("channel") and len(buses) == 1:
            cmap[buses[0]] = str(cfg["channel"])
    transport = transport or _DEFAULTS["transport"]
    from_cfg = transport == "socketcand" and cfg.get("interface") in (None, "socketcand")
    host = args.host or (str(cfg["host"]) if from_cfg and cfg.get("host") else _DEFAULTS["host"])
    port = args.port if args.port is not None else (int(cfg["port"]) if from_cfg and cfg.get("port")
                                                    else _DEFAULTS["port"])
    return transport, host, port, cmap


def run(args: argparse.Namespace) -> int:
    """Run ``benchtwin record``."""
    import math

    from benchtwin.chain.live.bench import recorder_from_setup, save_capture
    from benchtwin.segments import load_segments

    if not (args.speedup > 0 and math.isfinite(args.speedup)):
        raise ConfigError(f"--speedup must be a finite number > 0, got {args.speedup}")
    for opt, value in (("--duration", args.duration), ("--idle", args.idle),
                       ("--connect-timeout", args.connect_timeout)):
        if value is not None and not (value > 0 and math.isfinite(value)):
            raise ConfigError(f"{opt} {value}: give a finite number of seconds > 0")
    out = Path(args.out)
    if out.suffix.lower() != ".mf4":
        raise ConfigError(f"--out {out}: the Recording is written as MF4; use a .mf4 name")
    setup = load_setup_arg(args.setup)
    segments = []
    if args.segments:
        try:
            segments = load_segments(args.segments)
        except OSError as exc:
            raise ConfigError(f"--segments {args.segments}: cannot read the segment table ({exc.strerror})") from exc
    buses = [b.strip() for b in args.buses.split(",")] if args.buses else None
    if buses:
        unknown = [b for b in buses if b not in setup.buses]
        if unknown:
            raise ConfigError(f"--buses: {', '.join(unknown)} not in the setup ({', '.join(setup.buses)})")
    spool = Path(args.spool) if args.spool else out.with_name(out.name + ".spool")
    # before connecting: a recording that cannot be saved is a recording lost
    writable_file(out, "--out")
    writable_dir(spool, "--spool")
    raw_dir = out.with_name(out.stem + "_raw")
    if raw_dir.exists() and not raw_dir.is_dir():
        raise ConfigError(f"--out {out}: the raw logs go to {raw_dir}, which is a file")
    transport, host, port, cmap = python_can_defaults(args, buses or list(setup.buses))
    for part in filter(None, (s.strip() for s in args.channel_map.split(","))):
        bus, sep, iface = part.partition("=")
        if not sep:
            raise ConfigError(f"--channel-map: {part!r} is not bus=interface")
        cmap[bus] = iface
    args.transport = transport
    rec = recorder_from_setup(setup, spool, transport=transport, host=host, port=port,
                              modbus_host=args.modbus_host, modbus_port=args.modbus_port, speedup=args.speedup,
                              buses=buses, channel_map=cmap, modbus=not args.no_modbus,
                              connect_timeout=args.connect_timeout, segments=segments)
    rec.start()
    print(f"recording {', '.join(rec.buses)}"
          + (f" + modbus {', '.join(p.spec.device for p in rec.pollers)}" if rec.pollers else "")
          + (f" + canopen {', '.join(rec.canopen_spec)}" if rec.canopen_spec else "")
          + f"; raw spool in {spool}", flush=True)
    reason = rec.wait(duration_s=args.duration, idle_s=args.idle)
    capture = rec.stop(reason)
    print(f"stopped ({reason}): " + ", ".join(f"{b} {len(t)} frames" for b, t in capture.can.items())
          + "".join(f", {d} {len(pl)} polls" for d, pl in capture.polls.items())
          + "".join(f", {n} {len(lg.times)} PDOs" for n, lg in capture.pdos.items()), flush=True)
    drops = [e for e in capture.events if e.kind == "drop"]
    for e in drops:
        print(f"benchtwin: warning: {e.source} dropped at t = {e.time_s:.3f} s ({e.detail}); "
              "samples after it are flagged", file=sys.stderr, flush=True)
    recording = save_capture(capture, setup, out, segments=segments,
                             meta={"transport": args.transport, "stop_reason": reason}, spool_dir=spool)
    print(f"wrote {out} ({len(recording.channels)} channels) and raw logs in {raw_dir}", flush=True)
    return 0
