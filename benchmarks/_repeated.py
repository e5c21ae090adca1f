"""What the repeated-campaign benchmarks share: their command-line arguments and the chunked Recording they measure.

``bench_identify_chunks.py``, ``bench_identify_memory.py`` and ``bench_type_b_memory.py`` each take a shipped campaign
repeated 1x, 3x, ... (``bench_stream.repeated_campaign``), simulate it, run it through the chain test by test with the
Recording kept in the acquisition's raw chunk files (what ``validate --out`` identifies from) and measure one stage
on it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench_stream import repeated_campaign

from benchtwin.chain.stream import run_chunked, trace_pieces
from benchtwin.config._base import scenario_path
from benchtwin.config.campaign import load_campaign
from benchtwin.config.setup import load_setup
from benchtwin.config.vehicle import VehicleConfig, load_vehicle
from benchtwin.emulator import simulate_campaign
from benchtwin.recording import Recording


def size_parser(doc: str, campaign: str) -> argparse.ArgumentParser:
    """A parser with ``--sizes``, ``--campaign`` (default ``campaign``), ``--setup`` and ``--vehicle``, its
    description the first paragraph of ``doc``; a script adds its own arguments."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--sizes", default="1,3", help="campaign repeats (default 1,3)")
    ap.add_argument("--campaign", default=campaign, help=f"shipped campaign name (default {campaign})")
    ap.add_argument("--setup", default="paper", help="shipped setup name (default paper)")
    ap.add_argument("--vehicle", default="p2_phev_9at", help="shipped vehicle name")
    return ap


def size_arguments(doc: str, campaign: str, json_help: str) -> argparse.Namespace:
    """Parse ``--sizes``, ``--campaign`` (default ``campaign``), ``--setup``, ``--vehicle`` and ``--json``.

    Parameters
    ----------
    doc:
        The script's docstring (its first paragraph is the ``--help`` description).
    campaign:
        Default shipped campaign name.
    json_help:
        Help text of ``--json``.

    Returns
    -------
    argparse.Namespace
        The arguments, ``sizes`` as a list of ints.
    """
    ap = size_parser(doc, campaign)
    ap.add_argument("--json", type=Path, help=json_help)
    args = ap.parse_args()
    args.sizes = [int(s) for s in args.sizes.split(",")]
    return args


def chunked_recording(n: int, tmp: Path, campaign: str, setup: str, vehicle_name: str
                      ) -> tuple[VehicleConfig, Recording]:
    """The vehicle and the Recording (in chunk files under ``tmp``) of ``campaign`` repeated ``n`` times.

    Parameters
    ----------
    n:
        Repeats of the campaign's tests.
    tmp:
        Directory for the repeated campaign file and the chunk files (kept until the caller removes it).
    campaign, setup, vehicle_name:
        Shipped scenario names.

    Returns
    -------
    tuple
        The vehicle configuration and the Recording (seed 1); close it before ``tmp`` goes.
    """
    vehicle = load_vehicle(scenario_path("vehicles", f"{vehicle_name}.toml"))
    camp = repeated_campaign(n, tmp, scenario_path("campaigns", f"{campaign}.toml"))
    trace = simulate_campaign(vehicle, load_campaign(camp))
    rec = run_chunked(trace_pieces(trace), load_setup(setup), seed=1, keep_chunks=True)
    return vehicle, rec
