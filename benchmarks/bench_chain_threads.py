"""Where the chain stage of ``validate --out`` spends its time, per thread: cProfile of ``run_chunked``'s two threads.

Usage::

    python benchmarks/bench_chain_threads.py [--campaign paper] [--setup paper] [--vehicle p2_phev_9at]
                                             [--dir DIR] [--top 25] [--no-profile]

The campaign is simulated test by test straight into ``run_chunked(..., out_dir, keep_chunks=True)`` as
``validate --out`` runs it (the plant, encode and deliver on the prefetch thread; decoding, the chunk files, the bus
logs and ``finish`` on the calling thread). Each of the two threads has its own profiler (cProfile sees one thread:
the prefetch thread's is started inside its producer), written to ``DIR/main.prof`` and ``DIR/prefetch.prof``; the
top functions by own time and by cumulative time are printed for each, with ``finish``'s seconds and what the main
thread waited for the prefetch thread (``queue.get``). ``--no-profile`` times the stage without profilers (wall and
process CPU seconds). The outputs go to a temporary folder in ``DIR``.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import benchtwin.chain.acquisition as acquisition
import benchtwin.chain.stream as stream
from benchtwin.chain.stream import run_chunked, time_slices
from benchtwin.config._base import scenario_path
from benchtwin.config.campaign import load_campaign
from benchtwin.config.setup import load_setup
from benchtwin.config.vehicle import load_vehicle
from benchtwin.emulator import iter_campaign


def main(argv: list[str] | None = None) -> int:
    """Run the chain stage once (profiled per thread unless ``--no-profile``) and print the tables."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--campaign", default="paper")
    ap.add_argument("--setup", default="paper")
    ap.add_argument("--vehicle", default="p2_phev_9at")
    ap.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()) / "bench_chain_threads")
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--no-profile", action="store_true")
    args = ap.parse_args(argv)
    args.dir.mkdir(parents=True, exist_ok=True)
    vehicle = load_vehicle(scenario_path("vehicles", f"{args.vehicle}.toml"))
    camp = load_campaign(scenario_path("campaigns", f"{args.campaign}.toml"))
    setup = load_setup(args.setup)
    profs: dict[str, cProfile.Profile] = {}
    profile = not args.no_profile
    plain_prefetch, plain_finish = stream.prefetch, acquisition.Acquisition.finish
    seconds: dict[str, float] = {}

    def profiled_prefetch(items, depth=1, *, name="prefetch"):
        def producer():
            pr = profs["prefetch"] = cProfile.Profile()
            pr.enable()
            try:
                yield from items
            finally:
                pr.disable()
        return plain_prefetch(producer() if profile else items, depth, name=name)

    def timed_finish(self, **kw):
        t = time.perf_counter()
        try:
            return plain_finish(self, **kw)
        finally:
            seconds["finish"] = time.perf_counter() - t

    def pieces() -> Iterator:
        for piece in iter_campaign(vehicle, camp):
            yield from time_slices([piece])

    stream.prefetch = profiled_prefetch
    acquisition.Acquisition.finish = timed_finish
    try:
        with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
            main_prof = cProfile.Profile()
            t0, c0 = time.perf_counter(), time.process_time()
            if profile:
                main_prof.enable()
            rec = run_chunked(pieces(), setup, camp.seed, Path(tmp) / "out", keep_chunks=True)
            if profile:
                main_prof.disable()
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            rec.close()
    finally:
        stream.prefetch, acquisition.Acquisition.finish = plain_prefetch, plain_finish
    print(f"chain stage ({args.campaign}): wall {wall:.2f} s, process CPU {cpu:.2f} s, finish {seconds['finish']:.2f} s"
          + (" (profiled)" if profile else ""))
    if not profile:
        return 0
    profs["main"] = main_prof
    for name in ("main", "prefetch"):
        path = args.dir / f"{name}.prof"
        profs[name].dump_stats(str(path))
        st = pstats.Stats(str(path))
        waited = sum(v[3] for k, v in st.stats.items() if k[2] == "get" and k[0].endswith("queue.py"))
        print(f"===== {name} thread ({path}); waited in queue.get {waited:.2f} s")
        st.sort_stats("tottime").print_stats(args.top)
        st.sort_stats("cumulative").print_stats(args.top)
    return 0


if __name__ == "__main__":
    sys.exit(main())
