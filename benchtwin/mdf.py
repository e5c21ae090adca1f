"""MF4 files through asammdf: opening with one clear error, the compression choices, channels read one at a time.

Below :mod:`benchtwin.recording` (which re-exports :func:`open_mdf`); the bus logs, the Trace and the importers
use it too.
"""

from __future__ import annotations

import gc
import sys
import threading
import weakref
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.errors import DataError

__all__ = ["DEFAULT_COMPRESSION", "WRITE_BLOCK_BYTES", "WRITE_BLOCK_SAMPLES", "ChannelFile", "append_in_blocks",
           "check_compression", "group_block_samples", "open_mdf", "save_channel_groups", "texts_of",
           "value_text_conversion", "write_channel_groups"]


def _is_mdf_del(unraisable: Any) -> bool:
    name = getattr(unraisable.object, "__qualname__", "")
    return isinstance(name, str) and name.startswith(("MDF4.__del__", "MDF3.__del__", "MDF.__del__"))


class _QuietMdfDel:
    """While entered (by any thread), the ignored-exception report of asammdf's ``MDF4.__del__`` is dropped.

    ``sys.unraisablehook`` is process-wide: the threads that read bus logs in parallel share one
    filter, installed by the first to enter and removed by the last to leave.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._users = 0
        self._previous: Any = None

    def _hook(self, unraisable: Any) -> None:
        if not _is_mdf_del(unraisable):
            self._previous(unraisable)

    def __enter__(self) -> None:
        with self._lock:
            if self._users == 0:
                self._previous = sys.unraisablehook
                sys.unraisablehook = self._hook
            self._users += 1

    def __exit__(self, *exc: object) -> None:
        with self._lock:
            self._users -= 1
            if self._users == 0:
                sys.unraisablehook = self._previous
                self._previous = None


_QUIET_MDF_DEL = _QuietMdfDel()


def _disarm(tb: Any) -> None:
    """Mark the half-built MDF objects of a failed constructor closed, so their ``__del__`` has nothing to do.

    The object may outlive this call (a reference cycle, collected whenever the garbage collector next
    runs, in any thread); its ``close()`` returns at once when ``_closed`` is set.
    """
    while tb is not None:
        for value in list(tb.tb_frame.f_locals.values()):
            if type(value).__name__ in ("MDF4", "MDF3") and not (hasattr(value, "_file") and hasattr(value, "header")):
                value._closed = True
        tb = tb.tb_next


def open_mdf(path: str | Path, *, stream: Any = None, **kwargs: Any) -> Any:
    """Open an MF4 file with asammdf; a file asammdf cannot read is one :class:`DataError` line.

    ``stream``: the file already opened (binary) to read through instead of the path; asammdf then
    reads with ordinary reads rather than mapping the whole file into memory (whose pages, once read,
    count in the process's resident memory: the whole file for a day-long log).

    asammdf leaves a half-built object behind when its constructor fails, whose ``__del__`` then
    prints an ignored-exception traceback on stderr (``'MDF4' object has no attribute '_file'``);
    that object is marked closed (its ``__del__`` then does nothing) and collected here with exactly
    that report silenced, before the error is raised.

    Raises
    ------
    DataError
        No such file, or not a readable MF4 file (truncated, foreign, not MF4 at all).
    """
    from asammdf import MDF

    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file")
    if path.is_dir():
        raise DataError(f"{path}: is a folder, not an MF4 file")
    reason = ""
    with _QUIET_MDF_DEL:
        try:
            return MDF(path if stream is None else stream, **kwargs)
        except Exception as exc:  # asammdf raises many kinds for a bad file
            reason = str(exc) or type(exc).__name__
            _disarm(exc.__traceback__)
        gc.collect()  # the half-built object (held by the traceback until here) goes now, quietly
    raise DataError(f"{path}: not a readable MF4 file ({reason})")


#: asammdf compression of the MF4 files benchtwin writes: 2, transposed deflate (benchmarks/bench_files.py:
#: the Recording and the Trace shrink ~10x for ~2x the write time of no compression, and read faster than
#: they are written; deflate alone saves far less on float channels)
DEFAULT_COMPRESSION = 2

_COMPRESSIONS = {0: "none", 1: "deflate", 2: "transposed deflate"}


def check_compression(compression: int) -> int:
    """``compression`` if asammdf knows it (0, 1, 2), else a :class:`DataError` naming the choices."""
    if isinstance(compression, bool) or compression not in _COMPRESSIONS:
        raise DataError(f"MF4 compression must be one of {', '.join(f'{k} ({v})' for k, v in _COMPRESSIONS.items())}, "
                        f"got {compression!r}")
    return int(compression)


#: samples per block when a channel group is written in blocks (:func:`append_in_blocks`), at most (a wide group
#: gets fewer: :data:`WRITE_BLOCK_BYTES`)
WRITE_BLOCK_SAMPLES = 1 << 20

#: bytes of a channel group's columns (its times, each channel's float64 values and uint16 flags) written at a time,
#: at most: asammdf makes a record block as large again and compresses it, so a block is about three times this in
#: memory. A sample count alone let the block grow with the group's width up to 1 Mi records (88 B each for the
#: IVT groups of 8 channels: 92 MB of columns and as much again of records once a group is over 1 Mi samples long).
WRITE_BLOCK_BYTES = 16 << 20


def group_block_samples(n_channels: int, size: int | None = None, budget: int | None = None) -> int:
    """Samples of a group of ``n_channels`` channels (and their flags) written at a time: ``size`` (default
    :data:`WRITE_BLOCK_SAMPLES`), fewer when the group's columns would exceed ``budget`` bytes (default
    :data:`WRITE_BLOCK_BYTES`); at least one.

    Raises
    ------
    ValueError
        If ``n_channels`` is negative or ``size``/``budget`` is not positive.
    """
    size = WRITE_BLOCK_SAMPLES if size is None else int(size)
    budget = WRITE_BLOCK_BYTES if budget is None else int(budget)
    if n_channels < 0 or size < 1 or budget < 1:
        raise ValueError(f"group_block_samples: channels {n_channels}, size {size}, budget {budget} (want >= 0, > 0, "
                         "> 0)")
    return max(1, min(size, budget // (8 + n_channels * (8 + 2))))


def append_in_blocks(mdf: Any, blocks: Iterable[tuple[np.ndarray, list[np.ndarray]]],
                     signals: Callable[[np.ndarray, list[np.ndarray]], list[Any]], *, comment: str,
                     acq_name: str) -> None:
    """Write one channel group block by block: the first block ``mdf.append(signals(t, columns))``, the next ones
    ``mdf.extend`` (asammdf keeps each block as its own data fragment, compressed one at a time when saved), so
    what is in memory is one block of the group, not the group whole.

    Parameters
    ----------
    mdf:
        An ``asammdf.MDF`` being written.
    blocks:
        ``(timestamps, [column, ...])`` per block, in time order, the columns in the order of ``signals``'s list.
    signals:
        ``(timestamps, columns) -> [asammdf.Signal, ...]``: the group's signals made from the first block.
    comment, acq_name:
        The channel group's comment and acquisition name.
    """
    index = None
    for t, columns in blocks:
        if index is None:
            mdf.append(signals(t, columns), comment=comment, acq_name=acq_name)
            index = len(mdf.groups) - 1
        elif len(t):
            mdf.extend(index, [(t, None)] + [(c, None) for c in columns])
        del t, columns  # not held while the next block is read


def _channel_groups(channels: Iterable[Any], size: int) -> list[tuple[str, list[Any]]]:
    """``(source, channels)`` of each channel group: one per source and time base, in the order they are written."""
    by_source: dict[str, list[Any]] = {}
    for ch in channels:
        by_source.setdefault(ch.source or "default", []).append(ch)
    out = []
    for source, chans in sorted(by_source.items()):
        groups: list[list[Any]] = []
        for ch in chans:
            for group in groups:
                if _same_times(group[0], ch, size):
                    group.append(ch)
                    break
            else:
                groups.append([ch])
        out += [(source, group) for group in groups]
    return out


def _group_signals(group: list[Any], source: str, t: np.ndarray, cols: list[np.ndarray],
                   flag_conversion: dict[str, Any]) -> list[Any]:
    """The asammdf Signals of a group: each channel's values, then its ``<name>.flags``."""
    from asammdf import Signal

    out = []
    for k, ch in enumerate(group):
        out.append(Signal(cols[2 * k], t, name=ch.name, unit=ch.unit, comment=f"source={source}",
                          conversion=value_text_conversion(ch.value_texts)))
        out.append(Signal(cols[2 * k + 1], t, name=f"{ch.name}.flags", unit="",
                          comment="benchtwin quality flags (see benchtwin.recording.Flag)", conversion=flag_conversion))
    return out


def write_channel_groups(mdf: Any, channels: Iterable[Any], flag_conversion: dict[str, Any],
                         release: Callable[[list[str]], None], *, size: int | None = None) -> None:
    """Write a Recording's channels into ``mdf``: one channel group per source and time base, each channel followed
    by its ``<name>.flags`` channel (with ``flag_conversion``), block by block (:func:`append_in_blocks`).

    ``channels`` are :class:`~benchtwin.recording.Channel` objects (read through ``block(start, stop)``, so a lazy
    one with a block reader is never read whole), ``size`` samples at a time (default :data:`WRITE_BLOCK_SAMPLES`;
    fewer for a wide group, :func:`group_block_samples`: what is in memory does not grow with the group's width);
    ``release(names)`` is called after each group is written.
    Channels of one source may have different time bases (two streams of one device lose different frames: same
    length and start, other times): they are compared block by block. (asammdf alone: every block through its
    temporary file, compressed on ``save``; :func:`save_channel_groups` writes the same file faster.)
    """
    size = WRITE_BLOCK_SAMPLES if size is None else int(size)
    for source, group in _channel_groups(channels, size):
        def signals(t: np.ndarray, cols: list[np.ndarray], group: list[Any] = group, source: str = source) -> list:
            return _group_signals(group, source, t, cols, flag_conversion)

        append_in_blocks(mdf, _group_blocks(group, group_block_samples(len(group), size)), signals,
                         comment=source, acq_name=source)
        release([ch.name for ch in group])


def save_channel_groups(path: str | Path, mdf: Any, channels: Iterable[Any], flag_conversion: dict[str, Any],
                        release: Callable[[list[str]], None], *, compression: int = DEFAULT_COMPRESSION,
                        size: int | None = None, workers: int = 2) -> Path:
    """Save a Recording's channels as ``path`` (suffix ``.mf4``): the file :func:`write_channel_groups` and asammdf's
    ``save`` write, but its data blocks written as the groups are read and compressed on ``workers`` threads
    (:class:`benchtwin.mf4stream.StreamedMdf`); asammdf writes only what describes the file.

    ``mdf`` is a new ``asammdf.MDF`` with its header set (start time, comment); it is closed here. ``channels``,
    ``flag_conversion``, ``release`` and ``size`` as :func:`write_channel_groups` (the same groups, the same blocks in
    memory, plus a few data blocks of 4 MiB handed to the workers). Returns the path written. The values are
    written as float64 and the flags as uint16 (a Recording's channels hold those).
    """
    from benchtwin.mf4stream import GroupLayout, StreamedMdf, mdf_template

    size = WRITE_BLOCK_SAMPLES if size is None else int(size)
    compression = check_compression(compression)
    groups = _channel_groups(channels, size)
    layouts = []
    try:
        for source, group in groups:
            empty = [np.zeros(0, np.float64), np.zeros(0, np.uint16)] * len(group)
            mdf.append(_group_signals(group, source, np.zeros(0), empty, flag_conversion), comment=source,
                       acq_name=source)
            layouts.append(GroupLayout(8 + 10 * len(group)))
        template = mdf_template(mdf, compression)
    finally:
        mdf.close()
    path = Path(path).with_suffix(".mf4")  # as asammdf's save names it
    out = StreamedMdf(path, template, layouts, compression, workers=workers)
    try:
        for k, (_, group) in enumerate(groups):
            dtype = np.dtype([("t", "<f8")] + [x for j in range(len(group)) for x in ((f"v{j}", "<f8"),
                                                                                      (f"f{j}", "<u2"))])
            for t, cols in _group_blocks(group, group_block_samples(len(group), size)):
                rec = np.empty(len(t), dtype)
                rec["t"] = t
                for j in range(len(group)):
                    rec[f"v{j}"] = cols[2 * j]
                    rec[f"f{j}"] = cols[2 * j + 1]
                del t, cols
                out.append(k, rec, owned=True)  # a new array, not touched again
                del rec
            out.finish_group(k)
            release([ch.name for ch in group])
    finally:
        out.close()
    return path


def _same_times(a: Any, b: Any, size: int) -> bool:
    """Whether two channels have the same timestamps, compared block by block (within :data:`WRITE_BLOCK_BYTES` of
    reads each)."""
    if len(a) != len(b):
        return False
    size = group_block_samples(1, size)
    return all(np.array_equal(a.block(k, k + size)[0], b.block(k, k + size)[0]) for k in range(0, len(a), size))


def _group_blocks(group: list[Any], size: int) -> Iterator[tuple[np.ndarray, list[np.ndarray]]]:
    """``(timestamps, [values, flags, values, flags, ...])`` of channels on one time base, a block at a time."""
    for start in range(0, max(len(group[0]), 1), size):
        cols: list[np.ndarray] = []
        t = np.zeros(0)
        for k, ch in enumerate(group):
            tk, v, f = ch.block(start, start + size)
            t = tk if k == 0 else t
            cols += [v, f]
        yield t, cols


#: bytes of records asammdf reads at a time for one channel of a :class:`ChannelFile`
READ_FRAGMENT_BYTES = 8 << 20


class ChannelFile:
    """One MF4 file kept open for the lazy channels of a Recording: reads one channel (and its flags) at a time.

    Channels of one channel group share one timestamps array while any of them is loaded (held weakly).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._mdf: Any = None
        self._stream: Any = None
        self._lock = threading.RLock()
        self._times: dict[int, weakref.ref[np.ndarray]] = {}

    def mdf(self) -> Any:
        """The open asammdf MDF (opened on first use; :class:`DataError` if unreadable)."""
        with self._lock:
            if self._mdf is None:
                if not self.path.is_file():
                    open_mdf(self.path)  # says why (no such file, a folder)
                self._stream = self.path.open("rb")  # read, not mapped: resident memory is what is read now
                try:
                    self._mdf = open_mdf(self.path, stream=self._stream)
                except DataError:
                    self._stream.close()
                    self._stream = None
                    raise
                # records are read in fragments of this size: reading one channel of a long group holds one
                # fragment of the group's records at a time, not all of them
                self._mdf.configure(read_fragment_size=READ_FRAGMENT_BYTES)
            return self._mdf

    def close(self) -> None:
        """Close the file (it is opened again when a channel is next read)."""
        with self._lock:
            if self._mdf is not None:
                self._mdf.close()
                self._mdf = None
            if self._stream is not None:
                self._stream.close()
                self._stream = None


    def _guarded(self, what: str, fn: Callable[[], np.ndarray]) -> np.ndarray:
        with self._lock, _QUIET_MDF_DEL:
            try:
                return fn()
            except DataError:
                raise
            except Exception as exc:  # asammdf raises many kinds for a damaged data block
                raise DataError(f"{self.path}: {what} unreadable ({exc or type(exc).__name__})") from None

    def times(self, gi: int) -> np.ndarray:
        """The master (time) channel of channel group ``gi``, float64; one array per group while it is in use."""
        ref = self._times.get(gi)
        ts = ref() if ref is not None else None
        if ts is None:
            ts = self._guarded(f"time of channel group {gi}",
                               lambda: np.asarray(self.mdf().get_master(gi), dtype=np.float64))
            self._times[gi] = weakref.ref(ts)
        return ts

    def read(self, name: str, gi: int, ci: int, numeric_conversion: bool = False) -> np.ndarray:
        """The samples of channel ``ci`` of group ``gi`` as stored (``numeric_conversion``: physical values)."""
        def get() -> np.ndarray:
            if numeric_conversion:  # a numeric conversion (another tool's file): physical values
                return np.asarray(self.mdf().get(name, group=gi, index=ci).samples)
            return np.asarray(self.mdf().get(name, group=gi, index=ci, raw=True, samples_only=True)[0])

        return self._guarded(f"channel {name!r}", get)

    def select(self, picks: list[tuple[str, int, int]]) -> list[Any]:
        """asammdf Signals (raw samples) of ``(name, group, index)`` picks, each group's data read once."""
        if not picks:
            return []
        return list(self._guarded(f"channels {', '.join(repr(p[0]) for p in picks[:3])}...",
                                  lambda: self.mdf().select(picks, raw=True)))

    def loader(self, name: str, gi: int, ci: int, numeric_conversion: bool, flags_at: tuple[int, int] | None
               ) -> Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """``load() -> (timestamps, values float64, flags uint16)`` of one Recording channel and its flags channel."""
        def load() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            ts = self.times(gi)
            vs = np.asarray(self.read(name, gi, ci, numeric_conversion), dtype=np.float64)
            fl = (np.asarray(self.read(f"{name}.flags", *flags_at), dtype=np.uint16)
                  if flags_at is not None else np.zeros(vs.shape, dtype=np.uint16))
            return ts, vs, fl

        return load


def value_text_conversion(texts: dict[int, str] | None) -> dict[str, Any] | None:
    """An MDF value-to-text conversion (asammdf dict form) of a value table, or None."""
    if not texts:
        return None
    conv: dict[str, Any] = {}
    for k, (value, text) in enumerate(sorted(texts.items())):
        conv[f"val_{k}"] = float(value)
        conv[f"text_{k}"] = str(text)
    conv["default_addr"] = ""
    return conv


def texts_of(conversion: Any) -> dict[int, str] | None:
    """The value table of an MDF value-to-text conversion (None for any other conversion)."""
    if conversion is None or getattr(conversion, "conversion_type", None) != 7:  # 7: value to text (TABX)
        return None
    out = {}
    for k in range(int(conversion.ref_param_nr) - 1):
        text = conversion.referenced_blocks.get(f"text_{k}")
        if isinstance(text, bytes):
            out[int(conversion[f"val_{k}"])] = text.decode("utf-8", "replace")
    return out or None
