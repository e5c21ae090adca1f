"""The type B re-runs on both cores: a worker process forked for them takes units from the tail of the list.

``validate`` (with :data:`TYPE_B_WORKER` on) hands :func:`~benchtwin.identification.run.identify_all` a
:class:`ForkedShare` (a :class:`~benchtwin.identification.type_b_share.TypeBShare`). When
:func:`~benchtwin.identification.uncertainty.propagate_type_b` has its list of re-run units (after the nominal
identification), :meth:`ForkedShare.start` forks a worker: it inherits the nominal result, the plan's functions and
the Recording (the chunk files it reads from are read by position, ``os.preadv``: the two processes never move a
shared file offset). The worker claims units from the tail, the parent from the head on its threads, one unit at a
time under one lock in shared memory, so each unit runs once and both end together; each unit's result (per
parameter its changes, numbers and text) is pickled back through a pipe (:class:`~benchtwin.validation.beside.Beside`)
and the contributions are put together in the plan's order: the budget is the same bit for bit as in line.

A unit that raises in the worker is raised by the parent's :meth:`ForkedShare.collect` (the same type and message); a
worker that dies is a :class:`~benchtwin.validation.beside.SideStageError` there, never a wait; leaving the context
(the parent's own failure) ends a worker still running.
"""

from __future__ import annotations

import sys
from contextlib import ExitStack
from typing import Any

from benchtwin.identification.type_b_share import TailJob
from benchtwin.validation.beside import Beside, side_stages_beside

__all__ = ["HEAD_THREADS", "TYPE_B_WORKER", "ForkedShare", "type_b_worker_beside"]

#: whether ``validate`` forks a worker for the type B re-runs (where the side stages fork: a campaign short enough for
#: the process tree's memory, :data:`~benchtwin.validation.beside.SIDE_MAX_CAMPAIGN_S`). Off: on their own the paper
#: campaign's re-runs take 6.4 s instead of 11.7 s with it, but whole ``validate --out`` processes on this shared
#: 2-core machine (load 2.2-2.8) showed no gain (6 pairs with main, median +1.6 s, CPU the same: benchmarks/RESULTS.md,
#: branch tbpool); to be measured on a quiet machine before it is turned on
TYPE_B_WORKER: bool = False
#: threads the parent runs its units on while the worker runs: one (the type B re-runs of the paper campaign alone,
#: benchmarks/bench_type_b_worker.py: 6.40 s with one, 6.65 s with two, 11.69 s in line on two; in ``validate`` the
#: side stages' child shares the cores too, and a second thread of the parent only adds to the GIL's contention)
HEAD_THREADS = 1

#: the message key of the list of units the worker ran (each unit's result under ``"type_b:<unit>"``)
_UNITS = "type_b"


def type_b_worker_beside(*, streamed: bool, families: Any, campaign_s: float) -> bool:
    """Whether ``validate`` forks a :class:`ForkedShare` worker: :data:`TYPE_B_WORKER`, and a streamed whole campaign
    of at most :data:`~benchtwin.validation.beside.SIDE_MAX_CAMPAIGN_S` (see
    :func:`~benchtwin.validation.beside.side_stages_beside`)."""
    return TYPE_B_WORKER and side_stages_beside("fork", streamed=streamed, families=families, campaign_s=campaign_s)


class ForkedShare:
    """The tail of the type B units in a worker process forked when the units are known; a context manager (left: a
    worker still running is ended).

    Parameters
    ----------
    threads:
        Threads the parent runs the head on (default :data:`HEAD_THREADS`).
    """

    def __init__(self, threads: int | None = None) -> None:
        self.threads = HEAD_THREADS if threads is None else max(1, int(threads))
        self._stack = ExitStack()
        self.worker: Beside | None = None

    def __enter__(self) -> ForkedShare:
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stack.__exit__(*exc)

    def start(self, n_units: int, tail: TailJob) -> None:
        """Fork the worker with the counters of the units claimed (head 0, tail ``n_units``)."""
        import multiprocessing

        ctx = multiprocessing.get_context("fork")
        self._lock = ctx.Lock()
        self._lo, self._hi = ctx.RawValue("q", 0), ctx.RawValue("q", n_units)
        self._tail = tail
        self.worker = self._stack.enter_context(Beside(self._run_tail, "fork"))

    def claim_head(self, end: int) -> int | None:
        """The next unit from the head, below ``end`` and not claimed by the worker; None if there is none."""
        with self._lock:
            i = self._lo.value
            if i < min(end, self._hi.value):
                self._lo.value = i + 1
                return i
        return None

    def _claim_tail(self) -> int | None:
        with self._lock:
            i = self._hi.value - 1
            if i >= self._lo.value:
                self._hi.value = i
                return i
        return None

    def _run_tail(self, channel: Any) -> None:
        """In the worker: the units from the tail until the head meets them, each result sent as it comes."""
        ran: list[int] = []

        def send(i: int, result: Any) -> None:
            channel.put(f"{_UNITS}:{i}", result)
            ran.append(i)

        self._tail(self._claim_tail, send)
        channel.put(_UNITS, ran)

    def collect(self) -> dict[int, Any]:
        """The worker's units' results (waits for them; raises the worker's failure); the worker has ended after."""
        assert self.worker is not None
        try:
            ran = self.worker.get(_UNITS)
            got = {i: self.worker.get(f"{_UNITS}:{i}") for i in ran}
        except BaseException:
            self._stack.__exit__(*sys.exc_info())  # ends the worker (it failed, or sent something else)
            raise
        self._stack.close()  # the worker has sent everything: it is ending
        return got
