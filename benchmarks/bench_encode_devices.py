"""The chunked encoder alone, per device: where ``ChunkEncoder.feed`` spends its time and how much of it is GIL-free.

Usage::

    python benchmarks/bench_encode_devices.py [--campaign paper] [--setup paper] [--vehicle p2_phev_9at]
                                              [--workers 1] [--seed 0]

The campaign is simulated test by test first (untimed, held in memory; ``scipy.signal`` and ``control`` imported
before timing, as the plant's start imports them in ``validate``), then fed to one ``ChunkEncoder`` test by test as
``run_chunked``'s prefetch thread feeds it. Printed: the wall and process CPU seconds of the feeds; each device's
``encode`` seconds summed over its blocks (wall, in the calling thread: ``--workers 1``); and the seconds spent
inside the numba kernels that release the GIL (``wire.merge``'s k-way merge; ``sensors.readout``'s read-out, on
trees that have it). What is left (feed minus the kernels) holds the GIL: numpy on small arrays and Python.
Run it under the shared lock (``flock /tmp/benchtwin-heavy.lock nice -n 5 python benchmarks/...``).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from types import ModuleType


def _timed(mod: ModuleType, name: str, into: dict[str, float], key: str) -> None:
    """Wrap ``mod.name`` (looked up at call time by its module) to add its seconds to ``into[key]``."""
    f: Callable | None = getattr(mod, name, None)
    if f is None:
        return

    def wrapped(*a, **k):
        t = time.perf_counter()
        try:
            return f(*a, **k)
        finally:
            into[key] += time.perf_counter() - t

    setattr(mod, name, wrapped)


def main(argv: list[str] | None = None) -> int:
    """Simulate, then time the encoder's feeds per device and print one table."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--campaign", default="paper")
    ap.add_argument("--setup", default="paper")
    ap.add_argument("--vehicle", default="p2_phev_9at")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    import scipy.signal  # noqa: F401  (imported by the plant's start in validate: not the encoder's time)

    import benchtwin.wire.merge as merge
    from benchtwin.config._base import scenario_path
    from benchtwin.config.campaign import load_campaign
    from benchtwin.config.setup import load_setup
    from benchtwin.config.vehicle import load_vehicle
    from benchtwin.emulator import iter_campaign
    from benchtwin.sensors import ChunkEncoder

    vehicle = load_vehicle(scenario_path("vehicles", f"{args.vehicle}.toml"))
    tests = list(iter_campaign(vehicle, load_campaign(scenario_path("campaigns", f"{args.campaign}.toml"))))
    enc = ChunkEncoder(load_setup(args.setup), args.seed, workers=args.workers)
    kernels = {"merge kernel": 0.0, "read-out kernel": 0.0}
    _timed(merge, "_kway_gather", kernels, "merge kernel")
    _timed(merge, "_kway_order", kernels, "merge kernel")
    try:
        import benchtwin.sensors.readout as readout

        _timed(readout, "_read_out", kernels, "read-out kernel")
    except ImportError:  # a tree before the read-out kernel
        pass
    per = {d.name: 0.0 for d in enc.devices}
    for d in enc.devices:
        _timed(d, "encode", per, d.name)
    w0, c0 = time.perf_counter(), time.process_time()
    for i, test in enumerate(tests):
        enc.feed(test, final=i == len(tests) - 1)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    print(f"encode ({args.campaign}, {len(tests)} tests, workers {args.workers}): wall {wall:.2f} s, process CPU "
          f"{cpu:.2f} s; devices' encode {sum(per.values()):.2f} s; "
          + ", ".join(f"{k} {v:.2f} s" for k, v in kernels.items()))
    print("| device | encode s |\n|---|---|")
    for name, s in sorted(per.items(), key=lambda kv: -kv[1]):
        print(f"| {name} | {s:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
