"""Stages of ``validate`` run beside the identification: in a forked process, on a thread, or not at all.

The type B re-runs (``identify_all``'s :func:`~benchtwin.identification.uncertainty.propagate_type_b`) hold the GIL
nearly all the time: on the paper campaign their two threads use 0.98 of the machine's two cores. The chain checks,
the paper's estimation fits and the held-out prediction read the recording and the truth, not the type B budget, so
a forked child runs them on the other core while the parent identifies. The two exchange named messages
(:meth:`Beside.put` / :meth:`Beside.get`, each value pickled through a pipe in ``"fork"`` mode): the child sends
its results, the parent sends what the child must wait for (the parameter checks' tolerances).

An exception in the job is re-raised by the parent's :meth:`Beside.get` (the same type and message, the child's
traceback added as a note; a child that dies without a word raises :class:`SideStageError`); leaving the context
before the job has finished (the parent's own exception) ends the child, so a run never waits on a job it no
longer needs.
"""

from __future__ import annotations

import contextlib
import gc
import pickle
import queue
import threading
from collections.abc import Callable
from typing import Any, Literal

from benchtwin.errors import BenchtwinError, packed_exception

__all__ = ["MODES", "SIDE_MAX_CAMPAIGN_S", "Beside", "SideStageError", "side_stages_beside"]

#: how a job runs: ``"fork"`` a child process (the default where ``os.fork`` exists), ``"thread"`` a thread of this
#: process, ``"off"`` not beside anything (the caller runs the stages in line)
MODES = ("fork", "thread", "off")

Mode = Literal["fork", "thread", "off"]

#: seconds a child that has sent its results is given to end before it is ended
_JOIN_S = 30.0

#: the message key under which a job's exception travels
_ERROR = "\0error"
#: the message key that says the child's end of the pipe closed
_EOF = "\0eof"
#: the message key that says the job returned
_DONE = "\0done"


class SideStageError(BenchtwinError, RuntimeError):
    """A stage run beside the main one failed in a way that has no exception of its own to re-raise (the child
    process died, or its exception could not be sent)."""


class _Channel:
    """The job's end: :meth:`put` a result, :meth:`get` what the parent sends."""

    def __init__(self, side: Beside) -> None:
        self._side = side

    def put(self, key: str, value: Any) -> None:
        self._side._send_to_parent(key, value)

    def get(self, key: str) -> Any:
        return self._side._recv_from_parent(key)


class Beside:
    """Run ``job(channel)`` beside the caller; a context manager (entered: the job started).

    Parameters
    ----------
    job:
        Called with a channel (``put(key, value)``, ``get(key)``); what it returns is ignored.
    mode:
        ``"fork"`` (a forked child process; Linux) or ``"thread"``.
    """

    def __init__(self, job: Callable[[_Channel], Any], mode: Mode = "fork") -> None:
        if mode not in ("fork", "thread"):
            raise ValueError(f"mode {mode!r}: 'fork' or 'thread'")
        self.job, self.mode = job, mode
        self._got: dict[str, Any] = {}
        self._pid: int | None = None
        self._thread: threading.Thread | None = None

    # -- the parent's end ---------------------------------------------------------------------------------------
    def __enter__(self) -> Beside:
        if self.mode == "fork":
            import multiprocessing

            ctx = multiprocessing.get_context("fork")
            self._up_r, self._up_w = ctx.Pipe(duplex=False)  # child -> parent
            self._down_r, self._down_w = ctx.Pipe(duplex=False)  # parent -> child
            self._proc = ctx.Process(target=self._child_main, name="validate-beside", daemon=True)
            self._proc.start()
            self._pid = self._proc.pid
            self._up_w.close()
            self._down_r.close()
            self._up_q: queue.Queue = queue.Queue()
            # the child's messages are read as they come (a pipe holds 64 KiB: a child that sends more than that
            # while this thread identifies would wait for it), each put on the queue
            self._pump = threading.Thread(target=self._pump_main, name="validate-beside-pump", daemon=True)
            self._pump.start()
            # what the parent sends is written by a thread of its own: a value larger than the pipe holds (the
            # nominal fits for the figures) waits there until the busy child reads it, not the caller of put
            self._down_q = queue.Queue()
            self._sender = threading.Thread(target=self._send_main, name="validate-beside-send", daemon=True)
            self._sender.start()
        else:
            self._up_q = queue.Queue()
            self._down_q: queue.Queue = queue.Queue()
            self._thread = threading.Thread(target=self._thread_main, name="validate-beside", daemon=True)
            self._thread.start()
        return self

    def _pump_main(self) -> None:
        try:
            while True:
                self._up_q.put(self._up_r.recv())
        except (EOFError, OSError):  # the child has closed its end (ended), or this end was closed
            self._up_q.put((_EOF, None))

    def _send_main(self) -> None:
        while (item := self._down_q.get()) is not None:
            with contextlib.suppress(OSError):  # the child is gone: its fate is read by the next get
                self._down_w.send(item)

    def get(self, key: str) -> Any:
        """The value the job put under ``key`` (waits for it); re-raises the job's exception if it failed first."""
        while key not in self._got:
            k, v = self._recv_from_child()
            if k == _ERROR:
                raise v if isinstance(v, BaseException) else _rebuilt(v)
            if k == _DONE:
                raise SideStageError(f"the side stage ended without sending {key!r}")
            self._got[k] = v
        return self._got.pop(key)

    def put(self, key: str, value: Any) -> None:
        """Send ``value`` under ``key`` to the job (it may be waiting for it); returns at once (in ``"fork"`` mode the
        value is pickled here and written to the pipe by a thread, in the order sent)."""
        if self.mode == "fork":
            value = _Pickled(pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))  # as it is now
        self._down_q.put((key, value))

    def __exit__(self, *exc: Any) -> None:
        if self.mode == "fork":
            if exc[0] is None:
                self._proc.join(_JOIN_S)  # the job has sent what was asked of it: it is ending
            if self._proc.is_alive():
                self._proc.terminate()  # a job no longer waited for (the caller failed)
            self._proc.join()
            self._down_q.put(None)
            self._sender.join()  # the child has ended: a write it never read fails (its end is closed)
            self._pump.join()  # the child's end is closed: the pump has read to its end
            self._up_r.close()
            self._down_w.close()
        else:
            self._down_q.put((_ERROR, None))  # unblocks a job waiting in get: it raises there, and ends
            assert self._thread is not None
            self._thread.join()

    def _recv_from_child(self) -> tuple[str, Any]:
        k, v = self._up_q.get()
        if k == _EOF:
            self._up_q.put((k, v))  # for a further get
            self._proc.join()
            raise SideStageError(f"the side stage's process (pid {self._pid}) ended with exit code "
                                 f"{self._proc.exitcode} before sending its results")
        return k, v

    # -- the job's end ------------------------------------------------------------------------------------------
    def _send_to_parent(self, key: str, value: Any) -> None:
        if self.mode == "thread":
            self._up_q.put((key, value))
        else:
            self._up_w.send((key, value))

    def _recv_from_parent(self, key: str) -> Any:
        k, v = self._down_q.get() if self.mode == "thread" else self._down_r.recv()
        if isinstance(v, _Pickled):
            v = pickle.loads(v.data)
        if k == _ERROR:
            raise SideStageError("the main stage ended before sending " + repr(key))
        if k != key:
            raise SideStageError(f"the side stage waited for {key!r} and got {k!r}")
        return v

    def _run(self) -> None:
        try:
            self.job(_Channel(self))
        except BaseException as exc:  # every failure of the job is the parent's to raise
            self._send_to_parent(_ERROR, exc if self.mode == "thread" else packed_exception(exc))
        else:
            self._send_to_parent(_DONE, None)

    def _thread_main(self) -> None:
        self._run()

    def _child_main(self) -> None:
        # the objects inherited from the parent are left out of this process's garbage collections: a full
        # collection would walk (and, writing their headers, copy) every page of the parent's heap, for objects the
        # job never frees (its own objects are collected as before)
        gc.freeze()
        self._up_r.close()
        self._down_w.close()
        self._run()
        self._up_w.close()
        # the child leaves through multiprocessing's os._exit: the parent's files, temporary folders and atexit
        # handlers stay the parent's


class _Pickled:
    """A value pickled by the parent when it was sent (a later change to the object is not sent)."""

    __slots__ = ("data",)

    def __init__(self, data: bytes) -> None:
        self.data = data

    def __reduce__(self) -> tuple[Any, ...]:
        return (_Pickled, (self.data,))


def _rebuilt(packed: tuple[bytes | None, str] | None) -> BaseException:
    """The job's exception again (its traceback a note), or a :class:`SideStageError` with its text."""
    if packed is None:
        return SideStageError("the side stage failed")
    data, text = packed
    if data is None:
        return SideStageError("the side stage failed:\n" + text)
    exc = pickle.loads(data)
    if isinstance(exc, BaseException):
        exc.add_note("raised beside the main stage, in a child process:\n" + text)
        return exc
    return SideStageError("the side stage failed:\n" + text)


#: the longest campaign (s of tests) whose side stages run beside the type B re-runs. The two sides' memory adds up:
#: on the paper campaign (10,464 s) the process tree's peak PSS is 718 MB forked against 692 MB in line, on the
#: paper campaign ten times over 1,014 MB forked (2026-11-25, benchmarks/bench_overlap.py) against 683 MB of the in-line
#: run (bench_timeline.py, RESULTS.md), so a longer campaign runs them after the re-runs: its memory stays bounded by
#: a chunk, not by the campaign
SIDE_MAX_CAMPAIGN_S = 12_000.0


def side_stages_beside(mode: str, *, streamed: bool, families: Any, campaign_s: float) -> bool:
    """Whether ``validate`` runs its side stages beside the identification.

    Parameters
    ----------
    mode:
        :data:`SIDE_MODE` (``"off"``: never).
    streamed:
        A streamed whole-campaign run (the only kind with side stages).
    families:
        The families validated on their own (``None``: the whole campaign).
    campaign_s:
        The campaign's length in seconds of tests; over :data:`SIDE_MAX_CAMPAIGN_S` the stages run in line.

    Returns
    -------
    bool
    """
    return mode != "off" and streamed and families is None and 0.0 < campaign_s <= SIDE_MAX_CAMPAIGN_S
