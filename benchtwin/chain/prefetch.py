"""Run a producer one step ahead on a thread: the next item is made while the caller works on this one.

:func:`prefetch` wraps any iterator (the plant's tests from :func:`~benchtwin.emulator.iter_campaign`, the
delivered chunks of :func:`~benchtwin.chain.delivery.iter_delivered`) so a second core works on item k+1 while
the caller consumes item k. The items, their order and the exceptions are the producer's own; only where the
work runs changes. It pays where the producer or the consumer spends its time outside the GIL (numba
``nogil`` kernels, numpy on large arrays, compression, file writes).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator
from typing import TypeVar

__all__ = ["prefetch"]

T = TypeVar("T")

_END = object()


def prefetch(items: Iterable[T], depth: int = 1, *, name: str = "prefetch") -> Iterator[T]:
    """Yield ``items`` in order while a thread makes up to ``depth`` items ahead.

    Parameters
    ----------
    items:
        The producer (any iterable; it is iterated on the helper thread only).
    depth:
        Items made ahead of the one being consumed (each held in memory until taken).
    name:
        Name of the helper thread.

    Yields
    ------
    The items of ``items``, in order. An exception raised by the producer is raised here, at the point in the
    sequence where it occurred. Closing the generator early (``break``, an exception in the consumer) stops the
    producer once the item it is making is made, closes it (a generator's cleanup runs) and waits for the
    thread.

    Raises
    ------
    ValueError
        If ``depth`` is below 1.
    """
    if depth < 1:
        raise ValueError(f"prefetch depth must be at least 1, got {depth}")
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item: object) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        it = iter(items)
        try:
            for item in it:
                if not put((item, None)):
                    return
        except BaseException as exc:  # handed to the consumer, raised there
            put((_END, exc))
            return
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                close()  # a generator stopped early runs its cleanup on this thread, now
        put((_END, None))

    thread = threading.Thread(target=work, name=name, daemon=True)
    thread.start()
    try:
        while True:
            item, exc = q.get()
            if item is _END:
                if exc is not None:
                    raise exc
                return
            yield item
    finally:
        stop.set()
        thread.join()
