"""The streamed plant + chain stage of ``validate`` (``_simulated_and_measured``) with the plant forked or on the
chain's prefetch thread: wall, CPU, the chain's main thread waiting for the prefetch thread, the child's memory.

Usage::

    python benchmarks/bench_plant_fork.py [--campaign paper] [--setup paper] [--repeat 3] [--modes fork,thread]
                                         [--warmup 1]

Each repeat runs the stage once per mode (taking turns: fork thread fork thread ...) in this process, after one
untimed warm-up run per mode, on the campaign's tests (no identification): the truth spooled, the Recording from
the acquisition's chunk files (closed after each run). For each run: the stage's wall seconds, the CPU seconds of
this process and of the plant's child (``os.times``: the child's counted once it is waited for), ``run_chunked``'s
wall seconds, the seconds the chain's main thread waits for its prefetch thread (``queue.get`` in
:func:`benchtwin.chain.prefetch.prefetch`, summed over the chunks; and for the first chunk alone), the number of
chunks, the plant's seconds as the run reports them, and the peak proportional set (PSS, ``smaps_rollup``, sampled
every 0.1 s by a thread of this benchmark) of this process, of the plant's child and of the two summed, and the
child's peak private memory (``Private_Clean`` + ``Private_Dirty``: its own pages and those it copied on write).
Prints every run and the medians per mode. Heavy (the paper campaign's plant and chain, ~10 s a run): run it under
the shared lock, ``flock /tmp/benchtwin-heavy.lock nice -n 5 python benchmarks/bench_plant_fork.py``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import threading
import time
from contextlib import ExitStack
from typing import Any


def _pss_mb(pid: int, keys: tuple[str, ...] = ("Pss:",)) -> float:
    """The sum of ``keys``' lines of ``smaps_rollup`` (MB; 0 for a process that has ended)."""
    total = 0.0
    try:
        with open(f"/proc/{pid}/smaps_rollup", encoding="ascii") as fh:
            for line in fh:
                if line.startswith(keys):
                    total += int(line.split()[1]) / 1024
    except OSError:  # ended
        pass
    return total


def _children() -> list[int]:
    out = []
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/children", encoding="ascii") as fh:
                out += [int(p) for p in fh.read().split()]
        except OSError:
            pass
    return out


def timed(it: Any, waited: list[float]) -> Any:
    """Yield ``it``'s items, appending to ``waited`` the seconds each took to come (closing ``it`` at the end)."""
    try:
        while True:
            t = time.perf_counter()
            try:
                item = next(it)
            except StopIteration:
                return
            finally:
                waited.append(time.perf_counter() - t)
            yield item
    finally:
        it.close()


def compare_modes(args: argparse.Namespace, run: Any) -> None:
    """Load the scenario of ``args`` (``campaign``, ``setup``), run ``run(mode, vehicle, setup, campaign)`` for each
    of ``args.modes`` taking turns (after ``args.warmup`` untimed rounds), ``args.repeat`` times; print every run and
    the medians per mode."""
    from benchtwin.config import load_campaign, load_setup, load_vehicle, scenario_path

    camp = args.campaign if args.campaign.endswith(".toml") else str(scenario_path("campaigns",
                                                                                    f"{args.campaign}.toml"))
    vehicle, setup = load_vehicle(), load_setup(scenario_path("setups", f"{args.setup}.toml"))
    campaign = load_campaign(camp)
    modes = args.modes.split(",")
    for mode in modes * args.warmup:  # warm-up: numba caches, first-touch of the libraries
        run(mode, vehicle, setup, campaign)
    rows: dict[str, list[dict[str, float]]] = {m: [] for m in modes}
    for k in range(args.repeat):
        for mode in modes:
            r = run(mode, vehicle, setup, campaign)
            rows[mode].append(r)
            print(f"run {k} {mode:6s} " + ", ".join(f"{n} {v:.2f}" for n, v in r.items()), flush=True)
    print(f"load {os.getloadavg()[0]:.2f}; medians of {args.repeat}:")
    for mode in modes:
        med = {n: statistics.median(r[n] for r in rows[mode]) for n in rows[mode][0]}
        print(f"  {mode:6s} " + ", ".join(f"{n} {v:.2f}" for n, v in med.items()))


def _run(mode: str, vehicle: Any, setup: Any, campaign: Any) -> dict[str, float]:
    import benchtwin.chain.stream as stream
    import benchtwin.validation.run as vrun
    from benchtwin.chain.prefetch import prefetch

    waited: list[float] = []
    chained = [0.0]

    def timed_prefetch(items: Any, depth: int = 1, *, name: str = "prefetch") -> Any:
        return timed(prefetch(items, depth, name=name), waited)

    real_chunked = vrun.run_chunked

    def timed_chunked(*args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        try:
            return real_chunked(*args, **kwargs)
        finally:
            chained[0] = time.perf_counter() - t

    stream.prefetch, vrun.run_chunked = timed_prefetch, timed_chunked  # type: ignore[assignment]
    try:
        peak = {"self": 0.0, "child": 0.0, "child_private": 0.0, "sum": 0.0}
        done = threading.Event()

        def sample() -> None:
            while not done.wait(0.1):
                own = _pss_mb(os.getpid())
                kids = [(_pss_mb(pid), _pss_mb(pid, ("Private_Clean:", "Private_Dirty:"))) for pid in _children()]
                peak["self"] = max(peak["self"], own)
                peak["sum"] = max(peak["sum"], own + sum(k[0] for k in kids))
                for pss, private in kids:
                    peak["child"] = max(peak["child"], pss)
                    peak["child_private"] = max(peak["child_private"], private)

        sampler = threading.Thread(target=sample, daemon=True)
        real_forked = vrun.ForkedIter

        class SampledForked(real_forked):  # type: ignore[misc,valid-type]
            def __enter__(self) -> Any:  # the sampler's thread once the child is forked (validate forks only where
                out = super().__enter__()  # no other thread runs: forked_chain.fork_if_alone)
                sampler.start()
                return out

        vrun.ForkedIter = SampledForked  # type: ignore[misc]
        t0, c0 = time.perf_counter(), os.times()
        with ExitStack() as stack:
            _, _, plant_s = vrun._simulated_and_measured(vehicle, setup, campaign, None, stack, plant_mode=mode)
            wall = time.perf_counter() - t0
        c1 = os.times()
        done.set()
        sampler.join()
        return {"wall_s": wall, "cpu_s": c1.user + c1.system - c0.user - c0.system,
                "child_cpu_s": c1.children_user + c1.children_system - c0.children_user - c0.children_system,
                "chunked_s": chained[0], "wait_s": sum(waited), "first_wait_s": waited[0] if waited else 0.0,
                "chunks": float(len(waited)), "plant_s": plant_s,
                "pss_mb": peak["self"], "child_pss_mb": peak["child"],
                "child_private_mb": peak["child_private"], "pss_sum_mb": peak["sum"]}
    finally:
        stream.prefetch, vrun.run_chunked = prefetch, real_chunked  # type: ignore[assignment]
        vrun.ForkedIter = real_forked  # type: ignore[misc]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--campaign", default="paper", help="shipped campaign name or TOML path (default paper)")
    ap.add_argument("--setup", default="paper", help="shipped setup name (default paper)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per mode (default 3)")
    ap.add_argument("--warmup", type=int, default=1, choices=(0, 1),
                    help="untimed runs per mode first (default 1; 0: the first run is this process's first, cold)")
    ap.add_argument("--modes", default="fork,thread", help="comma-separated plant modes (default fork,thread)")
    compare_modes(ap.parse_args(), _run)

if __name__ == "__main__":
    main()
