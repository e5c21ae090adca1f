"""``benchtwin plan --setup S --campaign C [--vehicle V]``: identifiability before driving.

From the planned tests and the setup's noise model, without identifying anything from measured data,
predicts the standard error of every parameter (the linearised covariance of each fit at the operating
points the campaign reaches on the emulated plant), flags the parameters no planned test excites and
names the test to add in the campaign's TOML terms. Predicted standard errors are those of the
transmission (eta_m and C0 per gear, drive and coast), battery (eq. 30), brake, motor and torque-converter fits
and of the extension fits (battery.rc, soc_per_ah, motor.loss, engine.can_torque; some by draws of the readings
through the identification's own fit, see benchtwin.studies.plan_extensions); the shift lines and the other
families are checked for excitation only. The campaign's Trace comes from the disk cache
(simulated on a miss). ``--json`` prints the plan as one JSON document.
"""

from __future__ import annotations

import argparse

from benchtwin.commands._common import DEFAULT_VEHICLE, add_seed_arg, load_scenario

__all__ = ["add_subparser", "run"]


def add_subparser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``plan`` subcommand."""
    p = subparsers.add_parser("plan", help="predict each parameter's standard error and flag unexcited ones before "
                                           "driving", description=__doc__.split("\n\n", 1)[1] if __doc__ else None)
    p.add_argument("--setup", required=True, help="setup TOML or a shipped name: paper, ideal")
    p.add_argument("--campaign", required=True, help="campaign TOML or a shipped name: paper, quick, wltc")
    p.add_argument("--vehicle", default=DEFAULT_VEHICLE,
                   help="vehicle TOML or a shipped name: p2_phev_9at (default), p2_phev_alt")
    add_seed_arg(p)
    p.add_argument("--no-cache", action="store_true", help="simulate the campaign instead of using the Trace cache")
    p.add_argument("--json", action="store_true", help="print the plan as JSON")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Print the plan; return the exit status (0: planned, whether or not every parameter is identifiable)."""
    from benchtwin.studies.plan import plan_campaign

    vehicle, setup, campaign = load_scenario(args)
    plan = plan_campaign(vehicle, setup, campaign, cache=not args.no_cache)
    print(plan.to_json() if args.json else plan.format_table())
    return 0
