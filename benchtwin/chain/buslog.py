"""Raw bus logs: MF4 bus logging written and read in bulk, BLF export, Modbus poll logs.

MF4: one file per bus with the ASAM MDF 4 bus-logging layout (a ``CAN_DataFrame`` channel group of
the CAN bus-event type, the structure python-can's ``MF4Writer`` writes), appended in one
``MDF.append`` from the frame table's columns, so ``can.MF4Reader``, asammdf's
``extract_bus_logging`` and the asammdf viewer read it. Timestamps are relative to the header start
time (the device clocks as seen by the logger). Data bytes are stored 8 wide (classic CAN).

BLF: exported through python-can's ``BLFWriter`` (per message; for hand-over to Vector tools, not
for speed), with a ``.blf.json`` sidecar holding the exact first timestamp. Poll logs: ``.npz`` (bulk) and optional CSV.
"""

from __future__ import annotations

import csv
import json
import struct
import zipfile
import zlib
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from benchtwin.errors import DataError
from benchtwin.recording import open_mdf
from benchtwin.wire.frames import FRAME_DTYPE, FrameTable, PollLog
from benchtwin.wire.merge import merge_frames

__all__ = [
    "MF4_FRAME_DTYPE",
    "read_blf",
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

#: header start time of the logs written (the campaign's t = 0)
DEFAULT_START = datetime(2026, 1, 1, tzinfo=UTC)


def write_mf4(table: FrameTable, path: str | Path, *, channel: int = 1, start_time: datetime = DEFAULT_START,
              compression: int = 0) -> Path:
    """Write a frame table as an MF4 bus log in one bulk append.

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
        asammdf compression (0 none, 1 deflate, 2 transposed deflate).
    """
    from asammdf import MDF, Signal
    from asammdf.blocks.source_utils import Source

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    f = table.frames
    rec = np.zeros(len(f), dtype=MF4_FRAME_DTYPE)
    rec["CAN_DataFrame.BusChannel"] = channel
    rec["CAN_DataFrame.ID"] = f["arbitration_id"] | np.where(f["is_extended"], np.uint32(0x80000000), np.uint32(0))
    rec["CAN_DataFrame.IDE"] = f["is_extended"]
    rec["CAN_DataFrame.DLC"] = f["dlc"]
    rec["CAN_DataFrame.DataLength"] = np.minimum(f["dlc"], 8)
    rec["CAN_DataFrame.DataBytes"] = f["data"]
    mdf = MDF(version="4.10")
    mdf.header.start_time = start_time
    mdf.header.comment = f"benchtwin bus log: bus {table.bus}, {table.bitrate} bit/s"
    src = Source(name=table.bus, path=table.bus, comment=f"CAN bus {table.bus}", source_type=Source.SOURCE_BUS,
                 bus_type=Source.BUS_TYPE_CAN)
    mdf.append(Signal(name="CAN_DataFrame", samples=rec, timestamps=np.ascontiguousarray(f["timestamp"]),
                      source=src), acq_name=table.bus, comment=f"CAN bus {table.bus}")
    mdf.save(path, overwrite=True, compression=compression)
    mdf.close()
    return path


def read_mf4(path: str | Path, bus: str | None = None, bitrate: int = 500_000) -> FrameTable:
    """Read every CAN data frame of an MF4 bus log into a frame table (bulk, no per-frame objects).

    Timestamps are seconds since :data:`DEFAULT_START` (the logs benchtwin writes start there, so
    they come back unchanged; a file of another logger, e.g. python-can's ``MF4Writer``, is shifted
    by its header start time, as ``can.MF4Reader`` does).

    Raises
    ------
    DataError
        If the file is missing, unreadable or holds no CAN_DataFrame group.
    """
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such bus log")
    mdf = open_mdf(path, process_bus_logging=False)  # we decode the frames ourselves
    parts = []
    with mdf:
        # timestamps are relative to the header start: bring them to seconds since DEFAULT_START (the
        # campaign's t = 0 for the logs benchtwin writes; any other logger's file keeps its real time)
        shift = mdf.header.start_time.timestamp() - DEFAULT_START.timestamp()
        for gi, group in enumerate(mdf.groups):
            names = [ch.name for ch in group.channels]
            if "CAN_DataFrame" not in names:
                continue
            sig = mdf.get("CAN_DataFrame", group=gi)
            s = sig.samples
            fr = np.zeros(len(s), dtype=FRAME_DTYPE)
            fr["timestamp"] = sig.timestamps + shift if shift else sig.timestamps
            ids = s["CAN_DataFrame.ID"].astype(np.uint32)
            fr["arbitration_id"] = ids & np.uint32(0x1FFFFFFF)
            fr["is_extended"] = (s["CAN_DataFrame.IDE"] != 0) | ((ids & np.uint32(0x80000000)) != 0)
            fr["dlc"] = s["CAN_DataFrame.DLC"]
            data = np.asarray(s["CAN_DataFrame.DataBytes"])
            w = min(8, data.shape[1]) if data.ndim == 2 else 0
            if w:
                fr["data"][:, :w] = data[:, :w]
            parts.append(fr)
    if not parts:
        raise DataError(f"{path}: no CAN_DataFrame group (not a CAN bus log)")
    return FrameTable(bus or path.stem, merge_frames(parts), bitrate)


def write_blf(table: FrameTable, path: str | Path, *, channel: int = 1) -> Path:
    """Export a frame table as BLF with python-can's BLFWriter (timestamps relative to the log start)."""
    import can

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    f = table.frames
    ts = f["timestamp"].tolist()
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
    # BLF keeps times relative to its start (stored to the millisecond): remember the exact first time
    _blf_sidecar(path).write_text(json.dumps({"first_timestamp_s": ts[0] if ts else 0.0, "bus": table.bus}),
                                  encoding="utf-8")
    return path


def _blf_sidecar(path: Path) -> Path:
    return path.with_name(path.name + ".json")


def read_blf(path: str | Path, bus: str | None = None, bitrate: int = 500_000) -> FrameTable:
    """Read a BLF log with python-can into a frame table.

    python-can gives BLF times relative to the file start; the ``<file>.blf.json`` that
    :func:`write_blf` leaves next to the file restores the exact time base.
    """
    import can

    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such bus log")
    rows = []
    try:
        for msg in can.BLFReader(str(path)):
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            d = bytes(msg.data)[:8].ljust(8, b"\x00")
            rows.append((msg.timestamp, msg.arbitration_id, msg.is_extended_id, msg.dlc, tuple(d)))
    except (can.io.blf.BLFParseError, zlib.error, struct.error, ValueError, OSError) as exc:
        raise DataError(f"{path}: not a readable BLF bus log ({exc or type(exc).__name__})") from None
    fr = np.array(rows, dtype=FRAME_DTYPE) if rows else np.zeros(0, FRAME_DTYPE)
    side = _blf_sidecar(path)
    if side.exists() and len(fr):
        try:
            first = float(json.loads(side.read_text(encoding="utf-8"))["first_timestamp_s"])
            fr["timestamp"] += first - fr["timestamp"][0]
        except (ValueError, KeyError, TypeError):
            pass  # a foreign sidecar: keep the reader's times
    return FrameTable.concat(bus or path.stem, [fr], bitrate)


def write_poll_log(log: PollLog, path: str | Path) -> Path:
    """Save a poll log as ``.npz``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, device=np.array(log.device), unit_id=log.unit_id, function_code=log.function_code,
             first_register=log.first_register, times=log.times, values=log.values, status=log.status)
    return path


def read_poll_log(path: str | Path) -> PollLog:
    """Load a poll log written by :func:`write_poll_log`.

    Raises
    ------
    DataError
        If the file is missing or not a poll log.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            return PollLog(str(z["device"]), int(z["unit_id"]), int(z["function_code"]), int(z["first_register"]),
                           z["times"], z["values"], z["status"])
    except FileNotFoundError:
        raise DataError(f"{path}: no such poll log") from None
    except (KeyError, ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        why = "not an .npz archive" if "pickle" in str(exc) else (str(exc) or type(exc).__name__)
        raise DataError(f"{path}: not a poll log ({why})") from None


def write_poll_csv(log: PollLog, path: str | Path) -> Path:
    """Human-readable CSV of a poll log: time, unit, function code, status, then one column per register."""
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "unit_id", "function_code", "status",
                    *[f"reg{log.first_register + k}" for k in range(log.count)]])
        for k in range(len(log)):
            w.writerow([f"{log.times[k]:.6f}", log.unit_id, log.function_code, int(log.status[k]),
                        *log.values[k].tolist()])
    return path
