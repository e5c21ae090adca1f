"""Recording and Trace files: compressed round trips bit for bit, channels read on demand equal to those read at
once, and a damaged compressed file is one clear error."""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np
import pytest

from benchtwin.errors import DataError, MissingChannelError
from benchtwin.recording import Channel, Flag, LazyChannel, Recording
from benchtwin.segments import Segment
from benchtwin.trace import Trace


@pytest.fixture(scope="module")
def rec() -> Recording:
    rng = np.random.default_rng(3)
    out = Recording(segments=[Segment(0.0, 30.0, "ramp_up", "s1")], meta={"seed": 3},
                    start_time=datetime(2026, 1, 1, tzinfo=UTC))
    t100 = np.arange(3000) / 100.0
    out.add(Channel("battery_current_a", "A", t100, np.round(rng.normal(0, 50, t100.size), 2),
                    rng.choice(np.array([0, int(Flag.LOST_FRAME), int(Flag.SATURATED)], np.uint16), t100.size),
                    "ivt_battery"))
    out.add(Channel("battery_voltage_v", "V", t100, 350 + rng.normal(0, 1, t100.size), None, "ivt_battery"))
    t_jitter = np.sort(rng.uniform(0, 30, 700))  # another time base of the same source
    out.add(Channel("gear_actual", "", t_jitter, rng.integers(0, 10, t_jitter.size).astype(float), None, "vehicle_can",
                    {0: "N", 1: "1st", 2: "2nd"}))
    out.add(Channel("pedal_pct", "%", t_jitter[:0], np.zeros(0), None, "vehicle_can"))  # an empty channel
    return out


def _same(a: Channel, b: Channel) -> bool:
    return (a.name, a.unit, a.source, a.value_texts) == (b.name, b.unit, b.source, b.value_texts) and all(
        x.dtype == y.dtype and x.tobytes() == y.tobytes()
        for x, y in ((a.timestamps, b.timestamps), (a.values, b.values), (a.flags, b.flags)))


@pytest.mark.parametrize("compression", [0, 1, 2])
def test_compressed_recording_round_trip_is_bit_for_bit(rec: Recording, compression: int, tmp_path) -> None:
    back = Recording.load(rec.save(tmp_path / "r.mf4", compression=compression))
    assert list(back.channels) == list(rec.channels)
    assert all(_same(rec[n], back[n]) for n in rec)
    assert (back.segments, back.meta, back.start_time) == (rec.segments, rec.meta, rec.start_time)


def test_unknown_compression_is_refused(rec: Recording, tmp_path) -> None:
    with pytest.raises(DataError, match="compression must be one of"):
        rec.save(tmp_path / "r.mf4", compression=9)


def test_lazy_recording_reads_each_channel_when_used_and_equals_the_eager_one(rec: Recording, tmp_path) -> None:
    path = rec.save(tmp_path / "r.mf4")
    with Recording.open(path) as lazy:
        assert lazy.loaded() == set()
        assert [len(lazy[n]) for n in lazy] == [len(rec[n]) for n in rec]  # counts known without reading
        assert lazy["gear_actual"].source == "vehicle_can" and lazy.loaded() == set()
        assert _same(lazy["battery_current_a"], rec["battery_current_a"])
        assert lazy.loaded() == {"battery_current_a"}
        # channels of one time base share one array while loaded
        assert lazy["battery_voltage_v"].timestamps is lazy["battery_current_a"].timestamps
        lazy.drop()
        assert lazy.loaded() == set()
        assert all(_same(lazy[n], rec[n]) for n in rec)  # read again after the drop
        # a channel given new values is held in memory: dropping never loses it
        lazy["battery_voltage_v"].values = np.zeros(len(rec["battery_voltage_v"]))
        lazy.drop()
        assert lazy.loaded() == {"battery_voltage_v"} and not lazy["battery_voltage_v"].values.any()
    only = Recording.load(path, channels=["gear_actual"])
    assert list(only.channels) == ["gear_actual"] and not isinstance(only["gear_actual"], LazyChannel)
    with pytest.raises(MissingChannelError, match="no channel 'nope'"):
        Recording.open(path, channels=["nope"])


def test_a_damaged_compressed_recording_is_one_clear_error(rec: Recording, tmp_path) -> None:
    path = rec.save(tmp_path / "r.mf4", compression=2)
    raw = bytearray(path.read_bytes())
    cut = tmp_path / "cut.mf4"
    cut.write_bytes(bytes(raw[:len(raw) // 2]))
    with pytest.raises(DataError, match=r"cut\.mf4"):
        Recording.load(cut)
    # the blocks intact but the deflated data garbled: the channel read says which channel and file
    start = raw.index(b"##DZ") + 48
    raw[start:start + 64] = bytes(64)
    bad = tmp_path / "bad.mf4"
    bad.write_bytes(bytes(raw))
    with pytest.raises(DataError, match=r"bad\.mf4"):
        Recording.load(bad)
    with Recording.open(bad) as lazy, pytest.raises(DataError, match=r"bad\.mf4: .*unreadable"):
        for n in lazy:
            _ = lazy[n].values


@pytest.mark.parametrize("compression", [None, 1])
def test_compressed_trace_round_trip_is_bit_for_bit(compression: int | None, tmp_path) -> None:
    t = np.arange(2000) * 0.01
    tr = Trace(t, {"vehicle_speed_mps": np.sin(t) * 20, "gear_actual": (t // 3) % 9,
                   "battery_soc_frac": np.linspace(0.9, 0.2, t.size)}, [Segment(0.0, 20.0, "cycle", "a")], {"seed": 1})
    back = Trace.load(tr.save(tmp_path / "tr", compression=compression).parent)
    assert back.time_s.tobytes() == tr.time_s.tobytes()
    assert all(back[k].tobytes() == np.asarray(v, np.float64).tobytes() for k, v in tr.channels.items())
    assert back.segments == tr.segments and back.meta == tr.meta


def test_streams_of_one_device_with_other_lost_frames_keep_their_own_times(tmp_path) -> None:
    """Two channels of one source, as long and starting alike, that lost different frames (one IVT-S result
    each): each keeps its own time base in the file, and the saved channel order is the order read back."""
    full = np.arange(200) / 50.0
    a_t, b_t = np.delete(full, [60]), np.delete(full, [150])  # same length, same first samples, other gaps
    out = Recording()
    out.add(Channel("ivt_battery_u2_v", "V", b_t, np.arange(b_t.size, dtype=float), None, "ivt_battery"))
    out.add(Channel("battery_current_a", "A", a_t, -np.arange(a_t.size, dtype=float), None, "ivt_battery"))
    back = Recording.load(out.save(tmp_path / "r.mf4"))
    assert list(back.channels) == ["ivt_battery_u2_v", "battery_current_a"]
    for name in out.channels:
        assert _same(out[name], back[name]), name


@pytest.mark.parametrize("block", [512, 1000, 1 << 20])
def test_recording_written_block_by_block_reads_back_equal_and_never_whole(rec: Recording, block: int, tmp_path,
                                                                            monkeypatch) -> None:
    """Lazy channels with a block reader (the acquisition's chunk files) are written to recording.mf4 a block at a
    time: never read whole, and the file (compressed as by default) reads back equal with Recording.load and
    asammdf."""
    import asammdf

    import benchtwin.mdf

    monkeypatch.setattr(benchtwin.mdf, "WRITE_BLOCK_SAMPLES", block)
    widest: list[int] = [0]

    def lazy(ch: Channel) -> LazyChannel:
        def whole() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            raise AssertionError(f"{ch.name} read whole")

        def part(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            widest[0] = max(widest[0], b - a)
            return ch.timestamps[a:b].copy(), ch.values[a:b].copy(), ch.flags[a:b].copy()

        return LazyChannel(ch.name, ch.unit, ch.source, len(ch), whole, ch.value_texts, block_loader=part)

    blocked = Recording(segments=rec.segments, meta=rec.meta, start_time=rec.start_time)
    for ch in rec.channels.values():
        blocked.add(lazy(ch))
    path = blocked.save(tmp_path / "r.mf4")
    assert 0 < widest[0] <= block
    assert b"##DZ" in path.read_bytes()  # compressed data blocks (transposed deflate by default)
    back = Recording.load(path)
    assert list(back.channels) == list(rec.channels)
    assert all(_same(rec[n], back[n]) for n in rec)
    with asammdf.MDF(path) as mdf:
        for name, ch in rec.channels.items():
            sig = mdf.get(name, raw=True)
            assert sig.timestamps.tobytes() == ch.timestamps.tobytes()
            assert np.asarray(sig.samples, np.float64).tobytes() == ch.values.tobytes()
            assert np.asarray(mdf.get(f"{name}.flags", raw=True).samples, np.uint16).tobytes() == ch.flags.tobytes()
