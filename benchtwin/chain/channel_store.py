"""Where a chunked acquisition puts the samples it has decoded: in memory, or appended to files on disk.

:class:`ChannelStore` takes each chunk's samples of each channel (timestamps, values, flags) and gives the
whole channels back at the end: concatenated in memory, or, with a directory, as memory maps of files the
chunks were appended to, mapped when used and unmapped when dropped (the flags mapped read-write, so the
whole-recording passes flag them in place and drop them again: one channel mapped at a time). Once those passes
are done, :meth:`ChannelStore.reader` gives each channel read from its files through a file handle (plain
sequential reads of raw samples: the pages of a memory map would count as resident while the channel is used).
The files stay open while the store is (one descriptor per file, up to :data:`MAX_OPEN_FILES` in all the process's
stores): a chunk's appends
and a block's reads are a system call each, with no open and close around them (positional reads: safe on threads).
"""

from __future__ import annotations

import os
import resource
import shutil
import tempfile
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.recording import Channel, LazyChannel

__all__ = ["ChannelStore"]

_DTYPES = (np.dtype(np.float64), np.dtype(np.float64), np.dtype(np.uint16))  # timestamps, values, flags

#: files the stores of a process keep open together (three per channel; the others are opened for each read or append,
#: as before): at most a quarter of the process's limit on open files
MAX_OPEN_FILES = max(0, min(1024, resource.getrlimit(resource.RLIMIT_NOFILE)[0] // 4))

_open_lock = threading.Lock()
_open_count = 0  # files kept open by every store of the process


def _write_all(fd: int, a: np.ndarray) -> None:
    """Append the bytes of ``a`` (contiguous) through ``fd`` (opened for appending), however many writes it takes."""
    buf = memoryview(a).cast("B")
    while buf.nbytes:
        buf = buf[os.write(fd, buf):]


def _read_at(fd: int, dtype: np.dtype, count: int, offset: int) -> np.ndarray:
    """``count`` items of ``dtype`` at byte ``offset`` of ``fd`` (fewer at the end of the file, as ``np.fromfile``)."""
    out = np.empty(count, dtype)
    buf = memoryview(out).cast("B")
    got = 0
    while got < buf.nbytes:
        n = os.preadv(fd, [buf[got:]], offset + got)
        if n == 0:
            break
        got += n
    return out if got == buf.nbytes else out[:got // dtype.itemsize].copy()


@dataclass
class _Entry:
    unit: str
    source: str
    texts: dict[int, str] | None
    order: tuple[Any, ...]
    n: int = 0
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)


class ChannelStore:
    """The decoded samples of every channel, chunk after chunk.

    Parameters
    ----------
    directory:
        Append the samples to files in a new folder inside this one (removed by :meth:`cleanup`);
        None keeps them in memory.
    """

    def __init__(self, directory: str | Path | None = None) -> None:
        self._entries: dict[str, _Entry] = {}
        self._dir: Path | None = None
        if directory is not None:
            Path(directory).mkdir(parents=True, exist_ok=True)
            self._dir = Path(tempfile.mkdtemp(prefix=".acquisition-", suffix=".chunks", dir=directory))
        self._index: dict[str, int] = {}
        self._fds: dict[tuple[int, int], int] = {}  # (channel, column) -> its open file

    def append(self, name: str, unit: str, source: str, texts: dict[int, str] | None, order: tuple[Any, ...],
               t: np.ndarray, v: np.ndarray, f: np.ndarray) -> None:
        """Append one chunk's samples of channel ``name`` (``order``: where it goes among the channels)."""
        e = self._entries.get(name)
        if e is None:
            e = self._entries[name] = _Entry(unit, source, texts, order)
            self._index[name] = len(self._index)
        e.n += int(t.shape[0])
        arrays = (np.asarray(t, _DTYPES[0]), np.asarray(v, _DTYPES[1]), np.asarray(f, _DTYPES[2]))
        if self._dir is None:
            e.parts.append(arrays)
            return
        for k, a in enumerate(arrays):
            fd = self._fd(name, k)
            if fd is None:
                with self._file(name, k).open("ab") as fh:
                    np.ascontiguousarray(a).tofile(fh)
            else:
                _write_all(fd, np.ascontiguousarray(a))

    def _file(self, name: str, k: int) -> Path:
        assert self._dir is not None
        return self._dir / f"{self._index[name]}.{'tvf'[k]}"

    def _fd(self, name: str, k: int) -> int | None:
        """The open file of column ``k`` of ``name`` (opened for appending and reading on first use; None beyond
        :data:`MAX_OPEN_FILES` open in all stores: the caller opens the file itself)."""
        global _open_count
        key = (self._index[name], k)
        fd = self._fds.get(key)
        if fd is None:
            with _open_lock:
                fd = self._fds.get(key)
                if fd is None and _open_count < MAX_OPEN_FILES:
                    fd = self._fds[key] = os.open(self._file(name, k), os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o600)
                    _open_count += 1
        return fd

    def _read(self, name: str, k: int, start: int, count: int) -> np.ndarray:
        """``count`` samples of column ``k`` of ``name`` from sample ``start`` (``np.fromfile``'s numbers)."""
        fd = self._fd(name, k) if count >= 0 else None
        if fd is None:
            with self._file(name, k).open("rb") as fh:
                return np.fromfile(fh, dtype=_DTYPES[k], count=count, offset=start * _DTYPES[k].itemsize)
        return _read_at(fd, _DTYPES[k], count, start * _DTYPES[k].itemsize)

    def _close_files(self) -> None:
        global _open_count
        with _open_lock:
            fds, self._fds = list(self._fds.values()), {}
            _open_count -= len(fds)
        for fd in fds:
            os.close(fd)

    def __del__(self) -> None:  # a store never cleaned up: its files stay, its descriptors go
        if getattr(self, "_fds", None):
            self._close_files()

    def names(self) -> list[str]:
        """Channel names in their order (by the ``order`` keys, then first appearance)."""
        return sorted(self._entries, key=lambda n: (self._entries[n].order, self._index[n]))

    def channel(self, name: str) -> Channel:
        """The whole channel: concatenated (in memory) or a :class:`~benchtwin.recording.LazyChannel` mapped from its
        files when used (flags writable: what is flagged in place is in the file, so the channel can be dropped)."""
        e = self._entries[name]
        if self._dir is None:
            if len(e.parts) == 1:
                t, v, f = e.parts[0]
            else:
                t, v, f = (np.concatenate([p[k] for p in e.parts]) if e.parts else np.zeros(0, _DTYPES[k])
                           for k in range(3))
            e.parts = []
        elif e.n == 0:
            t, v, f = (np.zeros(0, d) for d in _DTYPES)
        else:
            files = [self._file(name, k) for k in range(3)]

            def load() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
                t, v, f = (np.memmap(files[k], dtype=_DTYPES[k], mode="r+" if k == 2 else "r", shape=(e.n,))
                           for k in range(3))
                return np.asarray(t), np.asarray(v), np.asarray(f)

            return LazyChannel(name, e.unit, e.source, e.n, load, e.texts, block_loader=self._block_reader(name))
        return Channel(name, e.unit, t, v, f, e.source, e.texts)

    def reader(self, name: str) -> Channel:
        """The whole channel as a :class:`~benchtwin.recording.LazyChannel` read from its files (raw samples,
        through a file handle) on first access and dropped again with :meth:`~benchtwin.recording.LazyChannel.drop`;
        in memory (as :meth:`channel`) when the store has no directory."""
        e = self._entries[name]
        if self._dir is None or e.n == 0:
            return self.channel(name)
        n = e.n

        def load() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            return self._read(name, 0, 0, n), self._read(name, 1, 0, n), self._read(name, 2, 0, n)

        return LazyChannel(name, e.unit, e.source, n, load, e.texts, block_loader=self._block_reader(name))

    def _block_reader(self, name: str) -> Callable[[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """``(start, stop) -> (timestamps, values, flags)`` of those samples of ``name``, read from its files."""
        def read(start: int, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            return (self._read(name, 0, start, stop - start), self._read(name, 1, start, stop - start),
                    self._read(name, 2, start, stop - start))

        return read

    def holds(self, name: str) -> bool:
        """Whether channel ``name`` has been appended to this store."""
        return name in self._entries

    def length(self, name: str) -> int:
        """Samples of channel ``name`` so far."""
        return self._entries[name].n

    def read_block(self, name: str, start: int, stop: int, columns: str = "tvf") -> tuple[Any, Any, Any]:
        """Timestamps, values and flags of samples ``start:stop`` of ``name`` read from its files (a store on disk;
        the arrays are the caller's); ``columns``: those read (``"t"``, ``"v"``, ``"f"``), None for the others."""
        if self._dir is None:
            raise ValueError("ChannelStore.read_block: the store keeps its samples in memory, not in files")
        if columns == "tvf":
            return self._block_reader(name)(start, stop)
        t, v, f = (self._read(name, k, start, stop - start) if c in columns else None for k, c in enumerate("tvf"))
        return t, v, f

    def write_flags(self, name: str, start: int, flags: np.ndarray) -> None:
        """Write ``flags`` over the flags of samples ``start:start + len(flags)`` of ``name`` in its file."""
        if self._dir is None:
            raise ValueError("ChannelStore.write_flags: the store keeps its samples in memory, not in files")
        with self._file(name, 2).open("r+b") as fh:
            fh.seek(start * _DTYPES[2].itemsize)
            np.ascontiguousarray(flags, dtype=_DTYPES[2]).tofile(fh)

    @property
    def directory(self) -> Path | None:
        """The folder the samples go to (None: in memory)."""
        return self._dir

    @property
    def on_disk(self) -> bool:
        """Whether the samples go to files (a directory was given)."""
        return self._dir is not None

    def close(self) -> None:
        """The same as :meth:`cleanup` (so a Recording read from the store can own it)."""
        self.cleanup()

    def cleanup(self) -> None:
        """Remove the files (channels mapped from them must no longer be used)."""
        self._close_files()
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
