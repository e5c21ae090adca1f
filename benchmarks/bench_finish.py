"""CPU and wall of ``Acquisition.finish`` and of its parts, on a campaign streamed as ``validate`` streams it.

Usage::

    python benchmarks/bench_finish.py [--campaign paper] [--setup paper] [--repeat 3] [--json FILE]

Each repeat runs a fresh process: the campaign simulated test by test into
:func:`benchtwin.chain.stream.run_chunked` (``keep_chunks=True``, ``defer_save=True``, the logs written to a
temporary folder: what ``validate --out`` runs), with timers around ``Acquisition.finish`` and the module-level
functions it calls (looked up in :mod:`benchtwin.chain.acquisition` by name; a part missing from the tree measured
is left out; the clock offsets found on a thread beside the other passes, where the tree does: the wait for them),
and around ``write_side_files`` (run just before ``finish``). Per part: the wall and the process CPU
(all threads, ``time.process_time``: a part that runs helpers on threads counts them) while it runs; medians over
the repeats. The chain before ``finish`` is not timed here (``bench_timeline.py`` and ``bench_overlap.py`` are the
whole-run figures). Run it under the shared lock:
``flock /tmp/benchtwin-heavy.lock nice -n 5 python benchmarks/bench_finish.py``.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: functions of benchtwin.chain.acquisition timed inside finish (those the tree has)
PARTS = ("flag_truncations", "decode_spooled", "flag_saturation", "detect_faults", "clock_offsets", "_flag_counts",
         "declared_uncertainty", "DeferredSave")


def _timed(fn, name: str, out: dict[str, list[float]]):
    def wrapper(*args, **kwargs):
        w, c = time.perf_counter(), time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            got = out.setdefault(name, [0.0, 0.0])
            got[0] += time.perf_counter() - w
            got[1] += time.process_time() - c
    return wrapper


def measure(campaign_name: str, setup_name: str) -> dict[str, list[float]]:
    """In this process: stream the campaign into the chain with the timers in place; per part [wall, CPU]."""
    import benchtwin.chain.acquisition as acq_mod
    import benchtwin.chain.stream as stream_mod
    from benchtwin.chain.stream import run_chunked, time_slices
    from benchtwin.config import load_campaign, load_setup, load_vehicle
    from benchtwin.emulator import iter_campaign

    times: dict[str, list[float]] = {}
    for name in PARTS:
        if hasattr(acq_mod, name):
            setattr(acq_mod, name, _timed(getattr(acq_mod, name), name, times))
    try:  # the clock offsets found on a thread beside the other passes: the wait for them (and the check)
        import benchtwin.chain.offsets_beside as beside_mod
    except ImportError:
        pass
    else:
        beside_mod.OffsetsBeside.result = _timed(beside_mod.OffsetsBeside.result, "clock_offsets (beside: wait)",
                                                 times)
    stream_mod.write_side_files = _timed(stream_mod.write_side_files, "write_side_files", times)
    acq_mod.Acquisition.finish = _timed(acq_mod.Acquisition.finish, "finish", times)
    name = campaign_name if campaign_name.endswith(".toml") else f"{campaign_name}.toml"
    campaign = load_campaign(name)
    vehicle, setup = load_vehicle(), load_setup(setup_name)

    def pieces():
        for piece in iter_campaign(vehicle, campaign):
            yield from time_slices([piece])

    with tempfile.TemporaryDirectory() as tmp:
        w, c = time.perf_counter(), time.process_time()
        rec = run_chunked(pieces(), setup, campaign.seed, tmp, keep_chunks=True, defer_save=True)
        times["run_chunked"] = [time.perf_counter() - w, time.process_time() - c]
        w, c = time.perf_counter(), time.process_time()
        rec.close()  # the deferred save runs here (not part of finish): timed apart
        times["close (save + cleanup)"] = [time.perf_counter() - w, time.process_time() - c]
    return times


def main(argv: list[str] | None = None) -> int:
    """Run the measurements in fresh processes and print the medians."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaign", default="paper")
    ap.add_argument("--setup", default="paper")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", help="also write the runs and medians to this file")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(measure(a.campaign, a.setup)))
        return 0
    runs = []
    for _ in range(a.repeat):
        out = subprocess.run([sys.executable, __file__, "--child", "--campaign", a.campaign, "--setup", a.setup],
                             check=True, capture_output=True, text=True).stdout
        runs.append(json.loads(out.strip().splitlines()[-1]))
    names = list(runs[0])
    med = {n: [statistics.median(r[n][k] for r in runs if n in r) for k in (0, 1)] for n in names}
    print(f"{platform.node()} {platform.processor() or platform.machine()}, campaign {a.campaign}, "
          f"{a.repeat} runs, medians")
    print(f"{'part':28s} {'wall s':>8s} {'CPU s':>8s}")
    for n in names:
        print(f"{n:28s} {med[n][0]:8.3f} {med[n][1]:8.3f}")
    inner = sum(med[n][0] for n in names if n in PARTS or n.startswith("clock_offsets"))
    print(f"{'finish, outside the parts':28s} {med['finish'][0] - inner:8.3f}")
    if a.json:
        Path(a.json).write_text(json.dumps({"runs": runs, "medians": med}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
