"""split_streams (one counting-sort pass) equals group_ids + per-stream record copies, on malformed and edge frames."""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.chain.decoding import BusLoad, group_ids
from benchtwin.chain.streams import dlc_histogram, split_streams
from benchtwin.wire.frames import FRAME_DTYPE
from benchtwin.wire.merge import take_frames


def _old(frames: np.ndarray, known: list[int]) -> tuple[dict, dict]:
    """The acquisition's path before split_streams: group_ids, then each stream's records gathered and its columns
    copied out (bus 01c45a7's ``Acquisition._decode_bus``)."""
    groups, unknown = group_ids(frames, known)
    out = {}
    for cid, idx in groups.items():
        mine = take_frames(frames, idx)
        out[cid] = (np.ascontiguousarray(mine["timestamp"]), np.ascontiguousarray(mine["dlc"]),
                    mine["data"].copy().view("<u8")[:, 0])
    return out, unknown


def _frames(n: int, rng: np.random.Generator, ids: np.ndarray) -> np.ndarray:
    f = np.zeros(n, FRAME_DTYPE)
    f["timestamp"] = np.sort(rng.uniform(0, 10, n))
    f["arbitration_id"] = rng.choice(ids, n)
    f["is_extended"] = rng.random(n) < 0.05  # extended frames: unknown whatever their identifier
    f["dlc"] = rng.choice(np.array([0, 1, 7, 8, 9, 15, 255], np.uint8), n)  # wrong and out-of-range lengths
    f["data"] = rng.integers(0, 256, (n, 8), dtype=np.uint8)
    return f


def _assert_same(frames: np.ndarray, known: list[int]) -> None:
    old, old_unknown = _old(frames, known)
    new = split_streams(frames, known)
    assert new.unknown == old_unknown
    assert sorted(new.bounds) == sorted(old)
    for cid, (t, dlc, words) in old.items():
        nt, nd, nw = new.stream(cid)
        assert nt.dtype == t.dtype and nd.dtype == dlc.dtype and nw.dtype == words.dtype
        np.testing.assert_array_equal(nt.view(np.uint64), t.view(np.uint64))  # bits: NaN and -0.0 too
        np.testing.assert_array_equal(nd, dlc)
        np.testing.assert_array_equal(nw, words)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_split_equals_group_and_copy_on_mixed_traffic(seed: int) -> None:
    rng = np.random.default_rng(seed)
    # known ids, unknown standard ids, 0x7FF, 0x800 and above, 29-bit ids
    ids = np.array([0x0, 0x100, 0x101, 0x102, 0x3C1, 0x7FF, 0x800, 0x801, 0x1FFFFFFF, 0x12345, 0x555], np.uint32)
    f = _frames(5000, rng, ids)
    f["timestamp"][::97] = np.nan  # a damaged time stamp: carried as it is
    f["timestamp"][5] = -0.0
    _assert_same(f, [0x0, 0x100, 0x101, 0x102, 0x3C1, 0x7FF])


def test_split_keeps_table_order_when_times_go_back() -> None:
    rng = np.random.default_rng(3)
    f = _frames(2000, rng, np.array([0x100, 0x200, 0x300], np.uint32))
    f["timestamp"] = rng.uniform(0, 1, 2000)  # not sorted: each stream in the table's order, not by time
    _assert_same(f, [0x100, 0x200])


def test_split_edge_tables() -> None:
    empty = np.zeros(0, FRAME_DTYPE)
    _assert_same(empty, [0x100])
    s = split_streams(empty, [0x100])
    assert s.bounds == {} and s.unknown == {} and s.t.size == 0
    one = np.zeros(1, FRAME_DTYPE)
    one["arbitration_id"] = 0x100
    _assert_same(one, [0x100])
    _assert_same(one, [])  # no decoder: every frame unknown
    ext = np.zeros(3, FRAME_DTYPE)
    ext["arbitration_id"], ext["is_extended"] = 0x100, True  # an extended frame with a known 11-bit value
    _assert_same(ext, [0x100])
    assert split_streams(ext, [0x100]).unknown == {0x100: 3}


def test_split_of_a_strided_table() -> None:
    rng = np.random.default_rng(4)
    f = _frames(3001, rng, np.array([0x100, 0x200, 0x7FF, 0x900], np.uint32))
    _assert_same(f[::3], [0x100, 0x200, 0x7FF])  # not contiguous: the columns read through a copy
    _assert_same(f[100:2000], [0x200])


def test_split_refuses_non_standard_known_ids_and_other_dtypes() -> None:
    f = np.zeros(2, FRAME_DTYPE)
    with pytest.raises(ValueError, match="standard"):
        split_streams(f, [0x800])
    with pytest.raises(ValueError, match="FRAME_DTYPE"):
        split_streams(np.zeros(2, np.float64), [0x100])
    with pytest.raises(ValueError, match="FRAME_DTYPE"):
        dlc_histogram(np.zeros(2, np.float64))


def test_dlc_histogram_equals_bincount() -> None:
    rng = np.random.default_rng(5)
    f = _frames(4000, rng, np.array([0x100, 0x1FFFFFFF], np.uint32))
    f["dlc"] = rng.integers(0, 256, 4000)
    key = (np.minimum(f["dlc"], 15).astype(np.uint8) << 1) | f["is_extended"].view(np.uint8)
    np.testing.assert_array_equal(dlc_histogram(f), np.bincount(key, minlength=32))
    np.testing.assert_array_equal(dlc_histogram(f[::7]), np.bincount(key[::7], minlength=32))
    load = BusLoad(500_000)
    load.add(f[:1000])
    load.add(f[1000:])
    assert load.n == 4000 and load.hist.sum() == 4000
