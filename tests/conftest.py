"""Session fixtures shared across test directories: expensive results that several modules use unchanged.

The paper campaign's Trace of the shipped vehicle is simulated once per session here (the emulator's tests
and tests/test_validation.py both read it; nothing writes to it), instead of once in each; so is the quick
campaign's ideal Recording of the shipped vehicle (tests/identification and tests/properties).
"""

from __future__ import annotations

import pytest

from benchtwin.config import load_campaign, load_setup, load_vehicle, scenario_path
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.emulator import simulate_campaign
from benchtwin.recording import Channel, LazyChannel, Recording
from benchtwin.trace import Trace


@pytest.fixture(scope="session")
def paper_trace() -> Trace:
    """The paper campaign (paper.toml, its own seed) on the shipped vehicle (p2_phev_9at.toml): read only."""
    return simulate_campaign(load_vehicle(), load_campaign("paper.toml"))


@pytest.fixture(scope="session")
def quick_ideal_9at() -> tuple[VehicleConfig, Recording]:
    """The quick campaign on the shipped vehicle through the ideal batch chain, seed 1: (vehicle, Recording), read
    only. The identification tests (``quick_ideal``) and the interval-coverage property both start from it."""
    from benchtwin.chain.batch import run_batch

    vehicle = load_vehicle(scenario_path("vehicles", "p2_phev_9at.toml"))
    trace = simulate_campaign(vehicle, load_campaign(scenario_path("campaigns", "quick.toml")))
    return vehicle, run_batch(trace, load_setup(scenario_path("setups", "ideal.toml")), seed=1)


def _blocks_only(ch: Channel) -> LazyChannel:
    """``ch`` as a lazy channel read by blocks only: a whole read fails the test."""
    def whole():
        raise AssertionError(f"{ch.name} read whole")

    def part(a: int, b: int):
        return ch.timestamps[a:b].copy(), ch.values[a:b].copy(), ch.flags[a:b].copy()

    return LazyChannel(ch.name, ch.unit, ch.source, len(ch), whole, ch.value_texts, block_loader=part)


@pytest.fixture
def blocks_only():
    """A function giving a channel as a lazy channel that only its blocks can read (a whole read fails the test),
    for checking that a reader never loads a channel whole."""
    return _blocks_only
