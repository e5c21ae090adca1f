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

            return LazyChannel(name, e.unit, e.source, e.n, load, e.texts)
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

        return LazyChannel(name, e.unit, e.source, n, load, e.texts, windows=_FileWindows(files, n))

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


#: samples checked for time order at a time (bounds the check's memory on a long channel)
_ORDER_BLOCK = 1 << 16


class _FileWindows:
    """Reads the samples of a span of one channel from its files (a binary search on the mapped timestamps, then
    plain reads of the rows found): a method that uses a few spans never holds the whole channel."""

    def __init__(self, files: list[Path], n: int) -> None:
        self._files = files
        self._n = n
        self._ordered: bool | None = None

    def _is_ordered(self) -> bool:
        if self._ordered is None:
            ok, last = True, -np.inf
            with self._files[0].open("rb") as fh:
                for k in range(0, self._n, _ORDER_BLOCK):
                    ts = np.fromfile(fh, dtype=_DTYPES[0], count=min(_ORDER_BLOCK, self._n - k))
                    if ts.size and (ts[0] < last or bool(np.any(ts[1:] < ts[:-1]))):
                        ok = False
                        break
                    last = ts[-1] if ts.size else last
            self._ordered = ok
        return self._ordered

    def window(self, start_s: float, end_s: float) -> tuple[int, np.ndarray, np.ndarray, np.ndarray] | None:
        """As :func:`benchtwin.identification._windows.window_of`, read from the files (None: not in time order)."""
        if self._n == 0 or not self._is_ordered():
            return None
        mapped = np.memmap(self._files[0], dtype=_DTYPES[0], mode="r", shape=(self._n,))
        try:
            k0 = max(int(np.searchsorted(mapped, start_s, side="right")) - 1, 0)
            k1 = min(int(np.searchsorted(mapped, end_s, side="left")) + 1, self._n)
        finally:
            del mapped
        k1 = max(k1, k0 + 1)
        out = []
        for k in range(3):
            with self._files[k].open("rb") as fh:
                fh.seek(k0 * _DTYPES[k].itemsize)
                out.append(np.fromfile(fh, dtype=_DTYPES[k], count=k1 - k0))
        return k0, out[0], out[1], out[2]
