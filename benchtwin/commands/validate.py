"""``benchtwin validate``: simulate a campaign, run it through the sensor chain, identify, compare with truth.

Prints every check (chain channels against the Trace, each identified parameter against the vehicle file,
torque-converter curves, shift lines, the BSFC map and, for a realistic setup, R^2 against the paper's)
and exits 0 when all pass, 1 otherwise. With ``--out`` the raw bus logs, ``recording.mf4``,
``params.json`` and ``validation.json`` are written (and the figures with ``--figures``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from benchtwin.commands._common import add_scenario_args, load_scenario

__all__ = ["add_subparser", "print_report", "run"]


def add_subparser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``validate`` subcommand."""
    p = subparsers.add_parser("validate", help="campaign -> chain -> identification, compared with the truth",
                              description=__doc__.split("\n\n", 1)[1] if __doc__ else None)
    add_scenario_args(p)
    p.add_argument("--profile", choices=("ideal", "realistic"), default=None,
                   help="tolerance profile (default: ideal for an ideal setup, else realistic)")
    p.add_argument("--out", type=Path, default=None, help="write logs, recording, params.json, validation.json")
    p.add_argument("--figures", action="store_true", help="also render the identification figures (with --out)")
    p.add_argument("--all", action="store_true", help="list every check, not only the failures")
    p.set_defaults(func=run)
    return p


def print_report(report: object, *, show_all: bool) -> None:
    """Print a ValidationReport: a summary per group, then the checks."""
    from benchtwin.validation import ValidationReport

    if not isinstance(report, ValidationReport):  # pragma: no cover - typing aid
        raise TypeError("expected a ValidationReport")
    m = report.meta
    print(f"benchtwin validate: {m['vehicle']} | setup {m['setup']} | campaign {m['campaign']} | "
          f"profile {m['profile']}")
    t = report.timings_s
    print(f"  simulate {t['simulate']:.1f} s, chain {t['chain']:.1f} s, identify {t['identify']:.1f} s; "
          f"{report.chain['plant_seconds']:.0f} s of tests")
    loads = ", ".join(f"{k} {100 * v:.1f} %" for k, v in sorted(report.chain.get("bus_load", {}).items()))
    print(f"  bus load: {loads}")
    offs = report.chain.get("clock_offsets_s", {})
    if offs:
        print("  clock offsets: " + ", ".join(f"{k} {1000 * v:+.1f} ms" for k, v in sorted(offs.items())))
    clipped = report.chain.get("clipped_samples", {})
    if clipped:
        print("  clipped samples: " + ", ".join(f"{k} {v}" for k, v in sorted(clipped.items())))
    groups: dict[str, list[int]] = {}
    for c in report.checks:
        g = groups.setdefault(c.group, [0, 0])
        g[0] += 1
        g[1] += int(c.passed)
    print("  " + ", ".join(f"{g} {ok}/{n}" for g, (n, ok) in groups.items()))
    if report.identification is not None and report.identification.errors:
        for k, v in sorted(report.identification.errors.items()):
            print(f"  not identified: {k}: {v}")
    print()
    print(report.format_table(only_failed=not show_all))


def run(args: argparse.Namespace) -> int:
    """Run the validation; return 0 when every check passes, 1 otherwise."""
    from benchtwin.validation import validate

    vehicle, setup, campaign = load_scenario(args)
    report = validate(vehicle, setup, campaign, profile=args.profile, out_dir=args.out,
                      figures=bool(args.figures and args.out), progress=True)
    print_report(report, show_all=args.all)
    if args.out is not None:
        print(f"\nwrote {args.out}/validation.json, params.json, recording.mf4 and the raw bus logs")
    return 0 if report.passed else 1
