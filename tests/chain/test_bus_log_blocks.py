"""Bus logs written block by block (benchtwin.mf4stream): the file asammdf's own ``save`` writes of the same
frames, byte for byte but the history block's time, for each compression and for one, several and no data blocks;
read back frame for frame by asammdf and can.MF4Reader; and a log cut while being written reads as a truncated one."""

from __future__ import annotations

import struct
from itertools import pairwise
from pathlib import Path

import can  # before asammdf (facts: can.MF4Reader may not find asammdf otherwise)
import numpy as np
import pytest

from benchtwin.chain.buslog import (
    DEFAULT_START,
    MF4_BLOCK_FRAMES,
    BusLogWriter,
    _mf4_records,
    read_bus_log,
    read_mf4,
    write_mf4,
)
from benchtwin.mf4stream import _blocks, without_history_time
from benchtwin.wire.frames import FRAME_DTYPE, FrameTable


def _frames(n: int, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    f = np.zeros(n, FRAME_DTYPE)
    f["timestamp"] = np.cumsum(rng.uniform(1e-4, 2e-3, n))
    f["arbitration_id"] = rng.choice(np.array([0x0A0, 0x1B2, 0x3F0, 0x18FF50E5]), n)
    f["is_extended"] = f["arbitration_id"] > 0x7FF
    f["dlc"] = rng.integers(0, 9, n)
    f["data"] = rng.integers(0, 256, (n, 8)) * (np.arange(8) < f["dlc"][:, None])
    return f


def _asammdf_log(frames: np.ndarray, path: Path, compression: int, bus: str = "vehicle", channel: int = 2) -> Path:
    """The bus log as asammdf alone writes it (the appended records through its temporary file, compressed on save):
    the writer benchtwin had before the data blocks were its own."""
    from asammdf import MDF, Signal
    from asammdf.blocks.source_utils import Source

    mdf = MDF(version="4.10")
    mdf.header.start_time = DEFAULT_START
    mdf.header.comment = f"benchtwin bus log: bus {bus}, 500000 bit/s"
    src = Source(name=bus, path=bus, comment=f"CAN bus {bus}", source_type=Source.SOURCE_BUS,
                 bus_type=Source.BUS_TYPE_CAN)
    half = len(frames) // 2
    for k, part in enumerate((frames[:half], frames[half:])):
        rec, ts = _mf4_records(part, channel), np.ascontiguousarray(part["timestamp"])
        if k == 0:
            mdf.append(Signal(name="CAN_DataFrame", samples=rec, timestamps=ts, source=src), acq_name=bus,
                       comment=f"CAN bus {bus}")
        elif len(part):
            mdf.extend(0, [(ts, None), (rec, None)])
    mdf.save(path, overwrite=True, compression=compression)
    mdf.close()
    return path


# one block, exactly one block, several with a short last one (asammdf cuts at 149,796 records)
@pytest.mark.parametrize("n", [0, 1, 5_000, MF4_BLOCK_FRAMES, 2 * MF4_BLOCK_FRAMES + 17])
@pytest.mark.parametrize("compression", [0, 1, 2])
@pytest.mark.parametrize("owned", [False, True])  # the caller's frames copied on its thread, or joined on the worker
def test_the_log_is_the_file_asammdf_writes_of_the_same_frames(n: int, compression: int, owned: bool,
                                                              tmp_path: Path) -> None:
    frames = _frames(n)
    ref = _asammdf_log(frames, tmp_path / "ref.mf4", compression)
    cuts = sorted({0, min(3, n), n // 3, min(n // 3 + 1, n), n})  # appends that do not fall on the block edges
    with BusLogWriter(tmp_path / "ours.mf4", "vehicle", 500_000, channel=2, compression=compression) as w:
        for a, b in pairwise(cuts):
            w.append(frames[a:b], owned=owned)
    assert w.frames == n
    assert without_history_time(w.path.read_bytes()) == without_history_time(ref.read_bytes())
    assert read_mf4(w.path).frames.tobytes() == frames.tobytes()


def test_frames_not_owned_are_copied_when_handed_over(tmp_path: Path) -> None:
    """Without ``owned`` the caller may overwrite its array once append returns: the log holds what was appended
    (a mix of a copied and an owned append in one block too)."""
    frames = _frames(3_000)
    ref = write_mf4(FrameTable("vehicle", frames, 500_000), tmp_path / "ref.mf4", block_frames=1_000)
    buf = frames.copy()
    with BusLogWriter(tmp_path / "ours.mf4", "vehicle", 500_000, block_frames=1_000) as w:
        for a in range(0, 2_500, 500):
            buf[a:a + 500] = frames[a:a + 500]
            w.append(buf[a:a + 500])
            buf[a:a + 500] = 0  # reused by the caller
        w.append(frames[2_500:], owned=True)
    assert read_mf4(w.path).frames.tobytes() == frames.tobytes()
    assert without_history_time(w.path.read_bytes()) == without_history_time(ref.read_bytes())


def test_small_blocks_read_back_by_asammdf_and_python_can(tmp_path: Path) -> None:
    from asammdf import MDF

    frames = _frames(7_001)
    path = write_mf4(FrameTable("vehicle", frames, 500_000), tmp_path / "v.mf4", block_frames=1_000)
    blocks = [a for a, _, _ in _blocks(path.read_bytes(), 64)]
    raw = path.read_bytes()
    assert sum(raw[a:a + 4] == b"##DZ" for a in blocks) == 8  # 7 of 1,000 frames and the last one
    with MDF(path) as mdf:
        sig = mdf.get("CAN_DataFrame", group=0)
        assert sig.timestamps.tobytes() == frames["timestamp"].tobytes()
        np.testing.assert_array_equal(sig.samples["CAN_DataFrame.DataBytes"], frames["data"])
        np.testing.assert_array_equal(sig.samples["CAN_DataFrame.ID"] & 0x1FFFFFFF, frames["arbitration_id"])
    with can.MF4Reader(str(path)) as reader:
        msgs = list(reader)
    assert len(msgs) == len(frames)
    np.testing.assert_array_equal([m.arbitration_id for m in msgs], frames["arbitration_id"])
    np.testing.assert_array_equal([m.is_extended_id for m in msgs], frames["is_extended"])
    assert b"".join(bytes(m.data) for m in msgs) == b"".join(frames["data"][k, :frames["dlc"][k]].tobytes()
                                                            for k in range(len(frames)))


def test_a_log_cut_while_written_reads_as_truncated_with_its_whole_blocks(tmp_path: Path) -> None:
    frames = _frames(10_000)
    w = BusLogWriter(tmp_path / "v.mf4", "vehicle", 500_000, block_frames=1_000)
    w.append(frames[:4_500])
    w._file._write_done(0)  # type: ignore[union-attr]  # the 4 whole blocks written, then the crash
    w._file._fh.flush()  # type: ignore[union-attr]
    got, damage = read_bus_log(w.path)
    assert damage is not None and "truncated" in damage
    assert got.frames.tobytes() == frames[:4_000].tobytes()
    w._file._pool.shutdown()  # type: ignore[union-attr]
    w._file._fh.close()  # type: ignore[union-attr]


def test_the_header_links_past_the_end_while_written(tmp_path: Path) -> None:
    w = BusLogWriter(tmp_path / "v.mf4", "vehicle", 500_000)
    w._file._fh.flush()  # type: ignore[union-attr]
    head = w.path.read_bytes()
    first_dg = struct.unpack_from("<Q", head, 64 + 24)[0]
    assert first_dg > 1 << 60
    w.close()
    first_dg = struct.unpack_from("<Q", w.path.read_bytes(), 64 + 24)[0]
    assert first_dg < w.path.stat().st_size
