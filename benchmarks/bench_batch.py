"""Batch chain throughput: encode -> raw logs written -> logs read -> decoded Recording, whole paper campaign.

Usage::

    python benchmarks/bench_batch.py [--trace DIR] [--setup paper] [--repeat 3] [--synthetic SECONDS]

The Trace is the emulator's paper campaign (``scenarios/campaigns/paper.toml``; simulated once and
cached in ``--trace`` if given), or a synthetic trace of the given length with ``--synthetic``.
Each stage is timed separately; the report gives medians over the repeats, frames/s end to end
(frames on all buses, PDOs included, divided by encode + deliver + write + read + acquire) and the
real-time factor (campaign seconds per wall second). Saving the Recording MF4 is timed on its own.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchtwin.chain.acquisition import acquire
from benchtwin.chain.batch import deliver, read_logs, write_logs
from benchtwin.config import load_setup, scenario_path
from benchtwin.sensors import encode
from benchtwin.trace import Trace


def paper_trace(cache: Path | None) -> Trace:
    """The paper campaign's Trace (from the cache folder if present)."""
    if cache is not None and (cache / "trace.mf4").exists():
        return Trace.load(cache)
    from benchtwin.config.campaign import load_campaign
    from benchtwin.config.vehicle import load_vehicle
    from benchtwin.emulator import simulate_campaign

    trace = simulate_campaign(load_vehicle(scenario_path("vehicles", "p2_phev_9at.toml")),
                              load_campaign(scenario_path("campaigns", "paper.toml")))
    if cache is not None:
        trace.save(cache)
    return trace


def run_once(trace: Trace, setup_name: str, workdir: Path) -> dict[str, float]:
    """One timed pass; returns stage -> seconds plus counts."""
    setup = load_setup(setup_name)
    t: dict[str, float] = {}

    def timed(name: str, fn, *a, **kw):
        c0, w0 = time.process_time(), time.perf_counter()
        out = fn(*a, **kw)
        t[name] = time.perf_counter() - w0
        t[name + "_cpu"] = time.process_time() - c0
        return out

    outputs = timed("encode", encode, trace, setup, 1)
    received = timed("deliver", deliver, outputs, setup, seed=1,
                     span_s=(float(trace.time_s[0]), float(trace.time_s[-1])))
    received.segments = list(trace.segments)
    del outputs
    logs = workdir / "logs"
    timed("write_logs", write_logs, received, setup, logs)
    n_frames = sum(len(tb) for tb in received.can.values())
    n_polls = sum(len(p) for p in received.polls.values())
    del received
    back, _ = timed("read_logs", read_logs, logs, setup)
    rec = timed("acquire", acquire, back, setup)
    for suffix in ("", "_cpu"):
        t["end_to_end" + suffix] = sum(t[k + suffix] for k in ("encode", "deliver", "write_logs", "read_logs",
                                                                  "acquire"))
    timed("save_recording", rec.save, workdir / "recording.mf4")
    t["frames"] = n_frames
    t["polls"] = n_polls
    t["samples"] = sum(len(c) for c in rec.channels.values())
    t["log_bytes"] = sum(p.stat().st_size for p in logs.glob("*.mf4"))
    shutil.rmtree(logs)
    return t


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print a Markdown section."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trace", type=Path, default=None, help="cache folder for the paper campaign Trace")
    ap.add_argument("--setup", default="paper")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--synthetic", type=float, default=None, help="use a synthetic trace of this many seconds")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.synthetic:
        from benchtwin.sensors.synthetic import synthetic_trace

        trace, source = synthetic_trace(args.synthetic, 100.0), f"synthetic {args.synthetic:.0f} s"
    else:
        trace, source = paper_trace(args.trace), "paper campaign (scenarios/campaigns/paper.toml)"
    print(f"trace: {source}, {trace.duration_s:.0f} s, {len(trace)} samples ({time.perf_counter() - t0:.1f} s "
          f"to get)", flush=True)
    runs = []
    for k in range(args.repeat):
        with tempfile.TemporaryDirectory(prefix="bench_batch_") as d:
            r = run_once(trace, args.setup, Path(d))
        runs.append(r)
        print(f"run {k + 1}: " + ", ".join(f"{n} {v:.2f} s" for n, v in r.items()
                                          if n not in ("frames", "polls", "samples", "log_bytes")), flush=True)
        print(f"       load average {os.getloadavg()[0]:.2f}", flush=True)
    med = {n: statistics.median(r[n] for r in runs) for n in runs[0]}
    frames = med["frames"]
    print()
    print(f"### Batch chain, {source}, setup `{args.setup}`")
    print()
    print(f"Machine: {platform.machine()}, {os.cpu_count()} cores, load average before "
          f"{os.getloadavg()[0]:.2f}; {args.repeat} runs, medians.")
    print()
    print("| stage | wall s (median) | frames/s (wall) | CPU s (median) | frames/s (CPU) |")
    print("|---|---|---|---|---|")
    for n in ("encode", "deliver", "write_logs", "read_logs", "acquire", "end_to_end", "save_recording"):
        c = med[n + "_cpu"]
        print(f"| {n} | {med[n]:.2f} | {frames / med[n]:,.0f} | {c:.2f} | {frames / max(c, 1e-9):,.0f} |")
    print()
    print(f"{frames:,.0f} CAN frames (PDOs included) on {len(load_setup(args.setup).buses)} buses, "
          f"{med['polls']:,.0f} Modbus polls, {med['samples']:,.0f} decoded samples, "
          f"{med['log_bytes'] / 1e6:,.0f} MB of MF4 bus logs.")
    print(f"End to end: **{frames / med['end_to_end']:,.0f} frames/s** wall "
          f"({frames / med['end_to_end_cpu']:,.0f} frames/s of process CPU time), real-time factor "
          f"**{trace.duration_s / med['end_to_end']:,.0f}x** (campaign {trace.duration_s:,.0f} s).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
