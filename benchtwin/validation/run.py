"""The whole validation run: campaign -> plant -> sensors -> chain -> identification -> comparison with the truth."""

from __future__ import annotations

import json
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.chain.batch import run_batch
from benchtwin.config._base import StrictModel
from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.setup import ChannelErrors, LinkErrors, SetupConfig
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.emulator import simulate_campaign
from benchtwin.emulator.cache import cached_campaign
from benchtwin.errors import ConfigError
from benchtwin.identification.run import identify_all
from benchtwin.recording import Flag
from benchtwin.trace import Trace
from benchtwin.validation.chain import chain_checks
from benchtwin.validation.families import (
    family_checks,
    family_spans,
    merge_recordings,
    resolve_families,
    span_seed,
    stitch_traces,
)
from benchtwin.validation.parameters import compare_with_truth, paper_estimation_fits
from benchtwin.validation.report import ValidationReport

__all__ = ["validate"]


def validate(vehicle: VehicleConfig, setup: SetupConfig, campaign: CampaignConfig, *, profile: str | None = None,
             out_dir: str | Path | None = None, figures: bool = False, progress: bool = False,
             trace: Trace | None = None, families: Iterable[str] | None = None,
             cache: bool | str | Path = False) -> ValidationReport:
    """Simulate the campaign, run the batch chain, identify, and compare with the truth.

    Parameters
    ----------
    vehicle, setup, campaign:
        The scenario.
    profile:
        ``ideal`` or ``realistic``; by default ``ideal`` when every sensor of the setup is ideal.
    out_dir:
        Where to write the raw bus logs, ``recording.mf4``, ``params.json``, ``validation.json`` (and
        figures); nothing is written when None.
    figures:
        Also render the identification figures (needs ``out_dir``).
    progress:
        Show the plant's progress bar.
    trace:
        A Trace of this vehicle and campaign already simulated (to compare several setups on one run).
    families:
        Validate only these identification families (see :mod:`benchtwin.validation.families`): the
        chain runs over the campaign's tests of the kinds they need, only their methods identify, and
        only their checks are made. None: everything.
    cache:
        Take the Trace from the disk cache (:mod:`benchtwin.emulator.cache`), simulating and storing it
        on a miss: True for the default directory, or a directory. ``meta['trace_cached']`` says
        whether it hit.

    Returns
    -------
    ValidationReport
    """
    prof = profile or ("ideal" if _setup_is_ideal(setup) else "realistic")
    fams = resolve_families(families)
    report = ValidationReport(meta={"vehicle": vehicle.name, "setup": setup.name, "campaign": campaign.name,
                                    "profile": prof, "seed": campaign.seed})
    if fams is not None:
        report.meta["families"] = [f.name for f in fams]
    t0 = time.perf_counter()
    if trace is None and cache is not False:
        trace, hit = cached_campaign(vehicle, campaign, directory=None if cache is True else cache,
                                     progress=progress)
        report.meta["trace_cached"] = hit
    elif trace is None:
        trace = simulate_campaign(vehicle, campaign, progress=progress)
    t1 = time.perf_counter()
    if fams is None:
        rec = run_batch(trace, setup, seed=campaign.seed, out_dir=out_dir)
        checked = trace
    else:
        spans = family_spans(trace.segments, {k for f in fams for k in f.kinds})
        if not spans:
            kinds = sorted({k for f in fams for k in f.kinds})
            raise ConfigError(f"campaign {campaign.name!r} has no test of the kind(s) {', '.join(kinds)} that "
                              f"the families {', '.join(f.name for f in fams)} need")
        slices = [trace.slice_time(a, b) for a, b in spans]
        recs = [run_batch(sl, setup, seed=span_seed(campaign.seed, k),
                          out_dir=None if out_dir is None else Path(out_dir) / f"span{k}")
                for k, sl in enumerate(slices)]
        rec, checked = merge_recordings(recs), stitch_traces(slices)
    t2 = time.perf_counter()
    methods = None if fams is None else [m for f in fams for m in f.methods]
    result = identify_all(rec, vehicle.specs, methods=None if methods is None else list(dict.fromkeys(methods)))
    t3 = time.perf_counter()
    report.timings_s = {"simulate": round(t1 - t0, 3), "chain": round(t2 - t1, 3), "identify": round(t3 - t2, 3)}
    report.identification = result
    report.chain = {
        "plant_seconds": round(trace.duration_s, 2),
        "bus_load": rec.meta.get("bus_load", {}),
        "clock_offsets_s": rec.meta.get("clock_offsets_s", {}),
        "flagged_samples": {k: int(np.count_nonzero(c.flags)) for k, c in rec.channels.items()
                            if np.count_nonzero(c.flags)},
        "clipped_samples": {k: int(np.count_nonzero(c.flags & int(Flag.SATURATED))) for k, c in rec.channels.items()
                            if np.count_nonzero(c.flags & int(Flag.SATURATED))},
    }
    gears = sorted({int(s.settings["gear"]) for s in trace.segments if s.kind == "ramp_up" and "gear" in s.settings})
    roles = None if fams is None else set().union(*(f.roles() for f in fams))
    report.checks = chain_checks(checked, rec, setup, profile=prof, roles=roles)
    want_paper = prof == "realistic" and (fams is None or any(f.name == "transmission" for f in fams))
    paper_sets = paper_estimation_fits(rec, vehicle, trace) if want_paper else {}
    params = compare_with_truth(result, vehicle, profile=prof, gears=gears or None, setup=setup,
                                paper_sets=paper_sets)
    report.checks += params if fams is None else family_checks(params, fams)
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        (out / "params.json").write_text(json.dumps(result.to_dict(), indent=1, default=str), encoding="utf-8")
        (out / "validation.json").write_text(json.dumps(report.to_dict(), indent=1, default=str), encoding="utf-8")
        if figures:
            from benchtwin.identification.figures import render_figures

            render_figures(result, out / "figures")
    return report


def _setup_is_ideal(setup: SetupConfig) -> bool:
    """Whether every channel and link of a setup is free of imperfections (and Modbus polls never fail)."""
    def ideal(obj: Any) -> bool:
        if isinstance(obj, (ChannelErrors, LinkErrors)):
            return obj.ideal
        if isinstance(obj, StrictModel):
            if any(getattr(obj, f, 0) for f in ("timeout_prob", "exception_prob")):
                return False
            return all(ideal(getattr(obj, name)) for name in type(obj).model_fields)
        if isinstance(obj, dict):
            return all(ideal(v) for v in obj.values())
        if isinstance(obj, list):
            return all(ideal(v) for v in obj)
        return True

    return ideal(setup)
