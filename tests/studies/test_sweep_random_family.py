"""A random vehicle family as a sweep axis (``[axes.vehicle] random = {count, seed}``), and runs.parquet kept
readable as runs finish.

The run test is small: the quick campaign, the battery family only (its constant-drive test), a family of two
(seed 1: an 8-speed petrol car of alpha 0.966 and a 9-speed diesel of alpha 0.987), two seeds; the four Traces
are simulated once into a temporary cache.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd
import pytest

import benchtwin.studies.sweep as sweep_mod
from benchtwin.config import load_vehicle
from benchtwin.config.campaign import RampUpTest
from benchtwin.errors import ConfigError
from benchtwin.studies.sweep import Sweep, _run_models, read_table
from benchtwin.studies.sweep_file import load_sweep
from benchtwin.studies.vehicle_family import RANGES, vehicle_gear

SWEEP = """
campaign = "quick"
seeds = [7, 8]
families = ["battery"]

[axes.vehicle]
random = {random}
"""


def _file(tmp: Path, random: str, name: str = "sweep.toml") -> Path:
    p = tmp / name
    p.write_text(SWEEP.format(random=random), encoding="utf-8")
    return p


def _family(tmp: Path, random: str) -> dict[str, dict[str, Any]]:
    cfg, *_ = load_sweep(_file(tmp, random, f"s{abs(hash(random))}.toml"))
    return cfg.model_files["vehicle"]


def test_same_seed_same_vehicles_other_seed_other_vehicles(tmp_path: Path) -> None:
    a = _family(tmp_path, "{count = 2, seed = 1}")
    assert list(a) == ["random-0", "random-1"]
    assert _family(tmp_path, "{count = 2, seed = 1}") == a
    b = _family(tmp_path, "{count = 2, seed = 2}")
    assert list(b) == list(a) and all(b[k] != a[k] for k in a)
    # vehicle i depends on (seed, i) only: a larger family keeps the smaller one's vehicles
    c = _family(tmp_path, "{count = 3, seed = 1}")
    assert {k: c[k] for k in a} == a and c["random-2"] not in a.values()
    for v in c.values():  # drawn inside the family's ranges
        assert all(RANGES["eta_m"][0] <= e <= RANGES["eta_m"][1] for e in v["transmission"]["eta_m"])
        assert all(RANGES["c0_nm"][0] <= x <= RANGES["c0_nm"][1] for x in v["transmission"]["c0_nm"])
    only8 = _family(tmp_path, '{count = 3, seed = 1, gears = [8], fuels = ["diesel"]}')
    assert all(len(v["specs"]["gear_ratios"]) == 8 and "diesel" in v["name"] for v in only8.values())


def test_the_campaign_follows_each_drawn_vehicles_gear_count(tmp_path: Path) -> None:
    sweep = Sweep.from_file(_file(tmp_path, "{count = 2, seed = 1}"), cache_dir=tmp_path / "c")
    base_ramps = [t for t in sweep.base["campaign"]["tests"] if t["kind"] == "ramp_up"]
    assert [t["gear"] for t in base_ramps] == [5, 4]  # the quick campaign's, for the 9-speed paper vehicle
    paper = load_vehicle()
    n_gears = set()
    for task in sweep.tasks:
        vehicle, _setup, campaign = _run_models(task)
        n_gears.add(vehicle.n_gears)
        ramps = [t for t in campaign.tests if isinstance(t, RampUpTest)]
        assert [t.gear for t in ramps] == [vehicle_gear(t["gear"], vehicle.n_gears) for t in base_ramps]
        for t, b in zip(ramps, base_ramps, strict=True):
            # the motor turns as fast as on the paper vehicle in the paper gear (speed rounded to 0.1 km/h)
            w_paper = b["speed_kmh"] / paper.specs.wheel_radius_m * paper.specs.final_drive_ratio \
                * paper.specs.gear_ratios[b["gear"] - 1]
            w = t.speed_kmh / vehicle.specs.wheel_radius_m * vehicle.specs.final_drive_ratio \
                * vehicle.specs.gear_ratios[t.gear - 1]
            assert abs(w / w_paper - 1.0) < 0.05 / t.speed_kmh + 1e-9
        assert campaign.seed == task.seed
    assert n_gears == {8, 9}
    # the key tells two families apart although both name their vehicles random-0, random-1
    other = Sweep.from_file(_file(tmp_path, "{count = 2, seed = 2}", "o.toml"), cache_dir=tmp_path / "c")
    assert not {t.key for t in sweep.tasks} & {t.key for t in other.tasks}


@pytest.mark.parametrize(("random", "match"), [
    ("{count = 2, sed = 1}", r"key 'axes.vehicle'.*unknown key 'sed'; allowed: count, seed, gears, fuels"),
    ("{count = 2}", r"key 'axes.vehicle'.*key 'seed' missing"),
    ("{count = 0, seed = 1}", r"key 'axes.vehicle'.*count: Input should be greater than or equal to 1"),
    ("{count = 2, seed = 1, gears = [7]}", r"key 'axes.vehicle'.*gear counts \[7\]: allowed 8, 9"),
    ('{count = 2, seed = 1, fuels = ["lpg"]}', r"key 'axes.vehicle'.*fuels \['lpg'\]: allowed diesel, petrol"),
    ("3", r"key 'axes.vehicle'.*random: Input should be a valid dictionary"),
])
def test_a_bad_random_family_is_one_error_naming_the_key(tmp_path: Path, random: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match) as exc:
        load_sweep(_file(tmp_path, random))
    assert len(str(exc.value).splitlines()) == 1, str(exc.value)


def test_a_sweep_over_a_random_family_runs_one_row_per_vehicle_and_seed(tmp_path: Path) -> None:
    sweep = Sweep.from_file(_file(tmp_path, "{count = 2, seed = 1}"), cache_dir=tmp_path / "cache")
    outcome = sweep.run(tmp_path / "out", workers=0, figures=False)
    assert (outcome.done, outcome.failed, outcome.simulated) == (4, 0, 4)  # one Trace per vehicle and seed
    t = read_table(tmp_path / "out")
    assert sorted(zip(t["vehicle"], t["seed"], strict=True)) == [("random-0", 7), ("random-0", 8),
                                                                  ("random-1", 7), ("random-1", 8)]
    assert t["passed"].all()
    truth = {k: v["battery"]["alpha"] for k, v in sweep.base["files"]["vehicle"].items()}
    assert abs(truth["random-0"] - truth["random-1"]) > 0.02
    # each run's alpha lies within a quarter of the two truths' gap (0.020) of its own vehicle's: an estimate
    # cannot come from the other vehicle (or the base vehicle's 1.008)
    for v, a in zip(t["vehicle"], t["value:battery.alpha"], strict=True):
        assert abs(a - truth[v]) < 0.005, (v, a, truth[v])
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "out" / "runs.parquet"), t)


def test_runs_parquet_is_readable_while_the_sweep_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """What a hard kill would leave: runs.parquet read during the sweep (before its end) holds the finished runs."""
    out = tmp_path / "out"
    seen: list[pd.DataFrame | None] = []

    def fake_run(task: sweep_mod.RunTask) -> dict[str, Any]:
        p = out / "runs.parquet"
        seen.append(pd.read_parquet(p) if p.exists() else None)
        return {"run_key": task.key, "index": task.index, "seed": task.seed, "params": task.params, "status": "ok",
                "error": "", "passed": True, "n_checks": 1, "n_failed": 0, "trace_cached": True, "wall_s": 0.0,
                "figures": {"value:x": float(task.index)}}

    monkeypatch.setattr(sweep_mod, "run_task", fake_run)
    monkeypatch.setattr(Sweep, "_prefetch", lambda self, backend, todo: 0)
    sweep = Sweep.from_file(_file(tmp_path, "{count = 2, seed = 1}"), cache_dir=tmp_path / "c")
    sweep.run(out, workers=0, figures=False)
    assert seen[0] is None
    for k, table in enumerate(seen[1:], start=1):  # before run k: the k finished runs, whole, in order
        assert table is not None and list(table["index"]) == list(range(k))
        assert list(table["value:x"]) == [float(i) for i in range(k)]
    assert not list(out.glob(".runs.parquet.*"))  # no temporary file left behind
