"""``benchtwin demo``: run the WLTC class 3b campaign on the embedded default vehicle and print a summary.

A quick look at the plant alone: it simulates WLTC 3b in road-load mode (driver following the trace)
and prints distance, speed tracking, fuel, battery energy, SOC and the closure of the energy ledger.
The main job (``make demo``) is ``benchtwin validate``: the whole campaign through the sensor chain and
identification, judged against the truth.
"""

from __future__ import annotations

import argparse
import time
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from benchtwin.trace import Trace

__all__ = ["add_subparser", "run", "summary_rows"]


def add_subparser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``demo`` subcommand."""
    p = subparsers.add_parser("demo", help="simulate WLTC 3b on the default vehicle and print a summary",
                              description=__doc__.split("\n\n", 1)[1] if __doc__ else None)
    p.add_argument("--campaign", default="wltc", help="campaign TOML or a shipped name (default: wltc)")
    p.set_defaults(func=run)
    return p


def summary_rows(trace: Trace) -> list[tuple[str, str]]:
    """Summary of a cycle trace as (quantity, value) rows."""
    from benchtwin.emulator import energy_balance
    from benchtwin.emulator.protocols import load_cycle

    rows: list[tuple[str, str]] = []
    v = trace["vehicle_speed_mps"]
    t = trace.time_s
    cyc = [s for s in trace.segments if s.kind == "cycle"]
    if cyc:
        seg = cyc[0]
        tc, vc = load_cycle(seg.settings.get("cycle", "wltc_class3b.csv"))
        m = seg.contains(t)
        t_cyc = t[m] - seg.start_s + float(seg.settings.get("from_s", 0.0))
        inside = t_cyc <= float(seg.settings.get("to_s") or tc[-1])
        err = (v[m] - np.interp(t_cyc, tc, vc))[inside]
        rows.append(("cycle", seg.name))
        rows.append(("RMS speed error", f"{3.6 * np.sqrt(np.mean(err**2)):.3f} km/h"))
        rows.append(("max speed error", f"{3.6 * np.max(np.abs(err)):.2f} km/h"))
    dt = trace.dt_s
    dist = float(trace["distance_m"][-1] + v[-1] * dt)
    rows.append(("distance", f"{dist / 1000:.3f} km"))
    fuel = float(np.sum(trace["fuel_mass_flow_kgps"]) * dt)
    rows.append(("fuel", f"{fuel * 1000:.1f} g ({fuel / 0.832 / max(dist / 1e5, 1e-9):.2f} l/100 km)"))
    e_b = float(np.sum(trace["battery_current_a"] * trace["battery_voltage_v"]) * dt)
    rows.append(("HV battery energy (terminal)", f"{e_b / 3.6e6:.3f} kWh"))
    soc = trace["displayed_soc_pct"]
    rows.append(("displayed SOC start -> end", f"{soc[0]:.1f} % -> {soc[-1]:.1f} %"))
    rows.append(("engine on", f"{100 * np.mean(trace['engine_on']):.0f} % of the time"))
    bal = energy_balance(trace.meta["energy_ledger_j"])
    rows.append(("energy in (fuel + batteries)", f"{bal['inputs_j'] / 1e6:.3f} MJ"))
    rows.append(("energy balance residual", f"{bal['residual_j'] / 1e3:.2f} kJ ({100 * bal['residual_frac']:.4f} %)"))
    return rows


def run(args: argparse.Namespace) -> int:
    """Run the demo campaign and print the summary table; return the exit status."""
    from benchtwin.commands._common import load_campaign_arg, load_vehicle_arg
    from benchtwin.emulator import simulate_campaign

    vehicle = load_vehicle_arg(None)
    campaign = load_campaign_arg(args.campaign)
    t0 = time.perf_counter()
    trace = simulate_campaign(vehicle, campaign, progress=True)
    wall = time.perf_counter() - t0
    rows = [("vehicle", vehicle.name), ("campaign", campaign.name),
            ("simulated", f"{trace.duration_s:.0f} s at {trace.meta['plant_rate_hz']:.0f} Hz in {wall:.2f} s "
                          f"(incl. compile on first run)"), *summary_rows(trace)]
    width = max(len(k) for k, _ in rows)
    print("benchtwin demo: WLTC on the emulated P2 PHEV (the plant's truth, before any sensor)")
    for k, val in rows:
        print(f"  {k:<{width}}  {val}")
    return 0
