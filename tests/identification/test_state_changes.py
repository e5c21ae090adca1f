"""The shift method reads ``gear_target`` by blocks: its changes and periodicity equal the whole channel's, bit for bit.

``_whole`` is the whole-channel work the shift method did before (the reference). About 3 s.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.identification._state_changes import good_step_median, state_changes
from benchtwin.identification.shifts import find_shift_events
from benchtwin.recording import Channel, Flag, Recording
from benchtwin.segments import Segment


def _whole(ch: Channel) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    ok = ch.good
    ts, g = ch.timestamps[ok], np.rint(ch.values[ok]).astype(int)
    k = np.flatnonzero(np.diff(g) != 0) + 1
    periodic = False
    if ts.size >= 10:
        dt = np.diff(ts)
        med = float(np.median(dt))
        periodic = med > 0 and float(np.mean(np.abs(dt - med) <= 0.1 * med)) > 0.8
    return ts[k], ts[k - 1], g[k - 1], g[k], periodic


def _gear(kind: str, n: int = 20000, seed: int = 2) -> Channel:
    """A target gear: periodic at 50 Hz with jitter, or event-driven (irregular), with flagged and NaN samples,
    changes at block edges and runs of equal gears."""
    rng = np.random.default_rng(seed)
    if kind == "periodic":
        t = np.arange(n) * 0.02 + rng.normal(0, 0.0005, n)
    elif kind == "sparse":  # a quarter of the steps within 10 % of the median: not periodic
        t = np.cumsum(np.where(rng.random(n) < 0.75, rng.uniform(0.01, 0.2, n), 0.02))
    else:
        t = np.cumsum(rng.exponential(0.3, n))
    g = np.clip(np.cumsum(rng.choice([-1, 0, 0, 0, 0, 0, 0, 1], n)) % 10, 0, 9).astype(float) + rng.normal(0, .1, n)
    flags = np.where(rng.random(n) < 0.02, int(Flag.TIMEOUT), 0).astype(np.uint16)
    g[rng.random(n) < 0.01] = np.nan
    return Channel("gear_target", "-", t, g, flags, "tcu")


@pytest.mark.parametrize("kind", ["periodic", "sparse", "events"])
@pytest.mark.parametrize("block", [61, 997, 1 << 16])
def test_block_changes_equal_the_whole_channel(blocks_only, kind: str, block: int) -> None:
    ch = _gear(kind)
    ref = _whole(ch)
    got = state_changes(blocks_only(ch), block)
    for a, b in zip(ref[:4], (got.t_new, got.t_old, got.old, got.new)):
        assert a.dtype.kind == b.dtype.kind and a.tobytes() == b.tobytes()
    assert got.periodic == ref[4]
    ts = ch.timestamps[ch.good]
    assert good_step_median(blocks_only(ch), ts.size - 1, block) == float(np.median(np.diff(ts)))
    assert got.t_new.size > 1000  # many changes, some at block edges


def test_the_periodicity_verdicts_both_ways() -> None:
    assert state_changes(_gear("periodic")).periodic and not state_changes(_gear("events")).periodic
    assert not state_changes(_gear("sparse")).periodic


def test_shift_events_read_the_gear_by_blocks(blocks_only) -> None:
    """find_shift_events on a Recording whose channels are read by blocks only: the events of the whole channel."""
    ch = _gear("periodic", 5000)
    t = np.arange(0.0, 101.0, 0.01)
    rng = np.random.default_rng(5)
    speed = Channel("vehicle_speed_kmh", "km/h", t, np.cumsum(rng.normal(0, 0.1, t.size)) + 50, np.zeros(t.size,
                    np.uint16), "vehicle_can")
    pedal = Channel("pedal_pct", "%", t, np.clip(np.cumsum(rng.normal(0, 0.2, t.size)), 0, 100),
                    np.zeros(t.size, np.uint16), "vehicle_can")
    rec = Recording(segments=[Segment(0.0, 60.0, "cycle", "cycle_1")])
    for c in (ch, speed, pedal):
        rec.add(blocks_only(c))
    ev = find_shift_events(rec)
    t_new, t_old, old, new, periodic = _whole(ch)
    assert periodic
    t_ev = 0.5 * (t_new + t_old)
    inside = (t_ev >= 0.0) & (t_ev < 60.0)
    assert ev["t"].tobytes() == t_ev[inside].tobytes()
    assert np.array_equal(ev["from_gear"], old[inside]) and np.array_equal(ev["to_gear"], new[inside])


def _counted(ch: Channel) -> tuple[Channel, list[int]]:
    """``ch`` read by blocks, counting the blocks read."""
    from benchtwin.recording import LazyChannel

    reads = [0]

    def block(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        reads[0] += 1
        return ch.timestamps[a:b], ch.values[a:b], ch.flags[a:b]

    return LazyChannel(ch.name, ch.unit, ch.source, len(ch), lambda: block(0, len(ch)), None,
                       block_loader=block), reads


def test_the_type_b_store_hands_out_an_unmoved_channels_changes_once() -> None:
    """Inside the re-runs' store the same channel object is worked out once and its result handed out again (copies);
    a moved copy of the channel (another object, other values) and another level of a derived channel are worked out
    for themselves, and equal what they give outside the store."""
    from benchtwin.identification._reuse import reusing
    from benchtwin.identification.engine_start import _above

    ch, reads = _counted(_gear("periodic"))
    ref = state_changes(ch, 997)
    per_run = reads[0]
    assert per_run > 0
    moved = _gear("periodic", seed=5)  # a re-run's moved channel: the same name, other values
    with reusing():
        first = state_changes(ch, 997)
        again = state_changes(ch, 997)
        assert reads[0] == 2 * per_run  # the run above, then once inside the store
        for a, b in zip((ref.t_new, ref.old), (again.t_new, again.old)):
            assert a.tobytes() == b.tobytes()
        again.t_new[:] = -1.0  # a caller writing into its copy does not change what the next one gets
        assert state_changes(ch, 997).t_new.tobytes() == first.t_new.tobytes()
        other = state_changes(moved, 997)
        assert other.t_new.tobytes() == state_changes(moved, 997).t_new.tobytes()
        assert other.t_new.tobytes() != ref.t_new.tobytes()
        lo = state_changes(_above(ch, 2.5), 997, of=(ch, ("above", 2.5)))
        hi = state_changes(_above(ch, 6.5), 997, of=(ch, ("above", 6.5)))
    assert lo.t_new.tobytes() == state_changes(_above(ch, 2.5), 997).t_new.tobytes()
    assert hi.t_new.tobytes() == state_changes(_above(ch, 6.5), 997).t_new.tobytes()
    assert lo.t_new.tobytes() != hi.t_new.tobytes()
