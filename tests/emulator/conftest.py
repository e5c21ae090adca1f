"""Shared, expensive emulator runs (one per session): the quick campaign and WLTC (the paper campaign's is in
tests/conftest.py, shared with tests/test_validation.py)."""

from __future__ import annotations

import pytest

from benchtwin.config.campaign import CampaignConfig, load_campaign
from benchtwin.config.vehicle import VehicleConfig, load_vehicle
from benchtwin.emulator import simulate_campaign
from benchtwin.trace import Trace


@pytest.fixture(scope="session")
def vehicle() -> VehicleConfig:
    return load_vehicle()


@pytest.fixture(scope="session")
def quick_campaign() -> CampaignConfig:
    return load_campaign("quick.toml")


@pytest.fixture(scope="session")
def quick_trace(vehicle: VehicleConfig, quick_campaign: CampaignConfig) -> Trace:
    return simulate_campaign(vehicle, quick_campaign)


@pytest.fixture(scope="session")
def wltc_trace(vehicle: VehicleConfig) -> Trace:
    return simulate_campaign(vehicle, load_campaign("wltc.toml"))
