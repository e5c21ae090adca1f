"""The Recording: what an acquisition decoded, per source on its own time base, with quality flags.

A Recording is the only input identification accepts. It comes from the acquisition (batch or
live), or from a real car's CSV/MF4 log through a signal map. It is saved and loaded as ASAM MDF 4
with asammdf: one channel group per source, each channel with its unit, and a companion
``<name>.flags`` channel holding the :class:`Flag` bits.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from datetime import datetime
from enum import IntFlag
from pathlib import Path
from typing import Any, Protocol, cast

import numpy as np

from benchtwin.errors import DataError, MissingChannelError
from benchtwin.mdf import (
    DEFAULT_COMPRESSION,
    ChannelFile,
    check_compression,
    open_mdf,
    save_channel_groups,
    texts_of,
)
from benchtwin.segments import Segment, segments_from_json, segments_to_json

__all__ = [
    "DEFAULT_COMPRESSION",
    "FLAG_CONVERSION",
    "Channel",
    "Flag",
    "LazyChannel",
    "Recording",
    "check_compression",
    "open_mdf",
]


class Flag(IntFlag):
    """Quality flags of one sample (bits of a uint16)."""

    OK = 0
    SATURATED = 1 << 0  #: the sensor or converter was at its range limit (clipped)
    LOST_FRAME = 1 << 1  #: a frame before this sample was lost (counter gap, PDO gap)
    STATUS_ERROR = 1 << 2  #: the device reported an error in its status bits
    OUT_OF_RANGE = 1 << 3  #: the device reported this result out of its measuring range
    TIMEOUT = 1 << 4  #: a poll timed out; the value is held from the last good one
    PROTOCOL_ERROR = 1 << 5  #: a malformed frame or exception response was received here
    DUPLICATE = 1 << 6  #: the same frame (counter) was received twice
    OUT_OF_ORDER = 1 << 7  #: the frame arrived after a newer one
    STALE = 1 << 8  #: the value did not change while it should (stuck-at suspected)
    TRANSPORT_DROP = 1 << 9  #: the transport dropped around this sample
    LATE = 1 << 10  #: the answer came late (a slow server); stamped with the module's own uptime, so still usable
    CLOCK = 1 << 11  #: the source's clock stepped or drifted here: its time base is off

    @classmethod
    def bad(cls) -> Flag:
        """The flags that make a sample unusable for identification."""
        return (cls.SATURATED | cls.STATUS_ERROR | cls.OUT_OF_RANGE | cls.TIMEOUT | cls.PROTOCOL_ERROR
                | cls.STALE | cls.CLOCK)


#: MDF bit-field text table of the flag bits: a viewer shows ``SATURATED|LOST_FRAME`` for 3
FLAG_CONVERSION: dict[str, Any] = {}
for _k, _f in enumerate(f for f in Flag if f.value):
    FLAG_CONVERSION[f"mask_{_k}"] = int(_f.value)
    FLAG_CONVERSION[f"text_{_k}"] = {"val_0": int(_f.value), "text_0": _f.name, "default_addr": ""}


@dataclass
class Channel:
    """One decoded channel.

    Attributes
    ----------
    name:
        Role name (see :mod:`benchtwin.roles`) or the user's own name.
    unit:
        Engineering unit.
    timestamps:
        Acquisition time of each sample, seconds, on the source's own clock.
    values:
        Decoded values, float64.
    flags:
        :class:`Flag` bits per sample, uint16.
    source:
        Which device or bus it came from (``ivt_battery``, ``vehicle_can``, ``modbus_pressure``).
    value_texts:
        For a state channel (hybrid mode, gear, clutch states): value -> text, from the DBC's value
        table; saved as an MDF value-to-text conversion so a viewer shows the words.
    """

    name: str
    unit: str
    timestamps: np.ndarray
    values: np.ndarray
    flags: np.ndarray | None = None
    source: str = ""
    value_texts: dict[int, str] | None = None

    def __post_init__(self) -> None:
        self.timestamps = np.asarray(self.timestamps, dtype=np.float64)
        self.values = np.asarray(self.values, dtype=np.float64)
        if self.flags is None:
            self.flags = np.zeros(self.values.shape, dtype=np.uint16)
        self.flags = np.asarray(self.flags, dtype=np.uint16)
        if not (self.timestamps.shape == self.values.shape == self.flags.shape) or self.values.ndim != 1:
            raise DataError(
                f"channel {self.name!r}: timestamps {self.timestamps.shape}, values {self.values.shape} and "
                f"flags {self.flags.shape} must be 1-D and of one length"
            )

    def __len__(self) -> int:
        return int(self.values.shape[0])

    @property
    def good(self) -> np.ndarray:
        """Boolean mask of samples free of :meth:`Flag.bad` flags and finite."""
        return ((self.flags & int(Flag.bad())) == 0) & np.isfinite(self.values)

    def at(self, t_s: np.ndarray, *, hold: bool = False) -> np.ndarray:
        """Values at times ``t_s``: linear interpolation, or zero-order hold with ``hold=True``.

        Outside the channel's span the result is NaN.
        """
        t_s = np.asarray(t_s, dtype=np.float64)
        if len(self) == 0:
            return np.full(t_s.shape, np.nan)
        if hold:
            idx = np.searchsorted(self.timestamps, t_s, side="right") - 1
            out = self.values[np.clip(idx, 0, len(self) - 1)].copy()
            out[idx < 0] = np.nan
        else:
            out = np.interp(t_s, self.timestamps, self.values)
            out[t_s < self.timestamps[0]] = np.nan
        out[t_s > self.timestamps[-1]] = np.nan
        return out

    def with_values(self, values: np.ndarray) -> Channel:
        """A plain in-memory Channel with these values and this channel's times, flags and metadata.

        Works for every Channel kind (a lazily read one included): the copy holds its arrays in memory.
        """
        return Channel(name=self.name, unit=self.unit, timestamps=self.timestamps, values=values, flags=self.flags,
                       source=self.source, value_texts=self.value_texts)

    def flags_at(self, t_s: np.ndarray) -> np.ndarray:
        """Flags of the sample at or before each time in ``t_s`` (zero-order hold)."""
        t_s = np.asarray(t_s, dtype=np.float64)
        if len(self) == 0:
            return np.full(t_s.shape, int(Flag.LOST_FRAME), dtype=np.uint16)
        idx = np.clip(np.searchsorted(self.timestamps, t_s, side="right") - 1, 0, len(self) - 1)
        return self.flags[idx]

    def block(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Timestamps, values and flags of samples ``start:stop`` (a lazy channel with a block reader reads only
        those; otherwise slices of the whole arrays)."""
        return self.timestamps[start:stop], self.values[start:stop], self.flags[start:stop]


class LazyChannel(Channel):
    """A :class:`Channel` whose arrays are read on first access (from an MF4 file) and can be dropped again.

    Name, unit, source, value texts and the sample count are known without reading the data. Reading is
    done by ``loader() -> (timestamps, values, flags)``; :meth:`drop` forgets the arrays (the next access
    reads them again), unless they were replaced (assigned) since: data that is not in the file is never
    dropped. Changing a loaded array in place is not tracked: drop only what was read for reading.
    """

    def __init__(self, name: str, unit: str, source: str, n: int,
                 loader: Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]],
                 value_texts: dict[int, str] | None = None, *,
                 block_loader: Callable[[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None) -> None:
        self.name = name
        self.unit = unit
        self.source = source
        self.value_texts = value_texts
        self._n = int(n)
        self._loader = loader
        self._block_loader = block_loader  # (start, stop) -> those samples, read without the whole channel
        self._arrays: list[np.ndarray] | None = None
        self._assigned = False

    def _load(self) -> list[np.ndarray]:
        arrays = self._arrays  # one read: another thread's drop() between the check and the return cannot empty it
        if arrays is None:
            ts, vs, fl = self._loader()
            if not (ts.shape == vs.shape == fl.shape == (self._n,)):
                raise DataError(f"channel {self.name!r}: the file gave {vs.shape[0]} values and {ts.shape[0]} times, "
                                f"its channel group counts {self._n}")
            arrays = self._arrays = [ts, vs, fl]
        return arrays

    def _set(self, k: int, value: Any, dtype: Any) -> None:
        arrays = self._load()
        arrays[k] = np.asarray(value, dtype=dtype)
        self._n = int(arrays[1].shape[0])
        self._assigned = True

    timestamps = property(lambda self: self._load()[0],  # type: ignore[assignment]
                          lambda self, v: self._set(0, v, np.float64))
    values = property(lambda self: self._load()[1],  # type: ignore[assignment]
                      lambda self, v: self._set(1, v, np.float64))
    flags = property(lambda self: self._load()[2],  # type: ignore[assignment]
                     lambda self, v: self._set(2, v, np.uint16))

    def __len__(self) -> int:
        return self._n if (arrays := self._arrays) is None else int(arrays[1].shape[0])  # read once (see _load)

    def __repr__(self) -> str:
        state = "loaded" if self._arrays is not None else "not loaded"
        return f"LazyChannel({self.name!r}, {self.unit!r}, source={self.source!r}, {self._n} samples, {state})"

    def block(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._arrays is None and self._block_loader is not None:
            start, stop = (min(max(k, 0), self._n) for k in (start, stop))
            return self._block_loader(start, max(start, stop))
        return super().block(start, stop)

    @property
    def loaded(self) -> bool:
        """Whether the arrays are in memory."""
        return self._arrays is not None

    def drop(self) -> bool:
        """Forget the arrays (read again on next access); False (kept) when they were assigned since."""
        if self._assigned:
            return False
        self._arrays = None
        return True


class Closable(Protocol):
    """What a Recording can own and close with itself: the source of its lazy channels."""

    def close(self) -> None: ...


#: MDF 4 channel data types that hold numbers (unsigned, signed, float; little or big endian)
_NUMERIC_DATA_TYPES = frozenset(range(6))


@dataclass
class Recording:
    """Decoded channels from every source, each on its own time base, plus the segment table.

    Attributes
    ----------
    channels:
        Name -> :class:`Channel`.
    segments:
        The campaign's tests (may be empty for real logs).
    meta:
        Free metadata: sources, detected clock offsets, counts of flagged samples, transports.
    start_time:
        Absolute time of timestamp 0 (UTC): the campaign start (batch) or the acquisition start (live);
        the raw bus logs of the run start at the same time. None: unknown (saved as the save time).
    """

    channels: dict[str, Channel] = field(default_factory=dict)
    segments: list[Segment] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)
    start_time: datetime | None = None
    _files: list[Closable] = field(default_factory=list, repr=False, compare=False)

    def __getitem__(self, name: str) -> Channel:
        try:
            return self.channels[name]
        except KeyError:
            raise MissingChannelError(
                f"recording has no channel {name!r} (has: {', '.join(sorted(self.channels)) or 'none'})"
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self.channels

    def __iter__(self) -> Iterator[str]:
        return iter(self.channels)

    def add(self, channel: Channel) -> None:
        """Add or replace a channel."""
        self.channels[channel.name] = channel

    def sources(self) -> list[str]:
        """Sorted names of the sources present."""
        return sorted({c.source for c in self.channels.values()})

    def time_span(self) -> tuple[float, float]:
        """Earliest and latest timestamp over all channels."""
        starts = [c.timestamps[0] for c in self.channels.values() if len(c)]
        ends = [c.timestamps[-1] for c in self.channels.values() if len(c)]
        if not starts:
            raise DataError("recording is empty")
        return float(min(starts)), float(max(ends))

    def resample(self, names: Iterable[str], rate_hz: float, *, start_s: float | None = None,
                 end_s: float | None = None, hold: Iterable[str] = ()) -> tuple[np.ndarray, dict[str, np.ndarray],
                                                                                np.ndarray]:
        """Bring channels onto one uniform time base.

        Parameters
        ----------
        names:
            Channels to resample.
        rate_hz:
            Rate of the common time base.
        start_s, end_s:
            Span; defaults to the overlap of the channels.
        hold:
            Channels to zero-order hold (states such as gears) instead of interpolating.

        Returns
        -------
        t, values, bad
            Common time base, name -> values, and a boolean mask of samples where any channel is
            flagged bad, missing or outside its span.
        """
        names = list(names)
        chans = [self[n] for n in names]
        hold = set(hold)
        if any(len(c) == 0 for c in chans):
            empty = [c.name for c in chans if len(c) == 0]
            raise DataError(f"channels without samples: {', '.join(empty)}")
        kept = self.loaded()  # lazy channels read here go again once used: one in memory at a time
        lo, hi = -np.inf, np.inf
        for c in chans:
            lo, hi = max(lo, c.timestamps[0]), min(hi, c.timestamps[-1])
            if c.name not in kept:
                self.drop([c.name])
        lo = lo if start_s is None else start_s
        hi = hi if end_s is None else end_s
        if not hi > lo:
            raise DataError(f"channels {', '.join(names)} do not overlap in time")
        t = np.arange(lo, hi, 1.0 / rate_hz)
        out: dict[str, np.ndarray] = {}
        bad = np.zeros(t.shape, dtype=bool)
        for c in chans:
            v = c.at(t, hold=c.name in hold)
            out[c.name] = v
            bad |= ~np.isfinite(v) | ((c.flags_at(t) & int(Flag.bad())) != 0)
            if c.name not in kept:
                self.drop([c.name])
        return t, out, bad

    def save(self, path: str | Path, *, compression: int = DEFAULT_COMPRESSION, workers: int = 2) -> Path:
        """Save as MF4 (one channel group per source) with units and flags (compressed on ``workers`` threads).

        ``compression`` is asammdf's: 0 none, 1 deflate, 2 transposed deflate (default
        :data:`DEFAULT_COMPRESSION`; every MDF 4.10 reader, CANape and asammdf among them, reads all three).

        The header start time is :attr:`start_time` (the raw logs' start: acquisition time 0), so the Recording and
        the bus logs of a run line up in any MDF tool. Each ``<name>.flags`` channel carries a bit-field text table
        (``SATURATED|LOST_FRAME``) and each state channel with :attr:`Channel.value_texts` a value-to-text table.

        The segment table and the metadata travel in the file comment (JSON), the segments also in a sidecar
        ``<stem>.segments.json``. Lazy channels read only to be written are dropped again (one group at a time).
        """
        from asammdf import MDF

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        mdf = MDF(version="4.10")
        kept = self.loaded()
        if self.start_time is not None:
            mdf.header.start_time = self.start_time
        mdf.header.comment = json.dumps({"benchtwin": {"meta": self.meta, "segments": json.loads(
            segments_to_json(self.segments)), "channels": list(self.channels)}}, default=str)
        # one group per source and time base, written block by block (a lazy channel with a block reader is never
        # read whole), compressed on threads; lazy channels read only to be written are dropped again, group by group
        path = save_channel_groups(path, mdf, self.channels.values(), FLAG_CONVERSION,
                                   lambda names: self.drop([n for n in names if n not in kept]),
                                   compression=check_compression(compression), workers=workers)
        path.with_suffix(".segments.json").write_text(segments_to_json(self.segments), encoding="utf-8")
        return path

    @classmethod
    def load(cls, path: str | Path, *, channels: Iterable[str] | None = None, lazy: bool = False) -> Recording:
        """Load a Recording saved by :meth:`save` (or another tool's MF4 of numeric channels).

        Parameters
        ----------
        path:
            The MF4 file.
        channels:
            Only these channels (default: all); a name not in the file is a :class:`MissingChannelError`.
        lazy:
            Read no data now: each channel is a :class:`LazyChannel` read from the file on first access
            (the file stays open until :meth:`close`); see :meth:`open`.

        Raises
        ------
        DataError
            If the file cannot be read as MF4, or a channel holds no numbers (a bus log).
        """
        path = Path(path)
        source = ChannelFile(path)
        mdf = source.mdf()
        rec = cls()
        found: dict[str, tuple[int, int, Any, str]] = {}
        flags_of: dict[str, tuple[int, int]] = {}
        for gi, group in enumerate(mdf.groups):
            acq = str(getattr(group.channel_group, "acq_name", "") or "")
            for ci, ch in enumerate(group.channels):
                if ch.name == "time" or ch.name.startswith("$") or int(getattr(ch, "channel_type", 0)) in (2, 3):
                    continue  # the master (time) channel
                if ch.name.endswith(".flags"):
                    flags_of[ch.name[:-6]] = (gi, ci)
                else:
                    found[ch.name] = (gi, ci, ch, acq)
        comment = getattr(mdf.header, "description", "") or ""
        try:
            blob = json.loads(comment)["benchtwin"]
        except (ValueError, KeyError, TypeError):
            blob = None
        if channels is None:  # in the order they were saved in (the groups hold them by source and time base)
            order = [n for n in blob.get("channels", []) if n in found] if isinstance(blob, dict) else []
            wanted = order + [n for n in found if n not in set(order)]
        else:
            wanted = list(dict.fromkeys(channels))
        absent = [n for n in wanted if n not in found]
        if absent:
            source.close()
            raise MissingChannelError(f"{path}: no channel {', '.join(map(repr, absent))} "
                                      f"(has: {', '.join(sorted(found)) or 'none'})")
        raw_picks: list[tuple[str, int, int]] = []  # read at once: every stored channel and its flags
        for name in wanted:
            gi, ci, ch, acq = found[name]
            if int(getattr(ch, "data_type", 0)) not in _NUMERIC_DATA_TYPES or getattr(ch, "component_addr", 0):
                source.close()
                kind = "text" if int(ch.data_type) in (6, 7, 8, 9) else "records (e.g. CAN frames)"
                raise DataError(
                    f"{path}: channel {name!r} holds {kind}, not numbers: this is not a benchtwin Recording (a raw "
                    "bus log: decode it with benchtwin acquire; another tool's log: import it with --signal-map)")
            conv = ch.conversion
            numeric = conv is not None and getattr(conv, "conversion_type", None) not in (7, 11)
            if not numeric:
                raw_picks.append((name, gi, ci))
                if name in flags_of:
                    raw_picks.append((f"{name}.flags", *flags_of[name]))
            unit = (getattr(conv, "unit", "") if conv is not None else "") or ch.unit or ""
            n = int(mdf.groups[gi].channel_group.cycles_nr)
            rec.add(LazyChannel(name, unit, acq, n, source.loader(name, gi, ci, numeric, flags_of.get(name)),
                                texts_of(conv)))
        rec.start_time = mdf.header.start_time
        rec.own(source)
        side = path.with_suffix(".segments.json")
        try:
            if blob is None:
                raise KeyError("benchtwin")
            rec.meta = dict(blob.get("meta", {}))
            rec.segments = segments_from_json(json.dumps(blob.get("segments", [])), str(path))
        except (ValueError, KeyError, TypeError):
            if side.exists():
                rec.segments = segments_from_json(side.read_text(encoding="utf-8"), str(side))
        if not lazy:
            try:
                # one select: each channel group's (compressed) data is read once for all its channels
                got = {p[0]: sig for p, sig in zip(raw_picks, source.select(raw_picks))}
                for ch in rec.channels.values():
                    chan = cast(LazyChannel, ch)
                    sig = got.get(chan.name)
                    if sig is None:  # a numeric conversion (another tool's file): its own read
                        ts, vs, fl = chan.timestamps, chan.values, chan.flags
                    else:
                        flags = got.get(f"{chan.name}.flags")
                        ts, vs = sig.timestamps, sig.samples
                        fl = flags.samples if flags is not None else None
                    rec.channels[chan.name] = Channel(chan.name, chan.unit, ts, vs, fl, chan.source, chan.value_texts)
            finally:
                rec.close()
        return rec

    @classmethod
    def open(cls, path: str | Path, *, channels: Iterable[str] | None = None) -> Recording:
        """A Recording whose channels are read from the MF4 file on first access (:meth:`load` with ``lazy=True``).

        Names, units, sources, sample counts, segments and metadata are there at once; each channel's
        arrays are read when first used and can be dropped again with :meth:`drop`. Close the file with
        :meth:`close` (or use the Recording in a ``with`` block) when done.
        """
        return cls.load(path, channels=channels, lazy=True)

    def loaded(self) -> set[str]:
        """Names of the channels whose arrays are in memory (every channel of an eager Recording)."""
        return {n for n, c in self.channels.items() if not isinstance(c, LazyChannel) or c.loaded}

    def drop(self, names: Iterable[str] | None = None) -> None:
        """Forget the arrays of lazy channels (default: all), to be read again from the file when next used.

        Channels held in memory only (not lazy, or assigned since they were read) are kept: nothing
        recorded is lost.
        """
        for n in (self.channels if names is None else names):
            ch = self.channels.get(n)
            if isinstance(ch, LazyChannel):
                ch.drop()

    def own(self, file: Closable) -> None:
        """Close ``file`` (the source of lazy channels, e.g. an imported log or the acquisition's chunk files) with
        this Recording."""
        self._files.append(file)

    def close(self) -> None:
        """Close the files of lazy channels (loaded arrays stay; channels not loaded can no longer be read)."""
        for f in self._files:
            f.close()

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

