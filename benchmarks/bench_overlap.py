"""Whole ``benchtwin validate --out`` processes, their children counted: wall, CPU and the process tree's peak memory.

Usage::

    python benchmarks/bench_overlap.py [--campaign paper] [--setup paper] [--runs 3]
                                       [--root DIR ...] [--mode fork|thread|off ...]

Each variant (a source tree ``--root``, put first on ``PYTHONPATH``, with ``benchtwin.validation.run.SIDE_MODE``
set to ``--mode``; a tree without that variable runs as it is) is started ``--runs`` times, the variants taking
turns (A B A B ...). For each run: the wall seconds, the CPU seconds of the process and every child it waited for
(``os.wait4``), and, sampled every 0.1 s from ``/proc``, the peak over time of the resident sets of the process and
its children summed (``rss``: pages a forked child shares with its parent counted twice) and of their proportional
sets summed (``pss``: a shared page counted once, split between its sharers; ``/proc/PID/smaps_rollup``). Prints
every run and the medians per variant.

A paper-campaign run takes about a minute of CPU and 0.7 GB: run under the shared lock
(``flock /tmp/benchtwin-heavy.lock nice -n 5 python benchmarks/bench_overlap.py ...``).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

_CODE = """
import sys
import benchtwin.validation.run as run
if {mode!r} != "as-is":
    if not hasattr(run, "SIDE_MODE"):
        raise SystemExit("this tree has no SIDE_MODE")
    run.SIDE_MODE = {mode!r}
from benchtwin.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _children(pid: int) -> list[int]:
    """``pid`` and its descendants (read from ``/proc/PID/task/*/children``)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                todo += [int(c) for c in Path(f"/proc/{p}/task/{task}/children").read_text().split()]
        except OSError:
            continue
    return out


def _kb(path: str, key: str) -> int:
    try:
        for line in Path(path).read_text().splitlines():
            if line.startswith(key):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def run_once(root: Path, mode: str, argv: list[str], python: str) -> dict[str, float]:
    """One whole process: wall s, cpu s (children included), peak summed RSS and PSS (MB), children seen."""
    env = dict(os.environ, PYTHONPATH=str(root))
    peak = {"rss": 0, "pss": 0, "procs": 1}
    done = threading.Event()
    t0 = time.perf_counter()
    proc = subprocess.Popen([python, "-c", _CODE.format(mode=mode), *argv], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)

    def sample() -> None:
        while not done.is_set():
            pids = _children(proc.pid)
            peak["procs"] = max(peak["procs"], len(pids))
            peak["rss"] = max(peak["rss"], sum(_kb(f"/proc/{p}/status", "VmRSS:") for p in pids))
            peak["pss"] = max(peak["pss"], sum(_kb(f"/proc/{p}/smaps_rollup", "Pss:") for p in pids))
            done.wait(0.1)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    _pid, status, ru = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    done.set()
    th.join()
    proc.returncode = os.waitstatus_to_exitcode(status)
    return {"wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime, "rss_mb": peak["rss"] / 1024,
            "pss_mb": peak["pss"] / 1024, "procs": peak["procs"], "rc": proc.returncode}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaign", default="paper")
    ap.add_argument("--setup", default="paper")
    ap.add_argument("--runs", type=int, default=3, help="runs per variant (default 3)")
    ap.add_argument("--root", type=Path, action="append", default=None,
                    help="a source tree (repeat; default: this one)")
    ap.add_argument("--mode", action="append", default=None,
                    help="SIDE_MODE per root, in order (fork, thread, off, or as-is for a tree without it; repeat)")
    args = ap.parse_args(argv)
    roots = args.root or [Path(__file__).resolve().parents[1]]
    modes = args.mode or ["as-is"] * len(roots)
    if len(modes) != len(roots):
        ap.error("give one --mode per --root")
    variants = list(zip(roots, modes, strict=True))
    results: dict[int, list[dict[str, float]]] = {k: [] for k in range(len(variants))}
    for r in range(args.runs):
        for k, (root, mode) in enumerate(variants):
            out = Path(tempfile.mkdtemp(prefix="bench_overlap_"))
            try:
                got = run_once(root, mode, ["validate", "--campaign", args.campaign, "--setup", args.setup,
                                            "--out", str(out)], sys.executable)
            finally:
                shutil.rmtree(out, ignore_errors=True)
            results[k].append(got)
            print(f"run {r} {root} {mode}: " + ", ".join(f"{n} {v:.1f}" for n, v in got.items()), flush=True)
    print(f"\nmedians of {args.runs} (load average {os.getloadavg()[0]:.1f})\n"
          "| tree | mode | wall s | cpu s | peak RSS sum MB | peak PSS sum MB |\n|---|---|---|---|---|---|")
    for k, (root, mode) in enumerate(variants):
        med = {n: statistics.median(g[n] for g in results[k]) for n in ("wall_s", "cpu_s", "rss_mb", "pss_mb")}
        print(f"| {root} | {mode} | {med['wall_s']:.1f} | {med['cpu_s']:.1f} | {med['rss_mb']:.0f} | "
              f"{med['pss_mb']:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
