"""The whole-recording passes read only the columns they use; a channel in one block is read once by the gap pass."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

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
