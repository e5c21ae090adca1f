"""The gearbox's actuation delay: identified from target and actual gear, and applied to the shift lines' gear."""

from __future__ import annotations

import numpy as np
import pytest
from test_predict import SPECS, _fit, cruise, synthetic_result

from benchtwin.identification.shift_delay import SHIFT_DELAY_KEY, identify_shift_delay, shift_delay_pairs
from benchtwin.identification.shifts import shift_fits
from benchtwin.recording import Channel, Recording
from benchtwin.validation.predict import MapVehicle
from benchtwin.validation.shift_lines import actuated_gears, shift_line_gears

DELAY = 0.34


def _gearbox(t_target: list[float], targets: list[int], t_actual: list[float], actual: list[int],
            rate_hz: float = 50.0, actual_rate_hz: float | None = None) -> Recording:
    """Target and actual gear sampled at ``rate_hz`` (the actual gear at ``actual_rate_hz``, default the same) from
    their change times (the first entry: the start)."""
    end = max(t_target + t_actual) + 5.0

    def held(times: list[float], values: list[int], rate: float) -> tuple[np.ndarray, np.ndarray]:
        t = np.arange(0.0, end, 1.0 / rate)
        x = np.full(t.size, float(values[0]))
        for tc, g in zip(times[1:], values[1:], strict=True):
            x[t >= tc] = g
        return t, x

    rec = Recording()
    rec.add(Channel("gear_target", "", *held(t_target, targets, rate_hz), source="vehicle_can"))
    rec.add(Channel("gear_actual", "", *held(t_actual, actual, actual_rate_hz or rate_hz), source="vehicle_can"))
    return rec


def test_actuated_gears_by_hand() -> None:
    # target 1 -> 2 first seen at sample 10 (t 1.0 s; the change taken at 0.95 s): engaged at the first sample at or
    # past 0.95 + 0.34 = 1.29 s, sample 13; target 2 -> 4 first seen at sample 30: 3 at 2.95 + 0.34 = 3.29 s (sample
    # 33), 4 one delay later at 3.63 s (sample 37)
    tgt = np.array([1] * 10 + [2] * 20 + [4] * 20)
    want = np.array([1] * 13 + [2] * 20 + [3] * 4 + [4] * 13)
    np.testing.assert_array_equal(actuated_gears(tgt, 0.1, DELAY), want)
    np.testing.assert_array_equal(actuated_gears(tgt, 0.1, 0.0), tgt)


def test_actuated_gears_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="dt_s"):
        actuated_gears(np.ones(5), 0.0, DELAY)
    with pytest.raises(ValueError, match="delay_s"):
        actuated_gears(np.ones(5), 0.1, float("nan"))
    with pytest.raises(ValueError, match="dt_s"):
        shift_line_gears({}, 9, np.ones(5), np.zeros(5), np.ones(5), delay_s=DELAY)


def test_delay_identified_from_target_and_actual_gear() -> None:
    # single shifts at times off the 50 Hz grid, and one two-gear target jump (5 -> 7) whose second step lags its
    # target change by 2 delays less the 0.1 s between the target's two changes: left out
    times = [0.0, 2.013, 5.507, 9.031, 12.0, 12.1, 16.77, 20.29]
    gears = [1, 2, 3, 4, 5, 6, 5, 4]
    # a gearbox that shifts one gear at a time, each DELAY after the target's change or after its own last step
    t_act = [0.0] + [x + DELAY for x in times[1:4]] + [12.0 + DELAY, 12.0 + 2 * DELAY] + [x + DELAY for x in times[6:]]
    rec = _gearbox(times, gears, t_act, gears)
    d = shift_delay_pairs(rec)
    assert d.size == 5  # 1-2, 2-3, 3-4, 6-5, 5-4; 4-5 (target moved on) and 5-6 (gearbox still in 4) left out
    # both change times are midpoints of a 20 ms step: each within 10 ms of the true time
    np.testing.assert_allclose(d, DELAY, atol=0.02 + 1e-9)
    fit = identify_shift_delay(rec)
    assert fit.status == "ok"
    assert fit.value("delay_s") == pytest.approx(DELAY, abs=0.02)


def test_delay_from_channels_at_different_rates() -> None:
    # target at 10 Hz, actual at 100 Hz, 40 shifts 1 <-> 2 at phases spread evenly over the 0.1 s step: a change time
    # taken at the first new sample is late by up to one step (0.1 s, 0.01 s), the midpoint by at most half a step
    # either way; over evenly spread phases the median of the midpoint delays is within 0.1 s / 40 + 0.005 s of the
    # truth (a first-new-sample estimate would be ~0.045 s short)
    t_tgt = [0.0] + [3.0 * k + 0.1 * k / 40 for k in range(1, 41)]
    gears = [1] + [2 if k % 2 else 1 for k in range(1, 41)]
    rec = _gearbox(t_tgt, gears, [0.0] + [x + DELAY for x in t_tgt[1:]], gears, rate_hz=10.0, actual_rate_hz=100.0)
    fit = identify_shift_delay(rec)
    assert fit.n_points == 40
    assert fit.value("delay_s") == pytest.approx(DELAY, abs=0.1 / 40 + 0.005 + 1e-9)


def test_delay_flagged_with_too_few_pairs_and_absent_without_actual_gear() -> None:
    rec = _gearbox([0.0, 2.0, 5.0], [1, 2, 3], [0.0, 2.0 + DELAY, 5.0 + DELAY], [1, 2, 3])
    fit = identify_shift_delay(rec)
    assert fit.status != "ok" and np.isnan(fit.value("delay_s"))
    r = Recording()
    r.add(rec["gear_target"])
    r.add(Channel("vehicle_speed_kmh", "km/h", rec["gear_target"].timestamps, np.ones(len(rec["gear_target"]))))
    r.add(Channel("pedal_pct", "%", rec["gear_target"].timestamps, np.zeros(len(rec["gear_target"]))))
    assert SHIFT_DELAY_KEY.partition(".")[2] not in shift_fits(r, n_gears=3)
    r.add(rec["gear_actual"])
    assert SHIFT_DELAY_KEY.partition(".")[2] in shift_fits(r, n_gears=3)


def test_the_model_engages_the_lines_gear_after_the_delay() -> None:
    res = synthetic_result()
    for g, (up, down) in enumerate(zip([15, 25, 35, 45, 55, 65, 80, 95], [8, 17, 26, 36, 46, 55, 67, 82]), start=1):
        res.fits[f"shifts.up_{g}_{g + 1}"] = _fit({"c0_kmh": float(up), "c1_kmh_per_pct": 0.0})
        res.fits[f"shifts.down_{g + 1}_{g}"] = _fit({"c0_kmh": float(down), "c1_kmh_per_pct": 0.0})
    drive = cruise(n=300, gear=1)
    drive.speed_kmh = 0.1 * np.arange(300) + 0.03  # crosses 15 km/h (up 1-2) and 25 km/h (up 2-3)
    no_delay = MapVehicle(res, SPECS).shift_gears(drive)
    res.fits[SHIFT_DELAY_KEY] = _fit({"delay_s": DELAY})
    model = MapVehicle(res, SPECS)
    assert model.shift_delay_s == DELAY
    gears = model.shift_gears(drive)
    # the lines' target: 2 from sample 150 (15.03 km/h), 3 from sample 250 (25.03 km/h)
    assert np.flatnonzero(no_delay == 2)[0] == 150 and np.flatnonzero(no_delay == 3)[0] == 250
    # the speed, linear between samples, crossed 15 km/h at 14.97 s (0.03 s before sample 150): engaged at the first
    # sample at or past 14.97 + 0.34 = 15.31 s, sample 154; 25 km/h likewise at sample 254 (half a sample before
    # the first sample showing the target would give 153 and 253)
    assert np.flatnonzero(gears == 2)[0] == 154 and np.flatnonzero(gears == 3)[0] == 254
    assert any("shifts.actuation" in n for n in model.notes)


def test_actuated_gears_from_the_crossing_time() -> None:
    tgt = np.array([1] * 10 + [2] * 20)
    late = np.full(tgt.size, np.nan)
    late[10] = -0.01  # the change 0.01 s before sample 10: engaged at >= 0.99 + 0.34 = 1.33 s, sample 14
    assert np.flatnonzero(actuated_gears(tgt, 0.1, DELAY, late) == 2)[0] == 14
    late[10] = -0.09  # at 0.91 s: >= 1.25 s, sample 13
    assert np.flatnonzero(actuated_gears(tgt, 0.1, DELAY, late) == 2)[0] == 13


def test_the_delay_counts_from_the_line_crossing_between_samples() -> None:
    lines = {(1, "up"): (15.0, 0.0), (2, "down"): (8.0, 0.0), (2, "up"): (25.05, 0.0), (3, "down"): (17.0, 0.0)}
    v = 0.1 * np.arange(300) + 0.03
    g = shift_line_gears(lines, 3, v, np.full(300, 20.0), np.ones(300), delay_s=DELAY, dt_s=0.1)
    # 15 km/h between samples 149 (14.93) and 150 (15.03), at 14.97 s: engaged at >= 15.31 s, sample 154;
    # 25.05 km/h between samples 250 (25.03) and 251 (25.13), at 25.02 s: engaged at >= 25.36 s, sample 254
    assert np.flatnonzero(g == 2)[0] == 154 and np.flatnonzero(g == 3)[0] == 254
