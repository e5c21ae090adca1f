"""Peak memory and time of the acquisition of a campaign: whole (``acquire``) vs in chunks (``Acquisition``).

Usage::

    python benchmarks/bench_chunked_acquisition.py [--campaign paper] [--setup paper] [--chunks-s 600,60]
                                                   [--repeat 3] [--keep DIR]

The campaign is simulated, encoded and delivered once (``sensors.encode`` + ``chain.batch.deliver``, as the
logs hold it: ``chain.batch.as_logged``) and the AcquisitionInput pickled to a temporary folder (or ``--keep``).
Each measurement is a fresh process that loads that input and then acquires it one way:

* ``whole``: ``acquire(input)`` (the Recording in memory), then ``Recording.save``;
* ``chunks N s``: ``input.split_by_time`` every N s, each chunk fed to ``Acquisition(setup, path)``, whose
  ``finish()`` saves the MF4 and opens it lazily.

The input is in memory in both cases, so the table gives the acquisition's own increment: the process's peak
resident set (``VmHWM``, reset through ``/proc/self/clear_refs`` once the input is loaded) minus its resident
set at that moment, and the wall time of the acquisition (decode + save); for the chunks also the part of both
spent feeding them (before ``finish()``). Medians over ``--repeat`` runs,
interleaved. The whole and chunked Recordings are compared (every channel and the meta data) once. Run it under
the shared lock: ``flock /tmp/benchtwin-heavy.lock nice -n 5 python benchmarks/bench_chunked_acquisition.py``.
"""

from __future__ import annotations

import argparse
import json
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _status_kb(key: str) -> int:
    m = re.search(rf"^{key}:\s+(\d+)", Path("/proc/self/status").read_text(), flags=re.M)
    return int(m.group(1)) if m else 0


def make_input(campaign: str, setup_name: str, path: Path, seed: int = 0) -> dict:
    """Simulate, encode and deliver the campaign; pickle the AcquisitionInput to ``path``."""
    import pickle

    from benchtwin.chain.batch import as_logged, deliver
    from benchtwin.config import load_campaign, load_setup, load_vehicle
    from benchtwin.emulator import simulate_campaign
    from benchtwin.sensors import encode

    setup = load_setup(setup_name)
    name = campaign if campaign.endswith(".toml") else f"{campaign}.toml"
    trace = simulate_campaign(load_vehicle(), load_campaign(name))
    received = deliver(encode(trace, setup, seed), setup, seed=seed,
                       span_s=(float(trace.time_s[0]), float(trace.time_s[-1])))
    received.segments = list(trace.segments)
    received.meta = {"seed": seed}
    data = as_logged(received, setup)
    with path.open("wb") as fh:
        pickle.dump(data, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return {"plant_s": float(trace.time_s[-1] - trace.time_s[0]),
            "frames": {b: len(t) for b, t in data.can.items()}}


def measure(input_path: Path, setup_name: str, chunk_s: float, out: Path) -> dict:
    """In this process: load the input, reset the peak RSS, acquire (whole if ``chunk_s`` <= 0), report."""
    import gc
    import pickle

    import numpy as np

    from benchtwin.chain.acquisition import Acquisition, acquire
    from benchtwin.config import load_setup

    setup = load_setup(setup_name)
    with input_path.open("rb") as fh:
        data = pickle.load(fh)
    gc.collect()
    Path("/proc/self/clear_refs").write_text("5")  # peak RSS (VmHWM) := RSS now
    base_kb = _status_kb("VmRSS")
    t0 = time.perf_counter()
    if chunk_s <= 0:
        rec = acquire(data, setup)
        rec.save(out)
    else:
        end = max(float(t.frames["timestamp"][-1]) for t in data.can.values() if len(t))
        acq = Acquisition(setup, out)
        for chunk in data.split_by_time(list(np.arange(chunk_s, end, chunk_s))):
            acq.feed(chunk)
        feed = {"feed_s": time.perf_counter() - t0, "feed_increment_mb": (_status_kb("VmHWM") - base_kb) / 1024}
        rec = acq.finish()
        rec.close()
    wall = time.perf_counter() - t0
    return {"wall_s": wall, "base_mb": base_kb / 1024, "increment_mb": (_status_kb("VmHWM") - base_kb) / 1024,
            **(feed if chunk_s > 0 else {})}


def same_content(a: Path, b: Path) -> list[str]:
    """Channels and meta data that differ between two saved Recordings."""
    import numpy as np

    from benchtwin.recording import Recording

    ra, rb = Recording.open(a), Recording.open(b)
    out = [] if list(ra.channels) == list(rb.channels) else ["channel list"]
    for name in ra.channels:
        ca, cb = ra[name], rb[name]
        if not (np.array_equal(ca.timestamps, cb.timestamps) and np.array_equal(ca.values, cb.values, equal_nan=True)
                and np.array_equal(ca.flags, cb.flags)):
            out.append(name)
        ra.drop([name])
        rb.drop([name])
    ma, mb = (json.loads(json.dumps(r.meta, default=str)) for r in (ra, rb))
    out += [f"meta {k}" for k in set(ma) | set(mb) if ma.get(k) != mb.get(k)]
    ra.close()
    rb.close()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--campaign", default="paper", help="campaign name or file (default paper)")
    ap.add_argument("--setup", default="paper", help="setup name or file (default paper)")
    ap.add_argument("--chunks-s", default="600,60", help="chunk lengths (s), comma-separated (default 600,60)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per variant (default 3)")
    ap.add_argument("--keep", type=Path, help="folder for the pickled input and the outputs (default: a temporary one)")
    ap.add_argument("--worker", nargs=4, metavar=("INPUT", "SETUP", "CHUNK_S", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        inp, setup, chunk, out = args.worker
        print(json.dumps(measure(Path(inp), setup, float(chunk), Path(out))))
        return 0
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_chunked_"))
    work.mkdir(parents=True, exist_ok=True)
    inp = work / "input.pkl"
    t0 = time.perf_counter()
    info = make_input(args.campaign, args.setup, inp)
    print(f"input: {info['plant_s']:.0f} s of plant time, {sum(info['frames'].values()):,} frames, "
          f"{inp.stat().st_size / 2**20:.0f} MB pickled, made in {time.perf_counter() - t0:.1f} s", flush=True)
    variants = [0.0] + [float(x) for x in args.chunks_s.split(",") if x.strip()]
    results: dict[float, list[dict]] = {v: [] for v in variants}
    for r in range(args.repeat):
        for v in variants:
            out = work / f"rec_{v:g}.mf4"
            got = subprocess.run([sys.executable, __file__, "--worker", str(inp), args.setup, str(v), str(out)],
                                 cwd=ROOT, capture_output=True, text=True, check=True)
            res = json.loads(got.stdout.strip().splitlines()[-1])
            results[v].append(res)
            print(f"run {r + 1} {'whole' if v <= 0 else f'chunks {v:g} s'}: {res}", flush=True)
    diffs = {v: same_content(work / "rec_0.mf4", work / f"rec_{v:g}.mf4") for v in variants if v > 0}
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    print(f"\nmachine: {platform.node()} {platform.processor() or platform.machine()}, "
          f"{len(__import__('os').sched_getaffinity(0))} cores; date {time.strftime('%Y-%m-%d')}; commit {commit}; "
          f"campaign {args.campaign}, setup {args.setup}, {args.repeat} runs each (medians)\n")
    print("| acquisition | wall (s) | peak RSS increment (MB) | of which feeding the chunks: wall (s), peak (MB) "
          "| RSS with the input loaded (MB) | same Recording |")
    print("|---|---|---|---|---|---|")
    for v in variants:
        rs = results[v]
        name = "whole: acquire + save" if v <= 0 else f"chunks of {v:g} s: Acquisition(setup, path)"
        feed = "-" if v <= 0 else (f"{statistics.median(x['feed_s'] for x in rs):.1f}, "
                                   f"{statistics.median(x['feed_increment_mb'] for x in rs):.0f}")
        same = "-" if v <= 0 else ("yes" if not diffs[v] else f"NO: {', '.join(diffs[v][:4])}")
        print(f"| {name} | {statistics.median(x['wall_s'] for x in rs):.1f} | "
              f"{statistics.median(x['increment_mb'] for x in rs):.0f} | {feed} | "
              f"{statistics.median(x['base_mb'] for x in rs):.0f} | {same} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
