"""Compressed MF4 bus logs: every frame read back by python-can's MF4Reader, asammdf and benchtwin as written (and
the BLF of the same frames by BLFReader), and a cut compressed log keeps exactly its first frames."""

from __future__ import annotations

from itertools import pairwise

import can  # before asammdf (facts: can.MF4Reader may not find asammdf otherwise)
import numpy as np
import pytest
from asammdf import MDF

from benchtwin.chain.buslog import DEFAULT_START, read_bus_log, read_mf4, write_blf, write_mf4
from benchtwin.wire.frames import FRAME_DTYPE, FrameTable

#: enough frames for two MF4 data blocks (asammdf splits the data at 4 MB: 149,796 records of 28 bytes)
N = 180_000


@pytest.fixture(scope="module")
def table() -> FrameTable:
    rng = np.random.default_rng(7)
    f = np.zeros(N, FRAME_DTYPE)
    f["timestamp"] = np.cumsum(rng.uniform(1e-4, 2e-3, N))
    f["arbitration_id"] = rng.choice(np.array([0x0A0, 0x1B2, 0x3F0, 0x18FF50E5]), N)
    f["is_extended"] = f["arbitration_id"] > 0x7FF
    f["dlc"] = rng.integers(0, 9, N)
    f["data"] = rng.integers(0, 256, (N, 8)) * (np.arange(8) < f["dlc"][:, None])
    return FrameTable("vehicle", f, 500_000)


@pytest.mark.parametrize("compression", [1, 2])
def test_a_compressed_bus_log_reads_back_frame_for_frame(table: FrameTable, compression: int, tmp_path) -> None:
    ref = table.frames
    path = write_mf4(table, tmp_path / "vehicle.mf4", compression=compression)
    assert path.stat().st_size < N * 28  # smaller than the records it holds (28 bytes each, uncompressed)
    assert read_mf4(path).frames.tobytes() == ref.tobytes()
    with MDF(path) as mdf:
        sig = mdf.get("CAN_DataFrame", group=0)
        assert sig.timestamps.tobytes() == ref["timestamp"].tobytes()
        np.testing.assert_array_equal(sig.samples["CAN_DataFrame.DataBytes"], ref["data"])
    # python-can, message by message (slow: a shorter log), from the MF4 and from the BLF export of the same frames
    part = FrameTable("vehicle", ref[:20_000], 500_000)
    with can.MF4Reader(str(write_mf4(part, tmp_path / "part.mf4", compression=compression))) as reader:
        _same_messages(list(reader), part.frames)
    with can.BLFReader(str(write_blf(part, tmp_path / "part.blf"))) as reader:
        _same_messages(list(reader), part.frames, atol=2e-5)  # BLF keeps 10 us ticks


def _same_messages(msgs: list[can.Message], ref: np.ndarray, atol: float = 1e-6) -> None:
    assert len(msgs) == len(ref)
    np.testing.assert_array_equal([m.arbitration_id for m in msgs], ref["arbitration_id"])
    np.testing.assert_array_equal([m.is_extended_id for m in msgs], ref["is_extended"])
    assert b"".join(bytes(m.data) for m in msgs) == b"".join(ref["data"][k, :ref["dlc"][k]].tobytes()
                                                            for k in range(len(ref)))
    # the readers add the header start time to each frame's offset: float64 rounding of ~1.8e9 s is ~0.2 us
    np.testing.assert_allclose(np.array([m.timestamp for m in msgs]) - DEFAULT_START.timestamp(), ref["timestamp"],
                               rtol=0, atol=atol)


@pytest.mark.parametrize("compression", [1, 2])
@pytest.mark.parametrize("keep", [0.3, 0.6, 0.97])
def test_a_cut_compressed_bus_log_keeps_its_first_frames(table: FrameTable, compression: int, keep: float,
                                                         tmp_path) -> None:
    path = write_mf4(table, tmp_path / "vehicle.mf4", compression=compression)
    raw = path.read_bytes()
    path.write_bytes(raw[:int(len(raw) * keep)])
    got, damage = read_bus_log(path)
    assert damage is not None and "truncated" in damage
    assert len(got) < N
    assert got.frames.tobytes() == table.frames[:len(got)].tobytes()
    if compression == 1:  # a deflated block is read up to the cut: most frames before it are kept
        assert len(got) > 0.8 * keep * N


def test_a_bus_log_written_chunk_by_chunk_is_the_log_written_at_once(table: FrameTable, tmp_path) -> None:
    from benchtwin.chain.buslog import BusLogWriter

    whole = write_mf4(table, tmp_path / "whole.mf4", block_frames=50_000)
    cuts = [0, 1, 7, 49_999, 50_000, 123_457, N]  # chunk edges inside and on the writer's block edges
    with BusLogWriter(tmp_path / "chunks.mf4", table.bus, table.bitrate, block_frames=50_000) as w:
        for a, b in pairwise(cuts):
            w.append(table.frames[a:b])
        w.append(table.frames[:0])  # an empty chunk changes nothing
    assert w.frames == N
    assert read_mf4(w.path).frames.tobytes() == read_mf4(whole).frames.tobytes() == table.frames.tobytes()
    with can.MF4Reader(str(w.path)) as reader:
        assert sum(1 for _ in reader) == N
    with BusLogWriter(tmp_path / "empty.mf4", table.bus, table.bitrate) as w:
        pass
    assert len(read_mf4(w.path).frames) == 0  # a bus that sent nothing still gets a readable log
