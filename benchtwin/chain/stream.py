"""The batch chain chunk by chunk: Trace pieces -> encode -> deliver -> raw logs and Recording, one chunk in memory.

:func:`run_chunked` is what :func:`benchtwin.chain.batch.run_batch` runs: the Trace comes in pieces (a test
each, from :func:`trace_pieces` or straight from :func:`benchtwin.emulator.iter_campaign`); each piece is
encoded and delivered (:func:`~benchtwin.chain.delivery.iter_delivered`, the same bytes for any chunking), its
frames are appended to the MF4 bus logs as the logger writes them (:class:`~benchtwin.chain.buslog.BusLogWriter`,
each bus cut at its injected ``log_truncation``) and decoded as the logs hold them
(:class:`~benchtwin.chain.acquisition.Acquisition`, bit-identical to decoding the whole run), and dropped. The
Recording is saved to ``recording.mf4`` and opened lazily when a folder is given, else kept in memory. What
needs the whole run is done at the end from what was counted on the way: the buses whose log ends early
(``damaged_logs`` and their ``truncated`` events, from each bus's first and last frame time), the poll logs
(a hundredth of the frames), the segment table and ``meta.json``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator
from contextlib import ExitStack, closing
from functools import partial
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.chain.acquisition import Acquisition, AcquisitionInput
from benchtwin.chain.buslog import DEFAULT_START, BusLogWriter, read_mf4, write_blf
from benchtwin.chain.delivery import iter_delivered
from benchtwin.chain.forked_iter import FORK_MODES, ForkedIter
from benchtwin.chain.logfolder import bus_channel, damaged_from_spans, write_side_files
from benchtwin.chain.prefetch import prefetch
from benchtwin.config.setup import SetupConfig
from benchtwin.recording import Recording
from benchtwin.sensors.imperfections import truncate_log
from benchtwin.trace import Trace
from benchtwin.wire.frames import FrameTable, TransportEvent

__all__ = ["PRODUCER_MODES", "SLICE_S", "run_chunked", "time_slices", "trace_pieces"]

#: where :func:`run_chunked` runs its producer (the pieces, their encoding and delivery): ``"thread"`` on a prefetch
#: thread of this process, ``"fork"`` in a child forked when the chain starts (benchtwin/chain/forked_iter.py)
PRODUCER_MODES = FORK_MODES
#: chunks the forked producer holds made and not yet read whole (:class:`~benchtwin.chain.forked_iter.ForkedIter`'s
#: ``depth``): 2, the child makes the next chunk while its writer thread sends the last one and this process decodes
#: the one before (measured: benchmarks/RESULTS.md)
PRODUCER_DEPTH = 2

#: plant seconds per chunk of :func:`time_slices` (two 60-s draw blocks of the encoders)
SLICE_S = 120.0


def trace_pieces(trace: Trace) -> Iterator[Trace]:
    """A Trace cut at its tests' starts (views on its arrays; the whole Trace if it has no segments).

    Each segment goes with the piece its start falls in (the first piece also takes those that start before the
    Trace's first sample, as in a Trace sliced from a longer one).
    """
    t = trace.time_s
    starts = sorted({float(s.start_s) for s in trace.segments})
    edges = [0, *sorted({int(k) for k in np.searchsorted(t, starts[1:], side="left")} - {0, len(t)}), len(t)]
    for a, b in pairwise(edges):
        lo = -np.inf if a == 0 else float(t[a])
        hi = np.inf if b == len(t) else float(t[b])
        segs = [s for s in trace.segments if lo <= s.start_s < hi]
        yield Trace(t[a:b], {k: v[a:b] for k, v in trace.channels.items()}, segs, dict(trace.meta))


def time_slices(pieces: Iterable[Trace], max_s: float = SLICE_S) -> Iterator[Trace]:
    """Each piece cut into slices of at most ``max_s`` plant seconds (views on its arrays), for a chain whose memory
    is bounded by a slice rather than by the longest test; the piece's segments go with its first slice.

    The chain's output is the same for any cut (:func:`run_chunked`), so this changes memory and speed only.
    """
    if not max_s > 0:
        raise ValueError(f"slice length must be positive, got {max_s}")
    for piece in pieces:
        t = piece.time_s
        if not len(t):
            yield piece
            continue
        edges = np.searchsorted(t, t[0] + max_s * np.arange(1, int((t[-1] - t[0]) // max_s) + 1), side="left")
        bounds = [0, *[int(e) for e in edges if 0 < e < len(t)], len(t)]
        for k, (a, b) in enumerate(pairwise(bounds)):
            yield Trace(t[a:b], {n: v[a:b] for n, v in piece.channels.items()}, piece.segments if k == 0 else [],
                        piece.meta)


def run_chunked(pieces: Iterable[Trace], setup: SetupConfig, seed: int | None = 0,
                out_dir: str | Path | None = None, *, blf: bool = False,
                meta: dict[str, Any] | None = None, save_recording: bool = True,
                keep_chunks: bool = False, defer_save: bool = False, producer_mode: str = "thread",
                notes: list[Any] | None = None, on_notes: Callable[[list[Any]], None] | None = None,
                while_forked: Callable[[], None] | None = None) -> Recording:
    """The batch chain over a Trace given in pieces, one chunk in memory at a time.

    Parameters
    ----------
    pieces:
        The Trace in time order (e.g. :func:`trace_pieces` of a whole Trace, or
        :func:`benchtwin.emulator.iter_campaign`); each piece's segments are the run's segment table.
    setup:
        The bench.
    seed:
        Campaign seed.
    out_dir:
        Where to write the raw logs (as :func:`benchtwin.chain.batch.write_logs` names them) and
        ``recording.mf4``; None: nothing is written and the Recording is kept in memory.
    blf:
        Also export BLF files (converted from each bus's MF4 log at the end: one bus in memory at a time).
    meta:
        Extra metadata for the Recording (``trace`` holds the last piece's meta: the ledger to the run's end).
    save_recording:
        With ``out_dir``: write ``recording.mf4`` as the acquisition goes and return it opened lazily (memory
        bounded by a chunk); False: keep the Recording in memory and leave saving it to the caller (e.g. on a
        thread while identification runs, which then reads no channel twice from the compressed file).
    keep_chunks:
        Return the Recording read from the acquisition's raw chunk files (one channel in memory while used, read
        again at the cost of a plain file read; the files go when the Recording is closed), ``recording.mf4``
        still written with ``out_dir`` and ``save_recording``; without ``out_dir`` the files are temporary.
    defer_save:
        With ``keep_chunks``, ``out_dir`` and ``save_recording``: ``recording.mf4`` is written when the caller runs
        :func:`~benchtwin.chain.deferred_save.pending_save` of the Recording (at the latest when it is closed).
    producer_mode:
        Where the pieces are iterated, encoded and delivered (:data:`PRODUCER_MODES`): on a prefetch thread of this
        process (``"thread"``) or in a child process forked before this function starts a thread or opens a file
        (``"fork"``: the chunks come through a pipe, bit for bit; the pieces' iterator runs in the child, so what
        it changes stays there but for ``notes``). The output is the same in both.
    notes:
        A list the pieces' iterator appends to (on the producer's side) as it makes the pieces: after each
        delivered chunk (and once at the end) what it holds is taken and handed to ``on_notes`` in this thread,
        before the chunk is used (in ``"fork"`` mode pickled across with the chunk).
    on_notes:
        Called with the notes taken (a list; empty where none were made) once per delivered chunk and at the end.
    while_forked:
        ``"fork"`` mode: called in this process once the child is forked, while it makes the first chunk.

    Returns
    -------
    Recording
        Equal to the one :func:`benchtwin.chain.acquisition.acquire` decodes of the raw logs written (opened
        lazily from ``recording.mf4`` with ``out_dir`` and ``save_recording``).
    """
    if producer_mode not in PRODUCER_MODES:
        raise ValueError(f"producer_mode {producer_mode!r}: one of {', '.join(PRODUCER_MODES)}")
    out = Path(out_dir) if out_dir is not None else None
    start = DEFAULT_START
    trace_meta: dict[str, Any] = {}
    segments = []
    # the producer first (forked before this process has a thread or an open file of the chain's own)
    producer = ForkedIter(partial(_produced, pieces, setup, seed, notes), producer_mode,
                          depth=PRODUCER_DEPTH if producer_mode == "fork" else 1)
    producer.__enter__()
    if producer_mode == "fork" and while_forked is not None:
        try:
            while_forked()
        except BaseException:
            producer.close()
            raise
    try:
        acq = Acquisition(setup, out / "recording.mf4" if out is not None and save_recording else None,
                          keep_chunks=keep_chunks)
    except BaseException:
        producer.close()
        raise
    spans: dict[str, list[float]] = {}  # bus -> [first, last, frames] as logged
    bitrates: dict[str, int] = {}
    events: list[TransportEvent] = []
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    try:
        with ExitStack() as stack:
            stack.callback(producer.close)
            writers: dict[str, BusLogWriter] = {}
            # the pieces (and the plant, when they come from it) are encoded and delivered on a second thread (or in
            # the forked child) while this one writes and decodes the previous chunk (stopped on an error here)
            delivered = iter(producer) if producer_mode == "fork" else prefetch(iter(producer), name="deliver")
            delivered = stack.enter_context(closing(delivered))
            for got, last_meta, taken in delivered:
                trace_meta.clear()
                trace_meta.update(last_meta)
                if on_notes is not None:
                    on_notes(taken)
                if got is None:  # the producer's end: its last word
                    continue
                segments += got.segments
                events += got.events
                chunk = AcquisitionInput(events=list(got.events), polls=dict(got.polls), start_time=start)
                for bus in sorted(got.can):
                    table = got.can[bus]
                    frames = truncate_log(table.frames, setup.faults_of(bus))
                    if not len(frames) and bus not in spans:
                        continue  # as the whole-run logs: a bus is logged from its first frame
                    bitrates[bus] = setup.buses[bus].bitrate if bus in setup.buses else 500_000
                    if len(frames):
                        sp = spans.setdefault(bus, [float(frames["timestamp"][0]), 0.0, 0])
                        sp[1], sp[2] = float(frames["timestamp"][-1]), sp[2] + len(frames)
                    if out is not None:
                        if bus not in writers:
                            channel = bus_channel(setup, bus)
                            writers[bus] = stack.enter_context(BusLogWriter(out / f"{bus}.mf4", bus, bitrates[bus],
                                                                            channel=channel, start_time=start))
                        writers[bus].append(frames, owned=True)  # the chunk's frames are only read from here on
                    chunk.can[bus] = FrameTable(bus, frames, bitrates[bus])
                acq.feed(chunk)
        poll_logs = acq.poll_logs  # spooled beside the chunk files (or in memory): the written logs read them by blocks
        run_meta = json.loads(json.dumps({"trace": dict(trace_meta), "seed": seed, **(meta or {})}, default=str))
        polled = [(p.first_s, p.last_s) for p in poll_logs.values() if len(p)]
        seg_spans = [(float(s.start_s), float(s.end_s)) for s in segments]
        damaged = damaged_from_spans({b: (s[0], s[1], int(s[2])) for b, s in spans.items()}, polled, seg_spans,
                                      {bus: (f"{bus}.mf4", None) for bus in spans})
        if damaged:
            run_meta["damaged_logs"] = damaged
            truncated = [TransportEvent(d["covered_s"][1], d["bus"], "truncated", d["expected_s"][1],
                                        f"damaged log {d['file']}: {d['reason']}") for d in damaged]
            acq.feed(AcquisitionInput(events=truncated, start_time=start))
        if out is not None:
            write_side_files(out, setup, segments, {"trace": dict(trace_meta), "seed": seed, **(meta or {})}, events,
                             start, polls=poll_logs)
            if blf:
                for bus in sorted(spans):
                    write_blf(read_mf4(out / f"{bus}.mf4", bus, bitrates[bus]), out / f"{bus}.blf",
                              channel=bus_channel(setup, bus), start_time=start)
        return acq.finish(segments=segments, meta=run_meta, defer_save=defer_save)
    except BaseException:
        producer.close()
        acq.close()  # the chunk files go; the raw logs written so far are kept
        raise


def _produced(pieces: Iterable[Trace], setup: SetupConfig, seed: int | None,
              notes: list[Any] | None) -> Iterator[tuple[AcquisitionInput | None, dict[str, Any], list[Any]]]:
    """:func:`run_chunked`'s producer: each delivered chunk with the meta of the last piece read so far and the notes
    taken since the last chunk; at the end ``None`` with the last piece's meta and the notes left."""
    meta: dict[str, Any] = {}

    def tracked(it: Iterable[Trace]) -> Iterator[Trace]:
        for piece in it:
            meta.clear()
            meta.update(piece.meta)
            yield piece

    def taken() -> list[Any]:
        if notes is None:
            return []
        out = list(notes)
        notes.clear()
        return out

    for got in iter_delivered(tracked(pieces), setup, seed):
        yield got, dict(meta), taken()
    yield None, dict(meta), taken()

