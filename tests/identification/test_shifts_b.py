"""Gear-shift threshold identification on a synthetic Recording with event-driven target gear."""

from __future__ import annotations

import numpy as np
import pytest
from _synth_b import N_GEARS, shift_recording

from benchtwin.errors import MissingChannelError
from benchtwin.identification.shifts import find_shift_events, identify_shift_thresholds
from benchtwin.recording import Channel, Flag, Recording


@pytest.fixture(scope="module")
def ideal():
    return shift_recording()


def test_every_pair_up_and_down_recovered(ideal):
    rec, truth = ideal
    res = identify_shift_thresholds(rec)
    assert len(res) == 2 * (N_GEARS - 1)
    for g in range(1, N_GEARS):
        up, down = res[f"up_{g}_{g + 1}"], res[f"down_{g + 1}_{g}"]
        np.testing.assert_allclose([up.value("c0_kmh"), up.value("c1_kmh_per_pct")], truth["up"][g], rtol=1e-3)
        np.testing.assert_allclose([down.value("c0_kmh"), down.value("c1_kmh_per_pct")], truth["down"][g],
                                   rtol=1e-3)
        assert up.status == down.status == "ok"
        assert up.n_points == len(truth["up_pedals"])


def test_actual_gear_lag_does_not_matter(ideal):
    rec, truth = ideal
    r = Recording(dict(rec.channels), rec.segments)
    gt = rec["gear_target"]
    r.add(Channel("gear_actual", "", gt.timestamps + 0.6, gt.values))  # actuation delay
    res = identify_shift_thresholds(r)
    np.testing.assert_allclose(res["up_4_5"].value("c0_kmh"), truth["up"][4][0], rtol=1e-3)


def test_few_events_and_small_spread_are_flagged():
    rec, _ = shift_recording(up_pedals=(40.0, 60.0), down_pedals=(20.0, 22.0))
    res = identify_shift_thresholds(rec, n_gears=N_GEARS)
    assert res["up_1_2"].status == "flagged" and "event" in res["up_1_2"].reasons[0]
    assert np.isnan(res["up_1_2"].value("c1_kmh_per_pct"))
    rec2, _ = shift_recording(up_pedals=(50.0, 52.0, 54.0, 51.0), down_pedals=(20.0, 30.0))
    res2 = identify_shift_thresholds(rec2)
    assert res2["up_3_4"].status == "flagged" and "pedal spread" in res2["up_3_4"].reasons[0]
    assert np.isnan(res2["up_3_4"].value("c0_kmh"))
    np.testing.assert_allclose(res2["up_3_4"].value("mean_pedal_pct"), 51.75)
    np.testing.assert_allclose(res2["up_3_4"].value("mean_speed_kmh"),
                               np.mean([41.0 + 0.33 * p for p in (50.0, 52.0, 54.0, 51.0)]), rtol=1e-3)


def test_missing_pairs_are_reported_flagged(ideal):
    rec, _ = ideal
    res = identify_shift_thresholds(rec, n_gears=10)
    assert res["up_9_10"].status == "flagged"
    assert res["up_9_10"].n_points == 0


def test_skipped_gears_are_not_used():
    t = np.arange(0.0, 10.0, 0.1)
    rec = Recording()
    rec.add(Channel("vehicle_speed_kmh", "km/h", t, 100 - 10 * t))  # slowing down: 5 -> 4 is a speed crossing
    rec.add(Channel("pedal_pct", "%", t, np.full(t.size, 50.0)))
    rec.add(Channel("gear_target", "", [0.0, 2.0, 5.0], [3.0, 5.0, 4.0]))
    ev = find_shift_events(rec)
    assert list(ev["from_gear"]) == [3, 5] and list(ev["to_gear"]) == [5, 4]
    res = identify_shift_thresholds(rec)
    assert res["up_3_4"].n_points == 0 and res["down_5_4"].n_points == 1


def test_missing_target_gear():
    rec = Recording()
    rec.add(Channel("vehicle_speed_kmh", "km/h", [0, 1], [0, 1]))
    with pytest.raises(MissingChannelError, match="gear_target"):
        identify_shift_thresholds(rec)


def test_pedal_step_shifts_are_not_speed_crossings():
    # cruising at 60 km/h in 3rd with pedal 80 %, the driver lifts to 10 %: the upshift comes from the
    # pedal step, far above the line at 10 %; it must not enter the fit
    t = np.arange(0.0, 20.0, 0.1)
    rec = Recording()
    rec.add(Channel("vehicle_speed_kmh", "km/h", t, np.full(t.size, 60.0)))
    rec.add(Channel("pedal_pct", "%", t, np.where(t < 10.0, 80.0, 10.0)))
    rec.add(Channel("gear_target", "", [0.0, 10.05], [3.0, 4.0]))
    ev = find_shift_events(rec)
    assert ev["crossing"].tolist() == [False]
    res = identify_shift_thresholds(rec)
    assert res["up_3_4"].n_points == 0 and res["up_3_4"].n_excluded == 1


def test_flagged_speed_at_an_event_is_excluded_and_counted(ideal):
    rec, truth = ideal
    ev = find_shift_events(rec)
    first_up_12 = ev["t"][(ev["from_gear"] == 1) & (ev["to_gear"] == 2)][0]
    sp = rec["vehicle_speed_kmh"]
    flags = sp.flags.copy()
    flags[np.abs(sp.timestamps - first_up_12) < 0.5] = int(Flag.STATUS_ERROR)
    r = Recording(dict(rec.channels), rec.segments)
    r.add(Channel("vehicle_speed_kmh", "km/h", sp.timestamps, sp.values, flags, sp.source))
    res = identify_shift_thresholds(r)
    assert res["up_1_2"].n_points == len(truth["up_pedals"]) - 1
    assert res["up_1_2"].n_excluded == 1
    np.testing.assert_allclose(res["up_1_2"].value("c0_kmh"), truth["up"][1][0], rtol=1e-3)
