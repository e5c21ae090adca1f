"""The chain checks of ``benchtwin validate`` (:func:`benchtwin.validation.chain.chain_checks`), timed on one Trace and
Recording against another version of the module.

Run with ``python benchmarks/bench_chain_checks.py [--campaign paper] [--runs 3] [--reference FILE]``: the campaign is
simulated and measured once as ``validate`` streams it (the paper setup), then the checks are made ``--runs`` times
by this tree's module and, with ``--reference``, alternately by a copy of ``chain.py`` from another commit (e.g.
``git show main:benchtwin/validation/chain.py > /tmp/chain_old.py``), on the same input. Prints whether the two
give the same checks, and the median wall and CPU seconds of each. Heavy (the campaign's chain first): run it under
``flock /tmp/benchtwin-heavy.lock nice -n 5``.
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import time
from contextlib import ExitStack
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaign", default="paper")
    ap.add_argument("--setup", default="paper")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--reference", type=Path, help="another version of benchtwin/validation/chain.py to time beside")
    args = ap.parse_args()
    from benchtwin.commands._common import campaign_for_vehicle, load_campaign_arg, load_setup_arg, load_vehicle_arg
    from benchtwin.emulator import absent_channels
    from benchtwin.sensors import setup_for_trace
    from benchtwin.validation import chain as chain_new
    from benchtwin.validation import run

    mods = {"this tree": chain_new}
    if args.reference is not None:
        spec = importlib.util.spec_from_file_location("chain_reference", args.reference)
        assert spec is not None and spec.loader is not None
        ref = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(ref)
        mods = {"reference": ref, **mods}
    vehicle = load_vehicle_arg(None)
    campaign = campaign_for_vehicle(vehicle, load_campaign_arg(args.campaign))
    setup, _ = setup_for_trace(load_setup_arg(args.setup), absent_channels(vehicle))
    with ExitStack() as stack:
        trace, rec, _ = run._simulated_and_measured(vehicle, setup, campaign, None, stack)
        times: dict[str, list[tuple[float, float]]] = {k: [] for k in mods}
        outs: dict[str, list[str]] = {}
        for _ in range(args.runs):
            for name, mod in mods.items():
                t, c = time.perf_counter(), time.process_time()
                got = mod.chain_checks(trace, rec, setup, profile="realistic")
                times[name].append((time.perf_counter() - t, time.process_time() - c))
                outs.setdefault(name, [repr(x) for x in got])
    if len(outs) == 2:
        a, b = outs.values()
        print(f"same checks: {a == b} ({len(a)} checks)")
    for name, tc in times.items():
        print(f"{name}: wall median {statistics.median(w for w, _ in tc):.3f} s, CPU median "
              f"{statistics.median(c for _, c in tc):.3f} s, walls {[round(w, 3) for w, _ in tc]}")


if __name__ == "__main__":
    main()
