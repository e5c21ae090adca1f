"""``benchtwin validate``: simulate a campaign, run it through the sensor chain, identify, compare with truth.

Prints every check (chain channels against the Trace, each identified parameter against the vehicle file,
torque-converter curves, shift lines, the BSFC map and, for a realistic setup, R^2 against the paper's)
and exits 0 when all pass, 1 otherwise. A campaign with a driving cycle beside its identification tests is
also identified without that cycle, and the map-based vehicle model built from that identification predicts
the cycle, the WLTC again from a low SOC and the NEDC (checks of group ``prediction``). With ``--out`` the raw bus logs,
``recording.mf4``, ``params.json``, ``validation.json`` and ``report.html`` (one self-contained page: verdict,
prediction, checks, chain, figures) are written (and the figure files with ``--figures``). With
``--families transmission,battery`` only those identification families are validated, each on the campaign's
tests it needs (the fast inner loop; no held-out prediction).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from benchtwin.commands._common import add_scenario_args, add_seed_arg, load_scenario, writable_dir

__all__ = ["FAMILY_NAMES", "HIGHLIGHTS", "add_subparser", "highlights", "print_report", "run"]


def add_subparser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``validate`` subcommand."""
    p = subparsers.add_parser("validate", help="campaign -> chain -> identification, compared with the truth",
                              description=__doc__.split("\n\n", 1)[1] if __doc__ else None)
    add_scenario_args(p)
    add_seed_arg(p)
    p.add_argument("--profile", choices=("ideal", "realistic"), default=None,
                   help="tolerance profile (default: ideal for an ideal setup, else realistic)")
    p.add_argument("--out", type=Path, default=None, help="write logs, recording, params.json, validation.json")
    p.add_argument("--figures", action="store_true", help="also render the identification figures (with --out)")
    p.add_argument("--all", action="store_true", help="list every check, not only the failures")
    p.add_argument("--families", type=_families, default=None, metavar="F1,F2",
                   help="validate only these identification families, each on its own tests (comma-separated: "
                        f"{', '.join(_family_names())}); no held-out prediction")
    p.add_argument("--type-b", action=argparse.BooleanOptionalAction, default=None,
                   help="propagate the setup's declared systematic uncertainties into the total intervals (GUM type "
                        "B; default: on for the whole campaign, off with --families)")
    p.set_defaults(func=run)
    return p


#: the identification families ``--families`` accepts (``benchtwin.validation.families.FAMILIES``, named here so
#: that building the parser imports no identification code; a test keeps the two equal)
FAMILY_NAMES: tuple[str, ...] = ("transmission", "torque_converter", "engine", "motor", "road_load", "brakes",
                                 "battery", "shifts")


def _family_names() -> tuple[str, ...]:
    return FAMILY_NAMES


def _families(text: str) -> list[str]:
    """``--families``: a comma-separated list of known family names (argparse error otherwise)."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"no family named; allowed: {', '.join(_family_names())}")
    bad = [n for n in names if n not in _family_names()]
    if bad:
        raise argparse.ArgumentTypeError(f"unknown famil{'y' if len(bad) == 1 else 'ies'} "
                                         f"{', '.join(map(repr, bad))}; allowed: {', '.join(_family_names())}")
    return names


def print_report(report: object, *, show_all: bool) -> None:
    """Print a ValidationReport: a summary per group, then the checks."""
    from benchtwin.validation import ValidationReport

    if not isinstance(report, ValidationReport):  # pragma: no cover - typing aid
        raise TypeError("expected a ValidationReport")
    m = report.meta
    print(f"benchtwin validate: {m['vehicle']} | setup {m['setup']} | campaign {m['campaign']} | "
          f"profile {m['profile']}")
    t = report.timings_s
    pred_t = f", predict {t['predict']:.1f} s" if "predict" in t else ""
    print(f"  simulate {t['simulate']:.1f} s, chain {t['chain']:.1f} s, identify {t['identify']:.1f} s{pred_t}; "
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
    for d in report.prediction.get("drives", []):
        e, m = d["errors"], d["measured"]
        firing = m.get("fuel_firing_g")
        p_firing = d["predicted"].get("fuel_firing_g", d["predicted"]["fuel_g"])
        f_firing = f" ({100 * (p_firing / firing - 1):+.2f} % without engine starts)" if firing else ""
        el = (f"{100 * e['electric_of_fuel_energy']:+.2f} % of the fuel energy (charge-sustaining)"
              if e.get("charge_sustaining") else f"{100 * e['electric']:+.2f} %")
        print(f"  predicted {d['name']} ({d['gear_source']} gears): fuel {100 * e['fuel']:+.2f} %{f_firing}, "
              f"electric energy {d['predicted']['electric_wh']:.0f} Wh vs {m['electric_wh']:.0f} Wh: {el}, "
              f"final SOC {e['soc_points']:+.2f} pt, CO2 {100 * e['co2']:+.2f} %")
    for note in report.prediction.get("notes", []):
        if note.startswith(("no prediction", "held-out drive")):
            print(f"  {note}")
    print()
    if show_all:
        print(report.format_table())
        return
    print(highlights(report))
    if report.failures():
        print()
        print(report.format_table(only_failed=True))
    else:
        print(f"{len(report.checks)} checks, all passed (--all lists every one)")


#: the parameters a test engineer looks at first, in the order of the paper
HIGHLIGHTS: tuple[str, ...] = (
    "transmission.gear5.eta_m", "transmission.gear5.C0", "motor.motoring.e", "motor.motoring.W_loss",
    "motor.generating.e_gen", "engine.bsfc.bsfc_min", "battery.alpha", "battery.beta_discharge",
    "battery.beta_charge", "torque_converter.converter.gamma_coupling", "torque_converter.capacity_factor_curve",
    "shifts.up_1_2", "shifts.down_2_1", "brakes.distribution.k_f", "road_load.F0", "road_load.F1", "road_load.F2",
)


def highlights(report: object) -> str:
    """The main parameters (identified, true, error, tolerance) and every R^2 check, as a short table."""
    from benchtwin.validation import ValidationReport

    if not isinstance(report, ValidationReport):  # pragma: no cover - typing aid
        raise TypeError("expected a ValidationReport")
    by_name = {c.name: c for c in report.checks}
    picked = [by_name[n] for n in HIGHLIGHTS if n in by_name] + [c for c in report.checks if c.group == "r2"]
    sub = type(report)(checks=picked)
    lines = sub.format_table().splitlines()[:-1]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Run the validation; return 0 when every check passes, 1 otherwise."""
    from benchtwin.validation import validate

    vehicle, setup, campaign = load_scenario(args)
    if args.out is not None:
        writable_dir(args.out, "--out")
    report = validate(vehicle, setup, campaign, profile=args.profile, out_dir=args.out,
                      figures=bool(args.figures and args.out), progress=True, families=args.families,
                      type_b=args.type_b)
    print_report(report, show_all=args.all)
    if args.out is not None:
        print(f"\nwrote {args.out}/report.html (open it in a browser), validation.json, params.json, recording.mf4 "
              f"and the raw bus logs")
    return 0 if report.passed else 1
