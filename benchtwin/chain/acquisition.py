"""The acquisition: decode what the bench received (CAN frames, PDOs, Modbus polls) into a Recording.

:func:`acquire` is the one decoder of the project. Batch mode calls it with the frame tables and
poll logs read from the raw logs (or straight from the sensors' outputs); the live recorder calls
it with what it received from the transports. It never raises on bad traffic: malformed frames
(wrong DLC, bad IVT-S mux byte), unknown identifiers, Modbus exception answers and timeouts,
counter gaps, duplicates, reordering, PDO gaps and transport drops are counted in
``Recording.meta`` and flagged on the samples they affect (:class:`~benchtwin.recording.Flag`),
and every good sample is kept. :class:`Acquisition` is the same decoder fed chunk by chunk (what spans chunks
carried explicitly, the result bit for bit :func:`acquire`'s); :func:`acquire` is its one-chunk case.

Decoding is vectorised: frames are grouped per identifier with one stable sort, and each group is
unpacked column-wise from the DBC/EDS layouts (:mod:`benchtwin.wire.codec` compiled from the
cantools Signal definitions of the IVT-S, AD module, vehicle and dyno messages;
:mod:`benchtwin.wire.canopen_pdo` from the EDS TPDO mapping read with canopen).

Channels keep the time base of their source (the device's clock as stamped on the frame, the
pressure module's uptime registers). ``meta["clock_offsets_s"]`` reports the offsets between
sources detected by cross-correlation: key ``"a->b"`` is the time to add to ``a``'s timestamps to
line them up with ``b``'s (vehicle speed on the vehicle CAN vs the dyno roller speed; CAN motor
power vs the HPCU shunt's power; the drive force from the CAN's engine and motor power over the vehicle
speed vs the telemetry's shaft torque), and ``"pressure->acquisition"`` the median of poll time minus
module uptime. On recordings of an hour or more, ``meta["clock_drift_ppm"]`` gives the relative
drift of the same pairs, ``meta["clock_drift_se_ppm"]`` their standard errors and ``meta["clock_offset_time_s"]``
the time (on the first source's clock) at which each detected offset holds (:mod:`benchtwin.chain.alignment`).
"""

from __future__ import annotations

import logging
import math
import tempfile
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.chain.alignment import detect_lag
from benchtwin.chain.blocks import BLOCK_SAMPLES, ChannelBlocks
from benchtwin.chain.channel_store import ChannelStore
from benchtwin.chain.decoding import (
    BusLoad,
    declared_uncertainty,
    decoders_of,
    events_for,
    flag_saturation,
    flag_truncations,
)
from benchtwin.chain.decoding import bus_load as _bus_load  # noqa: F401  (the name earlier code imports)
from benchtwin.chain.deferred_save import DeferredSave
from benchtwin.chain.faults import detect_faults
from benchtwin.chain.offsets_beside import OffsetsBeside
from benchtwin.chain.pollspool import PollSpool, decode_spooled
from benchtwin.chain.streams import hold_cut, split_streams
from benchtwin.config.setup import SetupConfig
from benchtwin.errors import DataError
from benchtwin.recording import Flag, Recording
from benchtwin.segments import Segment
from benchtwin.sensors import devices
from benchtwin.sensors.base import FrameDecoder
from benchtwin.wire.frames import FrameTable, PollLog, TransportEvent
from benchtwin.wire.quality import DecodeSink, FrameStream

__all__ = ["CONTEXT_FRAMES", "HOLD_FRAMES", "Acquisition", "AcquisitionInput", "acquire", "declared_uncertainty",
           "detect_lag"]

log = logging.getLogger(__name__)

#: polls of a poll log decoded at a time (at most; ``block_samples`` when smaller): 38 B a poll read, ~0.13 kB a poll
#: while its five channels are made
POLL_BLOCK = 1 << 18


@dataclass
class AcquisitionInput:
    """Everything an acquisition received, ready to decode.

    Attributes
    ----------
    can:
        Bus name -> frames received (PDO frames included on their bus).
    polls:
        Modbus device name -> poll log.
    events:
        Transport events (drops, reconnects) to flag.
    segments:
        The campaign's segment table (on the acquisition clock).
    meta:
        Extra metadata carried into the Recording.
    start_time:
        Absolute time (UTC) of time 0 (the campaign start in batch, the acquisition start live); the
        Recording and the raw logs carry it as their start time.
    """

    can: dict[str, FrameTable] = field(default_factory=dict)
    polls: dict[str, PollLog] = field(default_factory=dict)
    events: list[TransportEvent] = field(default_factory=list)
    segments: list[Segment] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)
    start_time: datetime | None = None

    def split_by_time(self, edges_s: list[float] | np.ndarray) -> list[AcquisitionInput]:
        """The input cut at ``edges_s`` (s, increasing) into ``len(edges_s) + 1`` chunks, for :class:`Acquisition`.

        Each chunk holds every bus's frames and every poll log's polls with ``edge[k-1] <= t < edge[k]``, and the
        transport events that start in it; the first carries the segments, meta data and start time. The frame
        tables are views on this input's (no copy).
        """
        edges = np.asarray(edges_s, dtype=np.float64)
        if edges.ndim != 1 or np.any(np.diff(edges) <= 0) or not np.all(np.isfinite(edges)):
            raise DataError(f"split_by_time: the edges must be finite and increasing, got {edges_s!r}")
        out = [AcquisitionInput() for _ in range(edges.size + 1)]
        out[0].segments, out[0].meta, out[0].start_time = list(self.segments), dict(self.meta), self.start_time
        for bus, table in self.can.items():
            cut = np.searchsorted(table.frames["timestamp"], edges, side="left")
            for k, (a, b) in enumerate(zip(np.concatenate([[0], cut]), np.concatenate([cut, [len(table)]]))):
                out[k].can[bus] = FrameTable(bus, table.frames[a:b], table.bitrate)
        for device, p in self.polls.items():
            cut = np.searchsorted(p.times, edges, side="left")
            for k, (a, b) in enumerate(zip(np.concatenate([[0], cut]), np.concatenate([cut, [len(p)]]))):
                out[k].polls[device] = PollLog(p.device, p.unit_id, p.function_code, p.first_register,
                                               p.times[a:b], p.values[a:b], p.status[a:b])
        for e in self.events:
            out[int(np.searchsorted(edges, e.time_s, side="right"))].events.append(e)
        return out


#: frames of each stream carried from one chunk to the next: a frame is judged from the frames before it (counter
#: continuity over duplicates, the spacing of a stream without a counter, the good frame after a bad one)
CONTEXT_FRAMES = 32
#: frames at the end of a chunk whose samples wait for the next chunk: a counter jump is told from a reorder by
#: the frame after it
HOLD_FRAMES = 8


@dataclass
class _Stream:
    """What one stream (bus, identifier) carries from one chunk to the next."""

    order: tuple[int, int]
    emitted_s: float = -math.inf  #: samples before this time are in the store
    t: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float64))  #: the context frames
    dlc: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint8))
    words: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint64))
    evidence: list[tuple[str, str, str, np.ndarray, np.ndarray]] = field(default_factory=list)


def _add_counts(into: dict[str, Any], counts: dict[str, Any], sign: int = 1) -> None:
    """``into[key][name] += sign * counts[key][name]`` for the per-frame counts of a decode."""
    for key, sub in counts.items():
        if key in ("frames", "unknown_ids") or not isinstance(sub, dict):
            continue
        d = into.setdefault(key, {})
        for name, n in sub.items():
            d[name] = d.get(name, 0) + sign * int(n)


class Acquisition:
    """A streaming acquisition: decode successive chunks of what the bench received, the Recording at the end.

    ``Acquisition(setup, path).feed(chunk)...feed(chunk).finish()`` gives the Recording :func:`acquire` gives
    of the chunks joined, bit for bit (every channel's timestamps, values and flags, and ``meta``), with the
    decoded samples appended to files beside ``path`` as they come, so what is held in memory is one chunk.
    Chunks are :class:`AcquisitionInput` pieces cut by time: on every bus (and poll log) a chunk's frames come
    after the previous chunk's.

    What spans chunks is carried explicitly. Per stream (bus, identifier): the last :data:`CONTEXT_FRAMES`
    frames, decoded again in front of the next chunk's so counter continuity, duplicates, reorders, cycle and
    PDO gaps and the good frame after a bad one are judged as in one piece, and the samples of the last
    :data:`HOLD_FRAMES` frames held back until the frame after them has come (a reorder is told from a loss by
    it); per-frame counts (protocol errors, IVT-S commands, answers and over-current frames, NMT messages) and
    fault evidence are kept for the new frames only. Per bus: frame counts, unknown identifiers, the bus-load
    histogram (:class:`~benchtwin.chain.decoding.BusLoad`). Transport events accumulate (a drop that spans a
    chunk edge flags the first sample after it, whichever chunk it is in). Poll logs are gathered and decoded
    in :meth:`finish` (the Modbus decoder judges the module's clock over the whole log; a poll log is a
    hundredth of the frames). :meth:`finish` runs what needs the whole recording on the stored channels:
    truncation and saturation flags, fault detection (gaps against the channel's median period, frozen
    outputs), clock offsets and drifts by cross-correlation (the few channels they use), the flag counts.

    Parameters
    ----------
    setup:
        The bench.
    path:
        Save the Recording here (MF4, :meth:`Recording.save <benchtwin.recording.Recording.save>`) and return it
        opened lazily; the chunks' samples are appended to files in a folder beside it until then. None: keep
        them in memory and return an in-memory Recording.
    align:
        Detect clock offsets between sources.
    keep_chunks:
        Return the Recording read from the chunks' files (raw samples, each channel read through a file handle
        when used and dropped again; the files go when the Recording is closed) instead of from the compressed
        ``path`` (which is still written when given): the channels are read many times over (identification,
        validation) at the cost of a plain file read. Without ``path`` the files are in a temporary folder.
    block_samples:
        Samples per block of :meth:`finish`'s whole-recording passes (:mod:`benchtwin.chain.blocks`): what they
        hold of a channel at a time, whatever the length of the recording. The result does not depend on it.
    """

    def __init__(self, setup: SetupConfig, path: str | Path | None = None, *, align: bool = True,
                 keep_chunks: bool = False, block_samples: int = BLOCK_SAMPLES) -> None:
        if int(block_samples) < 1:
            raise DataError(f"Acquisition: block_samples must be at least 1, got {block_samples}")
        self.block_samples = int(block_samples)
        self.setup = setup
        self.path = Path(path) if path is not None else None
        self.align = align
        self.keep_chunks = keep_chunks
        self._devs = devices(setup)
        self._polled = {d.poll_device: d for d in self._devs if d.poll_device is not None}
        where = self.path.parent if self.path is not None else (tempfile.gettempdir() if keep_chunks else None)
        self._store = ChannelStore(where)
        self._streams: dict[tuple[str, int], _Stream] = {}
        self._buses: dict[str, int] = {}  # bus -> position (first seen)
        self._of_bus: dict[str, set[str]] = {}
        self._loads: dict[str, BusLoad] = {}
        self._frames: dict[str, int] = {}
        self._unknown: dict[str, dict[int, int]] = {}
        self._counts: dict[str, Any] = {"protocol_errors": {}}
        self._polls: dict[str, PollSpool] = {}  # on disk beside the channels when the store is
        self._events: list[TransportEvent] = []
        self._segments: list[Segment] = []
        self._meta: dict[str, Any] = {}
        self._start_time: datetime | None = None
        self._last_s: dict[str, float] = {}
        self._bus_decoders: dict[str, tuple[dict[int, FrameDecoder], dict[int, str]]] = {}
        self._chunks = 0
        self._finished = False

    def feed(self, chunk: AcquisitionInput, *, last: bool = False) -> Acquisition:
        """Decode one chunk (``last``: nothing follows, hold nothing back).

        Raises
        ------
        DataError
            If ``chunk`` is not an :class:`AcquisitionInput`, comes after :meth:`finish`, or goes back in time.
        """
        if not isinstance(chunk, AcquisitionInput):
            raise DataError(f"acquire() takes an AcquisitionInput, not {type(chunk).__name__} (read logs with "
                            "benchtwin.chain.batch.read_logs, deliver device outputs with "
                            "benchtwin.chain.batch.deliver)")
        if self._finished:
            raise DataError("Acquisition.feed() after finish(): start a new Acquisition")
        self._chunks += 1
        self._events += chunk.events
        self._segments += chunk.segments
        self._meta.update(chunk.meta)
        if self._start_time is None:
            self._start_time = chunk.start_time
        for bus, table in chunk.can.items():
            self._buses.setdefault(bus, len(self._buses))
            self._of_bus.setdefault(bus, set())
            self._loads.setdefault(bus, BusLoad(table.bitrate)).add(table.frames)
            self._frames[bus] = self._frames.get(bus, 0) + len(table)
            if len(table):
                first = float(table.frames["timestamp"][0])
                if first < self._last_s.get(bus, -math.inf):
                    raise DataError(f"bus {bus}: a chunk starting at {first:.6f} s comes after frames up to "
                                    f"{self._last_s[bus]:.6f} s: feed the chunks in time order")
                self._last_s[bus] = float(table.frames["timestamp"][-1])
            try:
                self._decode_bus(table, last)
            except DataError:
                raise
            except Exception as exc:  # never lose the other buses because one is broken
                log.error("bus %s could not be decoded: %s", bus, exc)
                _add_counts(self._counts, {"protocol_errors": {f"{bus}: decoding failed ({exc})": max(1, len(table))}})
        for device, plog in chunk.polls.items():
            if device in self._polls:
                self._polls[device].append(plog)
            else:
                self._polls[device] = PollSpool(plog, self._store.directory)
        return self

    @property
    def poll_logs(self) -> dict[str, PollSpool]:
        """The poll logs fed so far, one :class:`~benchtwin.chain.pollspool.PollSpool` per device (read them, do not
        change them; :meth:`finish` decodes and removes them)."""
        return dict(self._polls)

    def _decode_bus(self, table: FrameTable, last: bool) -> None:
        frames = table.frames
        decoders, owner = self._decoders(table.bus)
        split = split_streams(frames, list(decoders))
        got = self._unknown.setdefault(table.bus, {})
        for k, v in split.unknown.items():
            got[k] = got.get(k, 0) + v
        drops = events_for(self._events, {table.bus})
        # one pass over the table writes every stream's columns (times, lengths, the data bytes as one 8-byte word)
        # side by side: one copy of the bus's three columns, each stream a view on them
        for cid in split.bounds:
            t, dlc, words = split.stream(cid)
            self._decode_stream(table.bus, cid, decoders[cid], owner[cid], t, dlc, words, drops, last)

    def _decoders(self, bus: str) -> tuple[dict[int, FrameDecoder], dict[int, str]]:
        """The decoders of ``bus`` and the device of each identifier (built once per bus)."""
        got = self._bus_decoders.get(bus)
        if got is None:
            owner = {cid: d.name for d in self._devs if d.bus == bus for cid in d.frame_decoders()}
            got = self._bus_decoders[bus] = (decoders_of(self._devs, bus), owner)
        return got

    def _decode_stream(self, bus: str, cid: int, dec: FrameDecoder, owner: str, t: np.ndarray, dlc: np.ndarray,
                       words: np.ndarray, drops: np.ndarray, last: bool) -> None:
        st = self._streams.get((bus, cid))
        if st is None:
            st = self._streams[(bus, cid)] = _Stream((self._buses[bus], cid))
        if st.t.size:
            t, dlc, words = (np.concatenate([st.t, t]), np.concatenate([st.dlc, dlc]),
                             np.concatenate([st.words, words]))
        n = t.shape[0]
        lo, hi = st.emitted_s, math.inf
        if not last:
            j = hold_cut(t, HOLD_FRAMES)  # cut between two frame times, HOLD_FRAMES or more before the end
            if j < 0:
                raise DataError(f"{bus}:0x{cid:X}: frame times go back within the stream; a chunked acquisition "
                                "needs each stream in time order (decode it in one piece with acquire())")
            hi = max(lo, float(t[j])) if j > 0 else lo
        sink = DecodeSink()
        _decode_frames(dec, owner, bus, cid, t, dlc, words, drops, sink)
        counts = {k: dict(v) for k, v in sink.counts.items() if isinstance(v, dict)}
        cut = not (lo == -math.inf and hi == math.inf)
        counted = any(v for k, v in counts.items() if k not in ("frames", "unknown_ids"))
        if cut and counted:  # per-frame counts of the frames decoded again (before) or held back (after): not now
            i_lo, i_hi = np.searchsorted(t, [lo, hi], side="left")
            for part in (slice(0, i_lo), slice(i_hi, n)):
                if part.stop > part.start:
                    other = DecodeSink()
                    _decode_frames(dec, owner, bus, cid, t[part], dlc[part], words[part], drops, other)
                    _add_counts(counts, other.counts, -1)
        _add_counts(self._counts, counts)
        for k, ch in enumerate(sink.rec.channels.values()):
            a, b = (np.searchsorted(ch.timestamps, [lo, hi], side="left") if cut else (0, len(ch)))
            self._store.append(ch.name, ch.unit, ch.source, ch.value_texts, (*st.order, k), ch.timestamps[a:b],
                               ch.values[a:b], ch.flags[a:b])
            self._of_bus[bus].add(ch.name)
        for kind, source, channel, ta, tb in sink.evidence:
            if cut:
                m = (ta >= lo) & (ta < hi)
                ta, tb = ta[m], tb[m]
            if ta.size:
                st.evidence.append((kind, source, channel, ta, tb))
        if last:
            st.t, st.dlc, st.words, st.emitted_s = t[:0].copy(), dlc[:0].copy(), words[:0].copy(), math.inf
            return
        j = int(np.searchsorted(t, hi, side="left"))
        c0 = max(0, min(n - CONTEXT_FRAMES, j - (CONTEXT_FRAMES - HOLD_FRAMES)))
        st.t, st.dlc, st.words, st.emitted_s = t[c0:].copy(), dlc[c0:].copy(), words[c0:].copy(), hi

    def close(self) -> None:
        """Remove the files of the chunks decoded so far (an acquisition given up before :meth:`finish`)."""
        self._finished = True
        if getattr(self, "_beside", None) is not None:  # finish() failed with the offsets' thread reading the files
            self._beside.join()
        self._store.cleanup()

    def __enter__(self) -> Acquisition:
        return self

    def __exit__(self, *exc: object) -> None:
        if not self._finished:
            self.close()

    def finish(self, *, segments: list[Segment] | None = None, meta: dict[str, Any] | None = None,
               defer_save: bool = False) -> Recording:
        """Decode what was held back and the poll logs, run the whole-recording passes, return the Recording.

        Parameters
        ----------
        segments:
            Segment table (overrides the chunks' segments).
        meta:
            Extra metadata for the Recording.
        defer_save:
            With a path and ``keep_chunks``: leave writing the file to a
            :class:`~benchtwin.chain.deferred_save.DeferredSave` the Recording owns (``pending_save(rec)``; run when
            the caller chooses, at the latest when the Recording is closed); the same file.
        """
        if self._finished:
            raise DataError("Acquisition.finish() called twice")
        self._finished = True
        for (bus, cid), st in sorted(self._streams.items(), key=lambda kv: kv[1].order):
            if st.t.size and st.t[-1] >= st.emitted_s:  # the held-back frames: nothing follows them
                decoders, owner = self._decoders(bus)
                self._decode_stream(bus, cid, decoders[cid], owner[cid], st.t[:0], st.dlc[:0], st.words[:0],
                                    events_for(self._events, {bus}), True)
        devs = self._devs
        rec = Recording()
        for name in self._store.names():
            rec.add(self._store.channel(name))
        counts: dict[str, Any] = {"protocol_errors": self._counts["protocol_errors"], "unknown_ids": {},
                                  "frames": dict(self._frames)}
        for bus in self._buses:
            if self._unknown.get(bus):
                counts["unknown_ids"][bus] = {f"0x{k:X}": v for k, v in sorted(self._unknown[bus].items())}
        counts.update({k: v for k, v in self._counts.items() if k != "protocol_errors"})
        sink = DecodeSink(rec=rec, counts=counts)
        sink.evidence = [ev for _, st in sorted(self._streams.items(), key=lambda kv: kv[1].order)
                         for ev in st.evidence]
        # each pass reads one block of one channel at a time (on disk: the flags written back block by block)
        view = ChannelBlocks(rec, self._store, self.block_samples)
        flag_truncations(view, self._events, self._of_bus)
        self._beside = OffsetsBeside(view) if self.align else None  # the CAN channels' times and values are final
        decoded = set(rec.channels)
        emitted = decode_spooled(self._polls, self._polled, self._events, sink, self._store,
                                 min(self.block_samples, POLL_BLOCK), self.setup.name)
        for name in emitted:  # in their place among the channels (read from the store's files when on disk)
            rec.channels[name] = self._store.channel(name)
        if self._store.on_disk:  # the poll logs' channels go to the store's files too: none stays in memory
            for k, name in enumerate(n for n in list(rec.channels) if n not in decoded and n not in emitted):
                ch = rec.channels[name]
                self._store.append(name, ch.unit, ch.source, ch.value_texts, (math.inf, len(emitted) + k),
                                   ch.timestamps, ch.values, ch.flags)
                rec.channels[name] = self._store.channel(name)  # in its place among the channels
        flag_saturation(view, devs)
        faults_found = detect_faults(view, devs, sink.evidence, self._events)
        rec.segments = list(segments if segments is not None else self._segments)
        m = dict(self._meta)
        m.update(meta or {})
        m["setup"] = self.setup.name
        m["sources"] = rec.sources()
        offsets = dict(sink.counts.pop("clock_offsets_s", {}))
        drifts: dict[str, float] = {}
        detail: dict[str, dict[str, float]] = {"clock_drift_se_ppm": {}, "clock_offset_time_s": {}}
        if self.align:
            found, drifts = self._beside.result(view, detail)  # clock_offsets(view, detail), found beside
            offsets.update(found)
            if self._store.on_disk:
                rec.drop()
        m["clock_offsets_s"] = offsets
        m["clock_drift_ppm"] = drifts
        m.update(detail)
        sink.counts["flagged_samples"] = _flag_counts(view)
        m.update(sink.counts)
        m["faults_detected"] = faults_found
        m["transport_events"] = [{"time_s": e.time_s, "source": e.source, "kind": e.kind, "end_s": e.end_s,
                                  "detail": e.detail} for e in self._events]
        m["bus_load"] = {bus: load.value() for bus, load in self._loads.items()}
        m["declared_uncertainty"] = declared_uncertainty(devs, set(rec.channels))
        rec.meta = m
        rec.start_time = self._start_time
        if not self._store.on_disk:
            return rec
        saved = deferred = None
        segs = rec.segments  # the returned Recording's (the deferred save keeps a copy)
        if self.path is not None and defer_save and self.keep_chunks:
            deferred = DeferredSave(rec, self.path)  # closed before the chunk files (owned first)
        elif self.path is not None:
            saved = rec.save(self.path)  # drops every channel it reads: nothing of the chunks' files stays mapped
        if self.keep_chunks or saved is None:
            out = Recording(segments=segs, meta=m, start_time=rec.start_time)
            rec.drop()
            for name in rec.channels:
                out.add(self._store.reader(name))
            if deferred is not None:
                out.own(deferred)
            out.own(self._store)
            return out
        self._store.cleanup()
        opened = Recording.open(saved)
        opened.meta = rec.meta  # as decoded (the file's copy went through JSON: integer keys became text)
        return opened


def _flag_counts(view: ChannelBlocks) -> dict[str, dict[str, int]]:
    """Per channel, the samples flagged LOST_FRAME, DUPLICATE, OUT_OF_ORDER and bad (only the non-zero counts)."""
    kinds = [(fl.name.lower(), int(fl)) for fl in (Flag.LOST_FRAME, Flag.DUPLICATE, Flag.OUT_OF_ORDER)]
    kinds.append(("bad", int(Flag.bad())))
    flagged: dict[str, dict[str, int]] = {}
    for name in view.rec.channels:
        got = dict.fromkeys((k for k, _ in kinds), 0)
        for _a, _t, _v, f in view.blocks(name, columns="f"):
            for key, bit in kinds:
                got[key] += int(np.count_nonzero(f & bit))
        for key, _ in kinds:
            if got[key]:
                flagged.setdefault(name, {})[key] = got[key]
    return flagged


def _decode_frames(dec: FrameDecoder, owner: str, bus: str, cid: int, t: np.ndarray, dlc: np.ndarray,
                   words: np.ndarray, drops: np.ndarray, sink: DecodeSink) -> None:
    """Decode the frames of one stream into ``sink`` (a wrong data length is evidence, judged from the wire)."""
    if dec.length:
        wrong = dlc != dec.length
        if wrong.any():  # judged from the wire: the identifier's layout has another length
            sink.fault("wrong_dlc", owner, t[wrong])
    dec.decode(FrameStream(bus, cid, t, dlc, words, drops), sink)


def acquire(data: AcquisitionInput, setup: SetupConfig, *, segments: list[Segment] | None = None,
            meta: dict[str, Any] | None = None, align: bool = True) -> Recording:
    """Decode everything received into a :class:`~benchtwin.recording.Recording` (an :class:`Acquisition` of one chunk).

    Parameters
    ----------
    data:
        An :class:`AcquisitionInput` (frame tables incl. PDO frames, poll logs, transport events),
        the sensors' :class:`~benchtwin.wire.frames.DeviceOutputs` (delivered first with
        :func:`benchtwin.chain.batch.deliver`), or a folder of raw logs (read with
        :func:`benchtwin.chain.batch.read_logs`).
    setup:
        The bench (buses, ids, scalings).
    segments:
        Segment table (overrides ``data.segments``).
    meta:
        Extra metadata for the Recording.
    align:
        Detect clock offsets between sources.

    Raises
    ------
    DataError
        If ``data`` is not an :class:`AcquisitionInput`.
    """
    return Acquisition(setup, align=align).feed(data, last=True).finish(segments=segments, meta=meta)
