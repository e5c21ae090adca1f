"""The BMS keeps the pack inside its usable window (docs/models.md, "BMS power limits").

The derating line is checked at points worked out by hand from its definition; the torque limit it imposes
through the Willans line against ``(P e - W_loss) / omega``; and a forced-electric ramp-up (engine "off", K0
"open") from 4 % displayed SOC at 115 km/h, which before the BMS drew the pack to -11 % displayed SOC, must keep
the SOC above soc_min, with the engine started against the test's command. One plant run of 132 s simulated,
~1 s CPU after the plant's compile (shared with the other emulator tests).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_plant_substeps import _params, _tables

from benchtwin.config import scenario_path
from benchtwin.config.campaign import CampaignConfig, RampUpTest
from benchtwin.config.vehicle import load_vehicle
from benchtwin.emulator import simulate_campaign
from benchtwin.emulator.models import bms_power_limits_w
from benchtwin.emulator.params import (
    P_BATT_MAX_CHARGE_W,
    P_BATT_MAX_DISCHARGE_W,
    P_BMS_CHARGE_BAND_PCT,
    P_BMS_DISCHARGE_BAND_PCT,
    P_BMS_ENGINE_START_PCT,
    P_COAST_REGEN_TORQUE_NM,
    P_WILLANS_E,
    P_WILLANS_E_GEN,
    P_WILLANS_LOSS_GEN_W,
    P_WILLANS_LOSS_W,
)
from benchtwin.emulator.steps_control import bms_commands, torque_demand

PDIS, PCHG = 100_000.0, 50_000.0


@pytest.mark.parametrize(("soc", "dis", "chg"), [
    (-3.0, 0.0, PCHG),  # below the floor: no discharge at all
    (0.0, 0.0, PCHG),
    (1.0, 0.2 * PDIS, PCHG),  # one point into a 5-point band: a fifth
    (2.5, 0.5 * PDIS, PCHG),
    (5.0, PDIS, PCHG),
    (50.0, PDIS, PCHG),
    (96.0, PDIS, PCHG),  # the charge band (4 points) starts at 96 %
    (97.0, PDIS, 0.75 * PCHG),
    (98.0, PDIS, 0.5 * PCHG),
    (99.0, PDIS, 0.25 * PCHG),
    (100.0, PDIS, 0.0),
    (101.0, PDIS, 0.0),
])
def test_derating_line(soc: float, dis: float, chg: float) -> None:
    for f in (bms_power_limits_w, bms_power_limits_w.py_func):
        got = f(PDIS, PCHG, soc, 5.0, 4.0)
        assert got == pytest.approx((dis, chg), rel=1e-12, abs=1e-9)


def test_derating_band_zero_is_a_step_at_the_window_ends() -> None:
    assert bms_power_limits_w(PDIS, PCHG, 0.01, 0.0, 0.0) == (PDIS, PCHG)
    assert bms_power_limits_w(PDIS, PCHG, 0.0, 0.0, 0.0) == (0.0, PCHG)
    assert bms_power_limits_w(PDIS, PCHG, 100.0, 0.0, 0.0) == (PDIS, 0.0)


def test_motor_torque_limit_follows_the_derated_power() -> None:
    p = _params()
    p[P_BATT_MAX_DISCHARGE_W], p[P_BATT_MAX_CHARGE_W] = PDIS, PCHG
    p[P_BMS_DISCHARGE_BAND_PCT], p[P_BMS_CHARGE_BAND_PCT] = 5.0, 4.0
    tab = _tables(p)
    w = 600.0  # full-load curve 300 -> 120 Nm: 165 Nm here, above every battery limit below
    for soc, p_dis, p_chg in ((2.0, 0.4 * PDIS, PCHG), (98.0, PDIS, 0.5 * PCHG), (0.0, 0.0, PCHG)):
        tm_max, tm_gen, _te, _td, _pd, wq = torque_demand(tab, w, w, 30.0, 50.0, 1, 0, 3, True, soc)
        assert wq == w
        assert tm_max == pytest.approx(max((p_dis * p[P_WILLANS_E] - p[P_WILLANS_LOSS_W]) / w, 0.0), abs=1e-9)
        assert tm_gen == pytest.approx((p_chg + p[P_WILLANS_LOSS_GEN_W]) / (p[P_WILLANS_E_GEN] * w), abs=1e-9)
    # coast regeneration (20 Nm) in the window, and at 100 % within the charge limit (the Willans loss alone)
    p[P_COAST_REGEN_TORQUE_NM] = 20.0
    assert torque_demand(tab, w, w, 30.0, 0.0, 1, 0, 3, True, 50.0)[3] == -20.0
    _m, tm_gen, _te, t_dem, _pd, _wq = torque_demand(tab, w, w, 30.0, 0.0, 1, 0, 3, True, 100.0)
    assert t_dem == pytest.approx(-tm_gen) and tm_gen * w < 800.0


def test_bms_engine_request_hysteresis() -> None:
    p = _params()
    p[P_BMS_DISCHARGE_BAND_PCT], p[P_BMS_ENGINE_START_PCT] = 5.0, 1.0
    assert bms_commands(p, 0.9, False, 0, 0) == (1, 1)  # below the start: engine on, K0 closed
    assert bms_commands(p, 1.1, False, 0, 0) == (0, 0)  # above it, engine off: the test's commands
    assert bms_commands(p, 4.9, True, 0, 0) == (1, 1)  # running: held up to the band's top
    assert bms_commands(p, 5.1, True, 0, 0) == (0, 0)
    p[P_BMS_ENGINE_START_PCT] = -1.0  # no HV pack: never
    assert bms_commands(p, -50.0, True, 0, 0) == (0, 0)


def test_forced_electric_drive_stays_above_soc_min() -> None:
    veh = load_vehicle(scenario_path("vehicles", "p2_phev_9at.toml"))
    camp = CampaignConfig(name="soc_floor", seed=1, initial_displayed_soc_pct=4.0, tests=[RampUpTest(
        kind="ramp_up", mode="electric", gear=5, speed_kmh=115.0, pedal_steps_pct=[30.0, 60.0, 80.0, 80.0, 80.0],
        step_hold_s=15.0, engine="off", k0="open")])
    tr = simulate_campaign(veh, camp)
    soc, dsoc = tr["battery_soc_frac"], tr["displayed_soc_pct"]
    # the drive would cross the floor: at 80 % pedal the motor alone draws about 100 kW, some 1 % of the
    # window every 4 s, from 4 %
    assert np.min(soc) >= veh.battery.soc_min_frac, f"SOC {np.min(dsoc):.2f} % displayed"
    # the BMS started the engine although the test commands it off during the pedal steps, and closed K0
    assert np.any((tr["engine_on"] > 0.5) & (tr["k0_closed"] > 0.5) & (tr["pedal_pct"] >= 30.0))
    # while the engine is off the motor's DC power stays within the derated discharge limit
    ba = veh.battery
    off = tr["engine_on"] < 0.5
    limit = np.array([bms_power_limits_w(ba.max_discharge_power_w, ba.max_charge_power_w, s,
                                         ba.discharge_derate_band_pct, ba.charge_derate_band_pct)[0]
                      for s in dsoc[off]])
    assert np.all(tr["em_elec_power_w"][off] <= limit * (1.0 + 1e-9) + 1e-6)
