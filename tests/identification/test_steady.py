"""Steady-state detection finds holds by itself, respects states and flags, and uses segments when present."""

from __future__ import annotations

import numpy as np
from _synth_a import to_recording

from benchtwin.identification.steady import Tolerance, detect_steady, find_steady_windows
from benchtwin.recording import Flag


def test_detect_steady_finds_each_hold_of_a_staircase() -> None:
    dt = 0.1
    t = np.arange(0, 55, dt)
    # four holds of 10 s joined by 5 s ramps
    x = np.interp(t, [0, 10, 15, 25, 30, 40, 45, 55], [10, 10, 50, 50, 20, 20, 80, 80])
    spans = detect_steady(dt, {"x": x}, {"x": Tolerance(0.5, 0.0, 0.5)}, window_s=2.0, min_duration_s=3.0,
                          trim_s=0.5)
    assert len(spans) == 4
    means = [x[a:b].mean() for a, b in spans]
    np.testing.assert_allclose(means, [10, 50, 20, 80])
    for (a, b), lo in zip(spans, [0, 15, 30, 45]):
        assert t[a] >= lo - 1e-9 and t[b - 1] <= lo + 10 + 1e-9


def test_state_change_and_flagged_samples_split_windows() -> None:
    dt = 0.1
    t = np.arange(0, 30, dt)
    x = np.full(t.size, 5.0)
    gear = np.where(t < 15, 3.0, 4.0)
    valid = ~((t > 22) & (t < 23))
    spans = detect_steady(dt, {"x": x}, {"x": Tolerance(0.1)}, states={"g": gear}, valid=valid, window_s=2.0,
                          min_duration_s=3.0)
    assert len(spans) == 3
    for a, b in spans:
        assert np.unique(gear[a:b]).size == 1 and valid[a:b].all()


def test_noise_within_tolerance_is_steady_and_drift_is_not() -> None:
    rng = np.random.default_rng(0)
    dt = 0.02
    t = np.arange(0, 20, dt)
    quiet = 100 + rng.normal(0, 0.5, t.size)
    drift = 100 + 2.0 * t
    tol = {"x": Tolerance(1.5, 0.0, 0.5)}
    assert len(detect_steady(dt, {"x": quiet}, tol, min_duration_s=10.0)) == 1
    assert detect_steady(dt, {"x": drift}, tol) == []


def test_recording_windows_use_segments_and_count_flags(ramp_plant) -> None:
    t, sig, segs = ramp_plant
    rec = to_recording(t, sig, segments=segs)
    ch = rec["em_torque_nm"]
    hit = (ch.timestamps > 3.0) & (ch.timestamps < 4.0)
    ch.flags[hit] = int(Flag.STATUS_ERROR)
    names = ["vehicle_speed_kmh", "em_speed_rpm", "em_torque_nm", "engine_torque_nm"]
    sw = find_steady_windows(rec, names,
                             states=["gear_actual", "k0_closed"], kinds=["ramp_up"])
    # 10 ramp-up settings x 11 torque levels; the flagged second splits nothing long enough away
    assert 105 <= len(sw) <= 111
    assert sw.n_excluded >= 9
    assert all(w.segment.startswith("ramp_up") for w in sw.windows)
    for w in sw.windows:
        assert w.stds["em_torque_nm"] < 0.5
        assert not ((w.start_s < 4.0) & (w.end_s > 3.0))
    # without matching segment kinds the whole recording is searched (the slipping hold is found too)
    sw2 = find_steady_windows(rec, names, kinds=["coastdown"])
    assert len(sw2) > len(sw) and sw2.reasons
    # max_duration cuts holds into several points
    sw3 = find_steady_windows(rec, names, kinds=["ramp_up"], max_duration_s=2.5)
    assert len(sw3) > len(sw)


def test_out_of_order_samples_give_the_same_windows_and_means(ramp_plant) -> None:
    t, sig, segs = ramp_plant
    rec = to_recording(t, sig, segments=segs)
    names = ["vehicle_speed_kmh", "em_speed_rpm", "em_torque_nm"]
    ref = find_steady_windows(rec, names, kinds=["ramp_up"])
    ref_raw = ref.raw_average(rec, "em_torque_nm")
    ch = rec["em_torque_nm"]
    rng = np.random.default_rng(3)
    swap = rng.choice(np.arange(1, len(ch) - 1, 2), 500, replace=False)  # swap neighbours: frames reordered
    for arr in (ch.timestamps, ch.values, ch.flags):
        arr[swap], arr[swap + 1] = arr[swap + 1].copy(), arr[swap].copy()
    got = find_steady_windows(rec, names, kinds=["ramp_up"])
    assert [(w.i0, w.i1) for w in got.windows] == [(w.i0, w.i1) for w in ref.windows]
    np.testing.assert_allclose(got.raw_average(rec, "em_torque_nm"), ref_raw, rtol=1e-12)
    np.testing.assert_allclose(got.means("em_torque_nm"), ref.means("em_torque_nm"), rtol=1e-12)
    # the search over the whole grid (a grid given) finds the windows the piece-by-piece search found
    from benchtwin.identification._signals import gather, segments_span

    g = gather(rec, names, 10.0, span=segments_span(rec, ["ramp_up"]))
    whole = find_steady_windows(rec, names, kinds=["ramp_up"], grid=g)
    assert got.windowed and not whole.windowed
    assert [(w.start_s, w.end_s, w.i0, w.i1) for w in whole.windows] == [
        (w.start_s, w.end_s, w.i0, w.i1) for w in got.windows]
    np.testing.assert_allclose(whole.average(g["em_torque_nm"]), got.means("em_torque_nm"), rtol=1e-9)


def test_sources_are_put_on_one_clock_with_the_detected_offsets(ramp_plant) -> None:
    """The acquisition keeps each source on its own clock and reports offsets; gather aligns them."""
    from benchtwin.identification._signals import gather, source_shifts

    t, sig, segs = ramp_plant
    rec = to_recording(t, sig, segments=segs)
    for ch in rec.channels.values():
        if ch.source == "telemetry":
            ch.timestamps = ch.timestamps + 0.7  # the telemetry clock runs 0.7 s ahead
        if ch.source == "modbus_pressure":
            ch.timestamps = ch.timestamps - 0.2
    rec.meta["clock_offsets_s"] = {"vehicle_can->telemetry": 0.7, "pressure->acquisition": 0.2}
    assert source_shifts(rec) == {"telemetry": -0.7}  # no pressure channel in this recording
    rec.add(type(rec["em_torque_nm"])("brake_pressure_fl_bar", "bar", t[::2] - 0.2, np.zeros(t[::2].size), None,
                                      "modbus_pressure"))
    assert source_shifts(rec) == {"telemetry": -0.7, "modbus_pressure": 0.2}
    g = gather(rec, ["em_torque_nm", "shaft_torque_nm"], 10.0)
    exact = gather(to_recording(t, sig), ["em_torque_nm", "shaft_torque_nm"], 10.0)
    k = np.searchsorted(exact.t, g.t[0])
    np.testing.assert_allclose(g["shaft_torque_nm"][5:-5], exact["shaft_torque_nm"][k + 5:k + g.t.size - 5],
                               atol=1e-6)
    unaligned = gather(rec, ["em_torque_nm", "shaft_torque_nm"], 10.0, align=False)
    assert unaligned.shifts == {} and g.shifts == {"telemetry": -0.7, "modbus_pressure": 0.2}
