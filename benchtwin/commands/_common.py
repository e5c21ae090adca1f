"""Argument helpers shared by the subcommands: scenario files by path or by shipped name, output checks."""

from __future__ import annotations

import argparse
import os
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from benchtwin.config.campaign import CampaignConfig
    from benchtwin.config.setup import SetupConfig
    from benchtwin.config.vehicle import VehicleConfig

__all__ = ["MIN_FREE_BYTES", "add_scenario_args", "check_writable", "load_scenario"]

#: free space an output needs before any work starts (a Recording or a few minutes of raw logs)
MIN_FREE_BYTES = 64 * 1024 * 1024


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


def check_writable(path: str | Path, *, directory: bool = False, what: str = "--out",
                   min_free_bytes: int = MIN_FREE_BYTES) -> Path:
    """Check that ``path`` can be written, before any work is done; one-line :class:`DataError` if not.

    Creates the missing parent folders (or the folder itself with ``directory``), writes and removes a
    probe file next to the output and checks the free space of that file system. Nothing that exists
    is opened for writing, so a file already there is never damaged by the check.

    Raises
    ------
    DataError
        The path (or a parent) is not a folder, cannot be created or written, or the disk has less
        than ``min_free_bytes`` free.
    """
    from benchtwin.errors import DataError

    p = Path(path)
    folder = p if directory else p.parent
    if not directory and p.is_dir():
        raise DataError(f"{what} {p}: is a folder; give a file name")
    if directory and p.exists() and not p.is_dir():
        raise DataError(f"{what} {p}: is a file; give a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".benchtwin-write-check-{os.getpid()}"
        with probe.open("wb") as fh:
            fh.write(b"0")
        probe.unlink()
        if not directory and p.exists() and not os.access(p, os.W_OK):
            raise PermissionError(13, "permission denied", str(p))
        free = shutil.disk_usage(folder).free
    except OSError as exc:
        raise DataError(f"{what} {p}: cannot write there ({exc.strerror or exc})") from None
    if free < min_free_bytes:
        raise DataError(f"{what} {p}: disk full ({free / 2**20:.1f} MiB free, need at least "
                        f"{min_free_bytes / 2**20:.0f} MiB); nothing was written")
    return p
