"""The window reads of the type B re-runs (``identify_all(type_b=True)``) on a Recording read from the acquisition's
chunk files, for a campaign repeated 1x, 3x, ...: the most bytes of block reads alive at once and who read them.

Usage::

    python benchmarks/bench_window_reads.py [--sizes 1,3] [--campaign paper] [--setup paper] [--json FILE]

Each size runs in a fresh process: the campaign's tests written that many times, simulated and run through the chain
with the Recording kept in chunk files (``_repeated.chunked_recording``), then ``identify_all(type_b=True)`` with
``_windows._window`` wrapped: every block it reads from a channel read by blocks is held weakly, with the call stack
(benchtwin frames) that asked for it. A thread sums the bytes of the reads alive every 0.02 s and keeps the largest
sum with its breakdown by channel and caller; the largest single read is reported too. What grows from one size to the
next is memory that grows with the campaign. With ``--loads N`` the whole-channel reads (``LazyChannel._load`` of a
channel not in memory) of more than ``N`` samples are listed too, by channel and caller, with their count and bytes.
To measure another tree, run this script with ``PYTHONPATH`` set to it.
"""

from __future__ import annotations

import collections
import gc
import json
import os
import subprocess
import sys
import tempfile
import threading
import traceback
import weakref
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _stack(skip: int = 1) -> str:
    frames = [f for f in traceback.extract_stack()[:-skip] if "benchtwin" in f.filename and "_reuse" not in f.filename
              and not f.filename.endswith("recording.py")]
    return " > ".join(f"{Path(f.filename).name}:{f.lineno}:{f.name}" for f in frames[-5:])


def _watch_loads(min_samples: int) -> dict[str, list[float]]:
    """Wrap ``LazyChannel._load``: whole reads of more than ``min_samples`` samples, by channel and caller ->
    [count, MB]."""
    from benchtwin.recording import LazyChannel

    loads: dict[str, list[float]] = {}
    orig = LazyChannel._load

    def load(self):  # type: ignore[no-untyped-def]
        fresh = self._arrays is None
        arrays = orig(self)
        if fresh and len(self) > min_samples:
            row = loads.setdefault(f"{self.name} ({len(self)} samples): {_stack(2)}", [0, 0.0])
            row[0] += 1
            row[1] += round(sum(a.nbytes for a in arrays) / 1e6, 2)
        return arrays

    LazyChannel._load = load  # type: ignore[method-assign]
    return loads


def one(n: int, campaign: str, setup: str, vehicle_name: str, min_load: int | None = None) -> dict[str, Any]:
    """Measure the window reads on the campaign repeated ``n`` times (in this process)."""
    from _repeated import chunked_recording

    from benchtwin.identification import _windows
    from benchtwin.identification.run import identify_all

    alive: dict[int, tuple[weakref.ref, str, int, str]] = {}
    lock = threading.Lock()
    largest = {"bytes": 0, "who": ""}
    orig = _windows._window

    def wrapped(ch, start_s, end_s, ordered=None):  # type: ignore[no-untyped-def]
        w = orig(ch, start_s, end_s, ordered)
        if w is not None and _windows.reads_by_block(ch):
            stack = " > ".join(f"{Path(f.filename).name}:{f.lineno}:{f.name}" for f in traceback.extract_stack()[:-1]
                               if "benchtwin" in f.filename and "_reuse" not in f.filename)
            stack = " > ".join(stack.split(" > ")[-5:])
            total = 0
            for arr in w[1:]:
                base = arr.base if arr.base is not None else arr
                key = id(base)
                total += base.nbytes
                with lock:
                    alive[key] = (weakref.ref(base, lambda _r, k=key: alive.pop(k, None)), stack, base.nbytes,
                                  ch.name)
            if total > largest["bytes"]:
                largest.update(bytes=total, who=f"{ch.name} {end_s - start_s:.0f} s: {stack}")
        return w

    _windows._window = wrapped
    most: dict[str, Any] = {"bytes": 0, "arrays": 0, "by": []}
    stop = threading.Event()

    def monitor() -> None:
        while not stop.is_set():
            with lock:
                items = [(r(), st, nb, name) for r, st, nb, name in list(alive.values())]
            items = [i for i in items if i[0] is not None]
            total = sum(i[2] for i in items)
            if total > most["bytes"]:
                by: collections.Counter[str] = collections.Counter()
                for _a, st, nb, name in items:
                    by[f"{name}: {st}"] += nb
                most.update(bytes=total, arrays=len(items), by=[(k, round(v / 1e6, 2)) for k, v in by.most_common(8)])
            del items
            stop.wait(0.02)

    with tempfile.TemporaryDirectory() as tmp:
        vehicle, rec = chunked_recording(n, Path(tmp), campaign, setup, vehicle_name)
        rec.drop()
        gc.collect()
        loads = _watch_loads(min_load) if min_load is not None else {}
        th = threading.Thread(target=monitor, daemon=True)
        th.start()
        identify_all(rec, vehicle.specs, type_b=True)
        stop.set()
        th.join()
        rec.close()
    return {"n": n, "alive_max_mb": round(most["bytes"] / 1e6, 2), "alive_arrays": most["arrays"], "by": most["by"],
            "largest_read_mb": round(largest["bytes"] / 1e6, 2), "largest_read": largest["who"],
            "whole_loads": sorted(([k, *v] for k, v in loads.items()), key=lambda r: -r[2])}


def main() -> None:
    from _repeated import size_parser

    ap = size_parser(__doc__, "paper")
    ap.add_argument("--json", type=Path, help="write the rows as JSON")
    ap.add_argument("--loads", type=int, metavar="N", help="also list whole-channel reads of more than N samples")
    ap.add_argument("--one", type=int, help="measure this size in this process (internal)")
    args = ap.parse_args()
    if args.one is not None:
        print(json.dumps(one(args.one, args.campaign, args.setup, args.vehicle, args.loads)))
        return
    rows = []
    for n in [int(s) for s in args.sizes.split(",")]:
        cmd = [sys.executable, __file__, "--one", str(n), "--campaign", args.campaign, "--setup", args.setup,
               "--vehicle", args.vehicle] + (["--loads", str(args.loads)] if args.loads is not None else [])
        out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=os.environ).stdout
        rows.append(json.loads(out.strip().splitlines()[-1]))
    for r in rows:
        print(f"x{r['n']}: window reads alive at most {r['alive_max_mb']} MB in {r['alive_arrays']} arrays; "
              f"largest read {r['largest_read_mb']} MB ({r['largest_read']})")
        for who, mb in r["by"]:
            print(f"    {mb:8.2f} MB  {who}")
        for who, count, mb in r.get("whole_loads", []):
            print(f"    whole read x{count}, {mb:.2f} MB: {who}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
