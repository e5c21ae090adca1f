"""prefetch: the producer's items in order, made on another thread, its errors raised in place, stopped early."""

from __future__ import annotations

import itertools
import threading

import pytest

from benchtwin.chain.prefetch import prefetch


def test_items_in_order_made_on_another_thread():
    made_on = set()

    def produce():
        for k in range(50):
            made_on.add(threading.get_ident())
            yield k

    assert list(prefetch(produce(), depth=3)) == list(range(50))
    assert made_on and threading.get_ident() not in made_on


def test_producer_error_is_raised_where_it_occurred():
    def produce():
        yield from range(3)
        raise RuntimeError("plant left its domain")

    got = []
    with pytest.raises(RuntimeError, match="plant left its domain"):
        for item in prefetch(produce()):
            got.append(item)
    assert got == [0, 1, 2]


def test_early_stop_bounds_the_lookahead_and_closes_the_producer():
    made = itertools.count()
    closed = threading.Event()

    def produce():
        try:
            while True:
                yield next(made)
        finally:
            closed.set()

    items = prefetch(produce(), depth=1)
    assert next(items) == 0
    items.close()  # the consumer stops: the producer is stopped, closed, and its thread joined
    assert closed.is_set()
    # taken (1) + queued (depth 1) + the one it was putting when stopped (1)
    assert next(made) <= 3


def test_depth_below_one_is_refused():
    with pytest.raises(ValueError, match="depth"):
        list(prefetch(range(3), depth=0))
