"""Whole-model sweep axes: ``vehicle = [files]`` swaps the run's vehicle (its truth too), a bad file is an error
naming the axis and the file before anything runs, and the dotted axes still apply to each swapped model.

The run test is small: the quick campaign, the battery family only (its constant-drive test), two vehicles, one
seed; the two Traces are simulated once into a temporary cache.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from benchtwin.config import load_vehicle, scenario_path
from benchtwin.errors import ConfigError
from benchtwin.studies.sweep import Sweep, read_table
from benchtwin.studies.sweep_file import apply_axes, load_sweep

SWEEP = """
campaign = "quick"
seeds = [7]
families = ["battery"]

[axes]
vehicle = {vehicles}
setup.ivt.battery.current_errors.noise_std = [0.0, 0.5]
"""


def _file(tmp: Path, vehicles: str) -> Path:
    p = tmp / "sweep.toml"
    p.write_text(SWEEP.format(vehicles=vehicles), encoding="utf-8")
    return p


def test_a_vehicle_axis_swaps_the_whole_vehicle_and_keeps_the_dotted_axes(tmp_path: Path) -> None:
    alt = load_vehicle(scenario_path("vehicles", "p2_phev_alt.toml"))
    (tmp_path / "mine.toml").write_text(scenario_path("vehicles", "p2_phev_alt.toml").read_text(encoding="utf-8"),
                                        encoding="utf-8")
    sweep = Sweep.from_file(_file(tmp_path, '["p2_phev_9at", "mine.toml"]'), cache_dir=tmp_path / "c")
    assert len(sweep.tasks) == 4 and len({t.key for t in sweep.tasks}) == 4
    for t in sweep.tasks:
        doc = apply_axes(t.base, t.params)
        want = alt.name if t.params["vehicle"] == "mine.toml" else "P2 diesel PHEV, 9-speed AT (paper vehicle)"
        assert doc["vehicle"]["name"] == want
        assert doc["vehicle"]["battery"]["alpha"] == (alt.battery.alpha if t.params["vehicle"] == "mine.toml"
                                                      else 1.008)
        assert doc["setup"]["ivt"]["battery"]["current_errors"]["noise_std"] == \
            t.params["setup.ivt.battery.current_errors.noise_std"]
    # the base models are not changed by a run's swap
    assert sweep.base["vehicle"]["battery"]["alpha"] == 1.008


@pytest.mark.parametrize(("vehicles", "match"), [
    ('["p2_phev_9at", "nowhere/car.toml"]', r"key 'axes.vehicle' = 'nowhere/car.toml'"),
    ('["p2_phev_9at", "p2_phev_9at"]', r"key 'axes.vehicle'.*must not repeat"),
    ("[1, 2]", r"key 'axes.vehicle'.*list of vehicle files or shipped names"),
])
def test_a_bad_vehicle_axis_is_one_error_naming_it(tmp_path: Path, vehicles: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        load_sweep(_file(tmp_path, vehicles))


def test_each_run_is_judged_against_its_own_vehicle(tmp_path: Path) -> None:
    sweep = Sweep.from_file(_file(tmp_path, '["p2_phev_9at", "p2_phev_alt"]'), cache_dir=tmp_path / "cache")
    outcome = sweep.run(tmp_path / "out", workers=0, figures=True)
    assert (outcome.done, outcome.failed, outcome.simulated) == (4, 0, 2)  # one Trace per vehicle
    t = read_table(tmp_path / "out")
    assert t["passed"].all()
    alpha = t.groupby("vehicle")["value:battery.alpha"].mean()
    # the two vehicles' alpha (1.008 and 0.992) lie 0.016 apart: within a quarter of that of its own vehicle's, an
    # estimate cannot come from the other vehicle's truth
    assert abs(alpha["p2_phev_9at"] - 1.008) < 0.004 and abs(alpha["p2_phev_alt"] - 0.992) < 0.004, alpha
    assert (tmp_path / "out" / "error_vs_vehicle.png").exists()
