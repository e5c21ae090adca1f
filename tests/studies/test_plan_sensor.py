"""The sensor's noise-free response the plan draws its readings around (``plan_noise.sensor_response``).

A drawn reading is the quantised noisy value at what the sensor reads without noise; where that value sits
against the quantisation thresholds decides which grid samples a selection keeps (the turbine-torque
calibration lost its sample at the first pedal step of the paper campaign with a pure delay of the truth:
474 against the bench's 475 in gear 2, and its median jumped). Checked here against the chain itself, run
without the shaft torque's noise: every quantised reading must be reproduced, while the best pure delay of
the truth misses readings at the pedal steps. Time: about 3 s.
"""

from __future__ import annotations

import numpy as np

from benchtwin.chain.batch import run_batch
from benchtwin.config import load_campaign, load_setup, load_vehicle, scenario_path
from benchtwin.emulator.cache import cached_campaign
from benchtwin.recording import Channel
from benchtwin.studies.plan_noise import noise_budget, sensor_response, truth_recording
from benchtwin.studies.plan_windows import reading_lag


def test_sensor_response_reproduces_the_noise_free_chain_where_a_delay_does_not() -> None:
    vehicle, setup, campaign = load_vehicle(), load_setup(scenario_path("setups", "paper.toml")), \
        load_campaign("quick.toml")
    trace, _ = cached_campaign(vehicle, campaign)
    truth, noise = noise_budget(setup)
    cn = noise["shaft_torque_nm"]
    assert cn.q > 2.0 and cn.gain != 0  # 12-bit telemetry (2.1 Nm), a declared gain error
    tel = setup.telemetry
    assert tel.errors.bandwidth_hz > 0 and tel.link.clock_drift_ppm != 0 and tel.link.latency_s > 0
    quiet = setup.model_copy(update={"telemetry": tel.model_copy(
        update={"errors": tel.errors.model_copy(update={"noise_std": 0.0})})})
    # a ramp-up: pedal steps, where a filter is not a delay
    seg = next(s for s in trace.segments if s.kind == "ramp_up")
    part = trace.slice_time(seg.start_s, seg.end_s)
    rec = run_batch(part, quiet, seed=7)
    ch = rec["shaft_torque_nm"]
    use = ch.good & (ch.timestamps > seg.start_s + 1.0)  # the filter starts from steady state at the slice
    code = np.rint(ch.values[use] / cn.q)
    sensed = sensor_response(rec, part, setup, ["shaft_torque_nm"])["shaft_torque_nm"]
    assert np.array_equal(sensed.timestamps, ch.timestamps)
    assert np.array_equal(np.rint((1.0 + cn.gain) * sensed.values[use] / cn.q), code)
    # the best pure delay of the truth (what the plan took before) misses readings where the torque steps
    t = ch.timestamps
    tr = truth_recording(rec, part, truth)["shaft_torque_nm"]
    lag = reading_lag(tr, ch, cn, np.arange(0.0, 0.06, 0.0005))
    delayed = (1.0 + cn.gain) * np.interp(t - lag, t, tr.values)
    missed = int(np.sum(np.rint(delayed[use] / cn.q) != code))
    assert lag > 0.005 and missed >= 10, (lag, missed)
    # roles without a truth in the Trace or not asked for are left out
    assert set(sensor_response(rec, part, setup, ["shaft_torque_nm", "no_such_role"])) == {"shaft_torque_nm"}
    assert isinstance(sensed, Channel)
