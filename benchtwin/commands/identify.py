"""``benchtwin identify RECORDING --out DIR``: identify every parameter a Recording supports.

RECORDING is an MF4 file saved by benchtwin (``Recording.save``), or any CSV/MF4 log when
``--signal-map`` maps its channels to roles. The vehicle specs come from ``--specs`` (a TOML file with
the VehicleSpecs keys, at top level or in a ``[specs]`` table) or from the signal map's ``[specs]``.
Writes ``DIR/params.json`` (every fit with every parameter and its statistics, the errors of the
methods that could not give trustworthy numbers, and what was skipped), ``DIR/figures/*.png`` and the
identified battery maps as CSV tables (``DIR/battery_cell_maps.csv``, ``DIR/battery_ocv_r_map_free.csv``).
"""

from __future__ import annotations

import argparse
import json
import tomllib
from pathlib import Path
from typing import Any

from benchtwin.commands._common import writable_dir
from benchtwin.errors import ConfigError, DataError

__all__ = ["add_subparser", "run"]


def add_subparser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``identify`` subcommand."""
    p = subparsers.add_parser(
        "identify",
        help="identify powertrain parameters from a Recording or a real log",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    p.add_argument("recording", type=Path, help="Recording (.mf4) or a CSV/MF4 log with --signal-map")
    p.add_argument("--out", type=Path, required=True, help="output folder (params.json, figures/)")
    p.add_argument("--signal-map", type=Path, default=None, help="signal map TOML for a user's log")
    p.add_argument("--specs", type=Path, default=None, help="vehicle specs TOML (VehicleSpecs keys)")
    p.add_argument("--methods", default=None,
                   help="comma-separated methods (default: all whose channels are present); "
                        "e.g. battery_map_free,shifts")
    p.add_argument("--option", "-O", action="append", default=[], metavar="METHOD.KEY=VALUE",
                   help="a method's keyword option, value as a TOML literal, e.g. "
                        "torque_converter.max_pump_accel_rpm_s=300 or shifts.min_events=4 (repeatable)")
    p.add_argument("--start-soc", type=float, default=None, metavar="PCT",
                   help="SOC at the log's first sample, %% (anchors the coulomb count of a log without an SOC "
                        "channel; default: chosen from the data by a stated rule, reported in params.json)")
    p.add_argument("--no-figures", action="store_true", help="write params.json only")
    p.set_defaults(func=run)
    return p


def _load_specs(path: Path) -> Any:
    from benchtwin.config._base import read_toml, validate_data
    from benchtwin.config.specs import VehicleSpecs

    data = read_toml(path)
    if "specs" in data and isinstance(data["specs"], dict):
        data = data["specs"]
    return validate_data(VehicleSpecs, data, str(path))


def _parse_options(items: list[str], options: dict[str, dict[str, Any]]) -> None:
    """Parse ``METHOD.KEY=VALUE`` items into ``options`` (values as TOML literals); ConfigError on a bad one."""
    from benchtwin.identification.run import method_option_defaults, method_options

    for item in items:
        head, sep, raw = item.partition("=")
        method, dot, key = head.strip().partition(".")
        if not sep or not dot or not key:
            raise ConfigError(f"--option {item!r}: write METHOD.KEY=VALUE, e.g. shifts.min_events=4")
        try:
            allowed = method_options(method)
        except DataError as exc:
            raise ConfigError(f"--option {item!r}: {exc}") from None
        if allowed is not None and key not in allowed:
            raise ConfigError(f"--option {item!r}: {method} has no option {key!r}; options: "
                              f"{', '.join(sorted(allowed))}")
        try:
            value = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw.strip()  # a bare word: take it as a string
        default = method_option_defaults(method).get(key)
        problem = _option_problem(value, default)
        if problem:
            raise ConfigError(f"--option {item!r}: {method}.{key} {problem} (default {default!r})")
        if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        options.setdefault(method, {})[key] = value


def _option_problem(value: Any, default: Any) -> str | None:
    """What is wrong with an option value given the option's default (None: nothing, or nothing known)."""
    import math

    def number(v: Any) -> bool:
        return isinstance(v, int | float) and not isinstance(v, bool)

    if number(value) and not math.isfinite(value):
        return f"takes a finite number, got {value!r}"
    if isinstance(default, bool):
        return None if isinstance(value, bool) else f"takes true or false, got {value!r}"
    if isinstance(default, int):
        whole = isinstance(value, int) and not isinstance(value, bool)
        return None if whole else f"takes a whole number, got {value!r}"
    if isinstance(default, float):
        return None if number(value) else f"takes a number, got {value!r}"
    if isinstance(default, tuple | list):
        return None if isinstance(value, list) else f"takes a list in brackets, got {value!r}"
    if isinstance(default, str):
        return None if isinstance(value, str) else f"takes a word in quotes, got {value!r}"
    return None


def _write_tables(result: Any, out: Path) -> list[Path]:
    """Write the identified maps as CSV tables (the battery cell maps of Figure 16, the map-free OCV/R)."""
    import numpy as np

    written = []
    b = result.fits.get("battery")
    if b is not None and "map_soc" in b.data:
        path = out / "battery_cell_maps.csv"
        cols = np.column_stack([b.data["map_soc"], b.data["map_ocv"], b.data["map_r_dch"], b.data["map_r_ch"]])
        np.savetxt(path, cols, delimiter=",", fmt="%.6g", comments="",
                   header="# corrected cell maps (eq. 30): alpha*OCV_lit, beta_dch*R_lit_dch, beta_ch*R_lit_ch\n"
                          "soc_pct,ocv_v,r_discharge_ohm,r_charge_ohm")
        written.append(path)
    mf = result.fits.get("battery_map_free")
    if mf is not None and "soc_nodes" in mf.data:
        path = out / "battery_ocv_r_map_free.csv"
        cols = np.column_stack([mf.data["soc_nodes"], mf.data["ocv_nodes"], mf.data["r_dch_nodes"],
                                mf.data["r_ch_nodes"]])
        np.savetxt(path, cols, delimiter=",", fmt="%.6g", comments="",
                   header="# map-free V = OCV(SOC) - I R(SOC), piecewise linear between the nodes; nan: not "
                          "identified\nsoc_pct,ocv_v,r_discharge_ohm,r_charge_ohm")
        written.append(path)
    return written


def _summary(result: Any) -> list[str]:
    lines = []
    for key, fit in result.fits.items():
        shown = ", ".join(f"{n} {p.value:.5g}{(' ' + p.unit) if p.unit and p.unit != '-' else ''}"
                          for n, p in list(fit.params.items())[:4])
        r2 = f"R2 {fit.r2:.4f}" if fit.r2 == fit.r2 else "R2 -"
        lines.append(f"  {key:<34} {fit.status:<8} n={fit.n_points:<6} {r2:<10} {shown}")
    for key, msg in result.errors.items():
        lines.append(f"  {key:<34} error    {msg}")
    for key, why in result.meta.get("skipped", {}).items():
        lines.append(f"  {key:<34} skipped  {why}")
    ref = result.meta.get("soc_reference")
    if ref:
        lines.append(f"  SOC reference: {ref['rule']}: {ref['note']}")
    return lines


def run(args: argparse.Namespace) -> int:
    """Run the identification and write params.json and the figures."""
    from benchtwin.identification.run import identify_all
    from benchtwin.recording import Recording

    options: dict[str, dict[str, Any]] = {}
    specs = None
    _parse_options(args.option, options)  # a typo in an option costs nothing yet
    out: Path = writable_dir(args.out, "--out")
    if args.signal_map is not None:
        from benchtwin.identification.importers import import_log
        from benchtwin.identification.signal_map import load_signal_map

        smap = load_signal_map(args.signal_map)
        rec = import_log(args.recording, smap, lazy=True)  # an MF4 log: channels read per method
        specs = smap.specs
        if smap.battery is not None:
            b = smap.battery
            hints = {"capacity_ah": b.capacity_ah, "soc_nodes_pct": b.soc_nodes_pct,
                     "min_abs_current_a": b.min_abs_current_a, "min_rest_s": b.min_rest_s,
                     "start_soc_pct": b.start_soc_pct}
            options["battery_map_free"] = {**hints, **options.get("battery_map_free", {})}
    else:
        if args.recording.suffix.lower() not in (".mf4", ".mdf"):
            raise ConfigError(f"{args.recording}: not an MF4 Recording; give --signal-map to import a "
                              f"{args.recording.suffix or 'text'} log")
        rec = Recording.open(args.recording)  # channels read per method, not all at once
    if args.specs is not None:
        specs = _load_specs(args.specs)
    if args.start_soc is not None:
        if not 0.0 <= args.start_soc <= 100.0:
            raise ConfigError(f"--start-soc {args.start_soc:g}: a SOC within 0..100 %")
        options.setdefault("battery_map_free", {})["start_soc_pct"] = args.start_soc
    methods = [m.strip() for m in args.methods.split(",") if m.strip()] if args.methods else None
    result = identify_all(rec, specs, methods=methods, options=options)
    result.meta["recording"] = str(args.recording)
    result.meta["signal_map"] = str(args.signal_map) if args.signal_map else None
    params = out / "params.json"
    # the numbers first: whatever happens to the figures, the identified parameters are on disk
    params.write_text(json.dumps(result.to_dict(), indent=1, default=str), encoding="utf-8")
    result.meta["tables"] = sorted(str(p.relative_to(out)) for p in _write_tables(result, out))
    figures: dict[str, Path] = {}
    if not args.no_figures:
        from benchtwin.identification.figures import render_figures

        fig_errors: dict[str, str] = {}
        figures = render_figures(result, out / "figures", errors=fig_errors, specs=specs)
        if fig_errors:
            result.meta["figure_errors"] = fig_errors
    result.meta["figures"] = sorted(str(p.relative_to(out)) for p in figures.values())
    params.write_text(json.dumps(result.to_dict(), indent=1, default=str), encoding="utf-8")
    print(f"identified {len(result.parameters())} parameters in {len(result.fits)} fits "
          f"({len(result.errors)} errors, {len(result.meta.get('skipped', {}))} methods skipped)")
    for line in _summary(result):
        print(line)
    print(f"wrote {params}" + (f" and {len(figures)} figures in {out / 'figures'}" if figures else ""))
    if not result.fits:
        from benchtwin.errors import IdentificationError

        raise IdentificationError(f"nothing could be identified from {args.recording} (see {params})")
    return 0
