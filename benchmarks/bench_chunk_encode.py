"""Encode -> deliver of a campaign, whole against chunk by chunk, and the chain it feeds: time, memory, same bytes.

Usage::

    python benchmarks/bench_chunk_encode.py [--campaign paper] [--setup paper] [--modes whole,tests,60s]
                                            [--repeat 3] [--seed 0] [--python PYTHON]

    # the chain's stages on the paper campaign, a tree against another (PYTHONPATH selects the tree):
    python benchmarks/bench_chunk_encode.py --modes tests,acquire,chain

Each run is a fresh process (``--one MODE`` runs one mode in this process and prints one JSON line):

- ``whole``: the campaign simulated test by test (``iter_campaign``) and joined into one Trace, then
  ``encode`` + ``deliver`` at once (the whole-run API; it also runs on trees without the chunked encoder,
  for a before/after comparison with ``PYTHONPATH``);
- ``tests``: ``ChunkEncoder`` + ``ChunkDeliverer`` fed one test at a time as ``iter_campaign`` yields it,
  each chunk's frames hashed and dropped;
- ``60s`` (any ``<N>s``): the same, each test cut further into N-s slices;
- ``acquire``: every test encoded and delivered first (untimed), then only the acquisition timed:
  ``Acquisition(setup)`` fed the delivered chunks as ``run_chunked`` feeds them (cut at the bus's
  ``log_truncation``) and ``finish()`` (Recording in memory);
- ``chain``: the campaign simulated test by test first (untimed, held in memory), then
  ``chain.stream.run_chunked`` over those tests timed (encode, deliver, decode; no files), the Recording kept
  in memory as ``validate`` keeps it.

The ``acquire`` and ``chain`` modes digest the Recording (every channel's timestamps, values and flags, and
its meta data) instead of the frames: the same for both modes and any tree that decodes the same.

Reported per mode: the wall and CPU seconds spent in encode + deliver (the plant's time is not counted), the
peak resident set of the process (``getrusage``; the whole mode also holds the campaign's Trace and all its
frames, which is the point), the frames and polls delivered, and a SHA-256 over every bus's frame bytes and
the poll log in delivery order, which must be the same for every mode. Run it under the shared lock:
``flock /tmp/benchtwin-heavy.lock nice -n 5 python benchmarks/bench_chunk_encode.py``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time


def _one(mode: str, campaign: str, setup_name: str, seed: int) -> dict:
    import numpy as np

    from benchtwin.config import load_campaign, load_setup, load_vehicle
    from benchtwin.emulator import iter_campaign
    from benchtwin.trace import Trace

    setup = load_setup(setup_name)
    camp = load_campaign(campaign if campaign.endswith(".toml") else f"{campaign}.toml")
    hashes: dict[str, hashlib._Hash] = {}
    counts = {"frames": 0, "polls": 0}

    def take(received) -> None:
        for bus in sorted(received.can):
            f = received.can[bus].frames
            hashes.setdefault(bus, hashlib.sha256()).update(np.ascontiguousarray(f).tobytes())
            counts["frames"] += len(f)
        for dev in sorted(received.polls):
            log = received.polls[dev]
            for field in ("times", "values", "status"):
                h = hashes.setdefault(f"polls:{dev}.{field}", hashlib.sha256())
                h.update(np.ascontiguousarray(getattr(log, field)).tobytes())
            counts["polls"] += len(log)

    wall = cpu = 0.0
    if mode == "whole":
        from benchtwin.chain.batch import deliver
        from benchtwin.sensors import encode

        parts = list(iter_campaign(load_vehicle(), camp))
        trace = Trace(np.concatenate([p.time_s for p in parts]),
                      {k: np.concatenate([p[k] for p in parts]) for k in parts[0].channels},
                      [s for p in parts for s in p.segments], dict(parts[0].meta))
        del parts
        w0, c0 = time.perf_counter(), time.process_time()
        received = deliver(encode(trace, setup, seed), setup, seed=seed,
                           span_s=(float(trace.time_s[0]), float(trace.time_s[-1])))
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        take(received)
        n_chunks = 1
    elif mode in ("acquire", "chain"):
        from benchtwin.chain.acquisition import Acquisition, AcquisitionInput
        from benchtwin.chain.delivery import iter_delivered
        from benchtwin.chain.stream import run_chunked
        from benchtwin.sensors.imperfections import truncate_log
        from benchtwin.wire.frames import FrameTable

        tests = list(iter_campaign(load_vehicle(), camp))
        n_chunks = len(tests)
        if mode == "chain":
            w0, c0 = time.perf_counter(), time.process_time()
            rec = run_chunked(iter(tests), setup, seed, None)
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        else:
            chunks = []
            for got in iter_delivered(iter(tests), setup, seed):
                chunk = AcquisitionInput(events=list(got.events), polls=dict(got.polls), segments=got.segments)
                for bus in sorted(got.can):
                    t = got.can[bus]
                    chunk.can[bus] = FrameTable(bus, truncate_log(t.frames, setup.faults_of(bus)), t.bitrate)
                chunks.append(chunk)
            del tests
            w0, c0 = time.perf_counter(), time.process_time()
            acq = Acquisition(setup)
            for chunk in chunks:
                acq.feed(chunk)
            rec = acq.finish(meta={"seed": seed})
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        h = hashlib.sha256()
        for name in sorted(rec.channels):
            ch = rec[name]
            for a in (ch.timestamps, ch.values, ch.flags):
                h.update(np.ascontiguousarray(a).tobytes())
            counts["frames"] += len(ch)  # decoded samples, for these modes
        meta = {k: v for k, v in rec.meta.items() if k not in ("trace", "seed")}
        h.update(json.dumps(meta, sort_keys=True, default=str).encode())
        hashes["recording"] = h
    else:
        from benchtwin.chain.delivery import ChunkDeliverer
        from benchtwin.sensors import ChunkEncoder

        step = None if mode == "tests" else float(mode.rstrip("s"))
        enc = ChunkEncoder(setup, seed)
        dl = None
        n_chunks = 0
        last_t = None

        def feed(chunk, final: bool) -> None:
            nonlocal dl, wall, cpu
            w0, c0 = time.perf_counter(), time.process_time()
            if dl is None:
                dl = ChunkDeliverer(setup, seed, start_s=float(chunk.time_s[0]))
            got = dl.feed(enc.feed(chunk, final=final), end_s=last_t)
            wall += time.perf_counter() - w0
            cpu += time.process_time() - c0
            take(got)

        pending = None
        for test in iter_campaign(load_vehicle(), camp):
            pieces = [test] if step is None else [
                c for a in np.arange(test.time_s[0], test.time_s[-1] + step, step)
                if len(c := test.slice_time(a, a + step))]
            for piece in pieces:
                if pending is not None:
                    feed(pending, False)
                    n_chunks += 1
                pending = piece
        last_t = float(pending.time_s[-1])
        feed(pending, True)
        n_chunks += 1
    digest = hashlib.sha256("".join(f"{k}:{h.hexdigest()}" for k, h in sorted(hashes.items())).encode()).hexdigest()
    return {"mode": mode, "chunks": n_chunks, "wall_s": wall, "cpu_s": cpu,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, **counts,
            "sha256": digest[:16]}


def main() -> None:
    """Run every mode ``--repeat`` times in fresh processes and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--campaign", default="paper")
    ap.add_argument("--setup", default="paper")
    ap.add_argument("--modes", default="whole,tests,60s", help="comma-separated: whole, tests, <N>s, acquire, chain")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--python", default=sys.executable, help="interpreter of the tree to measure")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(_one(args.one, args.campaign, args.setup, args.seed)))
        return
    rows = []
    for mode in args.modes.split(","):
        runs = []
        for _ in range(args.repeat):
            out = subprocess.run([args.python, __file__, "--one", mode, "--campaign", args.campaign, "--setup",
                                  args.setup, "--seed", str(args.seed)], capture_output=True, text=True,
                                 env={**os.environ, "PYTHONHASHSEED": "0"})
            if out.returncode:
                raise SystemExit(out.stderr[-2000:])
            runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
        r = runs[0]
        rows.append((mode, r["chunks"], statistics.median(x["wall_s"] for x in runs),
                     statistics.median(x["cpu_s"] for x in runs), statistics.median(x["peak_rss_mb"] for x in runs),
                     r["frames"], r["polls"], {x["sha256"] for x in runs}))
    print(f"machine: {platform.node()} {os.cpu_count()} cores, python {platform.python_version()}; "
          f"campaign {args.campaign}, setup {args.setup}, seed {args.seed}, medians of {args.repeat}")
    print("| mode | chunks | timed wall s | CPU s | peak RSS MB | frames (acquire, chain: samples) | polls | sha256 |")
    print("|---|---|---|---|---|---|---|---|")
    for mode, n, w, c, m, f, p, h in rows:
        print(f"| {mode} | {n} | {w:.2f} | {c:.2f} | {m:.0f} | {f:,} | {p:,} | {','.join(sorted(h))} |")


if __name__ == "__main__":
    main()
