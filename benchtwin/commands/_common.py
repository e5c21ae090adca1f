"""Argument helpers shared by the subcommands.

* scenario files by path or by shipped name, resolved the same way by every command
  (``--campaign quick``, ``--campaign quick.toml`` and ``--campaign path/to/quick.toml``);
* ``--seed``, which overrides the campaign's seed wherever randomness is drawn;
* output paths checked for writability and free space before anything is simulated, so a typo in ``--out`` costs
  a second, not a campaign, and nothing already on disk is touched.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from benchtwin.errors import ConfigError, DataError

if TYPE_CHECKING:
    from benchtwin.config.campaign import CampaignConfig
    from benchtwin.config.setup import SetupConfig
    from benchtwin.config.vehicle import VehicleConfig

__all__ = [
    "MIN_FREE_BYTES",
    "add_scenario_args",
    "add_seed_arg",
    "campaign_for_vehicle",
    "check_writable",
    "load_campaign_arg",
    "load_scenario",
    "load_setup_arg",
    "load_vehicle_arg",
    "resolve_scenario",
    "with_seed",
    "writable_dir",
    "writable_file",
]

#: the shipped file each kind falls back to
DEFAULT_VEHICLE = "p2_phev_9at"

#: free space an output needs before any work starts (a Recording or a few minutes of raw logs)
MIN_FREE_BYTES = 64 * 1024 * 1024


def add_scenario_args(p: argparse.ArgumentParser, *, campaign: str = "paper", setup: str = "paper") -> None:
    """Add ``--vehicle``, ``--setup`` and ``--campaign`` (each a path or a shipped name)."""
    p.add_argument("--vehicle", default=DEFAULT_VEHICLE,
                   help="vehicle TOML or a shipped name: p2_phev_9at (default), p2_phev_alt, "
                   "p2_phev_9at_hifi")
    p.add_argument("--setup", default=setup, help=f"setup TOML or a shipped name: paper, ideal (default: {setup})")
    p.add_argument("--campaign", default=campaign,
                   help=f"campaign TOML or a shipped name: paper, quick, wltc (default: {campaign})")


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} is negative; a seed is >= 0")
    return value


def add_seed_arg(p: argparse.ArgumentParser, what: str = "the campaign's seed") -> None:
    """Add ``--seed N`` (a non-negative integer; default: ``what``)."""
    p.add_argument("--seed", type=_seed, default=None,
                   help=f"seed of every random draw, recorded in the outputs (default: {what})")


def with_seed(campaign: CampaignConfig, seed: int | None) -> CampaignConfig:
    """The campaign with its seed replaced by ``--seed`` when one was given."""
    return campaign if seed is None else campaign.model_copy(update={"seed": int(seed)})


def resolve_scenario(kind: str, value: str | Path) -> Path:
    """A scenario file: an existing path, else a shipped file of ``kind`` by its name (``.toml`` optional).

    Raises
    ------
    ConfigError
        Neither a file nor a shipped name; the message lists the shipped names.
    """
    from benchtwin.config._base import SCENARIO_ROOTS

    p = Path(value)
    if p.exists() or p.parent != Path("."):
        return p
    name = p.name if p.suffix == ".toml" else f"{p.name}.toml"
    for root in SCENARIO_ROOTS:
        if (root / kind / name).exists():
            return root / kind / name
    shipped = sorted({f.stem for root in SCENARIO_ROOTS for f in (root / kind).glob("*.toml")})
    raise ConfigError(f"{value}: no such file, and no shipped {kind[:-1]} of that name "
                      f"(shipped: {', '.join(shipped)})")


def load_vehicle_arg(value: str | Path | None) -> VehicleConfig:
    """Load ``--vehicle`` (None: the shipped default)."""
    from benchtwin.config.vehicle import load_vehicle

    return load_vehicle(resolve_scenario("vehicles", value if value is not None else DEFAULT_VEHICLE))


def load_setup_arg(value: str | Path) -> SetupConfig:
    """Load ``--setup``."""
    from benchtwin.config.setup import load_setup

    return load_setup(resolve_scenario("setups", value))


def load_campaign_arg(value: str | Path, seed: int | None = None) -> CampaignConfig:
    """Load ``--campaign``, with ``--seed`` applied."""
    from benchtwin.config.campaign import load_campaign

    return with_seed(load_campaign(resolve_scenario("campaigns", value)), seed)


def campaign_for_vehicle(vehicle: VehicleConfig, campaign: CampaignConfig) -> CampaignConfig:
    """The campaign's tests the vehicle can drive: all of them, or for a conventional car (no motor) those that
    :func:`benchtwin.emulator.conventional_tests`'s rule keeps, with a note on stderr naming the others."""
    if vehicle.has_motor:
        return campaign
    from benchtwin.emulator import conventional_tests

    campaign, dropped = conventional_tests(campaign)
    if dropped:
        print(f"note: vehicle {vehicle.name!r} has no motor: {len(dropped)} test(s) of the campaign need it and are "
              f"left out ({', '.join(dropped)})", file=sys.stderr)
    return campaign


def load_scenario(args: argparse.Namespace) -> tuple[VehicleConfig, SetupConfig, CampaignConfig]:
    """Load the vehicle, setup and campaign named by the arguments (ConfigError on any problem).

    For a conventional car (no motor) the campaign's tests that need the motor or the pack are left out by
    :func:`benchtwin.emulator.conventional_tests`'s rule, and a note on stderr names them.
    """
    vehicle = load_vehicle_arg(args.vehicle)
    campaign = campaign_for_vehicle(vehicle, load_campaign_arg(args.campaign, getattr(args, "seed", None)))
    return vehicle, load_setup_arg(args.setup), campaign


def check_writable(path: str | Path, *, directory: bool = False, what: str = "--out",
                   min_free_bytes: int = MIN_FREE_BYTES) -> Path:
    """Check that ``path`` can be written, before any work is done; one-line :class:`DataError` if not.

    Creates the missing parent folders (or the folder itself with ``directory``), writes and removes a
    probe file next to the output (permission bits alone do not tell: root, read-only mounts, ``/proc``)
    and checks the free space of that file system. Nothing that exists is opened for writing, so a file
    already there is never damaged by the check.

    Raises
    ------
    DataError
        The path (or a parent) is not a folder, cannot be created or written, or the disk has less
        than ``min_free_bytes`` free.
    """
    p = Path(path)
    folder = p if directory else p.parent
    if not directory and p.is_dir():
        raise DataError(f"{what} {p}: is a folder; a file name is needed here")
    if directory and p.exists() and not p.is_dir():
        raise DataError(f"{what} {p}: is a file; a folder is needed here")
    if not directory and folder.exists() and not folder.is_dir():
        raise DataError(f"{what} {p}: {folder} is a file, not a folder")
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


def writable_dir(path: str | Path, option: str) -> Path:
    """:func:`check_writable` for a folder (created when missing) given with ``option``."""
    return check_writable(path, directory=True, what=option)


def writable_file(path: str | Path, option: str) -> Path:
    """:func:`check_writable` for a file given with ``option`` (an existing file is left as it is)."""
    return check_writable(path, what=option)
