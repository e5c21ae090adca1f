"""The vectorised helpers give what the straightforward computations give.

``smooth_derivative`` applies the Savitzky-Golay filter and its edge fits to every run at once;
``SteadyWindows.raw_average`` sums only the samples inside the windows and finds them on shifted
clocks without shifting every sample; ``gather`` looks flags up at the samples it uses.
"""

from __future__ import annotations

import numpy as np
from _synth_a import to_recording
from scipy.signal import savgol_filter

from benchtwin.identification._signals import gather, runs, smooth_derivative
from benchtwin.identification.steady import find_steady_windows
from benchtwin.recording import Flag


def _reference_derivative(x: np.ndarray, dt: float, window_s: float, valid: np.ndarray, polyorder: int) -> np.ndarray:
    valid = valid & np.isfinite(x)
    w = max(round(window_s / dt) | 1, polyorder + 2 | 1)
    out = np.full(x.shape, np.nan)
    for i0, i1 in runs(valid):
        if i1 - i0 >= w:
            out[i0:i1] = savgol_filter(x[i0:i1], w, polyorder, deriv=1, delta=dt, mode="interp")
    return out


def test_smooth_derivative_matches_savgol_run_by_run() -> None:
    rng = np.random.default_rng(5)
    for _ in range(60):
        n = int(rng.integers(3, 600))
        x = np.cumsum(rng.normal(size=n)) * 3.0 + 50.0
        valid = rng.random(n) > rng.choice([0.0, 0.01, 0.05, 0.3])
        x[rng.integers(0, n, 2)] = np.nan
        dt = float(rng.choice([0.01, 0.05, 0.1]))
        window_s = float(rng.choice([0.1, 0.5, 1.0, 3.0]))
        order = int(rng.choice([2, 3]))
        got = smooth_derivative(x, dt, window_s, valid=valid, polyorder=order)
        ref = _reference_derivative(x, dt, window_s, valid, order)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
        fin = np.isfinite(ref)
        if fin.any():
            np.testing.assert_allclose(got[fin], ref[fin], rtol=1e-9, atol=1e-9 * float(np.max(np.abs(ref[fin]))))


def test_smooth_derivative_of_a_cubic_is_exact_at_the_edges() -> None:
    dt = 0.01
    t = np.arange(0.0, 5.0, dt)
    x = 2.0 + 0.5 * t - 0.3 * t**2 + 0.04 * t**3
    d = smooth_derivative(x, dt, 3.0)  # 301-sample window: edge fits over long windows stay accurate
    np.testing.assert_allclose(d, 0.5 - 0.6 * t + 0.12 * t**2, rtol=1e-9, atol=1e-9)


def _reference_raw_average(rec, sw, name: str) -> np.ndarray:
    ch = rec[name]
    ts = ch.timestamps + sw.grid.shifts.get(ch.source, 0.0)
    order = np.argsort(ts, kind="stable")
    ts, v, fl = ts[order], ch.values[order], ch.flags[order]
    good = ((fl & int(Flag.bad())) == 0) & np.isfinite(v)
    out = []
    for w in sw.windows:
        sel = (ts >= w.start_s) & (ts < w.end_s) & good
        out.append(v[sel].mean() if sel.any() else np.nan)
    return np.array(out)


def test_raw_average_matches_a_plain_mean_over_each_window_on_a_shifted_clock(ramp_plant) -> None:
    t, sig, segs = ramp_plant
    rec = to_recording(t, sig, segments=segs, noise=1.0, seed=2)
    for ch in rec.channels.values():
        if ch.source == "telemetry":
            ch.timestamps = ch.timestamps + 0.123  # its own clock, 0.123 s ahead
    rec.meta["clock_offsets_s"] = {"vehicle_can->telemetry": 0.123}
    tq = rec["shaft_torque_nm"]
    tq.flags[::97] |= int(Flag.SATURATED)
    tq.values[::211] = np.nan
    names = ["vehicle_speed_kmh", "em_speed_rpm", "em_torque_nm"]
    sw = find_steady_windows(rec, names, kinds=["ramp_up"], max_duration_s=2.5)
    assert len(sw) > 20 and sw.grid.shifts == {"telemetry": -0.123}
    for name in ("shaft_torque_nm", "em_torque_nm"):
        np.testing.assert_allclose(sw.raw_average(rec, name), _reference_raw_average(rec, sw, name), rtol=1e-9)
    empty = sw.select(np.zeros(len(sw), dtype=bool))
    assert empty.raw_average(rec, "shaft_torque_nm").size == 0


def test_gather_flags_every_grid_sample_touched_by_a_flagged_source_sample(ramp_plant) -> None:
    t, sig, _ = ramp_plant
    rec = to_recording(t, sig)
    ch = rec["em_torque_nm"]
    bad = np.zeros(len(ch), dtype=bool)
    bad[500:700] = True
    bad[2000] = True
    ch.flags[bad] |= int(Flag.TIMEOUT)
    ch.values[3000] = np.nan
    g = gather(rec, ["em_torque_nm", "vehicle_speed_kmh"], 10.0)
    # reference: a grid sample is flagged when the source sample at or before it, or (interpolated, the grid
    # time strictly between samples) the one after it, is flagged or not finite
    raw_bad = bad | ~np.isfinite(ch.values)
    i0 = np.clip(np.searchsorted(ch.timestamps, g.t, side="right") - 1, 0, len(ch) - 1)
    i1 = np.clip(i0 + 1, 0, len(ch) - 1)
    ref = raw_bad[i0] | (raw_bad[i1] & (ch.timestamps[i1] > g.t))
    ref &= (g.t >= ch.timestamps[0]) & (g.t <= ch.timestamps[-1])
    np.testing.assert_array_equal(g.flagged, ref)
    assert g.flagged.sum() > 10
