"""Argument helpers shared by the subcommands: scenario files by path or by shipped name."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from benchtwin.config.campaign import CampaignConfig
    from benchtwin.config.setup import SetupConfig
    from benchtwin.config.vehicle import VehicleConfig

__all__ = ["add_scenario_args", "load_scenario"]


def add_scenario_args(p: argparse.ArgumentParser, *, campaign: str = "paper", setup: str = "paper") -> None:
    """Add ``--vehicle``, ``--setup`` and ``--campaign`` (each a path or a shipped name)."""
    p.add_argument("--vehicle", default="p2_phev_9at",
                   help="vehicle TOML or a shipped name: p2_phev_9at (default), p2_phev_alt")
    p.add_argument("--setup", default=setup, help=f"setup TOML or a shipped name: paper, ideal (default: {setup})")
    p.add_argument("--campaign", default=campaign,
                   help=f"campaign TOML or a shipped name: paper, quick, wltc (default: {campaign})")


def _resolve(kind: str, value: str) -> Path:
    from benchtwin.config import scenario_path

    p = Path(value)
    if p.exists() or p.parent != Path("."):
        return p
    return scenario_path(kind, value if value.endswith(".toml") else f"{value}.toml")


def load_scenario(args: argparse.Namespace) -> tuple[VehicleConfig, SetupConfig, CampaignConfig]:
    """Load the vehicle, setup and campaign named by the arguments (ConfigError on any problem)."""
    from benchtwin.config import load_campaign, load_setup, load_vehicle

    return (load_vehicle(_resolve("vehicles", args.vehicle)), load_setup(_resolve("setups", args.setup)),
            load_campaign(_resolve("campaigns", args.campaign)))
