"""Which plan row covers a sweep's estimate (benchtwin.studies.plan_check); no simulation, instant."""

from __future__ import annotations

from benchtwin.studies.plan_check import plan_row_of, unplanned_keys

#: rows as the battery, engine and shifts plans name them
NAMES = ["battery.alpha", "battery.beta_discharge", "battery.beta_charge", "engine.*", "shifts.up_1_2.*",
         "shifts.*"]


def test_a_parameter_row_covers_its_own_estimate_only() -> None:
    assert plan_row_of("battery.alpha", NAMES) == "battery.alpha"
    assert plan_row_of("battery.alpha2", NAMES) is None


def test_a_family_row_covers_its_prefix_up_to_the_dot() -> None:
    assert plan_row_of("engine.start_fuel.m_g", NAMES) == "engine.*"
    # the prefix ends at the dot: a sibling name that merely starts alike is not covered
    assert plan_row_of("engine_cold.k", NAMES) is None
    assert plan_row_of("engineX.k", NAMES) is None


def test_the_longest_family_row_wins() -> None:
    assert plan_row_of("shifts.up_1_2.v0", NAMES) == "shifts.up_1_2.*"
    assert plan_row_of("shifts.down_2_1.v0", NAMES) == "shifts.*"


def test_a_new_fit_without_a_plan_is_named_not_planned() -> None:
    keys = ["battery.alpha", "battery.rc.R0", "battery.rc.tau1_s", "engine.start_fuel.m_g"]
    assert unplanned_keys(NAMES, keys) == ["battery.rc.R0", "battery.rc.tau1_s"]
    assert unplanned_keys(NAMES, []) == []
    # a generator of names is read once per key as well as a list is
    assert unplanned_keys(iter(NAMES), keys) == ["battery.rc.R0", "battery.rc.tau1_s"]


def test_another_familys_estimates_are_planned_there_by_name_only() -> None:
    own = ["torque_converter.converter.a0"]
    others = ["transmission.gear1.eta_m", "engine.*"]
    keys = ["torque_converter.converter.a0", "transmission.gear1.eta_m", "transmission.gear1.eta_m_C0",
            "engine.can_torque.gain"]
    # the transmission's gear row is planned in the transmission family; engine.* covers only the engine family's
    assert unplanned_keys(own, keys, others) == ["engine.can_torque.gain", "transmission.gear1.eta_m_C0"]
    assert unplanned_keys(own, keys) == ["engine.can_torque.gain", "transmission.gear1.eta_m",
                                         "transmission.gear1.eta_m_C0"]
