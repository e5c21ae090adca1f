"""The clip guard traced per gear (identification/transmission_clip.py) and the converter's verdict structure that
carries it (torque_converter_borrowed.UncalibratedShare)."""

from __future__ import annotations

import numpy as np

from benchtwin.identification._fit import IdentificationResult
from benchtwin.identification.torque_converter_borrowed import TURBINE_UNIDENTIFIED, uncalibrated_share
from benchtwin.identification.transmission_clip import ClipCause, clip_causes, clipped_by_gear
from benchtwin.recording import Channel, Flag, Recording
from benchtwin.segments import Segment

RAIL = 273.4  # Nm: K_TEL 8000's range on the paper's shaft (Table 2), the value a clipped sample reads


def _recording() -> Recording:
    # 100 s at 100 Hz: gear 1 for 0-40 s, gear 2 for 40-100 s; lock-up open 0-10 s; a ramp-up test 0-60 s, an
    # acceleration test 60-100 s. The shaft torque clips at the rail (SATURATED) over 5-15 s (gear 1, 5 s of it with
    # the lock-up open), 45-50 s (gear 2, in the ramp-up) and 70-80 s (gear 2, in the acceleration: not searched)
    t = np.arange(0.0, 100.0, 0.01)
    gear = np.where(t < 40.0, 1.0, 2.0)
    lock = (t >= 10.0).astype(float)
    sat = ((t >= 5.0) & (t < 15.0)) | ((t >= 45.0) & (t < 50.0)) | ((t >= 70.0) & (t < 80.0))
    torque = np.where(sat, RAIL, 100.0)
    torque[(t >= 5.0) & (t < 6.0)] = -RAIL  # the negative rail counts by its magnitude
    flags = np.where(sat, int(Flag.SATURATED), 0).astype(np.uint16)
    rec = Recording(segments=[Segment(0.0, 60.0, "ramp_up", "ramp_up_g1"),
                              Segment(60.0, 100.0, "acceleration", "acc")])
    rec.add(Channel("shaft_torque_nm", "Nm", t, torque, flags, "telemetry"))
    rec.add(Channel("gear_actual", "", t[::10], gear[::10], source="vehicle_can"))
    rec.add(Channel("lockup_closed", "", t[::10], lock[::10], source="vehicle_can"))
    return rec


def test_clipped_samples_counted_per_gear_in_the_searched_tests_with_the_lock_up_closed() -> None:
    # independent count from the construction: gear 1 clipped 10-15 s with the lock-up closed (5 s, 500 samples),
    # engaged with it closed 10-40 s (30 s); gear 2 clipped 45-50 s in the ramp-up (500 samples), engaged 40-60 s in
    # the searched test (20 s); the acceleration's clip is not in a searched test
    found = clipped_by_gear(_recording())
    assert sorted(found) == [1, 2]
    assert found[1].clipped_samples == 500 and found[2].clipped_samples == 500
    assert abs(found[1].clipped_s - 5.0) < 0.02 and abs(found[1].engaged_s - 30.0) < 0.2
    assert abs(found[2].engaged_s - 20.0) < 0.2
    assert found[1].range_nm == RAIL and found[2].range_nm == RAIL


def test_a_recording_without_clipping_traces_nothing() -> None:
    rec = _recording()
    ch = rec["shaft_torque_nm"]
    rec.add(Channel(ch.name, ch.unit, ch.timestamps, ch.values, np.zeros_like(ch.flags), ch.source))
    assert clipped_by_gear(rec) == {}


def test_clip_causes_only_for_gears_without_their_own_fit() -> None:
    # gear 1 failed for lack of steady points, gear 2 has its fit: only gear 1 is explained, with its fit's error
    res = IdentificationResult()
    res.errors["transmission.gear1"] = "InsufficientDataError: transmission.gear1: 2 steady points; need at least 3"
    res.fits["transmission.gear2"] = object()  # type: ignore[assignment]  # present is all that matters
    causes = clip_causes(_recording(), res, [1, 2])
    assert list(causes) == [1]
    assert "2 steady points" in causes[1].fit_error
    why = causes[1].reason()
    assert "K_TEL range +-273 Nm exceeded in gear 1" in why and "SATURATED" in why


def _share(points: dict[int, int], n: int, clipped: dict[int, ClipCause]):  # type: ignore[no-untyped-def]
    gear = np.concatenate([np.full(v, k) for k, v in points.items()] + [np.full(n - sum(points.values()), 3)])
    share = uncalibrated_share(gear, np.ones(n, dtype=bool), {k: 2 for k in points}, set())
    assert share is not None
    from dataclasses import replace

    return replace(share, clipped=clipped)


def test_the_clip_explains_the_verdict_only_when_its_gears_carry_the_share() -> None:
    cause = ClipCause(1, 500, 5.0, 30.0, RAIL, "InsufficientDataError: 2 steady points")
    # 100 points: gear 1 (clipped) 60 and gear 4 (not) 20 through uncalibrated models: without gear 1 the share is
    # 20 % <= 50 %: explained. With gear 4 at 55 (and gear 1 at 30) the share left is 55 % > 50 %: not explained
    # (mutant: a clip_explains that ignores the other gears' points passes the second case, and fails here)
    assert _share({1: 60, 4: 20}, 100, {1: cause}).clip_explains()
    assert not _share({1: 30, 4: 55}, 100, {1: cause}).clip_explains()
    assert not _share({1: 60, 4: 20}, 100, {}).clip_explains()  # no cause traced
    # exactly half left is still within the rule (not more than max_share)
    assert _share({1: 30, 4: 50}, 100, {1: cause}).clip_explains()
    # the words: the verdict and, when traced, the cause
    share = _share({1: 60, 4: 20}, 100, {1: cause})
    assert TURBINE_UNIDENTIFIED in share.reason() and cause.reason() in share.reason()
    assert cause.reason() not in _share({1: 60, 4: 20}, 100, {}).reason()


def test_a_lazy_shaft_torque_is_read_by_blocks_with_the_same_counts(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # the trace runs on the streamed (lazy) Recording too: the shaft torque read block by block (never whole), the
    # counts those of the eager channel; mutant: reading ch.values instead of blocks calls the whole loader
    import benchtwin.identification.transmission_clip as tc
    from benchtwin.recording import LazyChannel

    rec = _recording()
    eager = clipped_by_gear(rec)
    ch = rec["shaft_torque_nm"]
    arrays = (ch.timestamps, ch.values, ch.flags)

    def whole() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise AssertionError("the whole shaft torque was read")

    blocks: list[int] = []

    def block(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        blocks.append(b - a)
        return arrays[0][a:b], arrays[1][a:b], arrays[2][a:b]

    rec.add(LazyChannel(ch.name, ch.unit, ch.source, len(ch), whole, block_loader=block))
    monkeypatch.setattr(tc, "_BLOCK", 1000)
    assert clipped_by_gear(rec) == eager
    assert len(blocks) == 10 and max(blocks) == 1000
