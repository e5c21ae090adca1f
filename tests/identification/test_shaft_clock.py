"""The shaft torque's clock lined up with the dyno's axle forces test by test (identification/shaft_clock.py).

Synthetic channels, noiseless: a drive torque made of smooth pulses (a take-off every test), read by the dyno as two
axle forces (front 60 %, rear 40 %, on the dyno's own clock, put on the reference by a constant shift) and by the
telemetry as the shaft torque on a clock that drifts. Each test's lag comes from a cross-correlation on a 100 Hz grid
refined by a parabola through its peak; for a smooth peak that is well under a tenth of the 10 ms step, so the line
through 20 tests maps every time to within 1 ms, where the acquisition's constant offset left up to the drift's
whole span (here 40 ppm over 2,000 s: 80 ms). Well under a second in all.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.identification._clock import ClockShift, to_ref
from benchtwin.identification.shaft_clock import roller_aligned_shifts
from benchtwin.recording import Channel, Recording
from benchtwin.segments import Segment

DRIFT, LAG0, DYNO_SHIFT = 40e-6, 0.012, -0.120
N_TESTS, TEST_S = 20, 100.0


def _torque(t: np.ndarray) -> np.ndarray:
    """A take-off pulse 20 s into each 100 s test (rise and fall of about a second) on a slow wave."""
    phase = np.mod(t, TEST_S) - 20.0
    return 150.0 * np.exp(-0.5 * (phase / 0.6) ** 2) + 20.0 * np.sin(2 * np.pi * t / 37.0)


def _recording(*, dyno: bool = True, rear: bool = True) -> Recording:
    """``shaft_torque_nm`` on a telemetry clock reading ``LAG0 + DRIFT t`` early (so its shift is ``-(LAG0 + DRIFT
    t)``, which the caller's shifts leave out), the axle forces on a dyno clock whose shift ``DYNO_SHIFT`` is known."""
    t = np.arange(0.0, N_TESTS * TEST_S, 0.002)
    rec = Recording()
    rec.add(Channel("shaft_torque_nm", "N m", t + LAG0 + DRIFT * t, _torque(t), source="telemetry"))
    td = np.arange(0.0, N_TESTS * TEST_S, 0.01)
    if dyno:
        share = (0.6, 0.4) if rear else (1.0,)
        for name, s in zip(("dyno_force_front_n", "dyno_force_rear_n"), share, strict=False):
            rec.add(Channel(name, "N", td - DYNO_SHIFT, 12.0 * s * _torque(td), source="dyno"))
    rec.add(Channel("em_torque_nm", "N m", td, _torque(td), source="vehicle_can"))
    rec.segments = [Segment(k * TEST_S, (k + 1) * TEST_S, "acceleration", f"t{k}") for k in range(N_TESTS)]
    return rec


@pytest.mark.parametrize("rear", [True, False])
def test_a_drifting_shaft_clock_is_mapped_onto_the_rollers(rear: bool) -> None:
    rec = _recording(rear=rear)
    shifts, note = roller_aligned_shifts(rec, {"dyno": DYNO_SHIFT})
    s = shifts["telemetry"]
    assert isinstance(s, ClockShift), s
    assert shifts["dyno"] == DYNO_SHIFT
    ts = np.linspace(0.0, N_TESTS * TEST_S, 50) + LAG0  # telemetry stamps; the true time is ts - LAG0 - DRIFT t
    true_t = (ts - LAG0) / (1.0 + DRIFT)
    err = np.abs(to_ref(ts, s) - true_t)
    assert err.max() < 1e-3, err.max()  # the constant offset would leave 80 ms at the end
    assert f"over {N_TESTS} tests" in note and "ppm" in note


def test_a_drifting_dyno_clock_is_taken_out_first() -> None:
    # the dyno's clock drifts too (20 ppm about T_REF, where the acquisition's constant offset holds): the shaft torque
    # lined up with the rollers alone would carry that drift (20 ppm over 1,000 s either side: 20 ms); the vehicle
    # speed's lag against the roller speed per test takes it out first, and every time maps to within 1 ms again
    dyno_drift, t_ref = 20e-6, 1000.0
    rec = _recording()
    td = np.arange(0.0, N_TESTS * TEST_S, 0.01)
    stamps = td - DYNO_SHIFT + dyno_drift * (td - t_ref)
    for name in ("dyno_force_front_n", "dyno_force_rear_n"):
        ch = rec[name]
        rec.add(Channel(name, ch.unit, stamps, ch.values, source="dyno"))
    speed = 50.0 + 30.0 * np.sin(2 * np.pi * td / 53.0) + 0.1 * _torque(td)
    rec.add(Channel("vehicle_speed_kmh", "km/h", td, speed, source="vehicle_can"))
    rec.add(Channel("dyno_speed_kmh", "km/h", stamps, speed, source="dyno"))
    rec.meta["clock_offset_time_s"] = {"vehicle_can->dyno": t_ref}
    shifts, note = roller_aligned_shifts(rec, {"dyno": DYNO_SHIFT})
    ts = np.linspace(0.0, N_TESTS * TEST_S, 50) + LAG0
    err = np.abs(to_ref(ts, shifts["telemetry"]) - (ts - LAG0) / (1.0 + DRIFT))
    assert err.max() < 1e-3, err.max()
    assert "the dyno's clock first" in note


def test_without_the_rollers_the_shifts_stand() -> None:
    given = {"telemetry": 0.005}
    shifts, note = roller_aligned_shifts(_recording(dyno=False), given)
    assert shifts == given and note == ""


def test_without_a_drift_the_acquisitions_offset_stands() -> None:
    # the tests' lags agree (no drift the acquisition missed): the slope is within its noise, the shifts are the
    # given ones and nothing is said
    rec = _recording()
    ch = rec["shaft_torque_nm"]
    rec.add(Channel(ch.name, ch.unit, ch.timestamps - DRIFT * (ch.timestamps - LAG0) / (1.0 + DRIFT), ch.values,
                    source="telemetry"))
    given = {"dyno": DYNO_SHIFT, "telemetry": -LAG0 + 0.002}
    shifts, note = roller_aligned_shifts(rec, given)
    assert shifts == given and note == ""


def test_the_type_b_re_runs_share_the_lags_of_the_channels_they_do_not_move(monkeypatch: pytest.MonkeyPatch) -> None:
    """Inside the re-runs' store, a Recording whose shaft torque and axle forces are the nominal channels takes the
    tests' lags computed once; one whose shaft torque is another channel (a re-run moving it: read 30 ms later here)
    gets its own, those computed without the store."""
    from benchtwin.identification import _reuse, shaft_clock

    rec = _recording()
    moved = Recording(channels=dict(rec.channels), segments=rec.segments, meta=rec.meta)
    ch = rec["shaft_torque_nm"]
    moved.channels["shaft_torque_nm"] = Channel(ch.name, ch.unit, ch.timestamps + 0.030, ch.values, source=ch.source)
    other = Recording(channels=dict(rec.channels), segments=rec.segments, meta=rec.meta)
    em = rec["em_torque_nm"]
    other.channels["em_torque_nm"] = em.with_values(em.values * 1.01)  # a gain of a channel the lags do not read
    want_rec = roller_aligned_shifts(rec, {"dyno": DYNO_SHIFT})
    want_moved = roller_aligned_shifts(moved, {"dyno": DYNO_SHIFT})
    assert want_moved[0]["telemetry"] != want_rec[0]["telemetry"]
    calls = []
    computed = shaft_clock._test_lags_of
    monkeypatch.setattr(shaft_clock, "_test_lags_of", lambda *a: calls.append(1) or computed(*a))
    with _reuse.reusing():
        assert roller_aligned_shifts(rec, {"dyno": DYNO_SHIFT}) == want_rec
        assert len(calls) == 1
        assert roller_aligned_shifts(other, {"dyno": DYNO_SHIFT}) == want_rec  # shared: nothing computed again
        assert len(calls) == 1
        assert roller_aligned_shifts(moved, {"dyno": DYNO_SHIFT}) == want_moved  # its own lags
        assert len(calls) == 2


def test_non_finite_samples_are_left_out_of_the_tests_lags() -> None:
    """A shaft torque with NaN samples gives the shifts, bit for bit, of the same channel with those samples removed
    (the all-finite windows skip their copy; a window with a NaN must still drop it)."""
    rec = _recording()
    ch = rec["shaft_torque_nm"]
    bad = np.zeros(len(ch), dtype=bool)
    bad[::997] = True
    holed, cut = Recording(), Recording()
    for name, c in rec.channels.items():
        holed.add(c if name != "shaft_torque_nm" else
                  Channel(name, c.unit, c.timestamps, np.where(bad, np.nan, c.values), source=c.source))
        cut.add(c if name != "shaft_torque_nm" else
                Channel(name, c.unit, c.timestamps[~bad], c.values[~bad], source=c.source))
    holed.segments = cut.segments = rec.segments
    shifts = {"dyno": DYNO_SHIFT}
    got, note = roller_aligned_shifts(holed, shifts)
    expected, note_cut = roller_aligned_shifts(cut, shifts)
    assert isinstance(got["telemetry"], ClockShift) and got == expected and note == note_cut
