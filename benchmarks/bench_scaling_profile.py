"""Where the chain and identify stages of ``validate --out`` grow faster than the campaign: cProfile at two sizes.

Usage::

    python benchmarks/bench_scaling_profile.py [--sizes 1,3] [--campaign quick] [--setup paper] [--dir DIR]
                                               [--stages chain,identify] [--top 25]

Per size, the campaign's tests are written that many times (``bench_stream.repeated_campaign``) and simulated whole;
then each stage runs under cProfile as ``validate --out`` runs it: ``chain`` is
``run_chunked(time_slices(trace_pieces(trace)), setup, seed, out_dir, keep_chunks=True)`` (bus logs, poll logs and
``recording.mf4`` written, the Recording read back from the chunk files), ``identify`` is ``identify_all(rec, specs,
type_b=True)`` on that Recording, its type B re-runs on the profiled thread (cProfile sees one thread; the chain's
second thread, encoding and delivering, is not in the chain's profile). The profiles are written to ``DIR`` as
``<stage>_x<n>.prof``; the table printed per stage lists the functions whose own time (tottime) and cumulative time
grew the most from the first size to the last, with the ratio to compare with the size ratio (a linear part has a
ratio near the size ratio; cProfile's overhead inflates Python-heavy parts evenly at both sizes).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import cProfile
import pstats
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_stream import repeated_campaign

from benchtwin.chain.stream import run_chunked, time_slices, trace_pieces
from benchtwin.config._base import scenario_path
from benchtwin.config.campaign import load_campaign
from benchtwin.config.setup import load_setup
from benchtwin.config.vehicle import load_vehicle
from benchtwin.emulator import simulate_campaign
from benchtwin.identification.run import identify_all


class _InlineExecutor:
    """A stand-in for ThreadPoolExecutor that runs each task at submit, on the profiled thread (cProfile sees one
    thread); the type B budget is the same for any worker count (``propagate_type_b``)."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        pass

    def __enter__(self) -> _InlineExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def submit(self, fn, *args, **kwargs) -> concurrent.futures.Future:
        fut: concurrent.futures.Future = concurrent.futures.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as e:
            fut.set_exception(e)
        return fut


def profile_size(n: int, args: argparse.Namespace) -> dict[str, float]:
    """Profile the stages on the campaign repeated ``n`` times; return each stage's wall seconds (profiled)."""
    vehicle = load_vehicle(scenario_path("vehicles", f"{args.vehicle}.toml"))
    walls = {}
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        camp = load_campaign(repeated_campaign(n, Path(tmp), scenario_path("campaigns", f"{args.campaign}.toml")))
        trace = simulate_campaign(vehicle, camp)
        setup = load_setup(args.setup)
        prof = cProfile.Profile()
        t0 = time.perf_counter()
        prof.enable()
        rec = run_chunked(time_slices(trace_pieces(trace)), setup, camp.seed, Path(tmp) / "out", keep_chunks=True)
        prof.disable()
        walls["chain"] = time.perf_counter() - t0
        prof.dump_stats(str(args.dir / f"chain_x{n}.prof"))
        del trace
        if "identify" in args.stages:
            from benchtwin.identification import uncertainty

            prof = cProfile.Profile()
            saved, uncertainty.ThreadPoolExecutor = uncertainty.ThreadPoolExecutor, _InlineExecutor
            t0 = time.perf_counter()
            prof.enable()
            try:
                identify_all(rec, vehicle.specs, type_b=True)
            finally:
                prof.disable()
                uncertainty.ThreadPoolExecutor = saved
            walls["identify"] = time.perf_counter() - t0
            prof.dump_stats(str(args.dir / f"identify_x{n}.prof"))
        rec.close()
    return walls


def _table(a: Path, b: Path, ratio: float, top: int) -> str:
    sa, sb = pstats.Stats(str(a)).stats, pstats.Stats(str(b)).stats  # type: ignore[attr-defined]
    rows = []
    for key, vb in sb.items():
        va = sa.get(key, (0, 0, 0.0, 0.0, {}))
        extra = vb[2] - ratio * va[2]  # own seconds beyond linear growth
        rows.append((extra, key, va, vb))
    rows.sort(key=lambda r: r[0], reverse=True)
    out = ["| function | calls a -> b | tottime a -> b (s) | ratio | cumtime a -> b (s) | ratio |",
           "|---|---|---|---|---|---|"]
    for _extra, (file, line, name), va, vb in rows[:top]:
        r_t = vb[2] / va[2] if va[2] else float("inf")
        r_c = vb[3] / va[3] if va[3] else float("inf")
        out.append(f"| {Path(file).name}:{line} {name} | {va[1]} -> {vb[1]} | {va[2]:.2f} -> {vb[2]:.2f} | {r_t:.1f} "
                   f"| {va[3]:.2f} -> {vb[3]:.2f} | {r_c:.1f} |")
    return "\n".join(out)


def main() -> None:
    from _repeated import size_parser

    ap = size_parser(__doc__, "quick")
    ap.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()) / "bench_scaling_profile",
                    help="where the .prof files go")
    ap.add_argument("--stages", default="chain,identify", help="stages profiled (chain always runs)")
    ap.add_argument("--top", type=int, default=25, help="rows per table")
    ap.add_argument("--compare-only", action="store_true", help="only print the tables of profiles already in --dir")
    args = ap.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    sizes = [int(s) for s in args.sizes.split(",")]
    if not args.compare_only:
        for n in sizes:
            print(f"x{n}: " + ", ".join(f"{k} {v:.1f} s" for k, v in profile_size(n, args).items()), flush=True)
    a, b = sizes[0], sizes[-1]
    for stage in args.stages.split(","):
        pa, pb = args.dir / f"{stage}_x{a}.prof", args.dir / f"{stage}_x{b}.prof"
        if pa.exists() and pb.exists():
            print(f"\n### {stage}: x{a} -> x{b} (size ratio {b / a:.1f}), most own time beyond linear\n")
            print(_table(pa, pb, b / a, args.top))


if __name__ == "__main__":
    main()
