"""Raw bus logs: MF4 bus logging written and read in bulk, BLF export, Modbus poll logs.

MF4: one file per bus with the ASAM MDF 4 bus-logging layout (a ``CAN_DataFrame`` channel group of
the CAN bus-event type, the structure python-can's ``MF4Writer`` writes), appended in blocks
(``MDF.append`` then ``MDF.extend``, one block of records in memory at a time) from the frame table's
columns, so ``can.MF4Reader``, asammdf's ``extract_bus_logging`` and the asammdf viewer read it.
Timestamps are relative to the header start time (the device clocks as seen by the logger). Data bytes
are stored 8 wide (classic CAN). The data blocks are compressed (transposed deflate by default: ``##DZ``
blocks, which every MDF 4.1 reader reads).

BLF: exported through python-can's ``BLFWriter`` (per message; for hand-over to Vector tools, not
for speed), with a ``.blf.json`` sidecar holding the exact first timestamp, the frame count and the
last timestamp. Poll logs: ``.npz`` (bulk) and optional CSV.

Damaged logs: :func:`read_bus_log` reads a ``.mf4`` or ``.blf`` and says what is wrong with it, keeping
every frame before the damage. A BLF is checked against the object count in its own file header and
against the sidecar; a reading error ends the read at the last whole frame. An MF4 whose blocks cannot
be read (a truncated file: asammdf writes the channel and group blocks after the data) is salvaged when
it has benchtwin's own record layout: the data blocks that follow the header are read record by record
up to the cut (a deflated block up to the cut, a cut transposed block not at all), and the cycle count
of the channel group (when readable) is compared with the records.

Absolute time: every log of a run starts at one time, the run's start (``start_time``: the campaign
start :data:`DEFAULT_START` in batch, the acquisition start live); a frame at run time ``t`` is at
``start + t`` in every format. MF4 stores the start in its header and ``t`` per frame; BLF stores
absolute times (python-can's ``BLFWriter`` takes the file start from the first frame, to the
millisecond), so an unmodified ``can.MF4Reader`` or ``can.BLFReader`` aligns the buses of a run.
The readers here take the run start back off (``origin``) and return run times.
"""

from __future__ import annotations

import json
import logging
import struct
import zlib
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.chain.polllog import read_poll_log, write_poll_csv, write_poll_log
from benchtwin.errors import DataError
from benchtwin.mdf import DEFAULT_COMPRESSION, check_compression, open_mdf
from benchtwin.wire.frames import FRAME_DTYPE, FrameTable
from benchtwin.wire.merge import merge_frames

__all__ = [
    "MF4_FRAME_DTYPE",
    "read_blf",
    "read_bus_log",
    "read_mf4",
    "read_poll_log",
    "write_blf",
    "write_mf4",
    "write_poll_csv",
    "write_poll_log",
]

#: the CAN_DataFrame record (as python-can's MF4Writer, with 8 data bytes)
MF4_FRAME_DTYPE = np.dtype([
    ("CAN_DataFrame.BusChannel", "<u1"),
    ("CAN_DataFrame.ID", "<u4"),
    ("CAN_DataFrame.IDE", "<u1"),
    ("CAN_DataFrame.DLC", "<u1"),
    ("CAN_DataFrame.DataLength", "<u1"),
    ("CAN_DataFrame.DataBytes", "(8,)u1"),
    ("CAN_DataFrame.Dir", "<u1"),
    ("CAN_DataFrame.EDL", "<u1"),
    ("CAN_DataFrame.BRS", "<u1"),
    ("CAN_DataFrame.ESI", "<u1"),
])

log = logging.getLogger(__name__)

#: one MF4 record as benchtwin writes it: the time channel, then the CAN_DataFrame bytes (no invalidation)
_MF4_RECORD = np.dtype([("time", "<f8"), *[(n, MF4_FRAME_DTYPE.fields[n][0]) for n in MF4_FRAME_DTYPE.names]])

#: header start time of the logs written (the campaign's t = 0)
DEFAULT_START = datetime(2026, 1, 1, tzinfo=UTC)


def _mf4_records(f: np.ndarray, channel: int) -> np.ndarray:
    """The CAN_DataFrame records of frames (FRAME_DTYPE)."""
    rec = np.zeros(len(f), dtype=MF4_FRAME_DTYPE)
    rec["CAN_DataFrame.BusChannel"] = channel
    rec["CAN_DataFrame.ID"] = f["arbitration_id"] | np.where(f["is_extended"], np.uint32(0x80000000), np.uint32(0))
    rec["CAN_DataFrame.IDE"] = f["is_extended"]
    rec["CAN_DataFrame.DLC"] = f["dlc"]
    rec["CAN_DataFrame.DataLength"] = np.minimum(f["dlc"], 8)
    rec["CAN_DataFrame.DataBytes"] = f["data"]
    return rec


#: frames in one data block of an MF4 bus log: asammdf's ``save`` cuts a group's data at 4 MiB (149,796 records of
#: 28 bytes), so the blocks, compressed one at a time, are those it writes
MF4_BLOCK_FRAMES = (4 << 20) // _MF4_RECORD.itemsize


def _mf4_block(f: np.ndarray, channel: int, transposed: bool) -> bytes:
    """The records of frames (FRAME_DTYPE) as one MF4 data block holds them: record after record, or byte column
    after byte column (``transposed``: what transposed deflate compresses), built straight in that layout."""
    n = len(f)
    rec = _MF4_RECORD
    if not transposed:
        out = np.zeros(n, rec)
        out["time"] = f["timestamp"]
        r = _mf4_records(f, channel)
        for name in MF4_FRAME_DTYPE.names:
            out[name] = r[name]
        return out.tobytes()
    cols = np.zeros((rec.itemsize, n), np.uint8)

    def put(name: str, values: np.ndarray) -> None:
        dt, off = rec.fields[name][:2]
        width = dt.itemsize
        v = np.ascontiguousarray(values, dtype=dt.base if dt.shape else dt)
        cols[off:off + width] = v.view(np.uint8).reshape(n, width).T

    put("time", f["timestamp"])
    cols[rec.fields["CAN_DataFrame.BusChannel"][1]] = channel
    put("CAN_DataFrame.ID", f["arbitration_id"] | np.where(f["is_extended"], np.uint32(0x80000000), np.uint32(0)))
    put("CAN_DataFrame.IDE", f["is_extended"])
    put("CAN_DataFrame.DLC", f["dlc"])
    put("CAN_DataFrame.DataLength", np.minimum(f["dlc"], 8))
    put("CAN_DataFrame.DataBytes", f["data"])
    return cols.tobytes()


def write_mf4(table: FrameTable, path: str | Path, *, channel: int = 1, start_time: datetime = DEFAULT_START,
              compression: int = DEFAULT_COMPRESSION, block_frames: int = MF4_BLOCK_FRAMES) -> Path:
    """Write a frame table as an MF4 bus log, in data blocks of ``block_frames`` frames.

    Parameters
    ----------
    table:
        Frames of one bus.
    path:
        Output file.
    channel:
        Bus channel number stored in ``CAN_DataFrame.BusChannel`` (1-based, as loggers count).
    start_time:
        Header start time (frame timestamps are relative to it).
    compression:
        asammdf compression (0 none, 1 deflate, 2 transposed deflate; default
        :data:`~benchtwin.mdf.DEFAULT_COMPRESSION`, 2: the bus logs of the paper campaign shrink ~40x for
        ~1.6x the CPU of no compression, see benchmarks/bench_files.py). Every choice reads back the same
        with ``can.MF4Reader``, asammdf and :func:`read_mf4`.
    block_frames:
        Frames of one MF4 data block (the last one fewer; default :data:`MF4_BLOCK_FRAMES`, asammdf's own cut, so
        the file is the one asammdf's ``save`` writes of the same frames).
    """
    with BusLogWriter(path, table.bus, table.bitrate, channel=channel, start_time=start_time,
                      compression=compression, block_frames=block_frames) as writer:
        writer.append(table.frames)
    return writer.path


class BusLogWriter:
    """An MF4 bus log written as its frames arrive (e.g. chunk by chunk of a campaign): :func:`write_mf4` in parts.

    asammdf writes the blocks that describe the log (header, channel group, channels, source) once; the data blocks
    are written by :class:`~benchtwin.mf4stream.StreamedMdf` as the frames come, each block of
    ``block_frames`` frames compressed on a worker thread while the caller goes on (asammdf itself would put every
    block through its temporary file and compress them all on :meth:`close`). Memory: the frames of a few blocks.
    The frames appended must follow one another in time. The file equals what :func:`write_mf4` writes of all the
    frames at once, and what asammdf's ``save`` writes of them (but for the history block's time).

    Parameters
    ----------
    path, bus, bitrate:
        Output file, bus name and bit rate (header comment).
    channel, start_time, compression, block_frames:
        As :func:`write_mf4`.
    """

    def __init__(self, path: str | Path, bus: str, bitrate: int, *, channel: int = 1,
                 start_time: datetime = DEFAULT_START, compression: int = DEFAULT_COMPRESSION,
                 block_frames: int = MF4_BLOCK_FRAMES) -> None:
        from asammdf import MDF, Signal
        from asammdf.blocks.source_utils import Source

        from benchtwin.mf4stream import GroupLayout, StreamedMdf, mdf_template

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.bus, self.channel = bus, channel
        self.compression = check_compression(compression)
        self.block_frames = max(1, int(block_frames))
        self.frames = 0
        mdf: Any = MDF(version="4.10")
        try:
            mdf.header.start_time = start_time
            mdf.header.comment = f"benchtwin bus log: bus {bus}, {bitrate} bit/s"
            src = Source(name=bus, path=bus, comment=f"CAN bus {bus}", source_type=Source.SOURCE_BUS,
                         bus_type=Source.BUS_TYPE_CAN)
            empty = np.zeros(0, FRAME_DTYPE)
            mdf.append(Signal(name="CAN_DataFrame", samples=_mf4_records(empty, channel), timestamps=np.zeros(0),
                              source=src), acq_name=bus, comment=f"CAN bus {bus}")
            template = mdf_template(mdf, self.compression)
        finally:
            mdf.close()
        layout = GroupLayout(_MF4_RECORD.itemsize, lambda f, transposed: _mf4_block(f, channel, transposed),
                             self.block_frames)
        self._file: StreamedMdf | None = StreamedMdf(self.path, template, [layout], self.compression)

    def append(self, frames: np.ndarray, *, owned: bool = False) -> None:
        """Append frames (FRAME_DTYPE, in time order, after those appended before).

        ``owned``: the caller will not change them (no copy is made on its thread:
        :meth:`StreamedMdf.append <benchtwin.mf4stream.StreamedMdf.append>`).
        """
        if self._file is None:
            raise ValueError(f"{self.path}: bus log already closed")
        self._file.append(0, frames, owned=owned)
        self.frames += len(frames)

    def close(self) -> Path:
        """Write the last block and the blocks that describe the log; return its path."""
        if self._file is not None:
            file, self._file = self._file, None
            file.close()
        return self.path

    def __enter__(self) -> BusLogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_mf4(path: str | Path, bus: str | None = None, bitrate: int = 500_000, *,
             origin: datetime = DEFAULT_START) -> FrameTable:
    """Read every CAN data frame of an MF4 bus log into a frame table (bulk, no per-frame objects).

    Timestamps are seconds since ``origin`` (the run start; the logs of a batch run start at
    :data:`DEFAULT_START`, so they come back unchanged; a file of another logger, e.g. python-can's
    ``MF4Writer``, is shifted by its header start time, as ``can.MF4Reader`` does). A truncated benchtwin
    log gives the frames before the cut (with a warning; :func:`read_bus_log` also returns what is wrong).

    Raises
    ------
    DataError
        If the file is missing, unreadable (and not salvageable) or holds no CAN_DataFrame group.
    """
    table, damage = _read_mf4(Path(path), bus, bitrate, origin)
    if damage:
        log.warning("%s: %s", path, damage)
    return table


def _frames_from_mf4(samples: np.ndarray, timestamps: np.ndarray, shift: float) -> np.ndarray:
    s = samples
    fr = np.zeros(len(s), dtype=FRAME_DTYPE)
    fr["timestamp"] = timestamps + shift if shift else timestamps
    ids = s["CAN_DataFrame.ID"].astype(np.uint32)
    fr["arbitration_id"] = ids & np.uint32(0x1FFFFFFF)
    fr["is_extended"] = (s["CAN_DataFrame.IDE"] != 0) | ((ids & np.uint32(0x80000000)) != 0)
    fr["dlc"] = s["CAN_DataFrame.DLC"]
    data = np.asarray(s["CAN_DataFrame.DataBytes"])
    w = min(8, data.shape[1]) if data.ndim == 2 else 0
    if w:
        fr["data"][:, :w] = data[:, :w]
    return fr


def _read_mf4(path: Path, bus: str | None, bitrate: int, origin: datetime = DEFAULT_START
              ) -> tuple[FrameTable, str | None]:
    if not path.exists():
        raise DataError(f"{path}: no such bus log")
    if _mf4_cut_before_its_groups(path):  # truncated: asammdf cannot open it; read the records up to the cut
        salvaged = _salvage_mf4(path, origin)
        if salvaged is not None:
            return FrameTable(bus or path.stem, salvaged[0], bitrate), salvaged[1]
    mdf, error = _open_mdf(path)
    if mdf is None:
        salvaged = _salvage_mf4(path, origin)
        if salvaged is None:
            raise DataError(f"{path}: not a readable MF4 file ({error})")
        frames, reason = salvaged
        return FrameTable(bus or path.stem, frames, bitrate), reason
    parts = []
    damage = []
    with mdf:
        # timestamps are relative to the header start: bring them to seconds since DEFAULT_START (the
        # campaign's t = 0 for the logs benchtwin writes; any other logger's file keeps its real time)
        shift = mdf.header.start_time.timestamp() - origin.timestamp()
        for gi, group in enumerate(mdf.groups):
            names = [ch.name for ch in group.channels]
            if "CAN_DataFrame" not in names:
                continue
            try:
                sig = mdf.get("CAN_DataFrame", group=gi)
            except Exception as exc:  # a damaged data block
                damage.append(f"channel group {gi} unreadable ({exc})")
                continue
            expected = int(getattr(group.channel_group, "cycles_nr", len(sig)))
            if len(sig) < expected:
                damage.append(f"{len(sig)} of the {expected} frames its channel group counts")
            parts.append(_frames_from_mf4(sig.samples, sig.timestamps, shift))
    if not parts and not damage:
        raise DataError(f"{path}: no CAN_DataFrame group (not a CAN bus log)")
    frames = merge_frames(parts) if parts else np.zeros(0, FRAME_DTYPE)
    return FrameTable(bus or path.stem, frames, bitrate), "; ".join(damage) or None


def _open_mdf(path: Path) -> tuple[Any, str]:
    """asammdf's MDF of ``path`` (without bus-logging processing: we decode the frames ourselves), or None and
    why (:func:`benchtwin.recording.open_mdf` keeps asammdf's complaint about a half-built object quiet)."""
    try:
        return open_mdf(path, process_bus_logging=False), ""
    except DataError as exc:
        return None, str(exc)


def _mf4_cut_before_its_groups(path: Path) -> bool:
    """True when an MF4 file ends before its header or its first data group block (a truncated file)."""
    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(64 + 24 + 8)
    if head[:3] != b"MDF":
        return False  # not an MF4 at all: let asammdf say so
    if len(head) < 64 + 32 or head[64:68] != b"##HD":
        return True
    first_dg = int.from_bytes(head[64 + 24:64 + 32], "little")
    return first_dg + 24 > size


def _salvage_mf4(path: Path, origin: datetime = DEFAULT_START) -> tuple[np.ndarray, str] | None:
    """The frames before the cut of a truncated MF4 with benchtwin's record layout (None if it is not one)."""
    raw = path.read_bytes()
    if raw[:3] != b"MDF":
        return None
    if len(raw) < 64 + 24 or raw[64:68] != b"##HD":
        return np.zeros(0, FRAME_DTYPE), "truncated inside its header: no frame left"
    hd_links = int.from_bytes(raw[64 + 16:64 + 24], "little")
    hd_data = 64 + 24 + 8 * hd_links
    found = [p for p in (raw.find(b"##DT", hd_data), raw.find(b"##DZ", hd_data)) if p >= 0]
    pos = min(found) if found else -1
    if hd_data + 8 > len(raw) or pos < 0:
        return np.zeros(0, FRAME_DTYPE), "truncated before its data: no frame left"
    start_ns = int.from_bytes(raw[hd_data:hd_data + 8], "little")
    if b"benchtwin bus log" not in raw[:pos]:
        return None  # another logger's layout: the records cannot be known without the channel blocks
    chunks, declared = _data_blocks(raw, pos)
    body = b"".join(chunks)
    n = len(body) // _MF4_RECORD.itemsize
    rec = np.frombuffer(body[:n * _MF4_RECORD.itemsize], dtype=_MF4_RECORD)
    shift = start_ns / 1e9 - origin.timestamp()
    frames = _frames_from_mf4(rec, rec["time"].astype(np.float64), shift)
    at_least = declared // _MF4_RECORD.itemsize
    return frames, (f"truncated: the file ends inside its data (channel blocks missing); {n} frames kept "
                    f"of at least {at_least} its data blocks declare")


def _data_blocks(raw: bytes, pos: int) -> tuple[list[bytes], int]:
    """The record bytes of the data blocks from ``pos`` on, up to the cut, and how many bytes they declare.

    ``##DT`` blocks hold records as they are; ``##DZ`` blocks hold them deflated (zip type 0) or transposed
    (record bytes by column) and deflated (zip type 1). The deflated stream of a cut DZ block gives its
    records up to the cut; a cut transposed block gives none (its first bytes are the first column only).
    """
    chunks: list[bytes] = []
    declared = 0
    while pos + 24 <= len(raw) and raw[pos:pos + 4] in (b"##DT", b"##DZ"):
        length = int.from_bytes(raw[pos + 8:pos + 16], "little")
        if length < 24:
            break
        end = min(pos + length, len(raw))
        if raw[pos:pos + 4] == b"##DT":
            declared += length - 24
            chunks.append(raw[pos + 24:end])
        else:
            if pos + 48 > len(raw):
                break
            zip_type = raw[pos + 26]
            param = int.from_bytes(raw[pos + 28:pos + 32], "little")
            original = int.from_bytes(raw[pos + 32:pos + 40], "little")
            declared += original
            try:
                body = zlib.decompressobj().decompress(raw[pos + 48:end])
            except zlib.error:
                break
            if zip_type == 1 and param > 1:
                if len(body) < original:
                    break  # a cut transposed block: its records cannot be rebuilt
                rows = original // param
                body = (np.frombuffer(body[:rows * param], np.uint8).reshape(param, rows).T.tobytes()
                        + body[rows * param:])
            elif zip_type not in (0, 1):
                break
            chunks.append(body)
        if end < pos + length:
            break
        pos += (length + 7) // 8 * 8
    return chunks, declared


def write_blf(table: FrameTable, path: str | Path, *, channel: int = 1, start_time: datetime = DEFAULT_START) -> Path:
    """Export a frame table as BLF with python-can's BLFWriter, frames at absolute times ``start_time + t``.

    python-can's ``BLFReader`` gives them back as Unix times (the file start is kept to the
    millisecond; the ``<file>.blf.json`` sidecar keeps the exact first time for :func:`read_blf`).
    """
    import can

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    f = table.frames
    epoch = start_time.timestamp()
    ts = (f["timestamp"] + epoch).tolist()
    ids = f["arbitration_id"].tolist()
    ext = f["is_extended"].tolist()
    dlc = f["dlc"].tolist()
    data = f["data"].tobytes()
    with can.BLFWriter(str(path)) as writer:
        for k in range(len(f)):
            n = min(dlc[k], 8)
            writer.on_message_received(can.Message(timestamp=ts[k], arbitration_id=ids[k], is_extended_id=ext[k],
                                                   dlc=dlc[k], data=data[8 * k:8 * k + n], channel=channel,
                                                   check=False))
    # BLF stores its start to the millisecond: remember the exact first time (run seconds), the run start, and
    # the frame count and last time (a truncated file is recognised by them)
    _blf_sidecar(path).write_text(json.dumps({"first_timestamp_s": float(f["timestamp"][0]) if len(f) else 0.0,
                                              "start_time": start_time.isoformat(), "bus": table.bus,
                                              "frames": len(f),
                                              "last_timestamp_s": float(f["timestamp"][-1]) if len(f) else 0.0}),
                                  encoding="utf-8")
    return path


def _blf_sidecar(path: Path) -> Path:
    return path.with_name(path.name + ".json")


def read_blf(path: str | Path, bus: str | None = None, bitrate: int = 500_000, *,
             origin: datetime = DEFAULT_START) -> FrameTable:
    """Read a BLF log with python-can into a frame table, times in seconds since ``origin`` (the run start).

    python-can gives the absolute times of the file (start to the millisecond); the ``<file>.blf.json``
    that :func:`write_blf` leaves next to the file restores the exact first time. A damaged or truncated
    file gives the frames before the damage (with a warning; :func:`read_bus_log` also returns what is wrong).
    """
    table, damage = _read_blf(Path(path), bus, bitrate, origin)
    if damage:
        log.warning("%s: %s", path, damage)
    return table


def _read_blf(path: Path, bus: str | None, bitrate: int, origin: datetime = DEFAULT_START
              ) -> tuple[FrameTable, str | None]:
    import can
    import can.io.blf

    if not path.exists():
        raise DataError(f"{path}: no such bus log")
    rows = []
    damage = []
    declared = None
    n_objects = 0
    try:
        reader = can.BLFReader(str(path))
        declared = int(reader.object_count)
        for msg in reader:
            n_objects += 1
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            d = bytes(msg.data)[:8].ljust(8, b"\x00")
            rows.append((msg.timestamp, msg.arbitration_id, msg.is_extended_id, msg.dlc, tuple(d)))
    except (can.CanError, can.io.blf.BLFParseError, struct.error, zlib.error, ValueError, OSError,
            EOFError) as exc:
        damage.append(f"unreadable after {n_objects} objects ({type(exc).__name__}: {exc or 'truncated'})")
    if declared is not None and declared and n_objects < declared:
        damage.append(f"{n_objects} of the {declared} objects its header counts")
    fr = np.array(rows, dtype=FRAME_DTYPE) if rows else np.zeros(0, FRAME_DTYPE)
    fr["timestamp"] -= origin.timestamp()
    side = _blf_sidecar(path)
    if side.exists():
        try:
            blob = json.loads(side.read_text(encoding="utf-8"))
            if len(fr):
                first = float(blob["first_timestamp_s"])
                if "start_time" in blob:
                    first += datetime.fromisoformat(blob["start_time"]).timestamp() - origin.timestamp()
                if abs(first - fr["timestamp"][0]) < 2e-3:  # the sidecar of this file: sub-millisecond start
                    fr["timestamp"] += first - fr["timestamp"][0]
            want = int(blob.get("frames", len(fr)))
            if len(fr) < want and not damage:
                damage.append(f"{len(fr)} of the {want} frames written")
        except (ValueError, KeyError, TypeError):
            pass  # a foreign sidecar: keep the reader's times
    return FrameTable.concat(bus or path.stem, [fr], bitrate), "; ".join(damage) or None


def read_bus_log(path: str | Path, bus: str | None = None, bitrate: int = 500_000, *,
                 origin: datetime = DEFAULT_START) -> tuple[FrameTable, str | None]:
    """Read a ``.mf4`` or ``.blf`` bus log; return its frames and what is wrong with the file (None if whole).

    The frames before any damage are kept. Only the file's own bookkeeping is checked here (object
    and cycle counts, readable blocks); :func:`benchtwin.chain.batch.read_logs` also compares the end
    of each bus's time base with the segment table and the other buses.

    Raises
    ------
    DataError
        If the file is missing or cannot be read at all (not a bus log).
    """
    p = Path(path)
    if p.suffix.lower() == ".blf":
        return _read_blf(p, bus, bitrate, origin)
    return _read_mf4(p, bus, bitrate, origin)
