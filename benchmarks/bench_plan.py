"""The plan against the seed sweep: predicted standard errors against the spread of the estimates over seeds.

Run with ``.venv/bin/python benchmarks/bench_plan.py [--campaign paper] [--setup paper] [--seeds 20]
[--families transmission,battery,...]`` (under the shared lock on a shared machine: the paper campaign
costs a few CPU seconds per family and seed). Prints a Markdown section to append to benchmarks/RESULTS.md.

:func:`~benchtwin.studies.plan.plan_campaign` predicts each parameter's standard error from the setup's
noise; then each family is validated on its own tests (``validate(..., families=[f], trace=...)``) once per
seed on one plant run (the campaign's cached Trace; the seed varies the sensor noise, which is what the plan
predicts), and the sample standard deviation of each estimate over the seeds is set beside the prediction.
With N seeds, ``(N-1) s^2 / sigma^2 ~ chi2(N-1)``: the script prints the two-sided 99 % interval of
``s / sigma`` so a ratio can be read against it. A family row ``name.*`` with a predicted standard error of 0
(every channel it reads free of random error) is compared with the largest spread of any of its estimates
relative to its value (float rounding leaves about 1e-15). An estimate no plan row covers (a fit added to
identification after its plan: ``battery.rc``) is listed as "not planned" with its std over the seeds, and a plan
row with no predicted standard error is named with its reason below the table; neither is in the count. A family
that runs another's method first (the torque converter runs the transmission's) reports its estimates too: those
another family plans by name are counted below the table, not compared (the plan is for that family's own tests).

A row whose plan says its spread is heavy-tailed (the turbine-torque scale over several calibrated gears: a gear's
median now and then jumps a quantisation level) is still checked on its std, what the plan's standard error is;
its note adds the seeds' robust width (1.4826 MAD) and the plan's reason (the draws' robust width), printed
below the table: with such a tail a std over 20 seeds scatters far more than the chi-square interval says (the
paper campaign's 400 scale draws: 20-draw subsets have a std within 0.28-1.68 times the draws' std, 5-95 %), so
the robust widths are the sharper check of the spread's core.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import time

import numpy as np
from scipy import stats

from benchtwin.config import load_campaign, load_vehicle, scenario_path
from benchtwin.config.setup import load_setup
from benchtwin.emulator.cache import cached_campaign
from benchtwin.studies.plan import plan_campaign
from benchtwin.studies.plan_check import plan_row_of, planned_elsewhere, unplanned_keys
from benchtwin.studies.plan_converter import HEAVY_TAILED, ROBUST_MAD
from benchtwin.validation.run import validate

#: a predicted 0 holds when every estimate agrees over the seeds to this relative spread (float rounding)
ZERO_REL = 1e-9


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaign", default="paper", help="shipped campaign name (default paper)")
    ap.add_argument("--setup", default="paper", help="shipped setup name (default paper)")
    ap.add_argument("--seeds", type=int, default=20, help="seeds of the sweep (default 20)")
    ap.add_argument("--first-seed", type=int, default=1000, help="first seed (default 1000)")
    ap.add_argument("--families", default="transmission,battery", help="comma-separated validation families")
    ap.add_argument("--save-estimates", metavar="JSON", help="write the sweep's estimates (family -> parameter -> "
                    "values over the seeds) to this file")
    ap.add_argument("--estimates", metavar="JSON", help="read the sweep's estimates from a file written by "
                    "--save-estimates instead of running the sweep (the plan is computed anew)")
    ap.add_argument("--save-plan", metavar="JSON", help="also write the plans (family -> plan document) to this file")
    ap.add_argument("--sweep-only", action="store_true", help="run the sweep and write --save-estimates only (no plan)")
    args = ap.parse_args()
    if args.sweep_only and not args.save_estimates:
        ap.error("--sweep-only needs --save-estimates")

    vehicle = load_vehicle()
    setup = load_setup(scenario_path("setups", f"{args.setup}.toml"))
    campaign = load_campaign(scenario_path("campaigns", f"{args.campaign}.toml"))
    fams = args.families.split(",")
    trace, _hit = cached_campaign(vehicle, campaign)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    # one plan per family: its chain runs over the family's own tests, as the family's validation does
    plans = ({} if args.sweep_only else
             {f: plan_campaign(vehicle, setup, campaign, trace=trace, families=[f]).parameters for f in fams})
    t_plan = time.perf_counter() - t0
    if args.save_plan:
        with open(args.save_plan, "w", encoding="utf-8") as fh:
            json.dump({f: [p.to_dict() for p in ps] for f, ps in plans.items()}, fh)
    est: dict[str, dict[str, list[float]]] = {f: {} for f in fams}
    t0 = time.perf_counter()
    if args.estimates:
        with open(args.estimates, encoding="utf-8") as fh:
            saved = json.load(fh)
        est = {f: saved["estimates"][f] for f in fams}
        args.seeds, args.first_seed = saved["seeds"], saved["first_seed"]
    else:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            for fam in fams:
                rep = validate(vehicle, setup, campaign.model_copy(update={"seed": seed}), trace=trace,
                               families=[fam])
                for fname, fit in rep.identification.fits.items():
                    for p in fit.params.values():
                        est[fam].setdefault(f"{fname}.{p.name}", []).append(p.value)
    t_sweep = time.perf_counter() - t0
    if args.save_estimates:
        with open(args.save_estimates, "w", encoding="utf-8") as fh:
            json.dump({"campaign": campaign.name, "setup": setup.name, "seeds": args.seeds,
                       "first_seed": args.first_seed, "estimates": est}, fh)
    if args.sweep_only:
        print(f"sweep of {args.seeds} seeds x {len(fams)} families: {t_sweep:.0f} s -> {args.save_estimates}")
        return
    n = args.seeds
    lo, hi = (math.sqrt(stats.chi2.ppf(a, n - 1) / (n - 1)) for a in (0.005, 0.995))
    rows = []
    heavy: list[str] = []
    unpredicted: list[str] = []
    unplanned: list[tuple[str, str, float, str]] = []
    elsewhere: dict[str, int] = {}
    for fam in fams:
        own = [p.name for p in plans[fam]]
        others = [p.name for f in fams if f != fam for p in plans[f]]
        n_else = sum(plan_row_of(k, own) is None and planned_elsewhere(k, others) is not None for k in est[fam])
        if n_else:
            elsewhere[fam] = n_else
        for key in unplanned_keys(own, est[fam], others):
            v = np.asarray(est[fam][key], dtype=float)
            v = v[np.isfinite(v)]
            sd = float(np.std(v, ddof=1)) if v.size >= 2 else float("nan")
            unplanned.append((fam, key, sd, f"mean {np.mean(v):.6g}, estimated on {v.size} of {n} seeds"
                              if v.size else f"estimated on 0 of {n} seeds"))
        for p in plans[fam]:
            if not (p.identifiable and math.isfinite(p.se)):
                unpredicted.append(f"{fam} {p.name}: {'identifiable' if p.identifiable else 'not identifiable'}, "
                                   f"SE {p.se:g}, {len(est[fam].get(p.name, []))} estimates; {p.reason}")
                continue
            if p.name.endswith(".*"):
                pre = p.name[:-1]
                # the spread relative to the estimate's size: float rounding leaves ~1e-15 where the inputs agree
                sds = [float(np.std(v, ddof=1) / max(abs(float(np.mean(v))), 1e-300)) for k, v in est[fam].items()
                       if k.startswith(pre) and len(v) == n and np.all(np.isfinite(v))]
                if sds:
                    rows.append((fam, p.name, p.se, max(sds), f"{len(sds)} estimates, largest relative spread"))
                continue
            v = np.asarray(est[fam].get(p.name, []), dtype=float)
            v = v[np.isfinite(v)]
            if v.size < 3:
                rows.append((fam, p.name, p.se, float("nan"), f"estimated on {v.size} of {n} seeds"))
                continue
            note = f"mean {np.mean(v):.6g}" + ("" if v.size == n else f", estimated on {v.size} of {n} seeds")
            if HEAVY_TAILED in p.reason:
                robust = ROBUST_MAD * float(np.median(np.abs(v - np.median(v))))
                note += f"; {HEAVY_TAILED}: robust width over the seeds {robust:.3g} (the plan: see below)"
                heavy.append(f"{fam} {p.name}: {p.reason}")
            rows.append((fam, p.name, p.se, float(np.std(v, ddof=1)), note))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    print("## Planned standard errors against the spread over seeds (benchmarks/bench_plan.py)\n")
    print(f"- date {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, machine {platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}, commit {commit}")
    print(f"- campaign {campaign.name} (seed {campaign.seed} for the plant), setup {setup.name}, families "
          f"{', '.join(fams)}; plan {t_plan:.1f} s, sweep of {n} seeds x {len(fams)} families {t_sweep:.0f} s, "
          f"load average {load0:.1f} before, {os.getloadavg()[0]:.1f} after")
    print(f"- N = {n}: a correct prediction gives s / sigma in [{lo:.3f}, {hi:.3f}] with 99 % probability "
          f"(chi-square, {n - 1} degrees of freedom); the check is the factor 1.5, i.e. [0.667, 1.5]\n")
    print("| family | parameter | predicted SE | std over seeds | ratio | within 1.5 | note |")
    print("|---|---|---|---|---|---|---|")
    n_ok = 0
    for fam, name, se, sd, note in rows:
        if se == 0.0:
            ok = sd <= ZERO_REL
            ratio = "-"
        else:
            r = sd / se
            ok = bool(1 / 1.5 < r < 1.5)
            ratio = f"{r:.3f}"
        n_ok += ok
        print(f"| {fam} | {name} | {se:.4g} | {sd:.4g} | {ratio} | {'yes' if ok else 'NO'} | {note} |")
    for fam, name, sd, note in unplanned:
        print(f"| {fam} | {name} | not planned | {sd:.4g} | - | - | {note} |")
    for line in heavy:
        print(f"\n- heavy-tailed spread, checked on its std as the others; the plan's reason: {line}")
    print(f"\n- {n_ok} of {len(rows)} predictions within the factor 1.5 (a predicted 0: every estimate the same over "
          f"the seeds to a relative {ZERO_REL:g}, float rounding)")
    if unplanned:
        names = list(dict.fromkeys(name for _f, name, _s, _n in unplanned))
        print(f"- {len(unplanned)} estimates not planned ({len(names)} names; no plan row covers them; not in the "
              "count): " + ", ".join(names))
    for fam, k in elsewhere.items():
        print(f"- {fam}: {k} estimates of another family's fits (run before its own, on this family's tests) are "
              "planned in that family's plan for its own tests: not compared here")
    for line in unpredicted:
        print(f"- planned but no standard error predicted (not in the count): {line}")


if __name__ == "__main__":
    main()
