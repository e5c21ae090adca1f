"""WLTC 3b in road-load mode: the driver follows, the energy ledger closes, the work matches the road load."""

from __future__ import annotations

import numpy as np

from benchtwin.emulator import energy_balance
from benchtwin.emulator.protocols import load_cycle
from benchtwin.trace import TRACE_CHANNELS

WLTC_DISTANCE_M = 23266.0


def test_trace_carries_every_contract_channel_at_plant_rate(wltc_trace) -> None:
    assert list(wltc_trace.channels) == list(TRACE_CHANNELS)
    np.testing.assert_allclose(wltc_trace.dt_s, 0.01, rtol=1e-9)
    for name, values in wltc_trace.channels.items():
        if name != "dyno_set_speed_mps":  # NaN in road-load mode by contract
            assert np.all(np.isfinite(values)), name
    assert np.all(np.isnan(wltc_trace["dyno_set_speed_mps"]))
    (seg,) = wltc_trace.segments
    assert seg.kind == "cycle" and seg.settings["mode"] == "hybrid"


def test_driver_follows_wltc_within_1kmh_rms_and_distance_within_half_percent(wltc_trace) -> None:
    tc, vc = load_cycle("wltc_class3b.csv")
    t = wltc_trace.time_s
    err_kmh = 3.6 * (wltc_trace["vehicle_speed_mps"] - np.interp(t, tc, vc))
    rms = float(np.sqrt(np.mean(err_kmh**2)))
    assert rms < 1.0, rms
    dist = wltc_trace["distance_m"][-1]
    assert abs(dist - WLTC_DISTANCE_M) / WLTC_DISTANCE_M < 0.005, dist


def test_energy_ledger_closes_within_half_percent(wltc_trace) -> None:
    led = wltc_trace.meta["energy_ledger_j"]
    bal = energy_balance(led)
    assert abs(bal["residual_frac"]) < 0.005, bal
    # every loss is a loss (nothing creates energy), and the big terms are physically sized
    for key in ("engine_loss", "motor_loss", "hv_battery_resistive", "torque_converter_slip", "transmission_loss",
                "brakes", "dcdc_loss", "lv_loads"):
        assert led[key] >= 0.0, key
    assert led["fuel_chemical"] > 0 and led["road_load_work"] > 0


def test_ledger_terms_agree_with_the_trace_channels(wltc_trace, vehicle) -> None:
    """The ledger is integrated in the loop; the Trace is sampled output. They must tell the same story."""
    led = wltc_trace.meta["energy_ledger_j"]
    dt = wltc_trace.dt_s
    v = wltc_trace["vehicle_speed_mps"]
    rl = vehicle.road_load
    vk = 3.6 * v
    f_rl = (rl.f0_n + rl.f1_n_per_kmh * vk + rl.f2_n_per_kmh2 * vk**2) * np.minimum(vk / 0.5, 1.0)
    np.testing.assert_allclose(np.sum(f_rl * v) * dt, led["road_load_work"], rtol=0.01)
    fuel_j = np.sum(wltc_trace["fuel_mass_flow_kgps"]) * dt * vehicle.specs.fuel_lhv_j_per_kg
    np.testing.assert_allclose(fuel_j, led["fuel_chemical"], rtol=0.01)
    e_chem = np.sum(wltc_trace["battery_ocv_v"] * wltc_trace["battery_current_a"]) * dt
    np.testing.assert_allclose(e_chem, led["hv_battery_chemical"], rtol=0.01)
    # the coulomb count in the trace matches the current
    soc = wltc_trace["battery_soc_frac"]
    q_as = np.sum(wltc_trace["battery_current_a"][:-1]) * dt
    np.testing.assert_allclose(soc[0] - soc[-1], q_as / (vehicle.battery.capacity_ah * 3600), rtol=1e-3)
