"""The telemetry gain as a sweep: the error of every transmission parameter against K_TEL.

``benchtwin gain --sweep`` runs one transmission-family validation (:mod:`benchtwin.validation.families`)
per switch position of the telemetry (:data:`~benchtwin.config.setup.K_TEL_STEPS`) through
:class:`~benchtwin.studies.sweep.Sweep`, on a local pool or a Dask cluster, with the campaign's Trace
from the cache.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.setup import K_TEL_STEPS, SetupConfig
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.studies.sweep import Sweep, SweepOutcome
from benchtwin.studies.sweep_file import CollectConfig, SweepConfig

__all__ = ["AXIS", "gain_sweep", "transmission_errors"]

#: the swept key
AXIS = "setup.telemetry.k_tel"


def gain_sweep(vehicle: VehicleConfig, setup: SetupConfig, campaign: CampaignConfig, out_dir: str | Path, *,
               workers: int = 2, scheduler: str | None = None, cache_dir: str | Path | None = None,
               progress: bool = False) -> tuple[SweepOutcome, dict[int, dict[str, float | None]]]:
    """Validate the transmission at every K_TEL; return the outcome and ``{k_tel: {check: error}}``.

    Rows already in ``out_dir`` for the same runs are kept (the sweep resumes).
    """
    cfg = SweepConfig(name=f"gain_{campaign.name}", vehicle=vehicle.name, setup=setup.name, campaign=campaign.name,
                      seeds=[campaign.seed], families=["transmission"], axes={AXIS: list(K_TEL_STEPS)},
                      collect=CollectConfig(checks=True, parameters=True, only=["transmission.*"]))
    sweep = Sweep(cfg, vehicle, setup, campaign, cache_dir=cache_dir)
    outcome = sweep.run(out_dir, workers=workers, scheduler=scheduler, resume=True, progress=progress)
    keys = {t.key for t in sweep.tasks}
    table = outcome.table[outcome.table["run_key"].isin(keys)]
    return outcome, transmission_errors(table)


def transmission_errors(table: Any) -> dict[int, dict[str, float | None]]:
    """K_TEL -> transmission check name -> error (None where the run failed or the parameter was not found)."""
    cols = [c for c in table.columns if c.startswith("error:transmission.") and not c.endswith("r2")]
    out: dict[int, dict[str, float | None]] = {}
    for _, row in table.sort_values(AXIS).iterrows():
        errs = {}
        for c in cols:
            v = row[c]
            errs[c[len("error:"):]] = None if v is None or v != v else float(v)
        out[int(row[AXIS])] = errs
    return out
