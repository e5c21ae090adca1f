"""The whole-recording passes read only the columns they use; a channel in one block is read once by the gap pass;
the clock offsets found beside the other passes are those found in line after them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchtwin.chain.acquisition import Acquisition
from benchtwin.chain.alignment import clock_offsets
from benchtwin.chain.blocks import ChannelBlocks
from benchtwin.chain.channel_store import ChannelStore
from benchtwin.chain.faults import _period, _period_of
from benchtwin.recording import Channel, Recording


def _stored(tmp_path: Path, n: int, seed: int = 3) -> tuple[Recording, ChannelStore, np.ndarray, np.ndarray,
                                                           np.ndarray]:
    """A channel of ``n`` samples with irregular steps, appended in three chunks to a store on disk."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.001, 0.003, n) + np.where(rng.random(n) < 0.01, 0.05, 0.0))
    v = rng.normal(size=n)
    f = rng.integers(0, 4, n).astype(np.uint16)
    store = ChannelStore(tmp_path)
    for a, b in ((0, n // 3), (n // 3, n // 2), (n // 2, n)):
        store.append("x", "V", "dev", None, (0,), t[a:b], v[a:b], f[a:b])
    rec = Recording()
    rec.add(store.channel("x"))
    return rec, store, t, v, f


@pytest.mark.parametrize("n", [10, 1000, 190_001, 250_001])
def test_the_period_of_one_block_is_the_period_read_by_blocks(tmp_path: Path, n: int) -> None:
    """_period_of(t) (the gap pass's channel in one block) gives _period's float, bit for bit, whatever the blocks
    _period reads (above 100,001 samples every k-th step is taken: the same ones)."""
    rec, store, t, _v, _f = _stored(tmp_path, n)
    got = _period_of(t)
    for size in (7, 997, 1 << 20):
        assert np.float64(_period(ChannelBlocks(rec, store, size), "x", n)).tobytes() == np.float64(got).tobytes()
    store.cleanup()


@pytest.mark.parametrize("on_disk", [True, False])
def test_blocks_give_the_columns_asked_for(tmp_path: Path, on_disk: bool) -> None:
    """Each column asked for equals the whole read's; the others are None; flags written back with ``write``."""
    rec, store, t, v, f = _stored(tmp_path, 5000)
    if not on_disk:
        store.cleanup()
        rec, store = Recording(), None
        rec.add(Channel("x", "V", t, v, f.copy(), "dev"))
    view = ChannelBlocks(rec, store, 997)
    for columns in ("t", "f", "tv", "vf", "tf", "tvf"):
        for a, *arrays in view.blocks("x", columns=columns):
            for c, got, whole in zip("tvf", arrays, (t, v, f)):
                if c in columns:
                    assert got.tobytes() == whole[a:a + got.shape[0]].tobytes(), (columns, c, a)
                else:
                    assert got is None, (columns, c)
        r = view.read("x", 100, 3000, columns)
        for c, got, whole in zip("tvf", r, (t, v, f)):
            assert (got.tobytes() == whole[100:3000].tobytes()) if c in columns else got is None
    assert view.sample("x", 0) == t[0] and view.sample("x", -1) == t[-1] and view.sample("x", 1234) == t[1234]
    for _a, _t, _v, fl in view.blocks("x", write=True, columns="tf"):
        fl |= 0x100
    back = np.concatenate([b[3] for b in view.blocks("x", columns="f")])
    assert np.array_equal(back, f | 0x100)
    with pytest.raises(ValueError, match="flags"):
        next(view.blocks("x", write=True, columns="t"))


class _InLine:
    """The clock offsets found in line when result() is called (finish() before they were found beside)."""

    def __init__(self, view: ChannelBlocks) -> None:
        pass

    def join(self) -> None:
        pass

    def result(self, view: ChannelBlocks, detail: dict) -> tuple[dict, dict]:
        return clock_offsets(view, detail)


@pytest.mark.parametrize("setup_name", ["paper", "faults"])
def test_finish_with_the_offsets_beside_equals_finish_in_line(quick_inputs, tmp_path: Path, monkeypatch,
                                                              setup_name: str) -> None:
    """The quick campaign on the paper and the faults setups (its dyno log cut short, stuck and clipped outputs,
    lost and late polls), chunked and on disk as validate acquires it: every channel (timestamps, values, flags),
    the clock offsets, drifts, faults and every other meta key as with the offsets found in line after the
    other passes."""
    from test_chunked_acquisition import THROUGH_FAULTS, differences

    from benchtwin.chain import acquisition
    from benchtwin.config import load_setup

    data = quick_inputs[setup_name]
    got = {}
    for way in ("beside", "in line"):
        if way == "in line":
            monkeypatch.setattr(acquisition, "OffsetsBeside", _InLine)
        acq = Acquisition(load_setup(setup_name), tmp_path / way / "r.mf4", keep_chunks=True)
        for chunk in data.split_by_time(THROUGH_FAULTS):
            acq.feed(chunk)
        got[way] = acq.finish()
    assert got["beside"].meta["clock_offsets_s"]  # offsets were found: the comparison covers them
    assert differences(got["beside"], got["in line"]) == []
    for rec in got.values():
        rec.close()


def test_the_offsets_are_found_again_when_a_pair_channel_changed_meanwhile() -> None:
    """A pair channel replaced (the dyno speed 0.25 s later) or added (the shaft torque) after the thread started:
    result() gives clock_offsets of the finished view, not the thread's; a channel of no pair added changes
    nothing (the thread's result, detail included)."""
    from test_clock_windows import _synthetic

    from benchtwin.chain.offsets_beside import OffsetsBeside

    channels = [ch for ch in _synthetic(0.5) if ch.name != "shaft_torque_nm"]
    shaft = next(ch for ch in _synthetic(0.5) if ch.name == "shaft_torque_nm")
    rec = Recording()
    for ch in channels:
        rec.add(ch)
    view = ChannelBlocks(rec, None, 997)
    want_detail: dict = {}
    want = clock_offsets(view, want_detail)
    assert "vehicle_can->dyno" in want[0]
    beside = OffsetsBeside(view)
    rec.add(Channel("brake_pressure_front_bar", "bar", np.arange(10.0), np.zeros(10), source="pressure"))
    detail: dict = {}
    assert beside.result(view, detail) == want and detail == want_detail
    beside = OffsetsBeside(view)
    dyno = rec.channels["dyno_speed_kmh"]
    rec.channels["dyno_speed_kmh"] = Channel(dyno.name, dyno.unit, dyno.timestamps + 0.25, dyno.values,
                                             source=dyno.source)
    got = beside.result(view, {})
    assert got == clock_offsets(view)
    # the later one's (within two steps of the correlation's 100 Hz grid)
    assert abs(got[0]["vehicle_can->dyno"] - want[0]["vehicle_can->dyno"] - 0.25) < 0.02
    beside = OffsetsBeside(view)
    rec.add(shaft)
    got = beside.result(view, {})
    assert got == clock_offsets(view) and "vehicle_can->telemetry" in got[0]
