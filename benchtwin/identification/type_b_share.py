"""The type B re-runs shared with another worker: this side runs them from the head of the list, the other from its
tail, each claiming one re-run unit at a time until they meet.

:func:`~benchtwin.identification.uncertainty.propagate_type_b` hands a :class:`TypeBShare` the number of its units
(one method and one component each, in the plan's order) and the function that runs units from the tail
(:meth:`TypeBShare.start`, e.g. in a process forked then: it has the nominal result and the plan's functions);
this side claims units from the head (:meth:`TypeBShare.claim_head`) on its threads (:attr:`TypeBShare.threads` of
them, or the caller's count), then takes the other side's results (:meth:`TypeBShare.collect`). Each unit's result
depends on its unit only (the rounding draws of a unit start from
:data:`~benchtwin.identification.uncertainty.RESOLUTION_SEED` wherever it runs; the re-runs' store,
:mod:`~benchtwin.identification._reuse`, only skips recomputing), and the contributions are put together in the
plan's order: the budget is the same bit for bit wherever each unit ran.

A lazy Recording (:meth:`~benchtwin.recording.Recording.open`) is worked through method by method on each side: what
one method's units read goes before the next method's (each side's memory bounded by one method). This module knows
nothing of processes: the caller's :class:`TypeBShare` does.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Protocol

from benchtwin.identification._reuse import reusing
from benchtwin.recording import Recording

__all__ = ["TailJob", "TypeBShare", "run_shared"]

#: the other side's work: ``tail(claim, send)`` runs ``send(i, result)`` for each unit ``i = claim()`` until it gives
#: None
TailJob = Callable[[Callable[[], "int | None"], Callable[[int, Any], None]], None]


class TypeBShare(Protocol):
    """Where the tail of the type B units runs and how both sides claim units."""

    #: threads this side runs its units on while the other side works (None: the caller's count)
    threads: int | None

    def start(self, n_units: int, tail: TailJob) -> None:
        """Start the other side: it runs ``tail(claim_tail, send)``, claiming units from ``n_units - 1`` down."""

    def claim_head(self, end: int) -> int | None:
        """The next unit from the head if it is below ``end`` and not claimed by the other side, else None."""

    def collect(self) -> dict[int, Any]:
        """The other side's results by unit (waits for them; raises the other side's failure)."""


def run_shared(share: TypeBShare, recording: Recording, methods: Sequence[Sequence[Any]],
               one: Callable[[Any], Any], *, threads: int, lazy: bool) -> list[Any]:
    """Every unit's result, in order, the units shared with ``share``'s other side.

    Parameters
    ----------
    share:
        Where the tail runs (:class:`TypeBShare`).
    recording:
        The Recording the units re-run (lazy: worked through method by method on each side).
    methods:
        The units per method, in the plan's order.
    one:
        Runs one unit, gives its result (the same wherever it runs).
    threads:
        Threads of this side.
    lazy:
        Drop what one method's units read before the next method's.

    Returns
    -------
    list
        The results in the units' order.
    """
    flat = [u for units in methods for u in units]
    owner = [k for k, units in enumerate(methods) for _ in units]
    ends, n = [], 0
    for units in methods:
        n += len(units)
        ends.append(n)
    if not lazy:
        ends = [n]

    def tail(claim: Callable[[], int | None], send: Callable[[int, Any], None]) -> None:
        kept = recording.loaded()  # what the other side's caller holds stays
        current = None
        with reusing():
            while (i := claim()) is not None:
                if lazy and owner[i] != current:
                    recording.drop(recording.loaded() - kept)
                    current = owner[i]
                send(i, one(flat[i]))
        recording.drop(recording.loaded() - kept)

    share.start(n, tail)
    done: dict[int, Any] = {}
    lock = threading.Lock()
    kept = recording.loaded()
    for end in ends:
        recording.drop(recording.loaded() - kept)

        def work(end: int = end) -> None:
            while (i := share.claim_head(end)) is not None:
                r = one(flat[i])
                with lock:
                    done[i] = r

        with reusing(), ThreadPoolExecutor(max_workers=max(1, threads), thread_name_prefix="type_b") as pool:
            for f in [pool.submit(work) for _ in range(max(1, threads))]:
                f.result()
    recording.drop(recording.loaded() - kept)
    done.update(share.collect())
    missing = [i for i in range(n) if i not in done]
    if missing:
        raise RuntimeError(f"type B units {missing} ran on neither side")
    return [done[i] for i in range(n)]
