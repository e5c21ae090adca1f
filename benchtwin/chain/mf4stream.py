"""An MF4 file of one channel group written as its records arrive: the data blocks compressed on a worker thread.

asammdf, writing a file it builds in memory, puts every appended block through its temporary file (lz4 in, lz4
out) and compresses the whole group on ``save``, on the caller's thread. Here asammdf writes only what describes the
file (header, channel group, channels, sources, history: its ``save`` of the group with no records, the *template*)
and :class:`StreamedGroupFile` writes the data blocks itself, as asammdf's ``save`` lays them out (the same
``##DT``/``##DZ`` blocks of the same records, a ``##DL`` list and, compressed, a ``##HL`` header when there are
several), compressed as asammdf's ``DataZippedBlock`` does (its compressor, its level) on one worker thread while
the caller goes on:

    identification, header and its comment | data blocks | DL | HL | the template's other blocks, moved

The template's blocks after the header keep their order; every link of theirs (and of the header) into them is moved
by the size of the data written in between, then the data group's data link and the channel group's cycle count are
set. MDF 4 blocks all start with the same header (``##XX``, reserved, length, link count, links), so moving them needs
no knowledge of the block types. The file therefore equals asammdf's ``save`` of the same records byte for byte,
but for the history block's time (tests/chain/test_mf4stream.py).

While the file is written the header's links point past its end, so a cut file (a crash mid-run) is read as a
truncated one (:func:`benchtwin.chain.buslog.read_bus_log` keeps the frames of the whole data blocks before the cut).
"""

from __future__ import annotations

import io
import struct
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["StreamedGroupFile", "mdf_template"]

_BLOCK_HEAD = struct.Struct("<4sIQQ")  # id, reserved, length, link count
_U64 = struct.Struct("<Q")
#: the header's links while the data are written: past any file's end (a cut file reads as truncated)
_UNWRITTEN = 1 << 62


def mdf_template(mdf: Any, compression: int) -> bytes:
    """asammdf's ``save`` of ``mdf`` (one channel group, no records yet) as bytes."""
    buf = io.BytesIO()
    mdf.save(buf, overwrite=True, compression=compression)
    return buf.getvalue()


def _blocks(raw: bytes, start: int) -> list[tuple[int, int, int]]:
    """``(address, length, links)`` of the blocks of ``raw`` from ``start`` on (zero padding between them skipped)."""
    out = []
    pos = start
    while pos < len(raw):
        if raw[pos:pos + 2] != b"##":
            if raw[pos:pos + 8].strip(b"\0"):
                raise ValueError(f"MF4 template: no block at {pos} ({raw[pos:pos + 8]!r})")
            pos += 8
            continue
        _, _, length, links = _BLOCK_HEAD.unpack_from(raw, pos)
        out.append((pos, length, links))
        pos += length + (-length % 8)
    return out


def _links_of(buf: bytearray, addr: int) -> tuple[int, int]:
    """First link's offset and link count of the block at ``addr``."""
    _, _, _, n = _BLOCK_HEAD.unpack_from(buf, addr)
    return addr + _BLOCK_HEAD.size, n


def _moved(buf: bytearray, addr: int, limit: int, shift: int) -> None:
    """Add ``shift`` to each link of the block at ``addr`` that points at or past ``limit``."""
    first, n = _links_of(buf, addr)
    for k in range(n):
        at = first + 8 * k
        link = _U64.unpack_from(buf, at)[0]
        if link >= limit:
            _U64.pack_into(buf, at, link + shift)


class StreamedGroupFile:
    """An MF4 file of one channel group (records of ``record_size`` bytes, no invalidation bytes) written block by
    block as its records arrive, equal to asammdf's ``save`` of the group with ``compression``.

    Parameters
    ----------
    path:
        Output file (written from the start: the header, then the data blocks as they come).
    template:
        :func:`mdf_template` of the group with no records.
    record_size:
        Bytes of one record (the channel group's).
    compression:
        asammdf's: 0 none (``##DT``), 1 deflate, 2 transposed deflate (``##DZ``).
    block_records:
        Records per data block (the last one fewer; asammdf's ``save`` cuts at 4 MiB: ``(4 << 20) // record_size``).
    records_of:
        ``(items, transposed) -> bytes``: the data of a block of the items appended (``transposed``: byte column by
        byte column, as transposed deflate stores them), run on the worker thread.
    max_pending:
        Blocks handed to the worker and not yet written, at most (the caller waits beyond: memory stays bounded).
    """

    def __init__(self, path: str | Path, template: bytes, record_size: int, compression: int, block_records: int,
                 records_of: Callable[[np.ndarray, bool], bytes], *, max_pending: int = 3) -> None:
        from asammdf.blocks import v4_constants as v4c

        self.path = Path(path)
        self.record_size = int(record_size)
        self.compression = int(compression)
        self.block_records = max(1, int(block_records))
        self.records = 0
        self._records_of = records_of
        self._template = template
        self._zip_type = v4c.FLAG_DZ_DEFLATE if self.compression == 1 else v4c.FLAG_DZ_TRANSPOSED_DEFLATE
        hd = 64
        if template[hd:hd + 4] != b"##HD":
            raise ValueError("MF4 template: no header block at 64")
        _, _, hd_len, hd_links = _BLOCK_HEAD.unpack_from(template, hd)
        end = hd + hd_len + (-hd_len % 8)
        comment = _U64.unpack_from(template, hd + 24 + 8 * (hd_links - 1))[0]  # hd_md_comment: the last link
        if comment == end:  # the header's comment is written with it, before the data (the cut-file reader needs it)
            _, _, c_len, _ = _BLOCK_HEAD.unpack_from(template, end)
            end += c_len + (-c_len % 8)
        self._prefix_end = end
        self._addresses: list[int] = []
        self._pending: list[np.ndarray] = []
        self._pending_n = 0
        self._futures: deque[Future[None]] = deque()
        self._max_pending = max(1, int(max_pending))
        self._fh: Any = self.path.open("wb")
        prefix = bytearray(template[:end])
        _moved(prefix, hd, end, _UNWRITTEN)
        self._fh.write(prefix)
        self._pool: ThreadPoolExecutor | None = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mf4-blocks")

    def append(self, items: np.ndarray) -> None:
        """Append items (whatever ``records_of`` turns into records), after those appended before."""
        k = 0
        n = len(items)
        while k < n:
            take = min(n - k, self.block_records - self._pending_n)
            self._pending.append(items[k:k + take])
            self._pending_n += take
            k += take
            if self._pending_n == self.block_records:
                self._submit()

    def _submit(self) -> None:
        if not self._pending_n:
            return
        # a copy of its own: the caller may reuse its arrays once append returns
        block = np.concatenate(self._pending) if len(self._pending) > 1 else self._pending[0].copy()
        self._pending, self._pending_n = [], 0
        self.records += len(block)
        assert self._pool is not None
        self._futures.append(self._pool.submit(self._write_block, block))
        while len(self._futures) > self._max_pending:
            self._futures.popleft().result()

    def _write_block(self, items: np.ndarray) -> None:
        """On the worker: the block's records, compressed as asammdf's ``save`` does, written at the file's end."""
        from asammdf.blocks import v4_blocks
        from asammdf.blocks import v4_constants as v4c

        transposed = self.compression == 2
        data = self._records_of(items, transposed)
        if self.compression:
            # asammdf's DataZippedBlock, but on records already laid out column by column (its ``transposed``
            # argument is reset by its own attribute setter): the same compressor at the same level
            zipped = v4_blocks.compress(data, v4_blocks.COMPRESSION_LEVEL)
            raw = v4c.DZ_COMMON_p(b"##DZ", 0, len(zipped) + v4c.DZ_COMMON_SIZE, 0, b"DT", self._zip_type, 0,
                                  self.record_size if transposed else 0, len(data), len(zipped)) + zipped
        else:
            raw = bytes(v4_blocks.DataBlock(data=data))
        self._addresses.append(self._fh.tell())
        self._fh.write(raw + b"\0" * (-len(raw) % 8))

    def close(self) -> Path:
        """Write the last block, the data list and the template's other blocks, moved; return the path."""
        if self._pool is None:
            return self.path
        try:
            self._submit()
            while self._futures:
                self._futures.popleft().result()
            self._finish()
        finally:
            self._pool.shutdown(wait=True)
            self._pool = None
            self._fh.close()
        return self.path

    def _finish(self) -> None:
        from asammdf.blocks.v4_blocks import DataList, HeaderList

        fh = self._fh
        data_link = 0
        if len(self._addresses) == 1:
            data_link = self._addresses[0]
        elif self._addresses:
            n = len(self._addresses)
            dl = DataList(flags=1, links_nr=n + 1, data_block_nr=n,
                          data_block_len=self.block_records * self.record_size)
            for i, addr in enumerate(self._addresses):
                dl[f"data_block_addr{i}"] = addr
            data_link = fh.tell()
            fh.write(bytes(dl))
            if self.compression:
                hl = HeaderList(flags=1, zip_type=self._zip_type, first_dl_addr=data_link)
                data_link = fh.tell()
                fh.write(bytes(hl))
        tail_at = fh.tell()
        end = self._prefix_end
        shift = tail_at - end
        buf = bytearray(self._template)
        blocks = _blocks(self._template, end)
        _moved(buf, 64, end, shift)
        for addr, _, _ in blocks:
            _moved(buf, addr, end, shift)
        dgs = [a for a, _, _ in blocks if buf[a:a + 4] == b"##DG"]
        cgs = [a for a, _, _ in blocks if buf[a:a + 4] == b"##CG"]
        if len(dgs) != 1 or len(cgs) != 1:
            raise ValueError(f"MF4 template: {len(dgs)} data groups and {len(cgs)} channel groups (want one each)")
        dg_links, _ = _links_of(buf, dgs[0])
        _U64.pack_into(buf, dg_links + 16, data_link)  # dg_data: the third link (next, first CG, data, comment)
        cg_links, cg_n = _links_of(buf, cgs[0])
        _U64.pack_into(buf, cg_links + 8 * cg_n + 8, self.records)  # after cg_record_id: cg_cycle_count
        fh.write(bytes(buf[end:]))
        fh.seek(0)
        fh.write(bytes(buf[:end]))
