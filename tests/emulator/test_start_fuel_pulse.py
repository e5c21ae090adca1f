"""The engine-start fuel burnt as a pulse over the cranking time: each start costs exactly start_fuel_g."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchtwin.config import VehicleConfig, load_campaign, load_vehicle
from benchtwin.emulator import simulate_campaign
from benchtwin.emulator.params import NP, P_DT_S, P_ENGINE_START_FUEL_KG, P_ENGINE_START_FUEL_S
from benchtwin.emulator.steps_control import engine_on_off

DT = 0.01
M_KG = 0.6e-3


def _p(duration_s: float) -> np.ndarray:
    p = np.zeros(NP)
    p[P_DT_S], p[P_ENGINE_START_FUEL_KG], p[P_ENGINE_START_FUEL_S] = DT, M_KG, duration_s
    return p


def _burns(p: np.ndarray, engine_cmd: np.ndarray) -> np.ndarray:
    """The start fuel burnt per step under a forced on/off command sequence (1 on, 0 off)."""
    on, on_t, left = False, 0.0, 0.0
    out = np.zeros(engine_cmd.size)
    for i, c in enumerate(engine_cmd):
        on, on_t, out[i], left = engine_on_off(p, int(c), 0, on, on_t, 0.0, 50.0, 0.0, 0.0, 50.0, left)
    return out


def test_pulse_is_flat_over_the_duration_and_sums_to_the_start_fuel() -> None:
    cmd = np.zeros(400, int)
    cmd[10:300] = 1  # one start at step 10
    burn = _burns(_p(0.5), cmd)
    # 0.5 s at 10 ms: 50 steps of m / 50, nothing before or after
    np.testing.assert_allclose(burn[10:60], M_KG / 50.0, rtol=1e-12)
    assert np.all(burn[:10] == 0.0) and np.all(burn[60:] == 0.0)
    assert burn.sum() == pytest.approx(M_KG, rel=1e-12)
    # a duration that is not a whole number of steps: ceil(0.333 / 0.01) = 34 steps, the last one the remainder
    burn = _burns(_p(0.333), cmd)
    assert np.count_nonzero(burn) == math.ceil(0.333 / DT)
    assert burn.sum() == pytest.approx(M_KG, rel=1e-12)
    # no duration (the former plant): the start's step only
    burn = _burns(_p(0.0), cmd)
    assert burn[10] == M_KG and np.count_nonzero(burn) == 1


def test_every_start_costs_the_start_fuel_even_when_stopped_within_the_pulse() -> None:
    # starts at steps 10, 100 (stopped after 0.2 s, within its 0.5 s pulse) and 130 (30 steps after the
    # second start: its pulse overlaps the second's rest). Every start must cost m: 3 m in all.
    cmd = np.zeros(600, int)
    cmd[10:80], cmd[100:120], cmd[130:200] = 1, 1, 1
    burn = _burns(_p(0.5), cmd)
    assert burn.sum() == pytest.approx(3 * M_KG, rel=1e-12)
    # the rate never exceeds one start's m / duration (the overlapping rest burns on at the same rate)
    assert burn.max() == pytest.approx(M_KG / 50.0, rel=1e-12)
    # the rest of the stopped start is burnt after the stop: fuel flows at steps 120..129 with the engine off
    assert np.all(burn[120:130] > 0.0)


def _wltc(vehicle: VehicleConfig, **engine: float):
    v = vehicle.model_copy(update={"engine": vehicle.engine.model_copy(update=engine)})
    return simulate_campaign(v, load_campaign("wltc.toml"))


def test_plant_fuel_integral_is_the_firing_fuel_plus_n_starts_times_the_start_fuel() -> None:
    vehicle = load_vehicle()  # paper form: the fuel does not feed back into the plant's states
    lhv = vehicle.specs.fuel_lhv_j_per_kg
    m_g, dur = vehicle.engine.start_fuel_g, vehicle.engine.start_fuel_duration_s
    assert m_g > 0 and dur == pytest.approx(0.5)
    spread = _wltc(vehicle)
    one_step = _wltc(vehicle, start_fuel_duration_s=0.0)
    none = _wltc(vehicle, start_fuel_g=0.0)
    on = spread["engine_on"] > 0.5
    rises = np.flatnonzero(on[1:] & ~on[:-1]) + 1
    assert rises.size >= 3
    fuel = {k: tr.meta["energy_ledger_j"]["fuel_chemical"] / lhv * 1e3 for k, tr in
            [("spread", spread), ("one_step", one_step), ("none", none)]}
    # spreading moves no fuel: the totals agree to rounding, and exceed the start-free run by n x start_fuel_g
    assert fuel["spread"] == pytest.approx(fuel["one_step"], rel=1e-9)
    assert fuel["spread"] - fuel["none"] == pytest.approx(rises.size * m_g, rel=1e-9)
    # the trace shows the pulse: m / duration above the start-free flow over duration / dt steps after the start
    extra = (spread["fuel_mass_flow_kgps"] - none["fuel_mass_flow_kgps"]) * 1e3
    k = rises[0]
    n = round(dur / spread.dt_s)
    np.testing.assert_allclose(extra[k:k + n], m_g / dur, rtol=1e-6)
    assert abs(extra[k + n]) < 1e-9 and abs(extra[k - 1]) < 1e-9
