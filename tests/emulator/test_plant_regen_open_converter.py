"""Regenerative braking through an open converter: the free pump side follows the turbine, a firing engine
is not dragged down (docs/models.md, "Regeneration with the lock-up open").

A deceleration from 80 km/h at a low SOC (charge-sustaining: K0 closed, the engine firing) downshifts while the
driver brakes, which opens the lock-up. The controller may regenerate only what the open converter carries and
holds the pump at the turbine speed with the idle gain k_idle, so the pump lags the turbine by at most the
proportional controller's tracking error ``J a_t / k_idle`` (J the pump side's inertia with K0 closed, ``a_t``
the turbine's deceleration: the driver's deceleration times the highest gain of a gear in which the lock-up
opens). Before the rule the motor's full generating torque pulled pump and engine to standstill within 0.3 s.
Two plant runs of 49 s simulated, ~1 s CPU each after the compile.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.config import scenario_path
from benchtwin.config.campaign import CampaignConfig, DecelerationTest
from benchtwin.config.vehicle import load_vehicle
from benchtwin.emulator import simulate_campaign

DECEL_MPS2 = 1.5


@pytest.mark.parametrize("vehicle_name", ["p2_phev_9at", "p2_phev_9at_hifi"])
def test_open_converter_braking_keeps_pump_at_turbine(vehicle_name: str) -> None:
    veh = load_vehicle(scenario_path("vehicles", f"{vehicle_name}.toml"))
    camp = CampaignConfig(name="decel_low_soc", seed=1, initial_displayed_soc_pct=14.0,
                          tests=[DecelerationTest(kind="deceleration", start_speed_kmh=80.0, decel_mps2=DECEL_MPS2,
                                                  approach_s=30.0)])
    tr = simulate_campaign(veh, camp)
    wp = tr["em_speed_radps"]
    wt = tr["tc_turbine_speed_radps"]
    v = tr["vehicle_speed_mps"]
    gear = tr["gear_actual"]
    firing = (tr["engine_on"] > 0.5) & (tr["k0_closed"] > 0.5)
    cutoff = veh.brakes.regen_cutoff_speed_kmh / 3.6
    open_braking = (tr["lockup_closed"] < 0.5) & (gear > 0) & (tr["brake_pedal_pct"] > 0) & (v > cutoff)
    # the situation is exercised: the lock-up opens while braking with the engine firing on K0
    assert np.count_nonzero(open_braking & firing) >= 20
    # tracking bound of the proportional hold: J a_t / k_idle, J with the engine on K0, a_t the driver's
    # deceleration through the largest gain k = i_g i_fd / r_w of a gear the lock-up closes in, doubled for the
    # driver's speed controller overshooting the ramp
    specs = veh.specs
    k_max = max(specs.gear_ratios[veh.torque_converter.lockup_min_gear - 1:]) * specs.final_drive_ratio \
        / specs.wheel_radius_m
    j = veh.motor.inertia_kgm2 + veh.engine.inertia_kgm2
    lag = j * 2.0 * DECEL_MPS2 * k_max / veh.motor.idle_gain_nm_per_radps
    worst = float(np.min((wp - wt)[open_braking]))
    assert worst >= -lag, f"pump {-worst:.1f} rad/s below the turbine (bound {lag:.1f})"
    idle = veh.engine.idle_speed_rpm * np.pi / 30.0
    floor = np.minimum(wt, idle) - lag
    assert np.all(wp[open_braking & firing] >= floor[open_braking & firing])
