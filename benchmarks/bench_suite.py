"""Test-suite time: pytest's per-test durations (setup and call apart) and the wall time of a selection.

Runs ``python -m pytest -q --durations=0 -p no:cacheprovider`` on the tests given (default: the whole suite) in
the directory given (default: this checkout), and prints the wall time, the load average before and after and
a markdown table of the slowest phases. Run it on two checkouts one after the other (say the tests of the
branch point unpacked with ``git archive`` and the branch) to compare them on one host in one session::

    flock /tmp/benchtwin-heavy.lock nice -n 5 .venv/bin/python benchmarks/bench_suite.py tests/test_validation.py

The result goes to benchmarks/RESULTS.md, "Test-suite time"; no timed test asserts it.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

_LINE = re.compile(r"^\s*([0-9.]+)s (setup|call|teardown)\s+(\S+)")


def main(argv: list[str] | None = None) -> int:
    """Run the selection once and print its wall time and slowest phases.

    Parameters
    ----------
    argv:
        Command-line arguments (default: ``sys.argv[1:]``); see ``--help``.

    Returns
    -------
    int
        pytest's exit status.
    """
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tests", nargs="*", default=["tests"], help="pytest node ids or paths (default: tests)")
    ap.add_argument("--cwd", type=Path, default=Path(__file__).resolve().parents[1],
                    help="directory to run pytest in (a checkout's root; default: this one)")
    ap.add_argument("--top", type=int, default=30, help="phases listed, slowest first (default 30)")
    args = ap.parse_args(argv)
    if not args.cwd.is_dir():
        print(f"bench_suite: --cwd {args.cwd} is not a directory", file=sys.stderr)
        return 2
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "--durations=0", "-p", "no:cacheprovider",
                          *args.tests], cwd=args.cwd, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    load1 = os.getloadavg()
    rows = [(float(m[1]), m[2], m[3]) for m in map(_LINE.match, out.stdout.splitlines()) if m]
    summary = [ln for ln in out.stdout.splitlines() if re.search(r"\d+ (passed|failed)", ln)]
    print(f"- cwd {args.cwd}, tests {' '.join(args.tests)}")
    print(f"- wall {wall:.1f} s; load average {load0[0]:.1f} -> {load1[0]:.1f}; {summary[-1] if summary else ''}")
    print("\n| s | phase | test |\n|---|---|---|")
    for sec, phase, node in sorted(rows, reverse=True)[:args.top]:
        print(f"| {sec:.2f} | {phase} | {node} |")
    return out.returncode


if __name__ == "__main__":
    raise SystemExit(main())
