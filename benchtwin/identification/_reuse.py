"""What the type B re-runs of the methods share: results computed from channels that a re-run does not move.

Each re-run of :func:`~benchtwin.identification.uncertainty.propagate_type_b` gets a Recording in which one
component's channels are new arrays and every other channel is the very same object as in the nominal run. The grid
values of an unmoved channel (:func:`~benchtwin.identification._signals.gather`) and its means over a set of steady
windows (:meth:`~benchtwin.identification.steady.SteadyWindows.raw_average`) are then the same numbers in every
re-run. Inside :func:`reusing` they are computed once and handed out again (as copies: callers may write into them),
keyed by the identity of the source arrays and by everything else the result depends on. The source arrays are held
weakly: the entries of a re-run's moved channel go with it, so the store holds results of channels that are alive
only (each weak reference's callback names its entry, dropped at the next insertion: not a scan of the whole store
per insertion, which made a campaign's identification grow with the square of its windows). Outside it nothing is
kept. A result is the same with or without the store: it only skips recomputing it.

The store assumes the channels' arrays are not changed in place while it is open (the re-runs only read them: a
perturbed channel is a new array, :func:`~benchtwin.identification.uncertainty.perturbed`).
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np

__all__ = ["reused", "reusing"]

T = TypeVar("T")

_lock = threading.Lock()
_store: dict[Hashable, tuple[tuple[weakref.ref[np.ndarray], ...], Any]] | None = None
#: keys of the store's entries one of whose arrays has gone (appended by the weak references' callbacks, which take
#: no lock: an array may go while this thread holds it)
_dead: list[Hashable] = []


@contextmanager
def reusing() -> Iterator[None]:
    """Keep shared results for the duration of the block (re-entrant: an inner block uses the outer store)."""
    global _store, _dead
    with _lock:
        outer = _store is not None
        if not outer:
            _store, _dead = {}, []
    try:
        yield
    finally:
        if not outer:
            with _lock:
                _store, _dead = None, []


def _copy(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x.copy()
    if isinstance(x, tuple):
        return tuple(_copy(v) for v in x)
    return x


def reused(kind: str, arrays: tuple[np.ndarray, ...], key: Hashable, compute: Callable[[], T]) -> T:
    """``compute()``, or a copy of what it gave before for the same source arrays and key (inside :func:`reusing`).

    Parameters
    ----------
    kind:
        Name of the computation.
    arrays:
        The source arrays the result is a function of (compared by identity, held weakly).
    key:
        Everything else the result depends on (hashable; arrays as bytes).
    compute:
        Computes the result (arrays, or tuples of arrays and plain values).
    """
    store, dead = _store, _dead
    if store is None:
        return compute()
    full = (kind, tuple(id(a) for a in arrays), key)
    hit = store.get(full)
    if hit is not None and all(r() is a for r, a in zip(hit[0], arrays, strict=True)):
        return _copy(hit[1])
    out = compute()
    with _lock:
        if _store is store:
            # entries of arrays that are gone (a finished re-run's moved channel) go too: those the callbacks named
            while dead:
                k = dead.pop()
                entry = store.get(k)
                if entry is not None and any(r() is None for r in entry[0]):
                    del store[k]
            store[full] = (tuple(weakref.ref(a, lambda _r, k=full: dead.append(k)) for a in arrays), _copy(out))
    return out
