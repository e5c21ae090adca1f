"""A poll log gathered chunk by chunk: kept in memory, or appended to raw files and read back by index ranges.

The acquisition and the streamed chain (:func:`benchtwin.chain.stream.run_chunked`) collect each polled device's log
here as the chunks come; with a directory nothing of it stays in memory (38 B a poll at 14 registers: 0.4 GB a
day at 100 Hz). :meth:`PollSpool.part` reads any range of polls back (the block-wise decoder), and
:meth:`PollSpool.write_npz` writes the ``.npz`` poll log :func:`benchtwin.chain.polllog.write_poll_log` writes,
block by block.
"""

from __future__ import annotations

import logging
import math
import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from numpy.lib import format as npformat

from benchtwin.chain.channel_store import ChannelStore
from benchtwin.chain.decoding import events_for
from benchtwin.errors import DataError
from benchtwin.wire.frames import PollLog, TransportEvent
from benchtwin.wire.quality import DecodeSink

__all__ = ["PollSpool", "decode_spooled"]

log = logging.getLogger(__name__)

_BLOCK = 1 << 18


class PollSpool:
    """One device's poll log, appended part by part.

    Parameters
    ----------
    first:
        The first part (its device, unit, function code, first register and register count are the log's).
    directory:
        Append the polls to files in a new folder inside this one (removed by :meth:`cleanup`); None keeps the
        parts in memory.
    """

    def __init__(self, first: PollLog, directory: str | Path | None = None) -> None:
        self.device = first.device
        self.unit_id = first.unit_id
        self.function_code = first.function_code
        self.first_register = first.first_register
        self.count = first.count
        self._n = 0
        self._parts: list[PollLog] = []
        self._starts: list[int] = []
        self._dir: Path | None = None
        if directory is not None:
            Path(directory).mkdir(parents=True, exist_ok=True)
            self._dir = Path(tempfile.mkdtemp(prefix=".polls-", dir=directory))
        self.first_s: float | None = None
        self.last_s: float | None = None
        self.append(first)

    def _file(self, k: int) -> Path:
        assert self._dir is not None
        return self._dir / ("times", "values", "status")[k]

    def append(self, part: PollLog) -> None:
        """Add the polls of ``part`` after those already held.

        Raises
        ------
        DataError
            If ``part`` is another device's or reads another register block.
        """
        if (part.device, part.unit_id, part.function_code, part.first_register, part.count) != (
                self.device, self.unit_id, self.function_code, self.first_register, self.count):
            raise DataError(f"poll log {self.device!r}: a chunk of {part.device!r} (unit {part.unit_id}, function "
                            f"{part.function_code}, registers {part.first_register}+{part.count}) does not continue it")
        if not len(part):
            if self._dir is None and not self._parts:
                self._parts.append(part)
                self._starts.append(0)
            return
        if self.first_s is None:
            self.first_s = float(part.times[0])
        self.last_s = float(part.times[-1])
        if self._dir is None:
            self._parts.append(part)
            self._starts.append(self._n)
        else:
            for k, a in enumerate((part.times, part.values, part.status)):
                with open(self._file(k), "ab") as fh:
                    np.ascontiguousarray(a).tofile(fh)
        self._n += len(part)

    def __len__(self) -> int:
        return self._n

    def part(self, start: int, stop: int) -> PollLog:
        """Polls ``start`` to ``stop`` (indices, clipped to the log)."""
        start, stop = max(0, int(start)), min(self._n, int(stop))
        stop = max(start, stop)
        if self._dir is None:
            if len(self._parts) == 1:
                return self._parts[0].part(start, stop)
            i = max(0, int(np.searchsorted(self._starts, start, side="right")) - 1)
            pieces = []
            while i < len(self._parts) and self._starts[i] < stop:
                s0 = self._starts[i]
                pieces.append(self._parts[i].part(max(0, start - s0), stop - s0))
                i += 1
            if len(pieces) == 1:
                return pieces[0]
            if not pieces:
                return self._parts[0].part(0, 0)
            return PollLog(self.device, self.unit_id, self.function_code, self.first_register,
                           np.concatenate([p.times for p in pieces]), np.concatenate([p.values for p in pieces]),
                           np.concatenate([p.status for p in pieces]))
        m = stop - start
        times = np.fromfile(self._file(0), np.float64, m, offset=8 * start) if m else np.zeros(0)
        values = (np.fromfile(self._file(1), np.uint16, m * self.count, offset=2 * self.count * start)
                  if m else np.zeros(0, np.uint16)).reshape(m, self.count)
        status = np.fromfile(self._file(2), np.int16, m, offset=2 * start) if m else np.zeros(0, np.int16)
        return PollLog(self.device, self.unit_id, self.function_code, self.first_register, times, values, status)

    def whole(self) -> PollLog:
        """The whole log in memory."""
        return self.part(0, self._n)

    def blocks(self, block: int = _BLOCK):
        """The log in parts of ``block`` polls."""
        for a in range(0, self._n, block):
            yield self.part(a, a + block)

    def write_npz(self, path: str | Path, block: int = _BLOCK) -> Path:
        """The log as :func:`benchtwin.chain.polllog.write_poll_log` saves it, written ``block`` polls at a time."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        n, c = self._n, self.count
        small = {"device": np.array(self.device), "unit_id": np.array(self.unit_id),
                 "function_code": np.array(self.function_code), "first_register": np.array(self.first_register)}
        big = {"times": (np.dtype(np.float64), (n,), 0), "values": (np.dtype(np.uint16), (n, c), 1),
               "status": (np.dtype(np.int16), (n,), 2)}
        with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
            for key in ("device", "unit_id", "function_code", "first_register", "times", "values", "status"):
                with zf.open(key + ".npy", "w", force_zip64=True) as fh:
                    if key in small:
                        npformat.write_array(fh, small[key], allow_pickle=False)
                        continue
                    dtype, shape, k = big[key]
                    npformat.write_array_header_1_0(fh, {"descr": npformat.dtype_to_descr(dtype),
                                                         "fortran_order": False, "shape": shape})
                    for p in self.blocks(block):
                        fh.write(np.ascontiguousarray((p.times, p.values, p.status)[k]).tobytes())
        return path

    def cleanup(self) -> None:
        """Remove the files (or drop the parts)."""
        self._parts = []
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)


def decode_spooled(polls: dict[str, PollSpool], polled: dict[str, Any], events: list[TransportEvent], sink: DecodeSink,
                   store: ChannelStore, block: int, setup_name: str) -> list[str]:
    """Decode every spooled poll log (removed from ``polls`` and cleaned up as it goes) ``block`` polls at a time,
    each block of each channel appended to ``store`` after its other channels (their order: as first emitted).

    ``polled``: device name -> the setup's device polled under it. Counts, protocol errors and fault evidence go to
    ``sink``; a log of no device is counted, one whose decoding fails is a protocol error. Returns the names of the
    channels appended, in order (a device's default decoder may instead put whole channels in ``sink.rec``).
    """
    emitted: list[str] = []

    def emit(name: str, unit: str, t: np.ndarray, v: np.ndarray, f: np.ndarray, source: str) -> None:
        if name not in emitted:
            emitted.append(name)
        store.append(name, unit, source, None, (math.inf, len(emitted) - 1), t, v, f)

    for device in list(polls):
        spool = polls.pop(device)
        dev = polled.get(device)
        try:
            if dev is None:
                log.warning("poll log %s belongs to no device of setup %s: not decoded", device, setup_name)
                sink.count("unknown_poll_devices", device, len(spool))
                continue
            try:
                dev.decode_poll_blocks(spool, sink, events_for(events, {device}), emit, block)
            except Exception as exc:
                log.error("poll log %s could not be decoded: %s", device, exc)
                sink.protocol_error(f"modbus:{device}: decoding failed ({exc})", max(1, len(spool)))
        finally:
            spool.cleanup()
    return emitted
