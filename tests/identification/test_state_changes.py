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
