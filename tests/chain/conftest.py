"""Fixtures shared by the chain's tests."""

from __future__ import annotations

import pytest

from benchtwin.chain.acquisition import AcquisitionInput
from benchtwin.chain.batch import as_logged, deliver
from benchtwin.config import load_setup, scenario_path
from benchtwin.sensors import encode


@pytest.fixture(scope="session")
def quick_inputs() -> dict[str, AcquisitionInput]:
    """The quick campaign as the paper and faults setups' acquisitions receive it (seed 5, the raw logs' view)."""
    emulator = pytest.importorskip("benchtwin.emulator")
    from benchtwin.config.campaign import load_campaign
    from benchtwin.config.vehicle import load_vehicle

    trace = emulator.simulate_campaign(load_vehicle(scenario_path("vehicles", "p2_phev_9at.toml")),
                                       load_campaign(scenario_path("campaigns", "quick.toml")))
    out = {}
    for name in ("paper", "faults"):
        setup = load_setup(name)
        received = deliver(encode(trace, setup, 5), setup, seed=5,
                           span_s=(float(trace.time_s[0]), float(trace.time_s[-1])))
        received.segments = list(trace.segments)
        received.meta = {"seed": 5}
        out[name] = as_logged(received, setup)  # the faults setup's dyno log is cut short: a `truncated` event
    return out
