"""Size and CPU cost of each MF4 compression for the files a run writes: bus logs, Recording, Trace, poll logs.

Run ``benchtwin validate --out DIR`` on the paper campaign first (``make demo`` writes ``out/demo``), then::

    flock /tmp/benchtwin-heavy.lock nice -n 5 .venv/bin/python benchmarks/bench_files.py DIR [--repeat 3]

Each file of DIR is read once, then written again with every choice (asammdf ``compression`` 0 none,
1 deflate, 2 transposed deflate; for the ``.npz`` poll logs ``np.savez`` against ``np.savez_compressed``),
``--repeat`` times: the table gives the size, the median wall and CPU seconds of the write and of reading
the file back, and checks that what is read back equals what was written. The Trace is the paper
campaign simulated here (``--no-trace`` leaves it out). Prints a Markdown section for benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import tempfile
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

CHOICES = {0: "none", 1: "deflate", 2: "transposed deflate"}


def _timed(fn: Callable[[], Any], repeat: int) -> tuple[float, float, Any]:
    walls, cpus, out = [], [], None
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return statistics.median(walls), statistics.median(cpus), out


def _rows_bus_log(path: Path, tmp: Path, repeat: int) -> list[list[str]]:
    from benchtwin.chain.buslog import read_mf4, write_mf4

    table = read_mf4(path)
    rows = []
    for c, name in CHOICES.items():
        out = tmp / f"{path.stem}.{c}.mf4"
        w, cpu, _ = _timed(lambda out=out, c=c: write_mf4(table, out, compression=c), repeat)
        rw, _rcpu, back = _timed(lambda out=out: read_mf4(out), repeat)
        same = back.frames.tobytes() == table.frames.tobytes()
        rows.append([path.name, f"{len(table):,} frames", name, f"{out.stat().st_size / 1e6:.1f}", f"{w:.2f}",
                     f"{cpu:.2f}", f"{rw:.2f}", "yes" if same else "NO"])
        out.unlink()
    return rows


def _digest(rec: Any) -> bytes:
    import hashlib

    h = hashlib.sha256()
    for n, ch in rec.channels.items():
        h.update(n.encode())
        for a in (ch.timestamps, ch.values, ch.flags):
            h.update(a.tobytes())
    return h.digest()


def _rows_recording(path: Path, tmp: Path, repeat: int) -> list[list[str]]:
    from benchtwin.recording import Recording

    rec = Recording.load(path)
    want = _digest(rec)
    n = sum(len(ch) for ch in rec.channels.values())
    rows = []
    for c, name in CHOICES.items():
        out = tmp / f"recording.{c}.mf4"
        w, cpu, _ = _timed(lambda out=out, c=c: rec.save(out, compression=c), repeat)
        rw, _rcpu, back = _timed(lambda out=out: Recording.load(out), repeat)
        rows.append([path.name, f"{n:,} samples, {len(rec.channels)} ch", name, f"{out.stat().st_size / 1e6:.1f}",
                     f"{w:.2f}", f"{cpu:.2f}", f"{rw:.2f}", "yes" if _digest(back) == want else "NO"])
        out.unlink()
    return rows


def _rows_trace(tmp: Path, repeat: int) -> list[list[str]]:
    from benchtwin.config import load_campaign, load_vehicle, scenario_path
    from benchtwin.emulator import simulate_campaign
    from benchtwin.trace import Trace

    trace = simulate_campaign(load_vehicle(scenario_path("vehicles", "p2_phev_9at.toml")),
                              load_campaign(scenario_path("campaigns", "paper.toml")))
    rows = []
    for c, name in CHOICES.items():
        d = tmp / f"trace{c}"
        w, cpu, out = _timed(lambda d=d, c=c: trace.save(d, compression=c), repeat)
        rw, _rcpu, back = _timed(lambda d=d: Trace.load(d), repeat)
        same = back.time_s.tobytes() == trace.time_s.tobytes() and all(
            np.asarray(back[k], np.float64).tobytes() == np.asarray(v, np.float64).tobytes()
            for k, v in trace.channels.items())
        rows.append(["trace.mf4 (paper campaign)", f"{len(trace):,} x {len(trace.channels)} ch", name,
                     f"{out.stat().st_size / 1e6:.1f}", f"{w:.2f}", f"{cpu:.2f}", f"{rw:.2f}", "yes" if same else "NO"])
        out.unlink()
    return rows


def _rows_polls(path: Path, tmp: Path, repeat: int) -> list[list[str]]:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    rows = []
    for name, save in (("none (np.savez)", np.savez), ("deflate (np.savez_compressed)", np.savez_compressed)):
        out = tmp / "polls.npz"
        w, cpu, _ = _timed(lambda out=out, save=save: save(out, **arrays), repeat)

        def load(out: Path = out) -> dict[str, np.ndarray]:
            with np.load(out, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}

        rw, _rcpu, back = _timed(load, repeat)
        same = all(back[k].tobytes() == v.tobytes() for k, v in arrays.items())
        rows.append([path.name, f"{len(arrays['times']):,} polls", name, f"{out.stat().st_size / 1e6:.1f}",
                     f"{w:.2f}", f"{cpu:.2f}", f"{rw:.2f}", "yes" if same else "NO"])
        out.unlink()
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("demo", type=Path, help="output folder of `benchtwin validate --out DIR` (paper campaign)")
    ap.add_argument("--repeat", type=int, default=3, help="writes and reads per choice (median reported)")
    ap.add_argument("--no-trace", action="store_true", help="leave out the Trace (it is simulated here)")
    args = ap.parse_args()
    rows: list[list[str]] = []
    with tempfile.TemporaryDirectory(prefix="bench_files") as tmp:
        t = Path(tmp)
        for p in sorted(args.demo.glob("*.mf4")):
            if p.name == "recording.mf4":
                rows += _rows_recording(p, t, args.repeat)
            else:
                rows += _rows_bus_log(p, t, args.repeat)
        for p in sorted(args.demo.glob("*.polls.npz")):
            rows += _rows_polls(p, t, args.repeat)
        if not args.no_trace:
            rows += _rows_trace(t, args.repeat)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    print("## File sizes and compression (benchmarks/bench_files.py)\n")
    print(f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, machine {platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}, load average {os.getloadavg()[0]:.1f}, commit {commit}")
    print(f"- files of `benchtwin validate --out` on the paper campaign; medians of {args.repeat} writes and reads\n")
    print("| file | content | compression | size (MB) | write wall (s) | write CPU (s) | read wall (s) "
          "| read back equal |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    main()
