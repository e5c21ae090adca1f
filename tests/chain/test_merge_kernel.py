"""The k-way merge kernel of ``merge_frames`` against the reference merges, record for record, on edge cases."""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.wire.frames import FRAME_DTYPE
from benchtwin.wire.merge import _kway_order, concat_frames, merge_frames, take_frames


def _frames(t: np.ndarray, ident: int, rng: np.random.Generator) -> np.ndarray:
    f = np.zeros(t.size, dtype=FRAME_DTYPE)
    f["timestamp"] = t
    f["arbitration_id"] = ident
    f["is_extended"] = rng.random(t.size) < 0.5
    f["dlc"] = rng.integers(0, 9, t.size)
    f["data"] = rng.integers(0, 256, (t.size, 8))
    return f


def _stable_sort(parts: list[np.ndarray]) -> np.ndarray:
    """The definition: all records, stably sorted by time (equal times keep the parts' order)."""
    allf = concat_frames(parts)
    return take_frames(allf, np.argsort(allf["timestamp"], kind="stable"))


def _kway_reference(parts: list[np.ndarray]) -> np.ndarray:
    """The previous merge: every record joined, the order from ``_kway_order``, one gather."""
    lens = np.array([len(p) for p in parts], dtype=np.int64)
    ends = np.cumsum(lens)
    return take_frames(concat_frames(parts), _kway_order(np.concatenate([p["timestamp"] for p in parts]),
                                                         ends - lens, ends))


def _cases() -> dict[str, list[np.ndarray]]:
    rng = np.random.default_rng(7)
    grid = np.round(np.arange(0.0, 2.0, 0.01), 2)
    return {
        # every part on the same instants: only the tie rule orders them
        "ties": [_frames(grid, k, rng) for k in range(5)],
        # ties between some parts, with empty parts between
        "ties_and_empty": [_frames(grid[::2], 1, rng), _frames(np.zeros(0), 2, rng), _frames(grid[::3], 3, rng),
                           _frames(np.zeros(0), 4, rng), _frames(grid, 5, rng)],
        # interleaved runs of different rates and lengths, nine parts (a bus of many devices)
        "interleaved": [_frames(np.sort(rng.uniform(0, 10, n)), k, rng)
                        for k, n in enumerate((5000, 4000, 1, 300, 2, 7000, 50, 1000, 3))],
        # one run after the other except for one frame of overlap
        "overlap_one": [_frames(np.arange(0.0, 1.0, 0.1), 1, rng), _frames(np.arange(0.9, 2.0, 0.1), 2, rng)],
        # a part given in reverse (sorted first), one part a strided view, two parts of one frame each
        "unsorted_strided": [_frames(np.arange(5.0, 0.0, -0.5), 1, rng), _frames(np.arange(0.0, 6.0, 0.25), 2,
                                                                                   rng)[::2],
                             _frames(np.array([2.5]), 3, rng), _frames(np.array([2.5]), 4, rng)],
        "two_equal_single": [_frames(np.array([1.0]), 1, rng), _frames(np.array([1.0]), 2, rng)],
    }


@pytest.mark.parametrize("name", list(_cases()))
def test_merge_frames_equals_stable_sort_record_for_record(name: str) -> None:
    parts = _cases()[name]
    got = merge_frames(parts)
    want = _stable_sort([p if np.all(np.diff(p["timestamp"]) >= 0) else _stable_sort([p]) for p in parts])
    assert got.dtype == FRAME_DTYPE and got.shape == want.shape
    assert got.tobytes() == want.tobytes()
    sorted_parts = [_stable_sort([p]) for p in parts if len(p)]
    if len(sorted_parts) > 1:
        assert got.tobytes() == _kway_reference(sorted_parts).tobytes()


def test_merge_frames_does_not_alias_or_change_its_parts() -> None:
    parts = _cases()["interleaved"]
    before = [p.copy() for p in parts]
    got = merge_frames(parts)
    got["data"] = 0
    for p, b in zip(parts, before):
        assert p.tobytes() == b.tobytes()


def test_merge_frames_empty_and_single() -> None:
    rng = np.random.default_rng(1)
    assert merge_frames([]).shape == (0,) and merge_frames([]).dtype == FRAME_DTYPE
    one = _frames(np.arange(0.0, 1.0, 0.1), 1, rng)
    assert merge_frames([np.zeros(0, FRAME_DTYPE), one]).tobytes() == one.tobytes()
