"""The streamed plant + chain stage of ``validate`` (``_simulated_and_measured``) with the chain's whole producer
(plant, truth spool, encode, deliver) in a forked child or on the chain's prefetch thread: wall, CPU of both
processes, the main thread's wait for the chunks, the pipe's cost, memory.

Usage::

    python benchmarks/bench_chain_fork.py [--campaign paper] [--setup paper] [--repeat 3] [--modes fork,thread]
                                          [--warmup 1]

Each repeat runs the stage once per mode (taking turns), after one untimed warm-up run per mode, on the campaign's
tests (no identification). Modes: ``fork`` (``producer_mode="fork"``: benchtwin/validation/forked_chain.py),
``thread`` (the plant and the encoding on the chain's prefetch thread, the default); ``fork:N`` forked with
``PRODUCER_DEPTH`` N (chunks the child holds made; plain ``fork``: the shipped depth). For each run: the stage's wall
seconds, the CPU seconds of this process and of the child (``os.times``, the child's once it is waited for),
``run_chunked``'s wall seconds, the seconds the chain's main thread waits for the next chunk (summed over the chunks:
``queue.get`` of the prefetch thread, or the pipe's reads and unpickling forked), forked: the seconds this process
spends reading the chunks' bodies out of the pipe (``ForkedIter._read_into`` of the arrays, after each head: the
copy, once the child has written) and the MB read, the plant's seconds as the run reports them and the peak PSS
(``smaps_rollup`` every 0.1 s) of this process, of the child and of the two summed. Prints every run and the medians.
Heavy (~10 s a run): run it under the shared lock, ``flock /tmp/benchtwin-heavy.lock nice -n 5 python ...``.
"""

from __future__ import annotations

import argparse
import os
import threading
import time
from contextlib import ExitStack
from typing import Any

from bench_plant_fork import _children, _pss_mb, compare_modes, timed


def _run(mode: str, vehicle: Any, setup: Any, campaign: Any) -> dict[str, float]:
    import benchtwin.chain.stream as stream
    import benchtwin.validation.forked_chain as fchain
    import benchtwin.validation.run as vrun
    from benchtwin.chain.forked_iter import ForkedIter
    from benchtwin.chain.prefetch import prefetch

    waited: list[float] = []
    copied = [0.0, 0.0]  # seconds, bytes
    chained = [0.0]

    def timed_prefetch(items: Any, depth: int = 1, *, name: str = "prefetch") -> Any:
        return timed(prefetch(items, depth, name=name), waited)

    class TimedForked(ForkedIter):
        def __iter__(self) -> Any:
            it = super().__iter__()
            return timed(it, waited) if self.mode == "fork" else it

        def _read_into(self, *bufs: Any, eof_ok: bool = False) -> bool:
            t = time.perf_counter()
            try:
                return super()._read_into(*bufs, eof_ok=eof_ok)
            finally:
                if len(bufs) > 1 or sum(b.nbytes for b in bufs) > 65536:  # an item's body, not a head
                    copied[0] += time.perf_counter() - t
                    copied[1] += sum(b.nbytes for b in bufs)

    real_chunked = stream.run_chunked

    def timed_chunked(*args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        try:
            return real_chunked(*args, **kwargs)
        finally:
            chained[0] = time.perf_counter() - t

    mode, _, depth = mode.partition(":")
    shipped_depth = stream.PRODUCER_DEPTH
    stream.PRODUCER_DEPTH = int(depth or shipped_depth)
    saved = stream.prefetch, stream.ForkedIter, vrun.run_chunked, fchain.run_chunked
    stream.prefetch, stream.ForkedIter = timed_prefetch, TimedForked  # type: ignore[assignment,misc]
    vrun.run_chunked = fchain.run_chunked = timed_chunked  # type: ignore[assignment]
    try:
        peak = {"self": 0.0, "child": 0.0, "sum": 0.0}
        done = threading.Event()

        def sample() -> None:
            while not done.wait(0.1):
                own = _pss_mb(os.getpid())
                kids = [_pss_mb(pid) for pid in _children()]
                peak["self"] = max(peak["self"], own)
                peak["sum"] = max(peak["sum"], own + sum(kids))
                peak["child"] = max([peak["child"], *kids])

        t0, c0 = time.perf_counter(), os.times()
        sampler = threading.Thread(target=sample, daemon=True)
        if mode == "thread":
            sampler.start()
        with ExitStack() as stack:
            if mode == "fork":  # the sampler's thread after the fork (the child is forked from a process without one)
                real_enter = TimedForked.__enter__

                def enter(self: Any) -> Any:
                    out = real_enter(self)
                    sampler.start()
                    return out

                TimedForked.__enter__ = enter  # type: ignore[method-assign]
            _, _, plant_s = vrun._simulated_and_measured(vehicle, setup, campaign, None, stack, producer_mode=mode)
            wall = time.perf_counter() - t0
        c1 = os.times()
        done.set()
        sampler.join()
        return {"wall_s": wall, "cpu_s": c1.user + c1.system - c0.user - c0.system,
                "child_cpu_s": c1.children_user + c1.children_system - c0.children_user - c0.children_system,
                "chunked_s": chained[0], "wait_s": sum(waited), "chunks": float(len(waited)),
                "copy_s": copied[0], "copy_mb": copied[1] / 2**20, "plant_s": plant_s,
                "pss_mb": peak["self"], "child_pss_mb": peak["child"], "pss_sum_mb": peak["sum"]}
    finally:
        stream.prefetch, stream.ForkedIter, vrun.run_chunked, fchain.run_chunked = saved  # type: ignore[misc]
        stream.PRODUCER_DEPTH = shipped_depth


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--campaign", default="paper", help="shipped campaign name or TOML path (default paper)")
    ap.add_argument("--setup", default="paper", help="shipped setup name (default paper)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per mode (default 3)")
    ap.add_argument("--warmup", type=int, default=1, choices=(0, 1), help="untimed runs per mode first (default 1)")
    ap.add_argument("--modes", default="fork,thread", help="comma-separated producer modes (default fork,thread)")
    compare_modes(ap.parse_args(), _run)

if __name__ == "__main__":
    main()
