"""``benchtwin plan`` flags the motor map regions (side x speed band x torque level) no planned test visits."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from benchtwin.config import load_campaign, load_setup, load_vehicle, scenario_path
from benchtwin.emulator.cache import cached_campaign
from benchtwin.studies.plan import planned_recording
from benchtwin.studies.plan_motor_regions import motor_regions, plan_motor_regions, region_counts, suggest_region_test
from benchtwin.trace import Trace

_HEAD = """name = "{name}"
seed = 7
plant_rate_hz = 100.0
initial_displayed_soc_pct = 70.0
"""
#: one electric ramp-up in gear 5 at 60 km/h (about 1,460 rpm, below the base speed), pedal steps only
_MOTORING_ONLY = """
[[tests]]
kind = "ramp_up"
name = "ramp_up_g5_60kmh_electric"
mode = "electric"
gear = 5
speed_kmh = 60.0
pedal_steps_pct = [5.0, 20.0, 45.0, 80.0]
step_hold_s = 6.0
engine = "off"
k0 = "open"
lockup = "closed"
"""


def test_regions_count_points_against_the_full_load_curve() -> None:
    """Hand-placed points on the paper vehicle (440 Nm, 90 kW: base speed 60 * 90000 / (2 pi 440) = 1953.3 rpm).

    At 3000 rpm the full-load torque is 90000 / (3000 * 2 pi / 60) = 286.5 Nm, so 150 Nm is high torque and 140 Nm
    low; at 1000 rpm it is 440 Nm (split at 220). Mutant: the split on T_max alone (220 Nm at every speed) counts the
    150 Nm point at 3000 rpm as low torque and fails.
    """
    specs = load_vehicle().specs
    t = np.array([150.0, 140.0, 230.0, 100.0, -150.0])
    n = np.array([3000.0, 3000.0, 1000.0, 1000.0, 1000.0])
    counts = region_counts(specs, t, n, {"motoring": t > 5, "generating": t < -5})
    assert counts == {"motor.motoring.region.below_base_speed.low_torque": 1,
                      "motor.motoring.region.below_base_speed.high_torque": 1,
                      "motor.motoring.region.above_base_speed.low_torque": 1,
                      "motor.motoring.region.above_base_speed.high_torque": 1,
                      "motor.generating.region.below_base_speed.low_torque": 1,
                      "motor.generating.region.below_base_speed.high_torque": 0,
                      "motor.generating.region.above_base_speed.low_torque": 0,
                      "motor.generating.region.above_base_speed.high_torque": 0}
    assert motor_regions(specs.model_copy(update={"em_max_power_w": None})) == []


def test_the_suggested_ramp_up_puts_the_motor_in_its_band() -> None:
    """The motor speed of the suggested gear and dyno speed, ``v / 3.6 / r_w * i_fd * i_g * 60 / (2 pi)``, lies
    inside the region's band and within 5 % of the speed the suggestion states (the dyno speed is rounded to 5 km/h:
    at most 2.5 km/h of at least 30). Mutant: the speed worked out with the next gear's ratio (an off-by-one in the
    gear index) puts the motor 20-40 % off the stated speed and fails."""
    specs = load_vehicle().specs
    for r in motor_regions(specs):
        text = suggest_region_test(specs, r)
        gear = int(re.search(r"gear = (\d+)", text).group(1))
        v = float(re.search(r"speed_kmh = ([\d.]+)", text).group(1))
        n = v / 3.6 / specs.wheel_radius_m * specs.final_drive_ratio * specs.gear_ratios[gear - 1] * 60 / (2 * math.pi)
        assert r.lo_rpm < n <= r.hi_rpm, (r.name, gear, v, n)
        stated = float(re.search(r"motor at about (\d+) rpm", text).group(1))
        assert abs(n / stated - 1.0) < 0.05, (r.name, gear, v, n, stated)
        assert ("brake_steps_pct" in text) == (r.side == "generating")


def _plan_rows(path: Path) -> tuple[dict[str, object], dict[str, object]]:
    vehicle, setup, campaign = load_vehicle(), load_setup(scenario_path("setups", "paper.toml")), load_campaign(path)
    trace, _hit = cached_campaign(vehicle, campaign)
    rec, _ = planned_recording(setup, campaign, trace, ["motor"])
    rows, meta = plan_motor_regions(rec, vehicle.specs)
    return {r.name: r for r in rows}, meta


def test_a_campaign_without_generating_points_is_flagged_and_the_suggested_test_clears_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Motoring in gear 5 at 60 km/h only: the generating regions and the motoring regions above the base speed are
    flagged, each with an electric ramp-up; the campaign with the suggested generating tests added visits them.
    Mutant: the generating regions counted on the motoring side's points (``T > 5``) flag a different set and fail."""
    monkeypatch.setenv("BENCHTWIN_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "motoring_only.toml"
    path.write_text(_HEAD.format(name="motoring_only") + _MOTORING_ONLY, encoding="utf-8")
    rows, _meta = _plan_rows(path)
    gen = {n for n in rows if n.startswith("motor.generating.region.")}
    # the light 5 % pedal step holds the speed with a little regenerative torque (measured: the one low-torque
    # generating region it reaches); the other three are flagged
    assert gen == {"motor.generating.region.below_base_speed.high_torque",
                   "motor.generating.region.above_base_speed.low_torque",
                   "motor.generating.region.above_base_speed.high_torque"}, sorted(rows)
    assert "motor.motoring.region.above_base_speed.high_torque" in rows
    assert "motor.motoring.region.below_base_speed.high_torque" not in rows
    r = rows["motor.generating.region.above_base_speed.high_torque"]
    assert r.identifiable is False and "e_gen" in r.reason and "never visited" in r.reason
    assert 'kind = "ramp_up"' in r.suggestion and "brake_steps_pct" in r.suggestion
    # the suggested tests, as TOML, added to the campaign
    added = {rows[n].suggestion for n in gen}
    snippets = []
    for k, s in enumerate(sorted(added)):
        pairs = re.findall(r'(\w+) = (\[[^\]]*\]|"[^"]*"|[\d.]+)', s)
        snippets.append(f"\n[[tests]]\nname = \"added_{k}\"\n" + "".join(f"{a} = {b}\n" for a, b in pairs))
    fixed = tmp_path / "with_regen.toml"
    fixed.write_text(_HEAD.format(name="with_regen") + _MOTORING_ONLY + "".join(snippets), encoding="utf-8")
    rows2, meta2 = _plan_rows(fixed)
    assert not any(n.startswith("motor.generating.region.") for n in rows2), (sorted(rows2), meta2)


def test_the_paper_campaign_visits_every_region(paper_trace: Trace) -> None:
    """The paper campaign (Table 4) reaches all eight regions (measured: 9 to 60 points each)."""
    vehicle, setup, campaign = load_vehicle(), load_setup(scenario_path("setups", "paper.toml")), \
        load_campaign(scenario_path("campaigns", "paper.toml"))
    rec, _ = planned_recording(setup, campaign, paper_trace, ["motor"])
    rows, meta = plan_motor_regions(rec, vehicle.specs)
    assert rows == []
    assert len(meta["counts"]) == 8 and min(meta["counts"].values()) >= 5


def test_the_plan_table_keeps_its_columns_under_a_long_parameter_name() -> None:
    """A region row's name (over 40 characters) widens the name column: each row's value ends where the head's does."""
    from benchtwin.studies.plan import Plan
    from benchtwin.studies.plan_fits import PlannedParameter

    long = "motor.generating.region.above_base_speed.high_torque"
    plan = Plan(parameters=[PlannedParameter("motor.e", "-", 0.9, 0.01, True, "ok", "", 10),
                            PlannedParameter(long, "-", float("nan"), float("nan"), False, "never visited", "add", 0)])
    lines = plan.format_table().splitlines()
    head, rows = lines[1], lines[3:5]
    col = head.index("value") + len("value")  # the value column is right-aligned to the end of its title
    assert len(long) > 40
    for row, value in zip(rows, ("0.9", " -"), strict=True):
        assert row[:col].endswith(value) and row[col] == " ", row
