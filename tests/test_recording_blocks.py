"""recording.mf4 written with its data blocks made on threads (benchtwin.mdf.save_channel_groups through
benchtwin.mf4stream): the file asammdf alone writes of the same Recording (benchtwin.mdf.write_channel_groups and
asammdf's save) byte for byte but the history block's time, for each compression, with groups of one and of several
data blocks, two time bases of one source, value texts and an empty channel; and read back channel for channel."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest

from benchtwin.mdf import write_channel_groups
from benchtwin.mf4stream import _blocks, without_history_time
from benchtwin.recording import FLAG_CONVERSION, Channel, Recording
from benchtwin.segments import segments_to_json


def _recording() -> Recording:
    rng = np.random.default_rng(5)
    rec = Recording(meta={"setup": "test"})
    rec.start_time = datetime(2026, 1, 1, tzinfo=UTC)  # else asammdf's: the moment each MDF is made
    # 200 k samples of a group of two channels (28-byte records): two data blocks (asammdf cuts at 149,796)
    t = np.cumsum(rng.uniform(1e-3, 2e-3, 200_000))
    for name in ("shaft_torque_nm", "shaft_speed_rpm"):
        rec.add(Channel(name, "Nm", t, rng.normal(size=len(t)), rng.integers(0, 4, len(t)).astype(np.uint16),
                        source="dyno"))
    # one source, two time bases (a stream that lost other frames): two groups
    u = np.arange(1_000) * 0.01
    rec.add(Channel("gear", "", u, rng.integers(0, 7, len(u)).astype(float), source="vehicle",
                    value_texts={0: "N", 1: "1", 2: "2"}))
    # a later group of two blocks too (18-byte records: asammdf cuts at 233,016): the first group's data list comes
    # after its last block, before this group's blocks
    w = np.arange(250_000) * 0.01 + 1e-4
    rec.add(Channel("vehicle_speed_kph", "km/h", w, rng.normal(size=len(w)), source="vehicle"))
    rec.add(Channel("pack_voltage_v", "V", np.zeros(0), np.zeros(0), source="ivt"))  # nothing received
    return rec


def _asammdf_save(rec: Recording, path: Path, compression: int) -> Path:
    """recording.mf4 as benchtwin wrote it before its data blocks were its own (asammdf alone)."""
    from asammdf import MDF

    mdf = MDF(version="4.10")
    write_channel_groups(mdf, rec.channels.values(), FLAG_CONVERSION, lambda names: None)
    if rec.start_time is not None:
        mdf.header.start_time = rec.start_time
    mdf.header.comment = json.dumps({"benchtwin": {"meta": rec.meta, "segments": json.loads(
        segments_to_json(rec.segments)), "channels": list(rec.channels)}}, default=str)
    out = Path(mdf.save(path, overwrite=True, compression=compression))
    mdf.close()
    return out


@pytest.mark.parametrize("compression", [0, 1, 2])
def test_recording_mf4_is_the_file_asammdf_writes(compression: int, tmp_path: Path) -> None:
    rec = _recording()
    ref = _asammdf_save(rec, tmp_path / "ref.mf4", compression)
    ours = rec.save(tmp_path / "ours.mf4", compression=compression)
    assert ours == tmp_path / "ours.mf4"
    raw = ours.read_bytes()
    assert sum(raw[a:a + 4] == b"##DL" for a, _, _ in _blocks(raw, 64)) == 2  # the groups of two blocks
    assert without_history_time(raw) == without_history_time(ref.read_bytes())
    back = Recording.load(ours)
    assert list(back.channels) == list(rec.channels)
    for name, ch in rec.channels.items():
        got = back[name]
        assert got.timestamps.tobytes() == ch.timestamps.tobytes()
        assert got.values.tobytes() == ch.values.tobytes()
        assert got.flags.tobytes() == ch.flags.tobytes()
        assert got.value_texts == ch.value_texts
