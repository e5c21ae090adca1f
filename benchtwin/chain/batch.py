"""Batch delivery: sensors' outputs -> what the bench's loggers record -> raw log files -> Recording.

:func:`deliver` turns :class:`~benchtwin.wire.frames.DeviceOutputs` into what an acquisition
receives (the thermo module's TPDO frames merged into their bus, the Modbus module polled at the
configured rate with the configured faults; a bus's injected faults: frame faults over spans and
transport disconnects, which also give a ``drop`` event). :func:`write_logs` writes the raw logs of a run
(``<bus>.mf4`` bus logs, ``<device>.polls.npz`` poll logs, ``<bus>.dbc`` and the EDS to decode
them, the segment table) and :func:`read_logs` reads them back. :func:`run_batch` is the whole
batch path in one call: encode -> deliver -> (write and read the logs) -> acquire.
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime
from pathlib import Path
from typing import Any

from benchtwin.chain.acquisition import AcquisitionInput
from benchtwin.chain.buslog import (
    DEFAULT_START,
    read_bus_log,
    read_poll_log,
    write_blf,
    write_mf4,
)
from benchtwin.chain.delivery import ChunkDeliverer
from benchtwin.chain.logfolder import (
    EVENTS_KEY,
    LOG_START_KEY,
    TRUNCATION_TOLERANCE_S,
    bus_channel,
    damaged_from_spans,
    write_side_files,
)
from benchtwin.config.setup import SetupConfig
from benchtwin.errors import DataError
from benchtwin.recording import Recording
from benchtwin.segments import load_segments, segments_from_json, segments_to_json
from benchtwin.sensors.imperfections import truncate_log
from benchtwin.trace import Trace
from benchtwin.wire.frames import DeviceOutputs, FrameTable, TransportEvent

__all__ = ["TRUNCATION_TOLERANCE_S", "ChunkDeliverer", "as_logged", "deliver", "read_logs", "run_batch", "write_logs"]



def deliver(outputs: DeviceOutputs, setup: SetupConfig, *, seed: int | None = 0,
            span_s: tuple[float, float] | None = None) -> AcquisitionInput:
    """What the bench's acquisition receives from a whole run's device outputs: the one-chunk case of
    :class:`~benchtwin.chain.delivery.ChunkDeliverer`.

    Parameters
    ----------
    outputs:
        The sensors' outputs.
    setup:
        The bench.
    seed:
        Campaign seed (poll faults draw from the ``modbus_poll`` stream, bus faults from ``faults:<bus>``).
    span_s:
        Acquisition span for polling; defaults to the span of the register snapshots.
    """
    if outputs.until_s is not None:
        raise DataError(f"deliver() takes a whole run's outputs; these end at {outputs.until_s:.3f} s of a "
                        "chunked run (use ChunkDeliverer)")
    start, end = (None, None) if span_s is None else span_s
    return ChunkDeliverer(setup, seed, start_s=start).feed(outputs, end_s=end)


def write_logs(received: AcquisitionInput, setup: SetupConfig, out_dir: str | Path, *, blf: bool = False,
               poll_csv: bool = False) -> dict[str, Path]:
    """Write the raw logs of a run into ``out_dir``; return name -> path.

    Files: ``<bus>.mf4`` (MF4 bus logging, one per bus with frames), ``<bus>.blf`` (if ``blf``),
    ``<device>.polls.npz`` (and ``.csv`` if ``poll_csv``), ``<bus>.dbc`` and ``thermo_module.eds``
    (to decode them with cantools/canopen), ``setup.json`` (the setup used), ``segments.json`` and
    ``meta.json`` (with ``log_start_utc`` and the transport events). Every bus log starts at
    ``received.start_time`` (default: the campaign start :data:`~benchtwin.chain.buslog.DEFAULT_START`)
    with frames at absolute times. A bus with an injected ``log_truncation`` is written up to its cut.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    start = received.start_time or DEFAULT_START
    paths: dict[str, Path] = {}
    buses = sorted((b, FrameTable(b, truncate_log(t.frames, setup.faults_of(b)), t.bitrate))
                   for b, t in received.can.items() if len(t))
    with ThreadPoolExecutor(max_workers=max(1, min(len(buses), os.cpu_count() or 1))) as pool:
        done = pool.map(lambda item: write_mf4(item[1], out / f"{item[0]}.mf4", channel=bus_channel(setup, item[0]),
                                               start_time=start), buses)
        for (bus, _), p in zip(buses, done):
            paths[f"{bus}.mf4"] = p
    if blf:
        for bus, table in buses:
            paths[f"{bus}.blf"] = write_blf(table, out / f"{bus}.blf", channel=bus_channel(setup, bus),
                                            start_time=start)
    paths.update(write_side_files(out, setup, received.segments, received.meta, received.events, start,
                                  polls=received.polls, poll_csv=poll_csv))
    return paths


def read_logs(directory: str | Path, setup: SetupConfig | None = None) -> tuple[AcquisitionInput, SetupConfig]:
    """Read the raw logs written by :func:`write_logs` (or a logger with the same names).

    Parameters
    ----------
    directory:
        Folder with ``<bus>.mf4`` (or ``<bus>.blf``) bus logs and ``<device>.polls.npz`` poll logs.
    setup:
        The bench; defaults to the ``setup.json`` in the folder.

    Raises
    ------
    DataError
        If the folder holds no bus log or poll log, or no setup is given or found.
    """
    d = Path(directory)
    if not d.is_dir():
        raise DataError(f"{d}: not a directory of raw logs")
    if setup is None:
        sp = d / "setup.json"
        if not sp.exists():
            raise DataError(f"{d}: no setup.json; pass the setup file used for the run")
        from benchtwin.config._base import validate_data

        setup = validate_data(SetupConfig, _read_json(sp, "the setup written with the logs"), str(sp))
    received = AcquisitionInput()
    skipped = []
    file_damage: dict[str, tuple[str, str | None]] = {}
    meta = d / "meta.json"
    if meta.exists():
        blob = _read_json(meta, "the logs' meta data")
        if not isinstance(blob, dict):
            raise DataError(f"{meta}: not the logs' meta data (a JSON object is expected)")
        received.meta = blob
    try:
        start = datetime.fromisoformat(str(received.meta.pop(LOG_START_KEY)))
    except (KeyError, ValueError):
        start = DEFAULT_START  # logs of another logger: times since the campaign start epoch
    received.start_time = start
    for e in received.meta.pop(EVENTS_KEY, []):
        received.events.append(TransportEvent(float(e[0]), str(e[1]), str(e[2]), float(e[3]), str(e[4])))

    def read_one(p: Path) -> tuple[FrameTable, str | None] | DataError:
        bitrate = setup.buses[p.stem].bitrate if p.stem in setup.buses else 500_000
        try:
            return read_bus_log(p, p.stem, bitrate, origin=start)
        except DataError as exc:
            return exc

    files = sorted(d.glob("*.mf4"))
    with ThreadPoolExecutor(max_workers=max(1, min(len(files), os.cpu_count() or 1))) as pool:
        for p, res in zip(files, pool.map(read_one, files)):
            if not isinstance(res, DataError):
                received.can[p.stem], file_damage[p.stem] = res[0], (p.name, res[1])
            elif p.stem in setup.buses:
                raise res
            else:
                skipped.append(f"{p.name}: {res}")  # e.g. a Recording saved next to the logs
    for p in sorted(d.glob("*.blf")):  # BLF-only buses (a logger that writes BLF)
        if p.stem not in received.can:
            res = read_one(p)
            if isinstance(res, DataError):
                raise res
            received.can[p.stem], file_damage[p.stem] = res[0], (p.name, res[1])
    for p in sorted(d.glob("*.polls.npz")):
        plog = read_poll_log(p)
        received.polls[plog.device] = plog
    if not received.can and not received.polls:
        raise DataError(f"{d}: no bus logs (*.mf4) or poll logs (*.polls.npz)")
    seg = d / "segments.json"
    if seg.exists():
        received.segments = load_segments(seg)
    if skipped:
        received.meta["skipped_files"] = skipped
    damaged = _damaged_logs(received, file_damage)
    if damaged:
        received.meta["damaged_logs"] = damaged
        for dmg in damaged:
            received.events.append(TransportEvent(dmg["covered_s"][1], dmg["bus"], "truncated", dmg["expected_s"][1],
                                                  f"damaged log {dmg['file']}: {dmg['reason']}"))
    return received, setup


def _damaged_logs(received: AcquisitionInput, file_damage: dict[str, tuple[str, str | None]],
                  tol_s: float = TRUNCATION_TOLERANCE_S) -> list[dict[str, Any]]:
    """Buses whose log is damaged or cut short: what the file says of itself, and the end of its time base
    against the segment table and the other sources (buses and poll logs)."""
    nan = float("nan")
    buses = {b: ((float(t.frames["timestamp"][0]), float(t.frames["timestamp"][-1]), len(t)) if len(t)
                 else (nan, nan, 0)) for b, t in received.can.items()}
    polled = [(float(pl.times[0]), float(pl.times[-1])) for pl in received.polls.values() if len(pl.times)]
    seg = [(float(s.start_s), float(s.end_s)) for s in received.segments]
    return damaged_from_spans(buses, polled, seg, file_damage, tol_s)


def _read_json(path: Path, what: str) -> Any:
    """A JSON file of a log folder; DataError naming the file if it is damaged."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise DataError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    except ValueError as exc:  # JSONDecodeError and UnicodeDecodeError
        raise DataError(f"{path}: damaged, not {what} ({exc})") from None


def run_batch(trace: Trace, setup: SetupConfig, seed: int | None = 0, out_dir: str | Path | None = None, *,
              blf: bool = False, meta: dict[str, Any] | None = None, save_recording: bool = True,
              chunk_s: float | None = None) -> Recording:
    """The whole batch chain: encode the trace, deliver, write the raw logs, acquire, test by test.

    The Trace goes through the chain one test at a time (:func:`benchtwin.chain.stream.run_chunked`), so the
    frames of one test are in memory at a time; the result equals decoding the whole run's raw logs.

    Parameters
    ----------
    trace:
        The truth.
    setup:
        The bench.
    seed:
        Campaign seed.
    out_dir:
        Where to write the raw logs and ``recording.mf4``; with None nothing is written and the Recording is kept
        in memory.
    blf:
        Also export BLF files.
    meta:
        Extra metadata for the Recording.
    save_recording:
        Save ``recording.mf4`` into ``out_dir`` as the acquisition goes and return it opened lazily (False: the
        Recording stays in memory and the caller saves it, e.g. beside other work).
    chunk_s:
        Cut the Trace into chunks of this many plant seconds instead of one test a time (the Recording is the same
        for any cut; fewer, longer chunks cost less per plant second where the tests are short, e.g. a family run's
        few thousand seconds: :data:`benchtwin.validation.families.FAMILY_CHUNK_S`).

    A Trace without some channels (a conventional car's, ``meta["absent_channels"]``) feeds the setup that
    :func:`~benchtwin.sensors.registry.setup_for_trace` keeps of ``setup`` (its rule: shunts and thermocouple
    places on absent channels removed, the vehicle CAN's roles on them not sent); the Recording's
    ``meta["dropped_devices"]`` lists what was taken out.
    """
    from benchtwin.chain.stream import run_chunked, time_slices, trace_pieces
    from benchtwin.sensors import setup_for_trace

    setup, dropped = setup_for_trace(setup, trace.meta.get("absent_channels", ()))
    if dropped:
        meta = {**(meta or {}), "dropped_devices": dropped}
    pieces = trace_pieces(trace) if chunk_s is None else time_slices([trace], chunk_s)
    return run_chunked(pieces, setup, seed, out_dir, blf=blf, meta=meta, save_recording=save_recording)


def as_logged(received: AcquisitionInput, setup: SetupConfig) -> AcquisitionInput:
    """What :func:`read_logs` gives back of the logs :func:`write_logs` writes of ``received``, without the files.

    The same content as the round trip through the files: the buses with frames (in name order, each cut at its
    injected ``log_truncation``), the poll logs, the meta data and transport events as ``meta.json`` holds them,
    the segment table, and the buses whose log ends early (``damaged_logs`` and their ``truncated`` events). The
    frame tables are the delivered ones (a bus without a cut is not copied).
    """
    start = received.start_time or DEFAULT_START
    out = AcquisitionInput(start_time=start)
    out.meta = json.loads(json.dumps(received.meta, default=str))
    out.events = [TransportEvent(float(e.time_s), str(e.source), str(e.kind), float(e.end_s), str(e.detail))
                  for e in received.events]
    for bus in sorted(received.can):
        t = received.can[bus]
        if len(t):
            bitrate = setup.buses[bus].bitrate if bus in setup.buses else 500_000
            out.can[bus] = FrameTable(bus, truncate_log(t.frames, setup.faults_of(bus)), bitrate)
    out.polls = dict(received.polls)
    out.segments = segments_from_json(segments_to_json(received.segments))
    damaged = _damaged_logs(out, {bus: (f"{bus}.mf4", None) for bus in out.can})
    if damaged:
        out.meta["damaged_logs"] = damaged
        for dmg in damaged:
            out.events.append(TransportEvent(dmg["covered_s"][1], dmg["bus"], "truncated", dmg["expected_s"][1],
                                             f"damaged log {dmg['file']}: {dmg['reason']}"))
    return out
