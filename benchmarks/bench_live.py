"""Live delivery benchmark: a loaded CAN bus + Modbus + PDOs over the socketcand endpoint, recorded by
another process.

The server (this process) plays, on our socketcand endpoint on 127.0.0.1:

- bus ``loaded``: 8-byte standard frames at ``--rate`` frames/s (4,000/s fills a 500 kbit/s bus),
- bus ``instrument``: the thermo module's TPDOs (canopen LocalNode, shipped EDS) every 100 ms,
- the pressure module on Modbus TCP (register updates at 500 Hz),

at ``--speedup``. A recorder in a child process (the project's LiveRecorder: drop-aware socketcand
client, pymodbus client polling at 100 Hz of plant time, canopen RemoteNode) records everything and
checks every frame against the served table (same ids and bytes, same order). Reported: pacing error
p50/p99/max of the scheduler, frames sent/received/lost, Modbus polls ok/failed, PDOs, bus load.

    python benchmarks/bench_live.py --duration 600 --speedup 1        # 10 min real time, loaded bus
    python benchmarks/bench_live.py --duration 600 --speedup 20       # 20x over the endpoint
    python benchmarks/bench_live.py ... --results benchmarks/RESULTS.md   # append a section
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from benchtwin.wire.frames import FRAME_DTYPE, DeviceOutputs, FrameTable, ProcessImage, RegisterSnapshots


def loaded_frames(duration_s: float, rate_hz: float) -> np.ndarray:
    """Deterministic 8-byte frames: 16 ids in turn, bytes 0-3 = frame index, 4-7 = a hash of it."""
    n = round(duration_s * rate_hz)
    idx = np.arange(n, dtype=np.uint32)
    f = np.zeros(n, dtype=FRAME_DTYPE)
    f["timestamp"] = idx / rate_hz
    f["arbitration_id"] = 0x100 + (idx % 16)
    f["dlc"] = 8
    f["data"][:, 0:4] = idx.astype(">u4").view(np.uint8).reshape(n, 4)
    f["data"][:, 4:8] = (idx * np.uint32(2654435761)).astype(">u4").view(np.uint8).reshape(n, 4)
    return f


def build_outputs(duration_s: float, rate_hz: float) -> DeviceOutputs:
    from benchtwin.wire.canopen_pdo import pdo_layout

    t_mb = np.arange(0.0, duration_s, 1 / 500)
    regs = np.zeros((len(t_mb), 14), dtype=np.uint16)
    regs[:, 0:5] = (np.arange(len(t_mb))[:, None] * 7 + np.arange(5)) % 65536
    regs[:, 11] = np.arange(len(t_mb)) % 65536
    ms = np.round(t_mb * 1000).astype(np.uint32)
    regs[:, 12], regs[:, 13] = ms >> 16, ms & 0xFFFF
    layout = pdo_layout(5)
    entries = sorted({e for tp in layout.tpdos for e in tp.entries})
    t_pi = np.arange(0.0, duration_s, 0.1)
    vals = (250 + (np.arange(len(t_pi))[:, None] + np.arange(len(entries))) % 500).astype(np.int64)
    return DeviceOutputs(
        can={"loaded": FrameTable("loaded", loaded_frames(duration_s, rate_hz), 500_000)},
        modbus={"brake_pressure": RegisterSnapshots("brake_pressure", 1, 0, t_mb, regs)},
        canopen={"thermo": ProcessImage("thermo", 5, t_pi, entries, vals)})


# ------------------------------------------------------------------------------------------------ child
def child(args: argparse.Namespace) -> int:
    """The recorder process: record, then compare with the served table and print a JSON summary."""
    from benchtwin.chain.live.recorder import LiveRecorder, ModbusPollSpec, open_acquisition_bus
    from benchtwin.wire.canopen_pdo import EDS_PATH

    buses = {b: open_acquisition_bus("socketcand", b, port=args.port) for b in ("loaded", "instrument")}
    with tempfile.TemporaryDirectory() as spool:
        rec = LiveRecorder(buses, spool, speedup=args.speedup,
                           modbus=[ModbusPollSpec("brake_pressure", port=args.modbus_port, unit_id=1, poll_hz=100.0)],
                           canopen={"thermo": (5, EDS_PATH, "instrument")}).start()
        print("ready", flush=True)
        reason = rec.wait(idle_s=3.0)
        cap = rec.stop(reason)
    got = cap.can["loaded"].frames
    expect = loaded_frames(args.duration, args.rate)
    n = min(len(got), len(expect))
    in_order = bool(np.array_equal(got["arbitration_id"][:n], expect["arbitration_id"][:n])
                    and np.array_equal(got["data"][:n], expect["data"][:n]))
    idx = got["data"][:, 0:4].copy().view(">u4").ravel() if len(got) else np.zeros(0)
    missing = len(np.setdiff1d(np.arange(len(expect)), idx))
    polls = cap.polls["brake_pressure"]
    pdo_cobs = np.asarray(cap.pdos["thermo"].cob_ids)
    out = {"reason": reason, "received": len(got), "expected": len(expect), "missing": missing,
           "in_order_and_exact": in_order, "polls": len(polls), "polls_ok": int(np.sum(polls.status == 0)),
           "polls_failed": int(np.sum(polls.status != 0)), "pdos": len(pdo_cobs),
           "instrument_frames": len(cap.can["instrument"])}
    print("RESULT " + json.dumps(out), flush=True)
    return 0


# ------------------------------------------------------------------------------------------------ server
def serve(args: argparse.Namespace) -> dict:
    from benchtwin.chain.live.session import LiveSession
    from benchtwin.wire.canopen_pdo import EDS_PATH

    outputs = build_outputs(args.duration, args.rate)
    session = LiveSession(outputs, transport="socketcand", speedup=args.speedup, eds=EDS_PATH,
                          canopen_bus={"thermo": "instrument"}, bitrates={"instrument": 500_000},
                          realtime_priority=args.realtime).start()
    try:
        # the child recorder is started while this process is real-time: it inherits the policy too
        cmd = [sys.executable, __file__, "child", "--port", str(session.transport.port), "--modbus-port",
               str(session.modbus.port), "--speedup", str(args.speedup), "--duration", str(args.duration),
               "--rate", str(args.rate)]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
        if proc.stdout.readline().strip() != "ready" or not session.wait_for_clients(2, 30):
            raise RuntimeError("recorder did not connect")
        t0 = time.perf_counter()
        report = session.run()
        wall = time.perf_counter() - t0
        stats = session.stats()
    finally:
        session.close()  # the child sees the end (or its idle timeout) and reports
    line = next(ln for ln in proc.stdout if ln.startswith("RESULT "))
    proc.wait(timeout=60)
    res = json.loads(line[7:])
    loaded = report.streams["can:loaded"]
    return {"speedup": args.speedup, "realtime": session.realtime_active,
            "duration_s": args.duration, "rate_hz": args.rate, "wall_s": wall,
            "achieved_speedup": report.achieved_speedup, "frames_served": loaded.sent,
            "frames_per_s_wall": loaded.sent / wall, "bus_load": loaded.bus_load,
            "pacing_p50_ms": report.pacing_p50_ms, "pacing_p99_ms": report.pacing_p99_ms,
            "pacing_max_ms": report.pacing_max_ms, "can_p99_ms": loaded.pacing_p99_ms,
            "modbus_p99_ms": report.streams["modbus:brake_pressure"].pacing_p99_ms,
            "lost_server": report.lost, "endpoint": stats.get("transport", {}), "recorder": res}


_HEADER = ("## Live delivery (benchmarks/bench_live.py)\n\n"
           "Server and socketcand endpoint in one process, recorder (LiveRecorder) in another, loopback.\n"
           "Pacing error = time the delivery call returned minus the item's deadline (all streams).\n\n"
           "| date (UTC) | machine | speed-up | priority | plant time | frames/s (plant) | "
           "bus load (500k) | frames/s (wall) | p50 ms | p99 ms | max ms | frames received | "
           "Modbus polls ok | PDOs |\n"
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")


def _append_row(path: Path, summary: str) -> None:
    """Add a row to the live table of RESULTS.md (after its last row; the section is made if missing)."""
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M")
    row = f"| {stamp} | {platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f} " + summary
    text = path.read_text() if path.exists() else ""
    if "## Live delivery (benchmarks/bench_live.py)" not in text:
        path.write_text(text.rstrip("\n") + "\n\n" + _HEADER + row + "\n")
        return
    lines = text.split("\n")
    head = lines.index("## Live delivery (benchmarks/bench_live.py)")
    i = next(k for k in range(head, len(lines)) if lines[k].startswith("|---"))
    while i + 1 < len(lines) and lines[i + 1].startswith("| "):
        i += 1
    lines.insert(i + 1, row)
    path.write_text("\n".join(lines))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mode", nargs="?", default="serve", choices=["serve", "child"])
    ap.add_argument("--duration", type=float, default=60.0, help="plant seconds")
    ap.add_argument("--rate", type=float, default=4000.0, help="frames/s on the loaded bus (plant time)")
    ap.add_argument("--speedup", type=float, default=1.0)
    ap.add_argument("--port", type=int, default=0)
    ap.add_argument("--modbus-port", type=int, default=0)
    ap.add_argument("--results", help="append a section to this RESULTS.md")
    ap.add_argument("--realtime", type=int, default=None, metavar="PRIO",
                    help="run the pacing thread under SCHED_FIFO at this priority (needs root/CAP_SYS_NICE)")
    args = ap.parse_args()
    if args.mode == "child":
        return child(args)
    r = serve(args)
    print(json.dumps(r, indent=1, default=float))
    rec = r["recorder"]
    lost = rec["expected"] - rec["received"]
    prio = f"FIFO {args.realtime}" if r["realtime"] else "normal"
    summary = (f"| {r['speedup']:g}x | {prio} | {r['duration_s']:g} s | {r['rate_hz']:g} | "
               f"{100 * r['bus_load']:.0f} % | "
               f"{r['frames_per_s_wall']:.0f} | {r['pacing_p50_ms']:.3f} | {r['pacing_p99_ms']:.3f} | "
               f"{r['pacing_max_ms']:.2f} | {rec['received']}/{rec['expected']} ({lost} lost, "
               f"{'exact, in order' if rec['in_order_and_exact'] else 'MISMATCH'}) | "
               f"{rec['polls_ok']}/{rec['polls']} | {rec['pdos']} |")
    print(summary)
    if args.results:
        _append_row(Path(args.results), summary)
    return 0 if lost == 0 and rec["in_order_and_exact"] else 1


if __name__ == "__main__":
    sys.exit(main())
