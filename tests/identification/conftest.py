"""Fixtures of the identification tests: synthetic Recordings (see _synth_a.py) and the emulated quick campaign."""

from __future__ import annotations

import numpy as np
import pytest
from _synth_a import (
    MERCEDES,
    SPECS,
    Truth,
    blending_plant,
    coastdown_plant,
    neutral_braking_plant,
    ramp_up_plant,
    to_recording,
)

from benchtwin.config.specs import VehicleSpecs
from benchtwin.recording import Recording
from benchtwin.segments import Segment


@pytest.fixture(scope="session")
def specs() -> VehicleSpecs:
    return SPECS


@pytest.fixture(scope="session")
def truth() -> Truth:
    return Truth()


@pytest.fixture(scope="session")
def ramp_plant(truth: Truth) -> tuple[np.ndarray, dict[str, np.ndarray], list[Segment]]:
    return ramp_up_plant(truth)


@pytest.fixture(scope="session")
def ramp_rec(ramp_plant) -> Recording:
    t, sig, segs = ramp_plant
    return to_recording(t, sig, segments=segs)


@pytest.fixture(scope="session")
def ramp_rec_noisy(ramp_plant) -> Recording:
    t, sig, segs = ramp_plant
    return to_recording(t, sig, noise=1.0, seed=7, segments=segs)


@pytest.fixture(scope="session")
def coast_plant(truth: Truth):
    return coastdown_plant(truth)


@pytest.fixture(scope="session")
def brake_plant(truth: Truth):
    return neutral_braking_plant(truth)


@pytest.fixture(scope="session")
def blend_plant(truth: Truth):
    return blending_plant(truth)


@pytest.fixture(scope="session")
def mercedes_points() -> dict[str, np.ndarray]:
    """The 24 measured steady points of the Mercedes 1.7 l engine (ADVISOR 2003 data)."""
    data = np.loadtxt(MERCEDES, skiprows=1)
    return {"speed_rpm": data[:, 0], "torque_nm": data[:, 1], "fuel_gps": data[:, 2]}


@pytest.fixture(scope="session", params=["p2_phev_9at.toml", "p2_phev_alt.toml"])
def quick_ideal(request):
    """The quick campaign of the emulator through the ideal batch chain: (vehicle config, Recording), on the
    paper vehicle and on a second vehicle file with other values (so nothing is tuned to one vehicle).

    This is the real path (plant -> sensors -> wire formats -> acquisition) with every imperfection off;
    what remains is each wire's resolution (e.g. 2.1 Nm on the shaft torque at K_TEL 500, 0.01 km/h speeds).
    """
    if request.param == "p2_phev_9at.toml":  # the same run as tests/conftest.py's, made once per session there
        return request.getfixturevalue("quick_ideal_9at")
    from benchtwin.chain.batch import run_batch
    from benchtwin.config._base import scenario_path
    from benchtwin.config.campaign import load_campaign
    from benchtwin.config.setup import load_setup
    from benchtwin.config.vehicle import load_vehicle
    from benchtwin.emulator import simulate_campaign

    vehicle = load_vehicle(scenario_path("vehicles", request.param))
    trace = simulate_campaign(vehicle, load_campaign(scenario_path("campaigns", "quick.toml")))
    rec = run_batch(trace, load_setup(scenario_path("setups", "ideal.toml")), seed=1)
    return vehicle, rec
