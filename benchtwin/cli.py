"""The ``benchtwin`` command.

Each subcommand is its own module in :mod:`benchtwin.commands` exposing
``add_subparser(subparsers)``; the module sets ``func`` on its parser. Subcommands are imported
lazily by name, so one whose optional dependency is missing degrades alone. Errors of the project
are printed as one line (``benchtwin: error: ...``) with exit status 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from benchtwin import __version__
from benchtwin._heap import one_heap
from benchtwin.errors import BenchtwinError

__all__ = ["main"]

#: subcommand modules, in the order of ``benchtwin --help``
SUBCOMMANDS: tuple[str, ...] = (
    "demo",
    "simulate",
    "acquire",
    "serve",
    "record",
    "identify",
    "validate",
    "gain",
    "sweep",
    "plan",
    "faults",
)


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser with every subcommand that imports."""
    parser = argparse.ArgumentParser(
        prog="benchtwin",
        description="Test-bench emulator and sensor-chain validator for a P2 PHEV on a chassis dyno.",
    )
    parser.add_argument("--version", action="version", version=f"benchtwin {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"benchtwin.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.startswith("benchtwin.commands"):
                continue  # not written yet
            _broken(sub, name, exc)
            continue
        except ImportError as exc:
            _broken(sub, name, exc)
            continue
        module.add_subparser(sub)
    return parser


def _broken(sub: argparse._SubParsersAction, name: str, exc: Exception) -> None:
    p = sub.add_parser(name, help=f"(unavailable: {exc})")

    def fail(_args: argparse.Namespace) -> int:
        raise BenchtwinError(f"command {name!r} is unavailable: {exc}")

    p.set_defaults(func=fail)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status.

    The process's threads share one C heap from here on (:func:`benchtwin._heap.one_heap`), so that the memory the
    chain's and the type B re-runs' threads free is given back between the stages of a command.
    """
    one_heap()
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2),
        format="%(levelname)s %(name)s: %(message)s",
    )
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help()
        return 1
    try:
        return int(func(args) or 0)
    except BenchtwinError as exc:
        msg = str(exc)
        print(f"benchtwin: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("benchtwin: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
