"""Fixtures of the live-chain tests."""

from __future__ import annotations

import pytest
from live_synth import make_small_outputs

from benchtwin.wire.frames import DeviceOutputs


@pytest.fixture(scope="session")
def small_outputs() -> DeviceOutputs:
    """2 s of plant time: two CAN buses, a Modbus device at 100 Hz, a CANopen node at 10 Hz."""
    return make_small_outputs()
