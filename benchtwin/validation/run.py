"""The whole validation run: campaign -> plant -> sensors -> chain -> identification -> comparison with the truth."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.chain.batch import run_batch
from benchtwin.config._base import StrictModel
from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.setup import ChannelErrors, LinkErrors, SetupConfig
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.emulator import simulate_campaign
from benchtwin.identification.run import identify_all
from benchtwin.recording import Flag
from benchtwin.trace import Trace
from benchtwin.validation.chain import chain_checks
from benchtwin.validation.parameters import compare_with_truth, paper_estimation_fits
from benchtwin.validation.report import ValidationReport

__all__ = ["validate"]


def validate(vehicle: VehicleConfig, setup: SetupConfig, campaign: CampaignConfig, *, profile: str | None = None,
             out_dir: str | Path | None = None, figures: bool = False, progress: bool = False,
             trace: Trace | None = None) -> ValidationReport:
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

    Returns
    -------
    ValidationReport
    """
    prof = profile or ("ideal" if _setup_is_ideal(setup) else "realistic")
    report = ValidationReport(meta={"vehicle": vehicle.name, "setup": setup.name, "campaign": campaign.name,
                                    "profile": prof, "seed": campaign.seed})
    t0 = time.perf_counter()
    if trace is None:
        trace = simulate_campaign(vehicle, campaign, progress=progress)
    t1 = time.perf_counter()
    rec = run_batch(trace, setup, seed=campaign.seed, out_dir=out_dir)
    t2 = time.perf_counter()
    result = identify_all(rec, vehicle.specs)
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
    report.checks = chain_checks(trace, rec, setup, profile=prof)
    paper_sets = paper_estimation_fits(rec, vehicle, trace) if prof == "realistic" else {}
    report.checks += compare_with_truth(result, vehicle, profile=prof, gears=gears or None, setup=setup,
                                        paper_sets=paper_sets)
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
