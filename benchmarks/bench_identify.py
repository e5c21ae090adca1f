"""Identification speed: every parameter from the whole paper-campaign Recording.

Run with ``.venv/bin/python benchmarks/bench_identify.py [--runs N] [--setups ideal,paper]``. Prints a
Markdown section to append to benchmarks/RESULTS.md.

The Recording is made the way a user makes it: ``simulate_campaign`` over ``scenarios/campaigns/paper.toml``
(100 Hz plant), then the batch chain (``benchtwin.chain.batch.run_batch``: sensors, wire encoding, delivery,
acquisition) with the ideal and the paper setups. Timed: :func:`benchtwin.identification.run.identify_all`
on that Recording with the vehicle's public specs (the median of ``--runs`` runs after one warm-up run),
per method from its own timing, and part B (battery, torque converter, shifts) alone. The goal is
<= 2 s; CO2MPAS spent about 29 s calibrating one hybrid WLTP test on this machine.

The machine may be shared with other jobs, so the CPU time of the process (``time.process_time``, all
threads) is reported beside the wall time, with the load average before and after; per method, the
CPU time comes from running that method alone (``identify_all(..., methods=[name])``; the torque
converter with the transmission before it, whose CPU time is subtracted).

Accuracy of part B against the vehicle file is printed as well (validation owns the full comparison).

The estimates are timed without the type B propagation of the declared systematic errors
(``identify_all(..., type_b=False)``; it re-runs each method once per declared component:
``--type-b`` times it included; benchmarks/bench_coverage.py prints its cost per validation).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import time

import numpy as np

from benchtwin.chain.batch import run_batch
from benchtwin.config import load_campaign, load_vehicle, scenario_path
from benchtwin.config.setup import load_setup
from benchtwin.emulator import simulate_campaign
from benchtwin.identification.run import identify_all

PART_B = ("battery", "torque_converter", "shifts")


def _method_cpu(rec, specs, names: list[str], runs: int) -> dict[str, float]:
    """Median CPU seconds of each method run alone (the torque converter after the transmission)."""
    out: dict[str, float] = {}
    for name in names:
        cpu = []
        for _ in range(runs):
            wanted = ["transmission", name] if name == "torque_converter" else [name]
            c0 = time.process_time()
            identify_all(rec, specs, methods=wanted, type_b=False)
            cpu.append(time.process_time() - c0)
        out[name] = statistics.median(cpu)
    if "torque_converter" in out and "transmission" in out:
        out["torque_converter"] = max(out["torque_converter"] - out["transmission"], 0.0)
    return out


def _accuracy(res, vehicle) -> list[str]:
    out = []
    b = res.fits.get("battery")
    if b is not None:
        tb = vehicle.battery
        errs = {n: b.value(n) / t - 1 for n, t in (("alpha", tb.alpha), ("beta_discharge", tb.beta_discharge),
                                                   ("beta_charge", tb.beta_charge))}
        out.append("battery: " + ", ".join(f"{n} {100 * e:+.3f} %" for n, e in errs.items())
                   + f", adj. R2 {b.adj_r2:.4f}")
    c = res.fits.get("torque_converter.converter")
    if c is not None:
        a = np.asarray(vehicle.torque_converter.a_nm_per_radps2)
        errs = [c.value(f"a{k}") / a[k] - 1 for k in range(6)]
        g_true = vehicle.torque_converter.coupling_speed_ratio
        g = c.value("gamma_coupling") / g_true - 1
        # the curves matter more than single coefficients (a1 is small and correlated with a0, a2)
        sr = np.linspace(0.0, g_true, 50)
        e = np.array([c.value(f"a{k}") for k in range(6)])
        tp_t, tp_e = a[0] + a[1] * sr + a[2] * sr**2, e[0] + e[1] * sr + e[2] * sr**2
        tr_t, tr_e = (a[3] + a[4] * sr + a[5] * sr**2) / tp_t, (e[3] + e[4] * sr + e[5] * sr**2) / tp_e
        k_err = 100 * np.max(np.abs(np.sqrt(tp_t / tp_e) - 1))
        out.append(f"torque converter curves over SR 0..Gamma: K-factor max {k_err:.2f} %, torque ratio max "
                   f"{np.max(np.abs(tr_e - tr_t)):.3f}")
        r2 = {k: res.fits[f"torque_converter.{k}"].r2 for k in ("torque_ratio", "capacity_factor",
                                                               "capacity_factor_coupling")
              if f"torque_converter.{k}" in res.fits}
        out.append("torque converter: a0..a5 " + ", ".join(f"{100 * e:+.2f}" for e in errs) + " %, "
                   f"Gamma {100 * g:+.2f} %, R2 " + ", ".join(f"{k} {v:.3f}" for k, v in r2.items()))
    sh = vehicle.shift_schedule
    worst = 0.0
    n_ok = 0
    for gi in range(1, len(sh.up_v0_kmh) + 1):
        for key, v0, s1 in ((f"shifts.up_{gi}_{gi + 1}", sh.up_v0_kmh, sh.up_slope_kmh_per_pct),
                            (f"shifts.down_{gi + 1}_{gi}", sh.down_v0_kmh, sh.down_slope_kmh_per_pct)):
            f = res.fits.get(key)
            if f is None or f.status != "ok":
                continue
            n_ok += 1
            p = np.array([0.0, 50.0, 100.0])
            true = v0[gi - 1] + s1[gi - 1] * p
            est = f.value("c0_kmh") + f.value("c1_kmh_per_pct") * p
            worst = max(worst, float(np.max(np.abs(est - true))))
    out.append(f"shift lines: {n_ok} of {2 * len(sh.up_v0_kmh)} pair-directions ok, worst speed error over "
               f"pedal 0..100 % {worst:.2f} km/h")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--setups", default="ideal,paper")
    ap.add_argument("--type-b", action="store_true", help="include the type B propagation in the timing")
    args = ap.parse_args()
    tb = args.type_b
    vehicle = load_vehicle(scenario_path("vehicles", "p2_phev_9at.toml"))
    campaign = load_campaign(scenario_path("campaigns", "paper.toml"))
    t0 = time.perf_counter()
    trace = simulate_campaign(vehicle, campaign)
    t_sim = time.perf_counter() - t0
    lines = [
        "## Identification of every parameter from the paper-campaign Recording (benchmarks/bench_identify.py)",
        "",
        f"- date {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, machine {platform.machine()}, "
        f"{os.cpu_count()} cores, Python {platform.python_version()}",
        f"- campaign paper.toml: {trace.time_s[-1] / 3600:.2f} h simulated, {len(trace.segments)} tests "
        f"(simulation {t_sim:.1f} s, not part of the timing)",
        f"- timing: median of {args.runs} runs of identify_all after one warm-up run; BLAS threads: "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}; type B propagation "
        f"{'included' if tb else 'off'}",
        "",
        "| setup | samples in Recording | channels | identify_all wall median (s) | min..max (s) | CPU median (s) "
        "| part B wall (s) | vs goal 2 s | vs CO2MPAS 29 s | load average before/after |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    details = []
    for name in [s.strip() for s in args.setups.split(",") if s.strip()]:
        setup = load_setup(scenario_path("setups", f"{name}.toml"))
        rec = run_batch(trace, setup)
        n_samples = sum(len(c) for c in rec.channels.values())
        identify_all(rec, vehicle.specs, type_b=tb)  # warm-up
        times, cpus, per = [], [], {}
        res = None
        load0 = os.getloadavg()[0]
        for _ in range(args.runs):
            t1, c1 = time.perf_counter(), time.process_time()
            res = identify_all(rec, vehicle.specs, type_b=tb)
            times.append(time.perf_counter() - t1)
            cpus.append(time.process_time() - c1)
            for m, s in res.meta["seconds"].items():
                per.setdefault(m, []).append(s)
        load1 = os.getloadavg()[0]
        med = statistics.median(times)
        part_b = sum(statistics.median(per[m]) for m in PART_B if m in per)
        lines.append(f"| {name} | {n_samples:,} | {len(rec.channels)} | {med:.2f} | {min(times):.2f}..{max(times):.2f} "
                     f"| {statistics.median(cpus):.2f} | {part_b:.2f} | {med / 2.0:.2f}x | {29.0 / med:.1f}x faster "
                     f"| {load0:.1f} / {load1:.1f} |")
        details.append(f"- {name}: per method, wall (median s): "
                       + ", ".join(f"{m} {statistics.median(v):.3f}" for m, v in per.items()))
        cpu_m = _method_cpu(rec, vehicle.specs, list(per), args.runs)
        details.append(f"- {name}: per method, CPU run alone (median s): "
                       + ", ".join(f"{m} {v:.3f}" for m, v in cpu_m.items()))
        details.append(f"- {name}: {len(res.parameters())} parameters in {len(res.fits)} fits, "
                       f"{len(res.errors)} fit errors, skipped: {sorted(res.meta['skipped']) or 'none'}")
        details.extend(f"- {name}, part B accuracy: {a}" for a in _accuracy(res, vehicle))
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                             check=False).stdout.strip()
    except OSError:
        rev = "?"
    lines += ["", *details, f"- commit {rev}", ""]
    print("\n".join(lines))


if __name__ == "__main__":
    main()
