"""The type B re-runs' shared store (``identification._reuse``): entries of arrays that are gone leave it at the next
insertion, named by their weak references' callbacks (not found by scanning every entry), and what it hands out is
what was computed for the very arrays asked about."""

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
        assert len(store) == 600
        del gone, a
        gc.collect()
        assert len(_reuse._dead) == 300  # named by the callbacks, the store untouched until the next insertion
        assert len(store) == 600
        extra = np.arange(3.0)
        reused("mean", (extra,), "x", lambda: _mean(extra))
        assert len(store) == 301 and not _reuse._dead
        # the live ones are handed out again (a copy), not recomputed
        for k, a in enumerate(live):
            out = reused("mean", (a,), k, lambda: np.array([np.nan]))
            assert out[0] == a.mean()
    assert _reuse._store is None and not _reuse._dead


def test_a_new_array_at_a_gone_one_s_address_is_computed_for_itself() -> None:
    with reusing():
        for k in range(200):  # CPython hands freed addresses out again: the same id(), another array
            a = np.full(8, float(k))
            assert reused("mean", (a,), "same key", lambda a=a: _mean(a))[0] == float(k)
            del a
        assert len(_reuse._store) <= 2


def test_without_the_store_nothing_is_kept() -> None:
    a = np.ones(3)
    calls = []
    for _ in range(2):
        reused("mean", (a,), 0, lambda: calls.append(1) or _mean(a))
    assert len(calls) == 2 and _reuse._store is None
