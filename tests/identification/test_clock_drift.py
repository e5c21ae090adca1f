"""A source whose clock drifts is put on the reference clock by an affine map (offset + drift x (t - t_ref)).

The telemetry's 25 ppm made the shaft torque read late by 0.2-0.6 s on the threefold paper campaign's later passes;
a constant offset cannot follow it. Well under a second in all (synthetic channels of two hours at 10 Hz).
"""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.identification._signals import ClockShift, gather, source_shifts, to_ref, to_source
from benchtwin.identification._window_sums import _edges
from benchtwin.identification._windows import gather_at, grid_bounds
from benchtwin.recording import Channel, Recording

DRIFT_PPM, LAG0, T_REF = 100.0, 0.1, 3600.0


def _f(t: np.ndarray) -> np.ndarray:
    """A smooth signal: |f'| <= 2 pi / 37 + 0.3 * 2 pi / 11 = 0.34 /s, |f''| <= (2 pi / 37)^2 + 0.3 (2 pi / 11)^2
    = 0.127 /s^2."""
    return np.sin(2 * np.pi * t / 37.0) + 0.3 * np.sin(2 * np.pi * t / 11.0)


def _recording(se_ppm: float) -> Recording:
    """Two hours at 10 Hz: ``em_torque_nm`` on the vehicle CAN, ``shaft_torque_nm`` (the same signal) on a telemetry
    clock that reads ``LAG0 + 100 ppm t`` late; the meta as the acquisition writes it (the offset at ``T_REF``)."""
    t = np.arange(0.0, 7200.0, 0.1)
    rec = Recording()
    rec.add(Channel("em_torque_nm", "N m", t, _f(t), source="vehicle_can"))
    rec.add(Channel("shaft_torque_nm", "N m", t + LAG0 + DRIFT_PPM * 1e-6 * t, _f(t), source="telemetry"))
    key = "vehicle_can->telemetry"
    rec.meta.update({"clock_offsets_s": {key: LAG0 + DRIFT_PPM * 1e-6 * T_REF}, "clock_drift_ppm": {key: DRIFT_PPM},
                     "clock_drift_se_ppm": {key: se_ppm}, "clock_offset_time_s": {key: T_REF}})
    return rec


# linear interpolation of each channel errs by at most h^2 / 8 |f''| (h 0.1 s): 1.6e-4 each, two channels
TOL = 2 * 0.1 ** 2 / 8 * 0.127 + 1e-9


def test_a_significant_drift_maps_the_source_affinely() -> None:
    """The shaft torque gathered on the vehicle CAN's clock is the motor torque's signal to the interpolation's
    error over both hours; with the offset alone it is 0.36 s off at the ends (up to 0.12 in value)."""
    rec = _recording(se_ppm=1.0)
    shift = source_shifts(rec)["telemetry"]
    assert isinstance(shift, ClockShift) and shift.rate == pytest.approx(-DRIFT_PPM * 1e-6)
    g = gather(rec, ["em_torque_nm", "shaft_torque_nm"], 10.0)
    assert g.t[-1] - g.t[0] > 7000.0
    np.testing.assert_allclose(g["shaft_torque_nm"], g["em_torque_nm"], atol=TOL, rtol=0)
    offset_only = gather(rec, ["em_torque_nm", "shaft_torque_nm"], 10.0, align=False)
    offset_only_err = np.abs(offset_only["shaft_torque_nm"] - offset_only["em_torque_nm"]).max()
    assert offset_only_err > 100 * TOL
    # the piece-by-piece grids (the windowed searches) give the very samples
    lo, n, shifts = grid_bounds(rec, ["em_torque_nm", "shaft_torque_nm"], 10.0)
    assert shifts == g.shifts and lo == g.t[0] and n == g.t.size
    piece = gather_at(rec, ["em_torque_nm", "shaft_torque_nm"], g.t[1000:2000], 10.0, shifts)
    np.testing.assert_array_equal(piece["shaft_torque_nm"], g["shaft_torque_nm"][1000:2000])


def test_a_drift_within_its_noise_is_not_applied() -> None:
    """Applied when ``|drift| > sqrt(2) se`` (see source_shifts): just above that bound the shift is the constant
    offset, just below it the affine map."""
    bound = DRIFT_PPM / np.sqrt(2.0)
    assert source_shifts(_recording(se_ppm=bound * 1.01)) == {"telemetry": -(LAG0 + DRIFT_PPM * 1e-6 * T_REF)}
    assert isinstance(source_shifts(_recording(se_ppm=bound * 0.99))["telemetry"], ClockShift)
    rec = _recording(se_ppm=1.0)
    del rec.meta["clock_offset_time_s"]  # an older recording: the drift cannot be placed, the offset stands
    assert source_shifts(rec) == {"telemetry": -(LAG0 + DRIFT_PPM * 1e-6 * T_REF)}


def test_the_map_inverts_and_the_window_edges_follow_it() -> None:
    """``to_source`` undoes ``to_ref``; the steady windows' edge search finds the samples of the mapped times."""
    shift = ClockShift(-0.46, -100e-6)
    ts = np.arange(0.0, 7200.0, 0.1)
    np.testing.assert_allclose(to_source(to_ref(ts, shift), shift), ts, atol=1e-9, rtol=0)
    times = np.array([5.0, 1234.56, 3600.0, 7100.03])
    np.testing.assert_array_equal(_edges(ts, shift, times), np.searchsorted(to_ref(ts, shift), times, side="left"))


def test_the_converter_points_resample_puts_the_shaft_torque_on_the_can_clock() -> None:
    """``resample_strict`` (the torque converter's points) with the shifts: in memory and read by blocks, the shaft
    torque is the motor torque's signal to the interpolation's error (the grid then starts 0.1 s late, where the
    telemetry's first sample lands on the CAN's clock); without them it is the drift's 0.82 s off at the end."""
    from benchtwin.identification._resample_blocks import resample_strict
    from benchtwin.recording import LazyChannel

    rec = _recording(se_ppm=1.0)
    names = ["em_torque_nm", "shaft_torque_nm"]
    shifts = source_shifts(rec)
    blocked = Recording(meta=rec.meta)
    for ch in rec.channels.values():
        def part(a: int, b: int, ch: Channel = ch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            return ch.timestamps[a:b].copy(), ch.values[a:b].copy(), ch.flags[a:b].copy()

        blocked.add(LazyChannel(ch.name, ch.unit, ch.source, len(ch), lambda ch=ch: (ch.timestamps, ch.values,
                                ch.flags), ch.value_texts, block_loader=part))
    for r in (rec, blocked):
        t, v, bad = resample_strict(r, names, 10.0, shifts=shifts)
        assert t[-1] - t[0] > 7000.0 and not bad[1:-1].any()
        np.testing.assert_allclose(v["shaft_torque_nm"][1:-1], v["em_torque_nm"][1:-1], atol=TOL, rtol=0)
    t, v, _bad = resample_strict(rec, names, 10.0)
    assert np.nanmax(np.abs(v["shaft_torque_nm"] - v["em_torque_nm"])) > 100 * TOL


@pytest.mark.parametrize("span", [(1000.0, 1300.0), (-50.0, 20.0), (7150.0, 9000.0), (0.0, 7200.0)])
def test_gather_span_equals_gather_without_a_whole_read(span: tuple[float, float]) -> None:
    """``gather_span`` (the held-out drives' inputs) is ``gather(..., span=...)`` bit for bit on a drifting clock
    with a held state, an optional channel with flagged samples and one that ends early, the channels read by blocks
    only (a whole read fails the test); the Recording keeps nothing loaded."""
    from benchtwin.identification._windows import gather_span
    from benchtwin.recording import Flag, LazyChannel

    rec = _recording(se_ppm=1.0)
    t = np.arange(0.0, 7200.0, 0.5)
    rec.add(Channel("gear_actual", "", t, np.floor(t / 97.0) % 9, source="vehicle_can"))
    flags = np.where(np.arange(t.size) % 13 == 0, int(Flag.TIMEOUT), 0).astype(np.uint16)
    rec.add(Channel("battery_current_a", "A", t + 0.01, _f(t) * 50, flags, source="telemetry"))
    rec.add(Channel("pedal_pct", "%", t[:5000], _f(t[:5000]), source="vehicle_can"))

    def whole() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise AssertionError("read whole")

    blocked = Recording(meta=rec.meta)
    for ch in rec.channels.values():
        def part(a: int, b: int, ch: Channel = ch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            return ch.timestamps[a:b].copy(), ch.values[a:b].copy(), ch.flags[a:b].copy()

        blocked.add(LazyChannel(ch.name, ch.unit, ch.source, len(ch), whole, ch.value_texts, block_loader=part))
    names, opt = ["em_torque_nm", "shaft_torque_nm", "gear_actual"], ["battery_current_a", "pedal_pct", "absent"]
    want = gather(rec, names, 10.0, optional=opt, span=span)
    got = gather_span(blocked, names, 10.0, optional=opt, span=span)
    np.testing.assert_array_equal(got.t, want.t)
    assert got.present == want.present and set(got.values) == set(want.values) and got.shifts == want.shifts
    for k in want.values:
        np.testing.assert_array_equal(got[k], want[k])
    np.testing.assert_array_equal(got.bad, want.bad)
    np.testing.assert_array_equal(got.flagged, want.flagged)
    assert not blocked.loaded()
