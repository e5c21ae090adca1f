"""Where a chunked acquisition puts the samples it has decoded: in memory, or appended to files on disk.

:class:`ChannelStore` takes each chunk's samples of each channel (timestamps, values, flags) and gives the
whole channels back at the end: concatenated in memory, or, with a directory, as memory maps of files the
chunks were appended to, mapped when used and unmapped when dropped (the flags mapped read-write, so the
whole-recording passes flag them in place and drop them again: one channel mapped at a time). Once those passes
are done, :meth:`ChannelStore.reader` gives each channel read from its files through a file handle (plain
sequential reads of raw samples: the pages of a memory map would count as resident while the channel is used).
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.recording import Channel, LazyChannel

__all__ = ["ChannelStore"]

_DTYPES = (np.dtype(np.float64), np.dtype(np.float64), np.dtype(np.uint16))  # timestamps, values, flags


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
            with self._file(name, k).open("ab") as fh:
                np.ascontiguousarray(a).tofile(fh)

    def _file(self, name: str, k: int) -> Path:
        assert self._dir is not None
        return self._dir / f"{self._index[name]}.{'tvf'[k]}"

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
        files = [self._file(name, k) for k in range(3)]
        n = e.n

        def load() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            out = []
            for k in range(3):
                with files[k].open("rb") as fh:
                    out.append(np.fromfile(fh, dtype=_DTYPES[k], count=n))
            return out[0], out[1], out[2]

        return LazyChannel(name, e.unit, e.source, n, load, e.texts, block_loader=self._block_reader(name))

    def _block_reader(self, name: str) -> Callable[[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """``(start, stop) -> (timestamps, values, flags)`` of those samples of ``name``, read from its files."""
        files = [self._file(name, k) for k in range(3)]

        def read(start: int, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            out = []
            for k in range(3):
                with files[k].open("rb") as fh:
                    out.append(np.fromfile(fh, dtype=_DTYPES[k], count=stop - start,
                                           offset=start * _DTYPES[k].itemsize))
            return out[0], out[1], out[2]

        return read

    def holds(self, name: str) -> bool:
        """Whether channel ``name`` has been appended to this store."""
        return name in self._entries

    def length(self, name: str) -> int:
        """Samples of channel ``name`` so far."""
        return self._entries[name].n

    def read_block(self, name: str, start: int, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Timestamps, values and flags of samples ``start:stop`` of ``name`` read from its files (a store on disk;
        the arrays are the caller's)."""
        if self._dir is None:
            raise ValueError("ChannelStore.read_block: the store keeps its samples in memory, not in files")
        return self._block_reader(name)(start, stop)

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
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
