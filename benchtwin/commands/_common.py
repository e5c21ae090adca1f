"""Argument helpers shared by the subcommands.

* scenario files by path or by shipped name, resolved the same way by every command
  (``--campaign quick``, ``--campaign quick.toml`` and ``--campaign path/to/quick.toml``);
* ``--seed``, which overrides the campaign's seed wherever randomness is drawn;
* output paths checked for writability before anything is simulated, so a typo in ``--out`` costs
  a second, not a campaign, and nothing already on disk is touched.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from benchtwin.errors import ConfigError

if TYPE_CHECKING:
    from benchtwin.config.campaign import CampaignConfig
    from benchtwin.config.setup import SetupConfig
    from benchtwin.config.vehicle import VehicleConfig

__all__ = [
    "add_scenario_args",
    "add_seed_arg",
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


def add_scenario_args(p: argparse.ArgumentParser, *, campaign: str = "paper", setup: str = "paper") -> None:
    """Add ``--vehicle``, ``--setup`` and ``--campaign`` (each a path or a shipped name)."""
    p.add_argument("--vehicle", default=DEFAULT_VEHICLE,
                   help="vehicle TOML or a shipped name: p2_phev_9at (default), p2_phev_alt")
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


def load_scenario(args: argparse.Namespace) -> tuple[VehicleConfig, SetupConfig, CampaignConfig]:
    """Load the vehicle, setup and campaign named by the arguments (ConfigError on any problem)."""
    return (load_vehicle_arg(args.vehicle), load_setup_arg(args.setup),
            load_campaign_arg(args.campaign, getattr(args, "seed", None)))


def writable_dir(path: str | Path, option: str) -> Path:
    """Check that ``path`` is (or can be made) a folder we can write in; create it.

    A probe file is created and removed again (permission bits alone do not tell: root, read-only
    mounts, ``/proc``). Nothing in an existing folder is touched.

    Raises
    ------
    ConfigError
        ``path`` is a file, or the folder cannot be created or written.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{option} {path}: is a file; a folder is needed here")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise ConfigError(f"{option} {path}: cannot write there ({exc.strerror or exc})") from None
    return path


def writable_file(path: str | Path, option: str) -> Path:
    """Check that the file ``path`` can be written (its folder writable, the file itself if it exists).

    An existing file is opened for appending and closed, so its content is left as it is.

    Raises
    ------
    ConfigError
        ``path`` is a folder, or it or its folder cannot be written.
    """
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{option} {path}: is a folder; a file name is needed here")
    parent = path.parent
    if parent.exists() and not parent.is_dir():
        raise ConfigError(f"{option} {path}: {parent} is a file, not a folder")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        if path.exists():
            with path.open("ab"):
                pass
        else:
            with tempfile.TemporaryFile(dir=parent):
                pass
    except OSError as exc:
        raise ConfigError(f"{option} {path}: cannot write there ({exc.strerror or exc})") from None
    return path
