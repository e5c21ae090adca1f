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

The store is bounded: it holds at most :data:`STORE_BYTES` of results (their arrays and the bytes of their keys). The
methods read a long Recording block by block, and each re-run walks the blocks in order, so the store would
otherwise keep a result per block of the whole campaign while a method's re-runs last (memory that grows with the
campaign). Once full, a new result is not kept (it is computed again by each re-run that needs it, as without the
store) and the first blocks' results stay: with re-runs that walk the blocks in the same order, dropping the oldest
instead would drop each block's result just before the next re-run asks for it. Arrays in a key (grid times, window
edges) go in as :func:`fingerprint`, a digest of their bytes, not as the bytes themselves.

A second store outlives one method: inside :func:`sharing_outputs` (one type B propagation), the output of a method
that another method runs first in its re-runs (the transmission inside the converter's) is kept per moved Recording
(:func:`moved_by`: the base Recording and the gain or offset step that moved it) by :func:`shared_output`, so the
converter's step re-run takes the transmission's output of the transmission's own re-run of that very step. A
rounding draw is not shared (the converter's draws move more roles, so its transmission inputs differ).
"""

from __future__ import annotations

import hashlib
import pickle
import threading
import weakref
from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any, TypeVar

import numpy as np

__all__ = ["OUTPUT_BYTES", "STORE_BYTES", "fingerprint", "moved_by", "only_values", "reused", "reusing",
           "shared_output", "sharing_outputs", "stored_bytes", "values_only"]

T = TypeVar("T")

#: most bytes of results (arrays and key bytes) the store holds at once; the paper campaign's re-runs keep about
#: 13 MB per method at most, so its results are all kept, and a campaign ten times as long keeps this much
STORE_BYTES = 32 * 2**20

_lock = threading.Lock()


class _Store:
    """The entries (key -> weak references to the source arrays, result, bytes) and their total bytes."""

    def __init__(self) -> None:
        self.entries: dict[Hashable, tuple[tuple[weakref.ref[np.ndarray], ...], Any, int]] = {}
        #: keys of entries one of whose arrays has gone (appended by the weak references' callbacks, which take no
        #: lock: an array may go while this thread holds it)
        self.dead: list[Hashable] = []
        self.nbytes = 0

    def drop_dead(self) -> None:
        """Remove the entries the callbacks named whose arrays are gone (with the lock held)."""
        while self.dead:
            k = self.dead.pop()
            entry = self.entries.get(k)
            if entry is not None and any(r() is None for r in entry[0]):
                del self.entries[k]
                self.nbytes -= entry[2]


_store: _Store | None = None

#: whether the methods run here are a type B re-run, whose caller reads the parameters' values only (per thread)
_values_only: ContextVar[bool] = ContextVar("values_only", default=False)


@contextmanager
def values_only() -> Iterator[None]:
    """Run the block as a type B re-run: its caller takes the change of each parameter's value, nothing else.

    Work whose only output is a parameter's standard error or interval (the BSFC map's bootstrap, the converter's
    calibration budget) may then be left out (:func:`only_values`); every value stays the same. Per thread (and
    re-entrant): the re-runs on the type B threads do not change the nominal run's.
    """
    token = _values_only.set(True)
    try:
        yield
    finally:
        _values_only.reset(token)


def only_values() -> bool:
    """Whether the methods run inside :func:`values_only` (a type B re-run): standard errors go unread."""
    return _values_only.get()


@contextmanager
def reusing() -> Iterator[None]:
    """Keep shared results for the duration of the block (re-entrant: an inner block uses the outer store)."""
    global _store
    with _lock:
        outer = _store is not None
        if not outer:
            _store = _Store()
    try:
        yield
    finally:
        if not outer:
            with _lock:
                _store = None


def stored_bytes() -> int:
    """Bytes of results the open store holds (0 outside :func:`reusing`)."""
    store = _store
    return 0 if store is None else store.nbytes


def fingerprint(a: np.ndarray) -> tuple[tuple[int, ...], str, bytes]:
    """A key for an array's contents: its shape, dtype and a 256-bit digest of its bytes.

    Parameters
    ----------
    a:
        The array (e.g. a block's grid times).

    Returns
    -------
    tuple
        ``(shape, dtype.str, digest)``; two arrays with the same fingerprint hold the same numbers (but with
        probability about 2**-256).
    """
    a = np.ascontiguousarray(a)
    return a.shape, a.dtype.str, hashlib.blake2b(a.data, digest_size=32).digest()


def _nbytes(x: Any) -> int:
    if isinstance(x, np.ndarray):
        return x.nbytes
    if isinstance(x, tuple):
        return sum(_nbytes(v) for v in x)
    if isinstance(x, bytes | bytearray):
        return len(x)
    return 0


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
    store = _store
    if store is None:
        return compute()
    full = (kind, tuple(id(a) for a in arrays), key)
    hit = store.entries.get(full)
    if hit is not None and all(r() is a for r, a in zip(hit[0], arrays, strict=True)):
        return _copy(hit[1])
    out = compute()
    with _lock:
        if _store is store:
            # entries of arrays that are gone (a finished re-run's moved channel) go too: those the callbacks named
            store.drop_dead()
            size = _nbytes(out) + _nbytes(key)
            old = store.entries.get(full)
            if old is not None:  # the same key of arrays that went (their ids used again): replaced
                del store.entries[full]
                store.nbytes -= old[2]
            if store.nbytes + size <= STORE_BYTES:
                dead = store.dead
                refs = tuple(weakref.ref(a, lambda _r, k=full: dead.append(k)) for a in arrays)
                store.entries[full] = (refs, _copy(out), size)
                store.nbytes += size
    return out


#: most bytes (pickled) of method outputs :func:`shared_output` keeps in one :func:`sharing_outputs` block; the paper
#: campaign's transmission output pickles to about 115 kB, and its 4 step re-runs shared with the converter's keep
#: 0.46 MB
OUTPUT_BYTES = 8 * 2**20


class _Outputs:
    """Pickled method outputs by key, the objects their keys name by identity (held: their ids stay theirs), and
    their total bytes."""

    def __init__(self) -> None:
        self.entries: dict[Hashable, tuple[bytes, tuple[Any, ...]]] = {}
        self.nbytes = 0


_outputs: _Outputs | None = None

#: what moved the Recording of the type B step re-run running here (per thread; None: not such a re-run)
_moved: ContextVar[Hashable | None] = ContextVar("moved_by", default=None)


@contextmanager
def sharing_outputs() -> Iterator[None]:
    """Keep the outputs of the methods run by :func:`shared_output` for the duration of the block (re-entrant).

    One :func:`~benchtwin.identification.uncertainty.propagate_type_b` call opens it: a method that another one runs
    first (the transmission inside the converter's re-runs) then runs once per moved Recording, not once per
    method that re-runs it.
    """
    global _outputs
    with _lock:
        outer = _outputs is not None
        if not outer:
            _outputs = _Outputs()
    try:
        yield
    finally:
        if not outer:
            with _lock:
                _outputs = None


@contextmanager
def moved_by(key: Hashable) -> Iterator[None]:
    """Run the block as a type B re-run on the base Recording moved as ``key`` says (the same key: the very same
    channels' values, e.g. the base Recording's id, a component's name, roles, kind and step)."""
    token = _moved.set(key)
    try:
        yield
    finally:
        _moved.reset(token)


def shared_output(name: str, key: Hashable, held: tuple[Any, ...], compute: Callable[[], T]) -> T:
    """``compute()``, or a copy of what it gave before for the same method ``name``, ``key`` and moved Recording.

    Only inside :func:`sharing_outputs` and a :func:`moved_by` block: elsewhere (the nominal run, a rounding draw,
    no store) it computes. ``key`` holds everything else the output depends on; ``held`` are objects named in it by
    ``id`` (kept alive with the entry, so an id cannot name another object meanwhile). The output is kept pickled
    (a copy handed out is unpickled: callers may change it) while the outputs' bytes stay within
    :data:`OUTPUT_BYTES`; one that does not pickle is not kept.
    """
    store = _outputs
    moved = _moved.get()
    if store is None or moved is None:
        return compute()
    full = (name, moved, key)
    hit = store.entries.get(full)
    if hit is not None:
        return pickle.loads(hit[0])  # type: ignore[no-any-return]
    out = compute()
    try:
        blob = pickle.dumps(out, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:  # an output that does not pickle is computed again by each re-run that needs it
        return out
    with _lock:
        if _outputs is store and full not in store.entries and store.nbytes + len(blob) <= OUTPUT_BYTES:
            store.entries[full] = (blob, held)
            store.nbytes += len(blob)
    return out


def shared_output_bytes() -> int:
    """Bytes of outputs the open :func:`sharing_outputs` block holds (0 outside it)."""
    store = _outputs
    return 0 if store is None else store.nbytes
