"""The Recording: what an acquisition decoded, per source on its own time base, with quality flags.

A Recording is the only input identification accepts. It comes from the acquisition (batch or
live), or from a real car's CSV/MF4 log through a signal map. It is saved and loaded as ASAM MDF 4
with asammdf: one channel group per source, each channel with its unit, and a companion
``<name>.flags`` channel holding the :class:`Flag` bits.
"""

from __future__ import annotations

import gc
import json
import sys
import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from datetime import datetime
from enum import IntFlag
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.errors import DataError, MissingChannelError
from benchtwin.segments import Segment, segments_from_json, segments_to_json

__all__ = ["FLAG_CONVERSION", "Channel", "Flag", "Recording", "open_mdf"]


#: numpy dtype kinds of MF4 channels that are not numbers, as a user would call them
_KINDS = {"V": "records (e.g. CAN frames)", "S": "bytes", "U": "text", "O": "objects"}


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
            if type(value).__name__ in ("MDF4", "MDF3") and not hasattr(value, "_file"):
                value._closed = True
        tb = tb.tb_next


def open_mdf(path: str | Path, **kwargs: Any) -> Any:
    """Open an MF4 file with asammdf; a file asammdf cannot read is one :class:`DataError` line.

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
            return MDF(path, **kwargs)
        except Exception as exc:  # asammdf raises many kinds for a bad file
            reason = str(exc) or type(exc).__name__
            _disarm(exc.__traceback__)
        gc.collect()  # the half-built object (held by the traceback until here) goes now, quietly
    raise DataError(f"{path}: not a readable MF4 file ({reason})")


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


def _value_text_conversion(texts: dict[int, str] | None) -> dict[str, Any] | None:
    """An MDF value-to-text conversion (asammdf dict form) of a value table, or None."""
    if not texts:
        return None
    conv: dict[str, Any] = {}
    for k, (value, text) in enumerate(sorted(texts.items())):
        conv[f"val_{k}"] = float(value)
        conv[f"text_{k}"] = str(text)
    conv["default_addr"] = ""
    return conv


def _texts_of(conversion: Any) -> dict[int, str] | None:
    """The value table of an MDF value-to-text conversion (None for any other conversion)."""
    if conversion is None or getattr(conversion, "conversion_type", None) != 7:  # 7: value to text (TABX)
        return None
    out = {}
    for k in range(int(conversion.ref_param_nr) - 1):
        text = conversion.referenced_blocks.get(f"text_{k}")
        if isinstance(text, bytes):
            out[int(conversion[f"val_{k}"])] = text.decode("utf-8", "replace")
    return out or None


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

    def flags_at(self, t_s: np.ndarray) -> np.ndarray:
        """Flags of the sample at or before each time in ``t_s`` (zero-order hold)."""
        t_s = np.asarray(t_s, dtype=np.float64)
        if len(self) == 0:
            return np.full(t_s.shape, int(Flag.LOST_FRAME), dtype=np.uint16)
        idx = np.clip(np.searchsorted(self.timestamps, t_s, side="right") - 1, 0, len(self) - 1)
        return self.flags[idx]


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
        lo = max(c.timestamps[0] for c in chans) if start_s is None else start_s
        hi = min(c.timestamps[-1] for c in chans) if end_s is None else end_s
        if not hi > lo:
            raise DataError(f"channels {', '.join(names)} do not overlap in time")
        t = np.arange(lo, hi, 1.0 / rate_hz)
        out: dict[str, np.ndarray] = {}
        bad = np.zeros(t.shape, dtype=bool)
        for c in chans:
            v = c.at(t, hold=c.name in hold)
            out[c.name] = v
            bad |= ~np.isfinite(v) | ((c.flags_at(t) & int(Flag.bad())) != 0)
        return t, out, bad

    def save(self, path: str | Path) -> Path:
        """Save as MF4 (one channel group per source) with units and flags.

        The header start time is :attr:`start_time` (the raw logs' start: acquisition time 0), so the
        Recording and the bus logs of a run line up in any MDF tool. Each ``<name>.flags`` channel
        carries a bit-field text table (``SATURATED|LOST_FRAME``) and each state channel with
        :attr:`Channel.value_texts` a value-to-text table, so the asammdf viewer shows words.

        The segment table and the metadata travel in the file comment (JSON) and in a sidecar
        ``<stem>.segments.json`` next to the file.
        """
        from asammdf import MDF, Signal

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        mdf = MDF(version="4.10")
        by_source: dict[str, list[Channel]] = {}
        for ch in self.channels.values():
            by_source.setdefault(ch.source or "default", []).append(ch)
        for source, chans in sorted(by_source.items()):
            # channels of one source may still have different time bases: one group per time base
            groups: dict[bytes, list[Channel]] = {}
            for ch in chans:
                groups.setdefault(ch.timestamps.tobytes()[:64] + bytes(str(len(ch)), "ascii"), []).append(ch)
            for group in groups.values():
                sigs = []
                for ch in group:
                    sigs.append(Signal(ch.values, ch.timestamps, name=ch.name, unit=ch.unit,
                                       comment=f"source={source}", conversion=_value_text_conversion(ch.value_texts)))
                    sigs.append(Signal(ch.flags, ch.timestamps, name=f"{ch.name}.flags", unit="",
                                       comment="benchtwin quality flags (see benchtwin.recording.Flag)",
                                       conversion=FLAG_CONVERSION))
                mdf.append(sigs, comment=source, acq_name=source)
        if self.start_time is not None:
            mdf.header.start_time = self.start_time
        mdf.header.comment = json.dumps({"benchtwin": {"meta": self.meta, "segments": json.loads(
            segments_to_json(self.segments))}}, default=str)
        path = Path(mdf.save(path, overwrite=True))  # asammdf makes the suffix .mf4: the real name
        mdf.close()
        path.with_suffix(".segments.json").write_text(segments_to_json(self.segments), encoding="utf-8")
        return path

    @classmethod
    def load(cls, path: str | Path) -> Recording:
        """Load a Recording saved by :meth:`save`.

        Raises
        ------
        DataError
            If the file cannot be read as MF4.
        """
        path = Path(path)
        mdf = open_mdf(path)
        rec = cls()
        with mdf:
            values: dict[str, Any] = {}
            flags: dict[str, np.ndarray] = {}
            for gi, group in enumerate(mdf.groups):
                source = str(getattr(group.channel_group, "acq_name", "") or "")
                for ci, ch in enumerate(group.channels):
                    if ch.name == "time" or ch.name.startswith("$"):
                        continue
                    sig = mdf.get(ch.name, group=gi, index=ci, raw=True)
                    if sig.conversion is not None and getattr(sig.conversion, "conversion_type", None) not in (7, 11):
                        sig = mdf.get(ch.name, group=gi, index=ci)  # a numeric conversion (another tool's file)
                    if ch.name.endswith(".flags"):
                        flags[ch.name[:-6]] = np.asarray(sig.samples, dtype=np.uint16)
                    else:
                        values[ch.name] = (sig, source)
            for name, (sig, source) in values.items():
                try:
                    samples = np.asarray(sig.samples, dtype=np.float64)
                except (TypeError, ValueError):  # a CAN frame group, text, a structure: not a Recording
                    raise DataError(
                        f"{path}: channel {name!r} holds {_KINDS.get(np.asarray(sig.samples).dtype.kind, 'data')}, "
                        "not numbers: this is not a benchtwin Recording (a raw bus log: decode it with benchtwin "
                        "acquire; another tool's log: import it with --signal-map)") from None
                rec.add(Channel(name, sig.unit or "", sig.timestamps, samples, flags.get(name), source,
                                _texts_of(sig.conversion)))
            comment = getattr(mdf.header, "description", "") or ""
            rec.start_time = mdf.header.start_time
        side = path.with_suffix(".segments.json")
        try:
            blob = json.loads(comment)["benchtwin"]
            rec.meta = dict(blob.get("meta", {}))
            rec.segments = segments_from_json(json.dumps(blob.get("segments", [])), str(path))
        except (ValueError, KeyError, TypeError):
            if side.exists():
                rec.segments = segments_from_json(side.read_text(encoding="utf-8"), str(side))
        return rec
