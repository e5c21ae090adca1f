"""Keys of the type B store: the strict grid's blocks shared by the re-runs, and the grid times' fingerprint.

Inside the type B store (:func:`~benchtwin.identification._reuse.reusing`) a channel a re-run does not move is read
around a block of grid points once for all re-runs (keyed by the channel object, its clock shift and the block's grid
points); a moved channel, another shift or another block is computed for itself. Each block the re-runs get must be
the very one computed without the store. The ramp-up test laid end to end twice, every channel read by blocks, grid
blocks of 37 points. About 2 s.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_block_reads import NAMES, _blocked, _repeated

import benchtwin.identification._resample_blocks as rb
from benchtwin.identification._clock import ClockShift
from benchtwin.identification._reuse import reusing
from benchtwin.identification.uncertainty import Component, perturbed
from benchtwin.recording import Recording


def _blocks(rec: Recording, names: list[str], shifts: dict | None) -> list[tuple[np.ndarray, dict, np.ndarray]]:
    grid = rb.StrictGrid(rec, names, 10.0, hold=("gear_actual",) if "gear_actual" in names else (), shifts=shifts)
    return [grid.block(a, a + 37) for a in range(0, grid.size, 37)]


def _equal(got: list, want: list) -> None:
    assert len(got) == len(want) > 3
    for (t1, v1, b1), (t0, v0, b0) in zip(got, want, strict=True):
        np.testing.assert_array_equal(t1, t0)
        np.testing.assert_array_equal(b1, b0)
        assert v1.keys() == v0.keys()
        for n in v0:
            np.testing.assert_array_equal(v1[n], v0[n])


@pytest.fixture(scope="module")
def blocked(ramp_plant) -> Recording:
    return _blocked(_repeated(ramp_plant, 2))


def test_a_moved_channel_is_resampled_for_itself_and_the_others_are_shared(blocked, monkeypatch) -> None:
    names = [*NAMES, "gear_actual"] if "gear_actual" in blocked else list(NAMES)
    comp = Component("em_torque_nm.gain", ("em_torque_nm",), "gain", 0.01)
    moved = perturbed(blocked, comp)
    drift = {c.source: ClockShift(0.0123, -3e-5) for c in blocked.channels.values()}
    # without the store: every block computed on its own
    want_nominal, want_moved = _blocks(blocked, names, None), _blocks(moved, names, None)
    want_drift = _blocks(moved, names, drift)
    # the vehicle CAN 5 ms early: the grid starts where it did (at the states' first sample), other samples
    offset = {"vehicle_can": -0.005}
    want_offset = _blocks(blocked, names, offset)
    assert rb.StrictGrid(blocked, names, 10.0, shifts=offset).lo == rb.StrictGrid(blocked, names, 10.0).lo
    assert not np.array_equal(want_offset[2][1]["em_torque_nm"], want_nominal[2][1]["em_torque_nm"])
    assert not np.array_equal(want_moved[2][1]["em_torque_nm"], want_nominal[2][1]["em_torque_nm"])
    calls: list[str] = []
    plain = rb._channel_block

    def counted(c, *rest):  # type: ignore[no-untyped-def]
        calls.append(c.name)
        return plain(c, *rest)

    monkeypatch.setattr(rb, "_channel_block", counted)
    with reusing():
        _equal(_blocks(blocked, names, None), want_nominal)
        n_blocks = len(want_nominal)
        assert len(calls) == n_blocks * len(names)
        calls.clear()
        # the re-run that moves the torque: only the torque is read again, and it reads its moved values
        _equal(_blocks(moved, names, None), want_moved)
        assert calls == ["em_torque_nm"] * n_blocks
        calls.clear()
        # the same channels on another clock: every channel again
        _equal(_blocks(moved, names, drift), want_drift)
        assert len(calls) == n_blocks * len(names)
        calls.clear()
        # a constant offset of one source on the same grid: its channels again, the states' from the store
        _equal(_blocks(blocked, names, offset), want_offset)
        assert sorted(set(calls)) == sorted(n for n in names if blocked[n].source == "vehicle_can")
        calls.clear()
        # and the nominal Recording once more: every block from the store, the same numbers
        _equal(_blocks(blocked, names, None), want_nominal)
        assert calls == []


def test_the_grid_s_fingerprint_is_that_of_the_times_sampled(blocked) -> None:
    """The fingerprint of a grid's times, worked out once per index cache for all the channels sampled at them,
    tells grids with the same count and first time apart (later points elsewhere): each sampled for itself."""
    from benchtwin.identification._signals import _IndexCache
    from benchtwin.identification._windows import _sample_at

    ch = blocked["em_torque_nm"]
    t1 = np.linspace(100.0, 400.0, 3001)
    t2 = t1.copy()
    t2[1:] += 0.037
    want1, want2 = _sample_at(ch, t1, False, _IndexCache(t1), 0.0), _sample_at(ch, t2, False, _IndexCache(t2), 0.0)
    assert not np.array_equal(want1[0], want2[0])
    with reusing():
        for t, want in ((t1, want1), (t2, want2), (t1, want1)):
            got = _sample_at(ch, t, False, _IndexCache(t), 0.0)
            np.testing.assert_array_equal(got[0], want[0])
            np.testing.assert_array_equal(got[1], want[1])


@pytest.mark.parametrize("shifted", [False, True])
def test_the_draws_of_a_moved_channel_share_its_timestamps_searches(blocked, monkeypatch, shifted: bool) -> None:
    """Two re-runs that move the torque's values (a gain, an offset: lazy copies sharing its time index) read their
    own values at every block, the very blocks computed without the store, while the searches among its timestamps
    (``_block_at``) ran once, for the channel the copies were made from; the other channels' blocks come from the
    store."""
    names = [*NAMES, "gear_actual"] if "gear_actual" in blocked else list(NAMES)
    shifts = {c.source: ClockShift(0.0123, -3e-5) for c in blocked.channels.values()} if shifted else None
    draws = [perturbed(blocked, Component("em_torque_nm.gain", ("em_torque_nm",), "gain", 0.01)),
             perturbed(blocked, Component("em_torque_nm.offset", ("em_torque_nm",), "offset", 0.5))]
    want = [_blocks(d, names, shifts) for d in draws]
    assert not np.array_equal(want[0][2][1]["em_torque_nm"], want[1][2][1]["em_torque_nm"])
    searched: list[int] = []
    plain = rb._block_at

    def counted(ts, *rest):  # type: ignore[no-untyped-def]
        searched.append(ts.size)
        return plain(ts, *rest)

    monkeypatch.setattr(rb, "_block_at", counted)
    with reusing():
        _blocks(blocked, names, shifts)  # the nominal channels: every channel's timestamps searched once a block
        assert len(searched) == len(want[0]) * len(names)
        searched.clear()
        for d, w in zip(draws, want, strict=True):  # the moved copies: their values read, no timestamp searched
            _equal(_blocks(d, names, shifts), w)
            assert searched == []
