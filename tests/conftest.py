"""Session fixtures shared across test directories: expensive results that several modules use unchanged.

The paper campaign's Trace of the shipped vehicle is simulated once per session here (the emulator's tests
and tests/test_validation.py both read it; nothing writes to it), instead of once in each.
"""

from __future__ import annotations

import pytest

from benchtwin.config import load_campaign, load_vehicle
from benchtwin.emulator import simulate_campaign
from benchtwin.trace import Trace


@pytest.fixture(scope="session")
def paper_trace() -> Trace:
    """The paper campaign (paper.toml, its own seed) on the shipped vehicle (p2_phev_9at.toml): read only."""
    return simulate_campaign(load_vehicle(), load_campaign("paper.toml"))
