"""``benchtwin gain``: choose the telemetry gain K_TEL of the propeller-shaft torque for a campaign.

Simulates the campaign, then puts its shaft torque through the strain gauge, the telemetry at every switch
position and the 12-bit AD module of the setup: Table 2 (K_TOT, resolution, range) with the campaign's
peak torque, the fraction of clipped samples and the tests they fall in; with ``--score`` the transmission
efficiency is identified again with each gain and its error against the truth shown. Recommends the
highest gain that covers the peak torque with the margin, without clipping.
"""

from __future__ import annotations

import argparse
import math

from benchtwin.commands._common import add_scenario_args, add_seed_arg, load_scenario

__all__ = ["add_subparser", "run"]


def add_subparser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``gain`` subcommand."""
    p = subparsers.add_parser("gain", help="choose the telemetry gain K_TEL for the shaft torque",
                              description=__doc__.split("\n\n", 1)[1] if __doc__ else None)
    add_scenario_args(p)
    add_seed_arg(p)
    p.add_argument("--margin", type=float, default=1.1, help="headroom factor on the peak torque (default 1.1)")
    p.add_argument("--score", action="store_true",
                   help="identify the transmission with every gain and show the error against the truth")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Print the gain table and the recommendation; return the exit status."""
    from benchtwin.emulator import simulate_campaign
    from benchtwin.errors import ConfigError
    from benchtwin.validation import select_gain

    if not (math.isfinite(args.margin) and args.margin >= 1.0):
        raise ConfigError(f"--margin {args.margin}: must be >= 1.0")
    vehicle, setup, campaign = load_scenario(args)
    if setup.telemetry is None:  # before the campaign is simulated, not after
        raise ConfigError(f"--setup {args.setup}: setup {setup.name!r} has no [telemetry] section: there is no "
                          "gain to choose")
    trace = simulate_campaign(vehicle, campaign, progress=True)
    base = None
    if args.score:
        from benchtwin.chain.batch import run_batch

        base = run_batch(trace, setup, seed=campaign.seed)
    best, options = select_gain(trace, setup, vehicle if args.score else None, seed=campaign.seed,
                                base_recording=base, margin=args.margin)
    print(f"benchtwin gain: campaign {campaign.name} (seed {campaign.seed}), "
          f"peak shaft torque {options[0].peak_torque_nm:.0f} Nm, "
          f"setup gain {setup.telemetry.k_tel}")
    head = f"{'K_TEL':>6s} {'K_TOT Nm/V':>11s} {'resol. Nm':>10s} {'range Nm':>10s} {'clipped':>9s}"
    if args.score:
        head += f" {'eta_m err':>10s} {'C0 err Nm':>10s}"
    print(head)
    for o in options:
        line = (f"{o.k_tel:6d} {o.k_tot_nm_per_v:11.1f} {o.resolution_nm:10.2f} {o.range_nm:10.0f} "
                f"{100 * o.clipped_frac:8.3f}%")
        if args.score:
            eta = f"{100 * o.transmission_eta_error:.3f}%" if math.isfinite(o.transmission_eta_error) else "-"
            c0 = f"{o.transmission_c0_error_nm:.2f}" if math.isfinite(o.transmission_c0_error_nm) else "-"
            line += f" {eta:>10s} {c0:>10s}"
        if o.k_tel == best:
            line += "  <- recommended"
        if o.clipped_segments:
            shown = ", ".join(o.clipped_segments[:3]) + (" ..." if len(o.clipped_segments) > 3 else "")
            line += f"  clips in {shown}"
        print(line)
    return 0
