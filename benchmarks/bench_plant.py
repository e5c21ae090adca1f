"""Plant speed: real-time factor over the paper campaign at 100 Hz, and WLTC 3b at 1 Hz beside FASTSim 3.1.

Run with ``.venv/bin/python benchmarks/bench_plant.py`` (FASTSim is the ``[bench]`` extra:
``pip install fastsim``). Prints a Markdown section to append to benchmarks/RESULTS.md.

Measured:
- numba compile time of the plant loop (cold, in a subprocess with an empty numba cache dir);
- real-time factor of ``simulate_campaign`` over ``paper.toml`` at 100 Hz (median of >= 3 runs after a
  warm-up), whole call: protocol, loop, thermal post-processing, Trace assembly;
- real-time factor of the conventional-layout plant (``conventional_9at.toml``) over ``conventional.toml`` at
  100 Hz, measured as the paper campaign;
- WLTC 3b with 1 Hz output: ours with the plant stepping internally at 10 Hz (and at 100 Hz for reference),
  FASTSim 3.1 with its bundled 2021 Sonata Hybrid on the same cycle (loaded from our cycle file), each the
  median of >= 7 runs in the same process.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from benchtwin.config import load_campaign, load_vehicle, validate_data
from benchtwin.config._base import scenario_path
from benchtwin.config.campaign import CampaignConfig
from benchtwin.emulator import energy_balance, simulate_campaign
from benchtwin.emulator.protocols import load_cycle

COLD = """
import time
t0 = time.perf_counter()
from benchtwin.config import load_campaign, load_vehicle, validate_data
from benchtwin.config.campaign import CampaignConfig
from benchtwin.emulator import simulate_campaign
c = validate_data(CampaignConfig, {"name": "c", "seed": 1, "tests": [{"kind": "deceleration", "start_speed_kmh": 20.0,
                  "decel_mps2": 1.0}]})
t1 = time.perf_counter()
simulate_campaign(load_vehicle(), c)
print(time.perf_counter() - t1)
"""


def _median_time(fn, n: int) -> tuple[float, list[float]]:
    """Median wall time of ``n`` calls (and the list); CPU time medians go to ``_CPU``."""
    times, cpu = [], []
    for _ in range(n):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    _CPU.append(statistics.median(cpu))
    return statistics.median(times), times


_CPU: list[float] = []


def _with_rates(campaign: CampaignConfig, plant_hz: float, out_hz: float | None) -> CampaignConfig:
    data = campaign.model_dump()
    data["plant_rate_hz"] = plant_hz
    data["output_rate_hz"] = out_hz
    return validate_data(CampaignConfig, data, "<bench>")


def _wltc_metrics(trace) -> str:
    tc, vc = load_cycle("wltc_class3b.csv")
    err = 3.6 * (trace["vehicle_speed_mps"] - np.interp(trace.time_s, tc, vc))
    bal = energy_balance(trace.meta["energy_ledger_j"])
    return (f"RMS speed error {np.sqrt(np.mean(err**2)):.3f} km/h, distance {trace['distance_m'][-1] / 1000:.3f} km, "
            f"energy residual {100 * bal['residual_frac']:.4f} %")


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the results section."""
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    vehicle = load_vehicle()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [f"## Plant (bench_plant.py), {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}", "",
             f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
             f"numpy {np.__version__}; 1-min load average at start {load:.1f} (wall times suffer when other "
             f"jobs share the 2 cores; CPU-time medians are given beside them)", ""]

    # cold compile in a fresh interpreter with an empty numba cache
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, "-c", COLD], env=env, capture_output=True, text=True, check=True)
        cold_total = time.perf_counter() - t0
        compile_s = float(res.stdout.strip().splitlines()[-1])
    lines.append(f"- numba compile of the plant (cold cache, first call incl. a 20 s test): {compile_s:.1f} s "
                 f"(whole cold process {cold_total:.1f} s)")

    # paper campaign, 100 Hz
    paper = load_campaign("paper.toml")
    simulate_campaign(vehicle, paper)  # warm-up (cache load)
    med, times = _median_time(lambda: simulate_campaign(vehicle, paper), 3)
    tr = simulate_campaign(vehicle, paper)
    steps = round(tr.duration_s * paper.plant_rate_hz)
    cpu = _CPU[-1]
    lines.append(f"- paper.toml at 100 Hz: {tr.duration_s:.0f} s simulated ({steps:,} steps, {len(tr.segments)} tests) "
                 f"in {med:.2f} s wall median of {len(times)} ({', '.join(f'{t:.2f}' for t in times)} s): "
                 f"**real-time factor {tr.duration_s / med:,.0f}x** wall, {tr.duration_s / cpu:,.0f}x on CPU time "
                 f"({1e6 * cpu / steps:.2f} us CPU per step, whole simulate_campaign call)")

    # the conventional layout: the same loop with the motor's terms zeroed, over the paper's engine tests
    conv_vehicle = load_vehicle(scenario_path("vehicles", "conventional_9at.toml"))
    conv = load_campaign("conventional.toml")
    simulate_campaign(conv_vehicle, conv)
    med, times = _median_time(lambda: simulate_campaign(conv_vehicle, conv), 3)
    tr = simulate_campaign(conv_vehicle, conv)
    steps = round(tr.duration_s * conv.plant_rate_hz)
    cpu = _CPU[-1]
    lines.append(f"- conventional.toml on conventional_9at at 100 Hz: {tr.duration_s:.0f} s simulated "
                 f"({steps:,} steps, {len(tr.segments)} tests) in {med:.2f} s wall median of {len(times)}: "
                 f"real-time factor {tr.duration_s / med:,.0f}x wall, {tr.duration_s / cpu:,.0f}x on CPU time "
                 f"({1e6 * cpu / steps:.2f} us CPU per step)")
    del tr

    # WLTC at 1 Hz output
    wltc = load_campaign("wltc.toml")
    rows = []
    for plant_hz in (10.0, 100.0):
        camp = _with_rates(wltc, plant_hz, 1.0)
        simulate_campaign(vehicle, camp)
        m, _ = _median_time(lambda camp=camp: simulate_campaign(vehicle, camp), 7)
        rows.append((plant_hz, m, _CPU[-1], _wltc_metrics(simulate_campaign(vehicle, camp))))
    for plant_hz, m, c, metrics in rows:
        lines.append(f"- WLTC 3b, 1 Hz output, plant stepping at {plant_hz:.0f} Hz: {1e3 * m:.1f} ms wall "
                     f"({1e3 * c:.1f} ms CPU) median of 7 ({metrics})")

    try:
        import fastsim as fsim
    except ImportError:
        lines.append("- FASTSim: not installed (pip install fastsim), no comparison")
        fs_med = None
    else:
        tc, vc = load_cycle("wltc_class3b.csv")
        n = len(tc)
        cyc_dict = {"init_elev_meters": 0.0, "time_seconds": tc.tolist(), "speed_meters_per_second": vc.tolist(),
                    "dist_meters": [], "grade": [0.0] * n, "elev_meters": [], "pwr_max_chrg_watts": [0.0] * n,
                    "temp_amb_air_kelvin": [296.15] * n, "pwr_solar_load_watts": [0.0] * n}
        cyc = fsim.Cycle.from_dict(cyc_dict)
        veh = fsim.Vehicle.from_resource("2021_Hyundai_Sonata_Hybrid_Blue_thrml.yaml")

        def run_fastsim() -> None:
            sd = fsim.SimDrive(veh, cyc)
            sd.run()

        run_fastsim()
        fs_med, fs_times = _median_time(run_fastsim, 7)
        del fs_times
        fs_cpu = _CPU[-1]
        lines.append(f"- FASTSim {getattr(fsim, '__version__', '3.x')} (2021 Sonata Hybrid, same WLTC 3b, 1 Hz): "
                     f"{1e3 * fs_med:.1f} ms wall ({1e3 * fs_cpu:.1f} ms CPU) median of 7")
        lines.append(f"- ratio FASTSim / ours, plant at 10 Hz: **{fs_med / rows[0][1]:.1f}x** wall, "
                     f"{fs_cpu / rows[0][2]:.1f}x CPU; plant at 100 Hz: {fs_med / rows[1][1]:.2f}x wall, "
                     f"{fs_cpu / rows[1][2]:.2f}x CPU")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
