"""Where the resident memory of ``benchtwin validate --out DIR`` goes: a timeline sampled every 0.1 s with a stage.

Usage::

    python benchmarks/bench_timeline.py [--campaign paper] [--setup paper] [--interval 0.1] [--csv FILE]
                                        [--depth 3] [--out DIR]

The command runs in this process (``benchtwin.cli.main``); a thread reads ``VmRSS`` from ``/proc/self/status``
every ``--interval`` seconds and, as the stage marker, the benchtwin functions on the main thread's stack below
``_validate`` (the first ``--depth`` of them, e.g. ``_validate>chain_checks>_chain_checks``). It prints, per stage
in the order first seen, the seconds sampled in it, its first and last sample time and its peak resident set, then
the run's peak and where it was reached; ``--csv`` also writes every sample (time, RSS in MB, stage). The sampler
needs the GIL, so a stage that holds it long (a numba kernel without ``nogil``) is seen late, not missed.

The paper campaign needs about 1 GB and a minute of CPU: run it under the shared lock
(``flock /tmp/benchtwin-heavy.lock nice -n 5 python benchmarks/bench_timeline.py``).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

_RSS = re.compile(r"VmRSS:\s+(\d+)")


def _rss_mb() -> float:
    m = _RSS.search(Path("/proc/self/status").read_text())
    return int(m.group(1)) / 1024 if m else float("nan")


def _stage(thread_id: int, depth: int) -> str:
    frame = sys._current_frames().get(thread_id)
    names: list[str] = []
    while frame is not None:
        code = frame.f_code
        if "benchtwin" in code.co_filename and "benchmarks" not in code.co_filename:
            names.append(code.co_name)
        frame = frame.f_back
    names.reverse()
    if "_validate" in names:
        names = names[names.index("_validate"):]
    return ">".join(names[:depth]) or "(outside benchtwin)"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaign", default="paper", help="campaign name or file (default paper)")
    ap.add_argument("--setup", default="paper", help="setup name or file (default paper)")
    ap.add_argument("--interval", type=float, default=0.1, help="seconds between samples (default 0.1)")
    ap.add_argument("--depth", type=int, default=3, help="benchtwin functions named per stage (default 3)")
    ap.add_argument("--csv", type=Path, default=None, help="also write every sample here")
    ap.add_argument("--out", type=Path, default=None, help="the run's --out (default: a temporary folder)")
    args = ap.parse_args(argv)
    from benchtwin.cli import main as cli

    out = args.out or Path(tempfile.mkdtemp(prefix="bench_timeline_"))
    samples: list[tuple[float, float, str]] = []
    done = threading.Event()
    main_id = threading.main_thread().ident
    assert main_id is not None
    t0 = time.perf_counter()

    def sample() -> None:
        while not done.is_set():
            samples.append((time.perf_counter() - t0, _rss_mb(), _stage(main_id, args.depth)))
            done.wait(args.interval)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    try:
        rc = cli(["validate", "--campaign", args.campaign, "--setup", args.setup, "--out", str(out)])
    finally:
        done.set()
        th.join()
        if args.out is None:
            shutil.rmtree(out, ignore_errors=True)
    stages: dict[str, list[float]] = {}
    for t, rss, st in samples:
        s = stages.setdefault(st, [0.0, t, t, rss])
        s[0] += args.interval
        s[2] = t
        s[3] = max(s[3], rss)
    print(f"\nrc {rc}, {len(samples)} samples, wall {time.perf_counter() - t0:.1f} s, "
          f"load average {os.getloadavg()[0]:.1f}\n")
    print("| stage | s sampled | first..last (s) | peak RSS (MB) |\n|---|---|---|---|")
    for st, (n, a, b, peak) in stages.items():
        print(f"| {st} | {n:.1f} | {a:.1f}..{b:.1f} | {peak:.0f} |")
    if samples:
        t, rss, st = max(samples, key=lambda s: s[1])
        print(f"\npeak {rss:.0f} MB at {t:.1f} s in {st}")
    if args.csv is not None:
        with args.csv.open("w", encoding="utf-8") as fh:
            fh.write("t_s,rss_mb,stage\n")
            for t, rss, st in samples:
                fh.write(f"{t:.2f},{rss:.1f},{st}\n")
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
