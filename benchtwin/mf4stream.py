"""MF4 files whose data blocks benchtwin writes as the records arrive, compressed on worker threads.

asammdf, writing a file it builds in memory, puts every appended block through its temporary file (lz4 in, lz4
out) and compresses every group on ``save``, on the caller's thread. Here asammdf writes only what describes the
file (header, channel groups, channels, conversions, sources, history: its ``save`` of the groups with no records,
the *template*) and :class:`StreamedMdf` writes the data blocks, as asammdf's ``save`` lays them out (the same
``##DT``/``##DZ`` blocks of the same records, cut at the same record counts, a ``##DL`` list and, compressed, a
``##HL`` header for a group of several blocks, after its blocks), compressed as asammdf's ``DataZippedBlock`` does
(its compressor at its level) on worker threads while the caller goes on:

    identification, header and its comment | group 0's data blocks, DL, HL | group 1's ... | the template's other
    blocks, moved

The template's blocks after the header keep their order; every link of theirs (and of the header) into them is moved
by the size of what is written in between, then each data group's data link and each channel group's cycle count are
set. MDF 4 blocks all start alike (``##XX``, reserved, length, link count, links), so moving them needs no knowledge of
the block types. A file equals asammdf's ``save`` of the same records byte for byte but for the history block's time
(tests/test_recording_blocks.py, tests/chain/test_bus_log_blocks.py).

While the file is written the header's links point past its end, so a file cut then (a crash mid-run) reads as a
truncated one (:func:`benchtwin.chain.buslog.read_bus_log` keeps the frames of the whole data blocks before the cut).
"""

from __future__ import annotations

import io
import struct
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["GroupLayout", "StreamedMdf", "mdf_template", "record_bytes", "without_history_time"]

_BLOCK_HEAD = struct.Struct("<4sIQQ")  # id, reserved, length, link count
_U64 = struct.Struct("<Q")
#: the header's links while the data are written: past any file's end (a cut file reads as truncated)
_UNWRITTEN = 1 << 62
#: asammdf's ``save`` cuts a group's data into blocks of this many bytes (whole records)
FRAGMENT_BYTES = 4 << 20


def mdf_template(mdf: Any, compression: int) -> bytes:
    """asammdf's ``save`` of ``mdf`` (its channel groups appended with no records) as bytes."""
    buf = io.BytesIO()
    mdf.save(buf, overwrite=True, compression=compression)
    return buf.getvalue()


def record_bytes(records: np.ndarray, transposed: bool) -> bytes:
    """The bytes of a block of records (a structured array): record after record, or byte column after byte column
    (``transposed``: what transposed deflate compresses)."""
    if not transposed:
        return records.tobytes()
    n = len(records)
    return np.ascontiguousarray(records).view(np.uint8).reshape(n, records.dtype.itemsize).T.tobytes()


@dataclass
class GroupLayout:
    """How one channel group's records are written.

    ``record_size``: bytes of a record (no invalidation bytes); ``records_of(items, transposed) -> bytes``: the data of
    a block of the items appended (run on a worker thread; default :func:`record_bytes`, items being records);
    ``block_records``: records of a data block (default asammdf's cut: ``4 MiB // record_size``).
    """

    record_size: int
    records_of: Callable[[np.ndarray, bool], bytes] = record_bytes
    block_records: int = 0
    pending: list[np.ndarray] = field(default_factory=list)
    pending_n: int = 0
    records: int = 0
    addresses: list[int] = field(default_factory=list)
    finished: bool = False
    link: int = 0

    def __post_init__(self) -> None:
        if self.block_records <= 0:
            self.block_records = max(1, FRAGMENT_BYTES // self.record_size)


def without_history_time(raw: bytes) -> bytes:
    """An MF4 file's bytes with its history block's time (when it was saved, ``fh_time_ns``) zeroed: two saves of the
    same data compare equal byte for byte.

    Raises
    ------
    ValueError
        The file has not exactly one history (``##FH``) block.
    """
    buf = bytearray(raw)
    fh = [a for a, _, _ in _blocks(raw, 64) if raw[a:a + 4] == b"##FH"]
    if len(fh) != 1:
        raise ValueError(f"{len(fh)} history blocks, expected one")
    at = fh[0] + 24 + 8 * 2  # after the block head and its two links: fh_time_ns
    buf[at:at + 8] = bytes(8)
    return bytes(buf)


def _blocks(raw: bytes | bytearray, start: int) -> list[tuple[int, int, int]]:
    """``(address, length, links)`` of the blocks of ``raw`` from ``start`` on (zero padding between them skipped)."""
    out = []
    pos = start
    while pos < len(raw):
        if raw[pos:pos + 2] != b"##":
            if bytes(raw[pos:pos + 8]).strip(b"\0"):
                raise ValueError(f"MF4 template: no block at {pos} ({bytes(raw[pos:pos + 8])!r})")
            pos += 8
            continue
        _, _, length, links = _BLOCK_HEAD.unpack_from(raw, pos)
        out.append((pos, length, links))
        pos += length + (-length % 8)
    return out


def _link(buf: bytes | bytearray, addr: int, k: int) -> int:
    return _U64.unpack_from(buf, addr + _BLOCK_HEAD.size + 8 * k)[0]


def _set_link(buf: bytearray, addr: int, k: int, value: int) -> None:
    _U64.pack_into(buf, addr + _BLOCK_HEAD.size + 8 * k, value)


def _moved(buf: bytearray, addr: int, limit: int, shift: int) -> None:
    """Add ``shift`` to each link of the block at ``addr`` that points at or past ``limit``."""
    n = _BLOCK_HEAD.unpack_from(buf, addr)[3]
    for k in range(n):
        link = _link(buf, addr, k)
        if link >= limit:
            _set_link(buf, addr, k, link + shift)


class StreamedMdf:
    """An MF4 file of channel groups written block by block as their records arrive, equal to asammdf's ``save`` of
    the same records with ``compression``.

    Parameters
    ----------
    path:
        Output file (written from the start: the header, then the data blocks as they come).
    template:
        :func:`mdf_template` of the groups with no records.
    groups:
        One :class:`GroupLayout` per channel group, in the file's order (asammdf's ``mdf.groups``).
    compression:
        asammdf's: 0 none (``##DT``), 1 deflate, 2 transposed deflate (``##DZ``).
    workers:
        Threads making the data blocks (compression releases the GIL; blocks are written in order).
    max_pending:
        Blocks handed to the workers and not yet written, at most (the caller waits beyond: memory stays bounded).
    """

    def __init__(self, path: str | Path, template: bytes, groups: list[GroupLayout], compression: int, *,
                 workers: int = 1, max_pending: int = 3) -> None:
        from asammdf.blocks import v4_constants as v4c

        self.path = Path(path)
        self.compression = int(compression)
        self.groups = groups
        self._template = template
        self._zip_type = v4c.FLAG_DZ_DEFLATE if self.compression == 1 else v4c.FLAG_DZ_TRANSPOSED_DEFLATE
        hd = 64
        if template[hd:hd + 4] != b"##HD":
            raise ValueError("MF4 template: no header block at 64")
        _, _, hd_len, hd_links = _BLOCK_HEAD.unpack_from(template, hd)
        end = hd + hd_len + (-hd_len % 8)
        if _link(template, hd, hd_links - 1) == end:  # the header's comment, written with it before the data
            c_len = _BLOCK_HEAD.unpack_from(template, end)[2]
            end += c_len + (-c_len % 8)
        self._prefix_end = end
        self._dgs = []  # the data groups, in the chain's order (asammdf's groups)
        dg = _link(template, hd, 0)
        while dg:
            self._dgs.append(dg)
            dg = _link(template, dg, 0)
        if len(self._dgs) != len(groups):
            raise ValueError(f"MF4 template: {len(self._dgs)} data groups for {len(groups)} group layouts")
        # blocks being made, in the file's order; None: the group's data list, once its blocks are written
        self._futures: deque[tuple[GroupLayout, Future[bytes] | None]] = deque()
        self._max_pending = max(1, int(max_pending))
        self._fh: Any = self.path.open("wb")
        prefix = bytearray(template[:end])
        _moved(prefix, hd, end, _UNWRITTEN)
        self._fh.write(prefix)
        self._pool: ThreadPoolExecutor | None = ThreadPoolExecutor(max_workers=max(1, int(workers)),
                                                                   thread_name_prefix="mf4-blocks")

    def append(self, group: int, items: np.ndarray, *, owned: bool = False) -> None:
        """Append items (whatever the group's ``records_of`` turns into records) to a group, after its earlier ones.

        ``owned``: the caller hands ``items`` over and will not change them, so no copy of them is made on its thread;
        otherwise they are copied here, and the caller may reuse its arrays once append returns. A block's pieces are
        joined on the worker.
        """
        g = self.groups[group]
        if g.finished:
            raise ValueError(f"StreamedMdf: group {group} already finished")
        k, n = 0, len(items)
        while k < n:
            take = min(n - k, g.block_records - g.pending_n)
            g.pending.append(items[k:k + take] if owned else items[k:k + take].copy())
            g.pending_n += take
            k += take
            if g.pending_n == g.block_records:
                self._submit(g)

    def _submit(self, g: GroupLayout) -> None:
        if not g.pending_n:
            return
        block = g.pending  # joined on the worker
        g.records += g.pending_n
        g.pending, g.pending_n = [], 0
        assert self._pool is not None
        self._futures.append((g, self._pool.submit(self._block, g, block)))
        self._write_done(self._max_pending)

    def finish_group(self, group: int) -> None:
        """No more records for this group: its last block and then its data list are written next (as asammdf's
        ``save`` writes a group's data list after its blocks, before the next group's)."""
        g = self.groups[group]
        if g.finished:
            return
        self._submit(g)
        g.finished = True
        self._futures.append((g, None))
        self._write_done(self._max_pending)

    def _write_done(self, keep: int) -> None:
        """Write the finished blocks at the head of the queue, waiting while more than ``keep`` are queued."""
        while self._futures and (len(self._futures) > keep or self._futures[0][1] is None
                                 or self._futures[0][1].done()):
            g, fut = self._futures.popleft()
            if fut is None:
                g.link = self._data_link(g)
                continue
            raw = fut.result()
            g.addresses.append(self._fh.tell())
            self._fh.write(raw)

    def _block(self, g: GroupLayout, items: list[np.ndarray]) -> bytes:
        """On a worker: a data block of the items' pieces, joined, compressed as asammdf's ``save`` does, padded to 8
        bytes."""
        from asammdf.blocks import v4_blocks
        from asammdf.blocks import v4_constants as v4c

        items = np.concatenate(items) if len(items) > 1 else items[0]
        transposed = self.compression == 2
        data = g.records_of(items, transposed)
        if self.compression:
            # asammdf's DataZippedBlock, but on records already laid out column by column (its ``transposed``
            # argument is reset by its own attribute setter): the same compressor at the same level
            zipped = v4_blocks.compress(data, v4_blocks.COMPRESSION_LEVEL)
            raw = v4c.DZ_COMMON_p(b"##DZ", 0, len(zipped) + v4c.DZ_COMMON_SIZE, 0, b"DT", self._zip_type, 0,
                                  g.record_size if transposed else 0, len(data), len(zipped)) + zipped
        else:
            raw = bytes(v4_blocks.DataBlock(data=data))
        return raw + b"\0" * (-len(raw) % 8)

    def close(self) -> Path:
        """Write the last blocks, the data lists and the template's other blocks, moved; return the path."""
        if self._pool is None:
            return self.path
        try:
            for k in range(len(self.groups)):
                self.finish_group(k)
            self._write_done(0)
            self._finish()
        finally:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
            self._fh.close()
        return self.path

    def _data_link(self, g: GroupLayout) -> int:
        """Write a group's data list (several blocks); its data link."""
        from asammdf.blocks.v4_blocks import DataList, HeaderList

        if len(g.addresses) <= 1:
            return g.addresses[0] if g.addresses else 0
        fh = self._fh
        n = len(g.addresses)
        dl = DataList(flags=1, links_nr=n + 1, data_block_nr=n, data_block_len=g.block_records * g.record_size)
        for i, addr in enumerate(g.addresses):
            dl[f"data_block_addr{i}"] = addr
        link = fh.tell()
        fh.write(bytes(dl))
        if self.compression:
            hl = HeaderList(flags=1, zip_type=self._zip_type, first_dl_addr=link)
            link = fh.tell()
            fh.write(bytes(hl))
        return link

    def _finish(self) -> None:
        links = [g.link for g in self.groups]
        fh = self._fh
        end = self._prefix_end
        shift = fh.tell() - end  # the template's blocks after the header go after the data
        buf = bytearray(self._template)
        cgs = [_link(buf, dg, 1) for dg in self._dgs]
        _moved(buf, 64, end, shift)
        for addr, _, _ in _blocks(self._template, end):
            _moved(buf, addr, end, shift)
        for dg, cg, g, link in zip(self._dgs, cgs, self.groups, links, strict=True):
            if _link(self._template, cg, 0):
                raise ValueError("MF4 template: a data group of several channel groups")
            _set_link(buf, dg, 2, link)  # dg_data: the third link (next, first CG, data, comment)
            n = _BLOCK_HEAD.unpack_from(buf, cg)[3]
            _U64.pack_into(buf, cg + _BLOCK_HEAD.size + 8 * n + 8, g.records)  # after cg_record_id: cg_cycle_count
        fh.write(bytes(buf[end:]))
        fh.seek(0)
        fh.write(bytes(buf[:end]))
