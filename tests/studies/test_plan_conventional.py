"""The planner on a conventional car: no motor or battery family is planned (named in the meta), no coast line
is asked for (validation expects none: the engine's overrun drag is one torque per speed), and a gear without a
ramp-up is still flagged with the ramp-up to add. About 8 s (two tests, 200 s simulated)."""

from __future__ import annotations

from benchtwin.config._base import scenario_path
from benchtwin.config.campaign import load_campaign
from benchtwin.config.setup import load_setup
from benchtwin.config.vehicle import load_vehicle
from benchtwin.emulator import conventional_tests
from benchtwin.studies.plan import plan_campaign


def test_a_conventional_plan_asks_for_nothing_a_conventional_car_cannot_do():
    vehicle = load_vehicle(scenario_path("vehicles", "conventional_9at.toml"))
    quick = load_campaign(scenario_path("campaigns", "conventional_quick.toml"))
    assert conventional_tests(quick) == (quick, {})  # nothing to drop: the same campaign, its name kept
    campaign = quick.model_copy(update={"tests": [t for t in quick.tests if t.name in ("ramp_up_g5_85kmh",
                                                                                       "neutral_braking_40kmh")]})
    plan = plan_campaign(vehicle, load_setup(scenario_path("setups", "ideal.toml")), campaign, cache=False)
    names = {p.name for p in plan.parameters}
    assert set(plan.meta["not_planned"]) == {"motor", "battery"}
    assert not any(n.startswith(("motor", "battery")) or "_coast." in n for n in names)
    g5 = [p for p in plan.parameters if p.name.startswith("transmission.gear5.")]
    g4 = [p for p in plan.parameters if p.name.startswith("transmission.gear4.")]
    assert g5 and all(p.identifiable for p in g5)
    assert g4 and not any(p.identifiable for p in g4) and 'kind = "ramp_up" with gear = 4' in g4[0].suggestion
