"""The type B re-runs' shared store (``identification._reuse``): entries of arrays that are gone leave it at the next
insertion, named by their weak references' callbacks (not found by scanning every entry), and what it hands out is
what was computed for the very arrays asked about; it never holds more than its bound of bytes (once full, new
results are computed and handed out but not kept, and the first ones stay)."""

from __future__ import annotations

import gc

import numpy as np

from benchtwin.identification import _reuse
from benchtwin.identification._reuse import reused, reusing


def _mean(a: np.ndarray) -> np.ndarray:
    return np.array([a.mean()])


def test_dead_entries_go_at_the_next_insertion_and_live_ones_stay() -> None:
    with reusing():
        store = _reuse._store
        assert store is not None
        live = [np.full(4, float(k)) for k in range(300)]
        gone = [np.full(4, -1.0 - k) for k in range(300)]
        for k, a in enumerate(live + gone):
            assert reused("mean", (a,), k, lambda a=a: _mean(a))[0] == a.mean()
        assert len(store.entries) == 600
        del gone, a
        gc.collect()
        assert len(store.dead) == 300  # named by the callbacks, the store untouched until the next insertion
        assert len(store.entries) == 600
        extra = np.arange(3.0)
        reused("mean", (extra,), "x", lambda: _mean(extra))
        assert len(store.entries) == 301 and not store.dead
        # each entry is one 8-byte mean (keys of ints and a str count nothing): the bytes follow the entries
        assert _reuse.stored_bytes() == 301 * 8
        # the live ones are handed out again (a copy), not recomputed
        for k, a in enumerate(live):
            out = reused("mean", (a,), k, lambda: np.array([np.nan]))
            assert out[0] == a.mean()
    assert _reuse._store is None and _reuse.stored_bytes() == 0


def test_a_new_array_at_a_gone_one_s_address_is_computed_for_itself() -> None:
    with reusing():
        for k in range(200):  # CPython hands freed addresses out again: the same id(), another array
            a = np.full(8, float(k))
            assert reused("mean", (a,), "same key", lambda a=a: _mean(a))[0] == float(k)
            del a
        assert len(_reuse._store.entries) <= 2


def test_without_the_store_nothing_is_kept() -> None:
    a = np.ones(3)
    calls = []
    for _ in range(2):
        reused("mean", (a,), 0, lambda: calls.append(1) or _mean(a))
    assert len(calls) == 2 and _reuse._store is None


def _block_sum(t: np.ndarray, src: np.ndarray) -> np.ndarray:
    return np.full(t.size, src.sum()) + t


def test_the_store_never_holds_more_than_its_bound(monkeypatch) -> None:
    # a re-run's walk over a long log: one result of 1,000 float64 (8,000 bytes) per block of grid times, keyed by
    # the block's fingerprint (a 32-byte digest); a bound of 5 results' worth (40,200 bytes) keeps five, never more
    monkeypatch.setattr(_reuse, "STORE_BYTES", 5 * (8_000 + 32) + 40)
    src = np.arange(10.0)
    blocks = [np.arange(1_000.0) + 1_000 * k for k in range(20)]
    calls: list[int] = []

    def walk() -> list[np.ndarray]:
        out = []
        for k, t in enumerate(blocks):
            out.append(reused("block", (src,), (t.size, _reuse.fingerprint(t)),
                              lambda k=k, t=t: calls.append(k) or _block_sum(t, src)))
            assert _reuse.stored_bytes() <= _reuse.STORE_BYTES
        return out

    with reusing():
        first = walk()
        assert _reuse.stored_bytes() == 5 * (8_000 + 32) and len(_reuse._store.entries) == 5
        calls.clear()
        second = walk()
        # the first five blocks are handed out again, the other fifteen computed again (as without the store)
        assert calls == list(range(5, 20))
    for a, b, t in zip(first, second, blocks, strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, _block_sum(t, src))


def test_a_fingerprint_tells_arrays_apart_by_contents_shape_and_dtype() -> None:
    a = np.arange(6.0)
    assert _reuse.fingerprint(a) == _reuse.fingerprint(a.copy())
    assert _reuse.fingerprint(a) != _reuse.fingerprint(a + 1e-12 * (np.arange(6) == 5))
    assert _reuse.fingerprint(a) != _reuse.fingerprint(a.reshape(2, 3))
    assert _reuse.fingerprint(a) != _reuse.fingerprint(a.astype(np.float32))
    assert _reuse.fingerprint(a[::2]) == _reuse.fingerprint(np.array([0.0, 2.0, 4.0]))  # strided: by its numbers
