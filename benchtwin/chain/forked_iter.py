"""Run a producer in a forked child process: its items come through a pipe while this process works on the last one.

:class:`ForkedIter` iterates ``make_iter()`` (e.g. the plant's tests, :func:`~benchtwin.emulator.iter_campaign`) in
a child forked when the context is entered, so the producer's CPU is spent under the child's own interpreter lock,
not under the one this process's threads share. Each item is pickled (protocol 5: a numpy array's data travels out
of band, written straight from the child's array and read straight into the array the parent unpickles, one copy
through the kernel each way). With ``depth`` 1 (the default) the child makes item k + 1 once the parent has read item
k (all but the pipe's buffer), so it makes the next while the parent works on the last one and holds one item at a
time; a larger ``depth`` has a thread of the child write while the producer runs ahead. The items, their order, their
bits and the producer's exceptions are the producer's own; only where the work runs changes (a numpy view arrives as
an array of its own).

Failures: the producer's exception is re-raised by the parent's iteration with its type and message (the child's
traceback added as a note; an exception that does not pickle back raises :class:`ForkedProducerError` with its
text), a child that dies without a word raises :class:`ForkedProducerError`, and leaving the context (or closing the
iteration) before the end ends the child: no process is left behind. ``mode="thread"`` (where ``os.fork`` is
missing) iterates the producer in the caller's thread, as a plain loop would.

Fork before the process starts threads of its own (a child forked from a process with threads inherits its locks
in whatever state those threads left them).
"""

from __future__ import annotations

import contextlib
import gc
import os
import pickle
import queue
import signal
import struct
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from functools import partial
from typing import Any, Generic, TypeVar

import numpy as np

from benchtwin.errors import BenchtwinError, packed_exception

__all__ = ["FORK_MODES", "ForkedIter", "ForkedProducerError"]

#: how the producer runs: ``"fork"`` in a child process (needs ``os.fork``), ``"thread"`` in the iterating thread
FORK_MODES = ("fork", "thread")

T = TypeVar("T")

_LEN = struct.Struct("<Q")
#: a pipe this large (bytes; Linux caps it at /proc/sys/fs/pipe-max-size) takes a large array in fewer system calls
_PIPE_BYTES = 1 << 20
#: the alignment (bytes) of each array's data in the block an item is read into
_ALIGN = 64
#: buffers per readv/writev call (POSIX's IOV_MAX on Linux)
_IOV_MAX = 1024


class ForkedProducerError(BenchtwinError, RuntimeError):
    """The producer run in a child process failed without an exception of its own to re-raise (the child died, or
    its exception could not be sent)."""


class ForkedIter(Generic[T]):
    """Iterate ``make_iter()`` in a forked child (a context manager: entering it forks; iterate it once).

    Parameters
    ----------
    make_iter:
        Called in the child (``"thread"`` mode: at the first item, in the iterating thread); returns the producer.
    mode:
        ``"fork"`` or ``"thread"`` (:data:`FORK_MODES`).
    depth:
        Items the child holds made and not yet read whole by the parent, the one being written included (each in the
        child's memory until then).

    Attributes
    ----------
    made_s:
        Seconds the producer spent making the item last yielded (its wall time in the child; in ``"thread"`` mode
        in the iterating thread).
    """

    def __init__(self, make_iter: Callable[[], Iterable[T]], mode: str = "fork", *, depth: int = 1) -> None:
        if mode not in FORK_MODES:
            raise ValueError(f"mode {mode!r}: one of {', '.join(FORK_MODES)}")
        if depth < 1:
            raise ValueError(f"depth must be at least 1, got {depth}")
        if mode == "fork" and not hasattr(os, "fork"):
            raise ValueError("mode 'fork' needs os.fork (not on this system): use 'thread'")
        self.make_iter, self.mode, self.depth = make_iter, mode, depth
        self.made_s = 0.0
        self.pid: int | None = None
        self._fd: int | None = None
        self._ended = False
        self._used = False
        self._froze = False

    # -- the parent's end ---------------------------------------------------------------------------------------
    def __enter__(self) -> ForkedIter[T]:
        if self.mode == "fork":
            # the objects made so far out of the collector's sight on both sides: a collection that walked them would
            # write to every page that holds one, and a page written is copied (both processes then hold it)
            self._froze = gc.get_freeze_count() == 0
            if self._froze:
                gc.freeze()
            r, w = os.pipe()
            parent = os.getpid()
            pid = os.fork()
            if pid == 0:  # the child: never returns
                os.close(r)
                self._child_main(w, parent)
            os.close(w)
            self.pid, self._fd = pid, r
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        """End the child (at once if it has not sent its end) and wait for it; idempotent."""
        if self.pid is not None:
            if not self._ended:
                with contextlib.suppress(ProcessLookupError):  # a producer no longer waited for: nothing is kept
                    os.kill(self.pid, signal.SIGKILL)
            self._reap()
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        if self._froze:
            self._froze = False
            gc.unfreeze()  # the child has ended: nothing to share any more

    def _reap(self) -> int:
        """Wait for the child; its exit status (as ``waitstatus_to_exitcode``)."""
        assert self.pid is not None
        _, status = os.waitpid(self.pid, 0)
        self.pid = None
        return os.waitstatus_to_exitcode(status)

    def __iter__(self) -> Iterator[T]:
        if self._used:
            raise RuntimeError("a ForkedIter is iterated once")
        self._used = True
        if self.mode == "thread":
            return self._in_thread()
        if self._fd is None:
            raise RuntimeError("enter the ForkedIter (with ...) before iterating it")
        return self._from_child()

    def _in_thread(self) -> Iterator[T]:
        it = iter(self.make_iter())
        try:
            while True:
                t = time.perf_counter()
                try:
                    item = next(it)
                except StopIteration:
                    return
                self.made_s = time.perf_counter() - t
                yield item
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                close()

    def _from_child(self) -> Iterator[T]:
        try:
            while True:
                head = self._read_message()
                if head is None:
                    code = self._reap()
                    raise ForkedProducerError(f"the producer's process ended with exit code {code} before its end")
                kind = head[0]
                if kind == "end":
                    self._ended = True
                    self._reap()
                    return
                if kind == "error":
                    self._ended = True
                    self._reap()
                    raise _rebuilt(head[1], head[2])
                _, sizes, made_s = head
                head_bytes, arrays = np.empty(sizes[0], dtype=np.uint8), _one_block(sizes[1:])
                self._read_into(head_bytes, *arrays)  # in as few reads as the pipe allows (each gives up the GIL)
                item = pickle.loads(memoryview(head_bytes), buffers=arrays)
                self.made_s = made_s
                yield item
        finally:
            self.close()  # an iteration left before the end ends the child here, not when the context ends

    def _read_message(self) -> Any:
        raw = self._read_exact(_LEN.size, eof_ok=True)
        if raw is None:
            return None
        return pickle.loads(self._read_exact(_LEN.unpack(raw)[0]))

    def _read_exact(self, n: int, *, eof_ok: bool = False) -> memoryview | None:
        out = np.empty(n, dtype=np.uint8)
        return memoryview(out) if self._read_into(out, eof_ok=eof_ok) else None

    def _read_into(self, *bufs: np.ndarray, eof_ok: bool = False) -> bool:
        """Fill ``bufs`` in order from the pipe (False: the pipe ended before a byte, with ``eof_ok``)."""
        assert self._fd is not None
        views = [memoryview(b).cast("B") for b in bufs if b.nbytes]
        first = True
        while views:
            k = os.readv(self._fd, views[:_IOV_MAX])
            if k == 0:
                if eof_ok and first:
                    return False
                code = self._reap() if self.pid is not None else None
                raise ForkedProducerError(f"the producer's process ended (exit code {code}) in the middle of an "
                                          "item")
            first = False
            while k:  # drop the views filled, trim the one filled in part
                n = min(k, len(views[0]))
                views[0] = views[0][n:]
                k -= n
                if not len(views[0]):
                    views.pop(0)
        return True

    # -- the child's end ----------------------------------------------------------------------------------------
    def _child_main(self, fd: int, parent: int) -> None:
        code = 0
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it ends this child
            _end_with_parent(parent)
            _bigger_pipe(fd)
            sent: queue.Queue = queue.Queue(maxsize=self.depth - 1 or 1)
            writer = None
            if self.depth > 1:  # the producer runs ahead while a thread writes (one item held more)
                writer = threading.Thread(target=_write_main, args=(fd, sent), name="forked-iter-send", daemon=True)
                writer.start()
            put = sent.put if writer is not None else partial(_send, fd)
            try:
                it = iter(self.make_iter())
                while True:
                    t = time.perf_counter()
                    try:
                        item = next(it)
                    except StopIteration:
                        break
                    made_s = time.perf_counter() - t
                    buffers: list[pickle.PickleBuffer] = []
                    data = pickle.dumps(item, protocol=5, buffer_callback=buffers.append)
                    del item
                    raws = [b.raw() for b in buffers]
                    put((("item", [len(data), *(r.nbytes for r in raws)], made_s), [data, *raws]))
                    del data, raws, buffers
                put((("end",), []))
            except _PipeGoneError:
                raise
            except BaseException as exc:  # every failure of the producer is the parent's to raise
                put(((("error", *packed_exception(exc))), []))
            if writer is not None:
                sent.put(None)
                writer.join()
        except BaseException:  # the pipe is gone (the parent ended): nothing to tell anyone
            code = 1
        finally:
            os._exit(code)  # the parent's files, temporary folders and exit handlers stay the parent's


def _one_block(sizes: list[int]) -> list[np.ndarray]:
    """Buffers of ``sizes`` bytes cut from one allocation (each start aligned to 64 bytes): an item's arrays come and go
    together as one block of memory, as the producer's rows of one array did, not as many small ones that leave the
    heap in pieces."""
    starts = np.concatenate([[0], np.cumsum([-(-n // _ALIGN) * _ALIGN for n in sizes])]).astype(int)
    block = np.empty(int(starts[-1]), dtype=np.uint8)
    return [block[a:a + n] for a, n in zip(starts[:-1], sizes, strict=True)]


def _write_main(fd: int, sent: queue.Queue) -> None:
    """The child's writer: each message's head, then its parts, until ``None`` (a write error ends the child)."""
    try:
        while (msg := sent.get()) is not None:
            _send(fd, msg)
    except _PipeGoneError:
        os._exit(1)  # the parent closed its end: it no longer wants the items


def _send(fd: int, msg: tuple[tuple[Any, ...], list[Any]]) -> None:
    """One message: its head pickled, with its length before it, then its parts."""
    head, parts = msg
    blob = pickle.dumps(head, protocol=5)
    try:
        _write_all(fd, [_LEN.pack(len(blob)) + blob, *parts])
    except OSError as exc:
        raise _PipeGoneError from exc


class _PipeGoneError(Exception):
    """The parent closed its end of the pipe: it no longer wants the items."""


def _write_all(fd: int, parts: list[Any]) -> None:
    """Write ``parts`` in order, in as few system calls as the pipe allows."""
    views = [v for v in (memoryview(p).cast("B") for p in parts) if len(v)]
    while views:
        k = os.writev(fd, views[:_IOV_MAX])
        while k:
            n = min(k, len(views[0]))
            views[0] = views[0][n:]
            k -= n
            if not len(views[0]):
                views.pop(0)


def _bigger_pipe(fd: int) -> None:
    """Ask for a larger pipe (Linux's F_SETPIPE_SZ); the default is kept where it is refused."""
    import fcntl

    setsz = getattr(fcntl, "F_SETPIPE_SZ", None)
    if setsz is not None:
        with contextlib.suppress(OSError):
            fcntl.fcntl(fd, setsz, _PIPE_BYTES)


def _end_with_parent(parent: int) -> None:
    """Have the kernel end this child when its parent ends (Linux's PR_SET_PDEATHSIG; elsewhere a write to the closed
    pipe ends it)."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # 1: PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent ended before the request was made
        os._exit(1)


def _rebuilt(data: bytes | None, text: str) -> BaseException:
    """The producer's exception again (its traceback a note), or a :class:`ForkedProducerError` with its text."""
    exc = pickle.loads(data) if data is not None else None
    if isinstance(exc, BaseException):
        exc.add_note("raised by the producer, in a child process:\n" + text)
        return exc
    return ForkedProducerError("the producer failed in its child process:\n" + text)
