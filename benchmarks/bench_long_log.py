"""Identification of a day-long real-style log: 24 h at 100 Hz, 60 channels, through a signal map.

Run (the log is made once, ~2 GB on disk; ``make`` needs ~2 GB of memory, so take the shared lock)::

    flock /tmp/benchtwin-heavy.lock nice -n 5 .venv/bin/python benchmarks/bench_long_log.py make DIR
    flock /tmp/benchtwin-heavy.lock nice -n 5 .venv/bin/python benchmarks/bench_long_log.py run DIR [--repeat 3]

``make`` simulates the paper campaign (the emulator's truth: every test kind, so each identification
method has something to fit) and lays it end to end until 24 h are filled, as a data logger would write
it: an MF4 with six channel groups (a raster each) of ten float32 channels named by the plant's names in
SI units (the truth's channels, 56 at 01c45a7, filled to 60 with constant extras), a float64 time base,
no segment table. It writes ``signal_map.toml`` (41 roles, units converted on import: m/s -> km/h, rad/s -> rpm,
Pa -> bar, kg/s -> g/s) and ``specs.toml`` (the vehicle's public specs) beside it.

``run`` times ``benchtwin identify LOG --signal-map signal_map.toml --specs specs.toml --no-figures`` in a
child process under ``/usr/bin/time -v`` (``--repeat`` times) and prints the median wall time and peak
resident memory, with the methods that ran, as a Markdown section for benchmarks/RESULTS.md. The goal is
a peak below 1 GB: 24 h x 100 Hz x 60 channels is 518 M samples, 4.1 GB as float64.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

DAY_S = 86_400.0
GROUPS = 6

#: role -> (trace channel, unit in the log)
MAPPED: dict[str, tuple[str, str]] = {
    "vehicle_speed_kmh": ("vehicle_speed_mps", "m/s"), "engine_speed_rpm": ("engine_speed_radps", "rad/s"),
    "engine_torque_nm": ("engine_torque_nm", "Nm"), "fuel_mass_flow_gps": ("fuel_mass_flow_kgps", "kg/s"),
    "em_speed_rpm": ("em_speed_radps", "rad/s"), "em_torque_nm": ("em_torque_nm", "Nm"),
    "displayed_soc_pct": ("displayed_soc_pct", "%"), "gear_target": ("gear_target", ""),
    "gear_actual": ("gear_actual", ""), "pedal_pct": ("pedal_pct", "%"), "brake_pedal_pct": ("brake_pedal_pct", "%"),
    "k0_closed": ("k0_closed", ""), "lockup_closed": ("lockup_closed", ""), "hybrid_mode": ("hybrid_mode", ""),
    "engine_on": ("engine_on", ""), "battery_current_a": ("battery_current_a", "A"),
    "battery_voltage_v": ("battery_voltage_v", "V"), "hpcu_current_a": ("hpcu_hv_current_a", "A"),
    "hpcu_voltage_v": ("hpcu_hv_voltage_v", "V"), "dcdc_lv_current_a": ("dcdc_lv_current_a", "A"),
    "dcdc_lv_voltage_v": ("dcdc_lv_voltage_v", "V"), "lv_battery_current_a": ("lv_battery_current_a", "A"),
    "lv_battery_voltage_v": ("lv_battery_voltage_v", "V"), "shaft_torque_nm": ("shaft_torque_nm", "Nm"),
    "brake_pressure_fl_bar": ("brake_pressure_fl_pa", "Pa"), "brake_pressure_fr_bar": ("brake_pressure_fr_pa", "Pa"),
    "brake_pressure_rl_bar": ("brake_pressure_rl_pa", "Pa"), "brake_pressure_rr_bar": ("brake_pressure_rr_pa", "Pa"),
    "master_cylinder_bar": ("master_cylinder_pa", "Pa"), "dyno_speed_kmh": ("dyno_speed_mps", "m/s"),
    "dyno_force_front_n": ("dyno_force_front_n", "N"), "dyno_force_rear_n": ("dyno_force_rear_n", "N"),
    "engine_coolant_in_degc": ("engine_coolant_in_degc", "degC"),
    "engine_coolant_out_degc": ("engine_coolant_out_degc", "degC"),
    "battery_coolant_in_degc": ("battery_coolant_in_degc", "degC"),
    "battery_coolant_out_degc": ("battery_coolant_out_degc", "degC"),
    "battery_temp_degc": ("battery_temp_degc", "degC"),
    "hpcu_coolant_in_degc": ("hpcu_coolant_in_degc", "degC"),
    "hpcu_coolant_out_degc": ("hpcu_coolant_out_degc", "degC"),
    "motor_coolant_in_degc": ("motor_coolant_in_degc", "degC"),
    "motor_coolant_out_degc": ("motor_coolant_out_degc", "degC"),
}


def make(out: Path, hours: float = 24.0) -> None:
    """Write ``day.mf4``, ``signal_map.toml`` and ``specs.toml`` in ``out``."""
    from asammdf import MDF, Signal

    from benchtwin.config import load_campaign, load_vehicle, scenario_path
    from benchtwin.emulator import simulate_campaign
    from benchtwin.trace import _unit_of

    vehicle = load_vehicle(scenario_path("vehicles", "p2_phev_9at.toml"))
    trace = simulate_campaign(vehicle, load_campaign(scenario_path("campaigns", "paper.toml")))
    names = [n for n in trace.channels if n != "dyno_set_speed_mps"]  # NaN in road-load mode: not logged
    extras = {"ambient_temp_degc": 23.0, "ambient_pressure_pa": 101_325.0, "ambient_humidity_pct": 45.0,
              "cell_temp_degc": 24.0, "logger_supply_v": 13.8}
    # the truth's channel count moves as the plant grows (55 at bd03a97, 56 since): the constant extras fill
    # the log up to 60 channels, so the 24-h log keeps its size from commit to commit
    if len(names) > 60 or len(names) + len(extras) < 60:
        raise SystemExit(f"the truth has {len(names)} logged channels: 60 cannot be made of them and "
                         f"{len(extras)} constant extras")
    extras = dict(list(extras.items())[:60 - len(names)])
    columns = names + list(extras)
    n, dt = len(trace), trace.dt_s
    per_day = round(hours * 3600.0 / dt)
    blocks = [(k, min(n, per_day - k)) for k in range(0, per_day, n)]
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    mdf = MDF(version="4.10")
    size = (len(columns) + GROUPS - 1) // GROUPS
    for g in range(GROUPS):
        cols = columns[g * size:(g + 1) * size]
        for b, (start, count) in enumerate(blocks):
            t = (start + np.arange(count)) * dt
            data = [np.asarray(trace.channels[c][:count], np.float32) if c in trace.channels
                    else np.full(count, extras[c], np.float32) for c in cols]
            if b == 0:
                mdf.append([Signal(v, t, name=c, unit=_unit_of(c) or ("degC" if c.endswith("degc") else ""))
                            for c, v in zip(cols, data)], acq_name=f"raster_{g}", comment=f"logger raster {g}")
            else:
                mdf.extend(g, [(t, None), *[(v, None) for v in data]])
    path = out / "day.mf4"
    mdf.save(path, overwrite=True, compression=0)
    mdf.close()
    lines = ['[source]', 'format = "mf4"', 'source_name = "day_logger"', '']
    for role, (col, unit) in MAPPED.items():
        lines += [f"[channels.{role}]", f'column = "{col}"', f'unit = "{unit}"', ""]
    (out / "signal_map.toml").write_text("\n".join(lines), encoding="utf-8")
    specs = vehicle.specs.model_dump()
    (out / "specs.toml").write_text("\n".join(f"{k} = {json.dumps(v)}" for k, v in specs.items()) + "\n",
                                    encoding="utf-8")
    print(f"wrote {path} ({path.stat().st_size / 1e9:.2f} GB, {per_day:,} samples x {len(columns)} channels in "
          f"{GROUPS} groups, from {len(blocks)} copies of the paper campaign) in {time.perf_counter() - t0:.0f} s")


def _samples(path: Path) -> int:
    from benchtwin.mdf import open_mdf

    with open_mdf(path) as mdf:
        return int(mdf.groups[0].channel_group.cycles_nr)


def run(d: Path, repeat: int) -> None:
    """Time ``benchtwin identify`` on the log of ``d``; print the RESULTS.md section."""
    exe = Path(sys.executable).with_name("benchtwin")
    walls, peaks, summary = [], [], ""
    for k in range(repeat):
        out = d / f"identify_{k}"
        cmd = ["/usr/bin/time", "-v", str(exe), "identify", str(d / "day.mf4"), "--signal-map",
               str(d / "signal_map.toml"), "--specs", str(d / "specs.toml"), "--out", str(out), "--no-figures"]
        w0 = time.perf_counter()
        p = subprocess.run(cmd, capture_output=True, text=True)
        walls.append(time.perf_counter() - w0)
        if p.returncode != 0:
            raise SystemExit(f"benchtwin identify failed ({p.returncode}):\n{p.stdout}\n{p.stderr[-3000:]}")
        peaks.append(int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr).group(1)) / 1024)
        summary = p.stdout.strip().splitlines()[0]
        params = json.loads((out / "params.json").read_text(encoding="utf-8"))
    meta = params["meta"]
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    size = (d / "day.mf4").stat().st_size / 1e9
    print("## Identification of a 24-hour, 100 Hz, 60-channel log (benchmarks/bench_long_log.py)\n")
    print(f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, machine {platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}, load average {os.getloadavg()[0]:.1f}, commit {commit}")
    n = _samples(d / "day.mf4")
    print(f"- log: day.mf4, {size:.2f} GB uncompressed, {n:,} samples ({n / 360_000:.1f} h) x 60 float32 channels in "
          f"{GROUPS} groups ({n * 60 / 1e6:.0f} M samples, {n * 60 * 8 / 1e9:.1f} GB as float64); {len(MAPPED)} roles "
          "mapped")
    print(f"- `benchtwin identify --signal-map --specs --no-figures` in a child process, {repeat} runs: {summary}\n")
    print("| runs | wall median (s) | wall min..max (s) | peak RSS median (MB) | peak RSS max (MB) | goal |")
    print("|---|---|---|---|---|---|")
    print(f"| {repeat} | {statistics.median(walls):.1f} | {min(walls):.1f}..{max(walls):.1f} | "
          f"{statistics.median(peaks):.0f} | {max(peaks):.0f} | <= 1024 MB: "
          f"{'met' if max(peaks) <= 1024 else 'NOT met'} |")
    print(f"\n- methods ran: {', '.join(meta.get('ran', []))}; skipped: {json.dumps(meta.get('skipped', {}))}")
    print(f"- per method (s): {json.dumps(meta.get('seconds', {}))}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("step", choices=["make", "run"], help="make the log, or time identification on it")
    ap.add_argument("dir", type=Path, help="folder of day.mf4, signal_map.toml and specs.toml")
    ap.add_argument("--repeat", type=int, default=3, help="identification runs (run; medians reported)")
    ap.add_argument("--hours", type=float, default=24.0, help="length of the log (make; a shorter one to try)")
    args = ap.parse_args()
    if args.step == "make":
        make(args.dir, args.hours)
    else:
        run(args.dir, args.repeat)


if __name__ == "__main__":
    main()
