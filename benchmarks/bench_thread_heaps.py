"""What glibc keeps resident after threads free their arrays, with and without validate's one heap (``one_heap``).

Usage::

    python benchmarks/bench_thread_heaps.py [--runs 3] [--threads 2] [--steps 300]

Each run is a fresh process: ``--threads`` threads each allocate ``--steps`` arrays of 0.8-32 MB (six alive at a
time) with small arrays between, then join; the main thread trims the heaps as validate does between its stages
(``give_back_freed_memory``: glibc's ``malloc_trim(0)``). Printed per mode: RssAnon grown (MB) after the threads and
after the trim, each run's and the median. ``one_heap`` calls ``benchtwin._heap.one_heap`` first (glibc's
``M_ARENA_MAX`` = 1); ``default`` leaves glibc's arenas (a heap per thread, up to 8 per core). glibc only.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys

_CHILD = """
import re, threading
from pathlib import Path
import numpy as np
from benchtwin._heap import give_back_freed_memory, one_heap
if {one_heap}:
    one_heap()
def anon_mb():
    return int(re.search(r"RssAnon:\\s+(\\d+)", Path("/proc/self/status").read_text()).group(1)) / 1024
before = anon_mb()
def work(seed):
    rng = np.random.default_rng(seed)
    keep = []
    for _ in range({steps}):
        a = np.empty(int(rng.integers(100_000, 4_000_000)))
        a[:] = 1.0
        keep.append(a)
        if len(keep) > 6:
            keep.pop(int(rng.integers(0, len(keep))))
        small = [np.ones(100) for _ in range(50)]
ths = [threading.Thread(target=work, args=(k,)) for k in range({threads})]
for th in ths:
    th.start()
for th in ths:
    th.join()
joined = anon_mb() - before
give_back_freed_memory()
print(joined, anon_mb() - before)
"""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="processes per mode (default 3)")
    ap.add_argument("--threads", type=int, default=2, help="threads allocating (default 2)")
    ap.add_argument("--steps", type=int, default=300, help="arrays each thread allocates (default 300)")
    args = ap.parse_args(argv)
    for mode in ("default", "one_heap"):
        got = []
        for _ in range(args.runs):
            code = _CHILD.format(one_heap=mode == "one_heap", steps=args.steps, threads=args.threads)
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
            got.append(tuple(float(x) for x in out.stdout.split()[-2:]))
        joined, trimmed = zip(*got, strict=True)
        print(f"{mode:9s} after the threads {' '.join(f'{x:6.1f}' for x in joined)} (median "
              f"{statistics.median(joined):.1f}) MB; after the trim {' '.join(f'{x:6.1f}' for x in trimmed)} "
              f"(median {statistics.median(trimmed):.1f}) MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
