"""Resident memory of the type B re-runs (``identify_all(type_b=True)``) on a Recording read from the acquisition's
chunk files, for a campaign repeated 1x, 3x, ...: the peak RSS, the peak of traced allocations and the most the
re-runs' shared store (``benchtwin.identification._reuse``) held.

Usage::

    python benchmarks/bench_type_b_rss.py [--sizes 1,3] [--campaign quick] [--setup paper] [--trace] [--trim]
        [--json FILE]

Each size runs in a fresh process (its own peak RSS): the campaign's tests are written that many times
(``bench_stream.repeated_campaign``), simulated and run through the chain test by test with the Recording kept in
chunk files (``run_chunked(..., keep_chunks=True)``, what ``validate --out`` identifies from); its channels are
dropped, the heap trimmed (``malloc_trim(0)``: the baseline is what is alive), the kernel's peak (``VmHWM``) reset
through ``/proc/self/clear_refs`` and ``identify_all(type_b=True)`` run on it. A thread samples the RSS and the bytes
of the store's entries (values and keys) every 0.05 s. ``--trace`` also runs
``tracemalloc`` (slower: the traced peak says whether the RSS growth is Python/numpy allocations or heap the C
allocator keeps); ``--trim`` calls glibc's ``malloc_trim(0)`` after the nominal run and every re-run (a test
of the allocator hypothesis). Environment variables such as ``MALLOC_ARENA_MAX`` pass through to the children.
To measure another tree, run this script with ``PYTHONPATH`` set to it.
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _status_mb(field: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _store_bytes() -> int:
    from benchtwin.identification import _reuse

    if hasattr(_reuse, "stored_bytes"):
        return _reuse.stored_bytes()
    store = _reuse._store
    if store is None:
        return 0
    total = 0
    try:
        for key, (_refs, value) in list(store.items()):
            for v in value if isinstance(value, tuple) else (value,):
                total += getattr(v, "nbytes", 0)
            total += sum(len(k) for k in key[2] if isinstance(k, bytes))  # the key's bytes (grid times, edges)
    except RuntimeError:  # changed size while listed: the next sample counts it
        return -1
    return total


def one(n: int, args: argparse.Namespace) -> dict[str, float]:
    """Measure the stage on the campaign repeated ``n`` times (in this process)."""
    from _repeated import chunked_recording

    from benchtwin.identification import run as run_mod
    from benchtwin.identification.run import identify_all

    with tempfile.TemporaryDirectory() as tmp:
        vehicle, rec = chunked_recording(n, Path(tmp), args.campaign, args.setup, args.vehicle)
        rec.drop()
        gc.collect()
        libc = ctypes.CDLL("libc.so.6")
        libc.malloc_trim(0)  # the baseline is what is alive, not heap the earlier stages left free
        if args.trim:
            orig = run_mod.propagate_type_b

            def trimmed(result, recording, plan, *a, **k):  # type: ignore[no-untyped-def]
                libc.malloc_trim(0)
                out = orig(result, recording, [_trim_after(p, libc) for p in plan], *a, **k)
                libc.malloc_trim(0)
                return out

            run_mod.propagate_type_b = trimmed
        base = _status_mb("VmRSS")
        Path("/proc/self/clear_refs").write_text("5")
        samples: list[tuple[float, float, int]] = []
        stop = threading.Event()

        def sample() -> None:
            t0 = time.perf_counter()
            while not stop.is_set():
                samples.append((time.perf_counter() - t0, _status_mb("VmRSS"), _store_bytes()))
                stop.wait(0.05)

        th = threading.Thread(target=sample, daemon=True)
        if args.trace:
            tracemalloc.start()
        th.start()
        t0 = time.perf_counter()
        res = identify_all(rec, vehicle.specs, type_b=True)
        wall = time.perf_counter() - t0
        stop.set()
        th.join()
        traced = tracemalloc.get_traced_memory()[1] / 1e6 if args.trace else float("nan")
        if args.trace:
            tracemalloc.stop()
        hwm = _status_mb("VmHWM")
        after = _status_mb("VmRSS")
        rec.close()
    return {"n": n, "wall_s": round(wall, 1), "rss_before_mb": round(base, 1), "peak_rss_mb": round(hwm, 1),
            "rss_after_mb": round(after, 1), "traced_peak_mb": round(traced, 1),
            "store_max_mb": round(max((s[2] for s in samples), default=0) / 1e6, 1),
            "reruns": res.meta.get("type_b", {}).get("reruns", 0),
            "fits": {k: {pk: [p.value, p.std_error, p.u_type_b, p.u_total] for pk, p in f.params.items()}
                     for k, f in sorted(res.fits.items())}}


def _trim_after(entry, libc):  # type: ignore[no-untyped-def]
    fits, roles, run = entry

    def wrapped(*a, **k):  # type: ignore[no-untyped-def]
        try:
            return run(*a, **k)
        finally:
            libc.malloc_trim(0)

    return fits, roles, wrapped


def main() -> None:
    from _repeated import size_parser

    ap = size_parser(__doc__, "quick")
    ap.add_argument("--trace", action="store_true", help="also run tracemalloc (the traced peak)")
    ap.add_argument("--trim", action="store_true", help="malloc_trim(0) after the nominal run and every re-run")
    ap.add_argument("--json", type=Path, help="write the rows (with every fit's value and interval) as JSON")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one is not None:
        print(json.dumps(one(args.one, args)))
        return
    rows = []
    for n in [int(s) for s in args.sizes.split(",")]:
        cmd = [sys.executable, __file__, "--one", str(n), "--campaign", args.campaign, "--setup", args.setup,
               "--vehicle", args.vehicle] + (["--trace"] if args.trace else []) + (["--trim"] if args.trim else [])
        out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=os.environ).stdout
        rows.append(json.loads(out.strip().splitlines()[-1]))
    print(f"| {args.campaign} | wall (s) | RSS before (MB) | peak RSS (MB) | RSS after (MB) | traced peak (MB) "
          "| store max (MB) | re-runs |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| x{r['n']} | {r['wall_s']} | {r['rss_before_mb']} | {r['peak_rss_mb']} | {r['rss_after_mb']} "
              f"| {r['traced_peak_mb']} | {r['store_max_mb']} | {r['reruns']} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
