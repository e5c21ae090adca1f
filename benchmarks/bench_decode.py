"""CPU seconds of the chain's decoding alone: ``Acquisition.feed`` over the chunks ``validate --out`` feeds it.

Usage::

    python benchmarks/bench_decode.py [--campaign paper] [--setup paper] [--vehicle p2_phev_9at]
                                      [--chunks FILE] [--repeat 3] [--profile FILE] [--dir DIR]

The chunks are made once: the campaign is run through ``run_chunked`` (the plant, encode and deliver as ``validate``
runs them, ``out_dir`` given) with ``Acquisition.feed`` wrapped to pickle every chunk it is given to ``--chunks``
(default ``DIR/chunks_<campaign>.pkl``; an existing file is reused, so two source trees can be timed on the same
chunks). Each run then feeds them, in memory, to a fresh ``Acquisition(setup, DIR/.../recording.mf4,
keep_chunks=True)`` (the chunk files on disk, as ``validate --out``) and times the feeding in CPU seconds of this
thread (``time.thread_time``) and wall seconds; ``finish`` is not run. The median of ``--repeat`` runs is printed
with a digest of what the feeding produced (every chunk file's bytes, the counts, the unknown identifiers and the
fault evidence), which must be the same from one source tree to another. ``--profile FILE`` writes a cProfile of
one more run. Run it from a folder outside the source trees with ``PYTHONPATH`` naming the tree to time, under the
shared lock: ``flock /tmp/benchtwin-heavy.lock nice -n 5 python benchmarks/bench_decode.py``.
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import json
import pickle
import statistics
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any


def prepare(campaign: str, setup_name: str, vehicle_name: str, path: Path, work: Path) -> int:
    """Run the campaign's chain once and pickle every chunk fed to the acquisition (with its ``last``) to ``path``."""
    import benchtwin.chain.acquisition as acquisition
    from benchtwin.chain.stream import run_chunked, time_slices
    from benchtwin.config._base import scenario_path
    from benchtwin.config.campaign import load_campaign
    from benchtwin.config.setup import load_setup
    from benchtwin.config.vehicle import load_vehicle
    from benchtwin.emulator import iter_campaign

    vehicle = load_vehicle(scenario_path("vehicles", f"{vehicle_name}.toml"))
    camp = load_campaign(scenario_path("campaigns", f"{campaign}.toml"))
    setup = load_setup(setup_name)
    plain = acquisition.Acquisition.feed
    n = 0
    tmp_path = path.with_suffix(".part")
    with tmp_path.open("wb") as fh:
        def recording_feed(self: Any, chunk: Any, *, last: bool = False) -> Any:
            nonlocal n
            pickle.dump((chunk, last), fh, protocol=pickle.HIGHEST_PROTOCOL)
            n += 1
            return plain(self, chunk, last=last)

        def pieces() -> Iterator:
            for piece in iter_campaign(vehicle, camp):
                yield from time_slices([piece])

        acquisition.Acquisition.feed = recording_feed
        try:
            with tempfile.TemporaryDirectory(dir=work) as tmp:
                run_chunked(pieces(), setup, camp.seed, Path(tmp) / "out", keep_chunks=True).close()
        finally:
            acquisition.Acquisition.feed = plain
    tmp_path.replace(path)
    return n


def load(path: Path) -> list[tuple[Any, bool]]:
    """The pickled chunks, in order."""
    out = []
    with path.open("rb") as fh:
        while True:
            try:
                out.append(pickle.load(fh))
            except EOFError:
                return out


def digest(acq: Any) -> str:
    """A digest of what ``acq`` holds after feeding: every chunk file's bytes, the counts and the evidence."""
    h = hashlib.sha256()
    store = acq._store
    for name in store.names():
        h.update(name.encode())
        for k in range(3):
            h.update(store._file(name, k).read_bytes())
    h.update(json.dumps([acq._counts, {b: sorted(u.items()) for b, u in acq._unknown.items()}],
                        sort_keys=True, default=str).encode())
    for key in sorted(acq._streams):
        st = acq._streams[key]
        h.update(repr((key, st.emitted_s)).encode())
        for a in (st.t, st.dlc, st.words):
            h.update(a.tobytes())
        for kind, source, channel, ta, tb in st.evidence:
            h.update(f"{kind}|{source}|{channel}".encode())
            h.update(ta.tobytes())
            h.update(tb.tobytes())
    return h.hexdigest()[:16]


def run_once(chunks: list[tuple[Any, bool]], setup: Any, work: Path, prof: cProfile.Profile | None = None
             ) -> tuple[float, float, str]:
    """Feed every chunk to a fresh on-disk Acquisition: (thread CPU s, wall s, digest)."""
    from benchtwin.chain.acquisition import Acquisition

    with tempfile.TemporaryDirectory(dir=work) as tmp:
        acq = Acquisition(setup, Path(tmp) / "recording.mf4", keep_chunks=True)
        try:
            c0, t0 = time.thread_time(), time.perf_counter()
            if prof is not None:
                prof.enable()
            for chunk, last in chunks:
                acq.feed(chunk, last=last)
            if prof is not None:
                prof.disable()
            cpu, wall = time.thread_time() - c0, time.perf_counter() - t0
            return cpu, wall, digest(acq)
        finally:
            acq.close()


def main(argv: list[str] | None = None) -> int:
    """Prepare the chunks (once), time the feeding ``--repeat`` times, print the medians and the digest."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--campaign", default="paper")
    ap.add_argument("--setup", default="paper")
    ap.add_argument("--vehicle", default="p2_phev_9at")
    ap.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()) / "bench_decode")
    ap.add_argument("--chunks", type=Path, help="pickled chunks (made when missing)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--profile", type=Path, help="write a cProfile of one more run here")
    args = ap.parse_args(argv)
    args.dir.mkdir(parents=True, exist_ok=True)
    path = args.chunks or args.dir / f"chunks_{args.campaign}.pkl"
    import benchtwin
    from benchtwin.config.setup import load_setup

    print(f"benchtwin from {Path(benchtwin.__file__).parent}")
    if not path.exists():
        t0 = time.perf_counter()
        n = prepare(args.campaign, args.setup, args.vehicle, path, args.dir)
        print(f"prepared {n} chunks in {time.perf_counter() - t0:.1f} s -> {path}")
    chunks = load(path)
    setup = load_setup(args.setup)
    run_once(chunks[:3], setup, args.dir)  # warm: numba's cached kernels, the decoders
    runs = []
    for r in range(args.repeat):
        cpu, wall, dig = run_once(chunks, setup, args.dir)
        runs.append((cpu, wall, dig))
        print(f"run {r + 1}: feed CPU {cpu:.3f} s, wall {wall:.3f} s, digest {dig}", flush=True)
    digests = {d for _, _, d in runs}
    print(f"{len(chunks)} chunks: median feed CPU {statistics.median(c for c, _, _ in runs):.3f} s, "
          f"wall {statistics.median(w for _, w, _ in runs):.3f} s, digest {' '.join(sorted(digests))}")
    if args.profile:
        prof = cProfile.Profile()
        run_once(chunks, setup, args.dir, prof)
        prof.dump_stats(str(args.profile))
        import pstats
        pstats.Stats(str(args.profile)).sort_stats("tottime").print_stats(30)
    return 0 if len(digests) == 1 else 1


if __name__ == "__main__":
    sys.exit(main())
