"""The wire formats: shipped DBCs (cantools), vectorised codec vs cantools, EDS PDO layout, register map."""

from __future__ import annotations

import cantools
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from benchtwin.config import load_setup
from benchtwin.errors import DataError
from benchtwin.sensors import bus_database
from benchtwin.wire.canopen_pdo import EDS_PATH, load_od, pdo_layout
from benchtwin.wire.codec import MessageCodec
from benchtwin.wire.dbc import DBC_DIR, build_ad_module, build_dyno, build_ivt, build_vehicle, load_dbc
from benchtwin.wire.frames import POLL_TIMEOUT, PollLog, ProcessImage
from benchtwin.wire.modbus_map import INPUT_COUNT, counts_to_volts, volts_to_counts

BUILDERS = {"vehicle": build_vehicle, "dyno": build_dyno, "ivt_s": build_ivt, "ad_module": build_ad_module}


@pytest.mark.parametrize("stem", sorted(BUILDERS))
def test_shipped_dbc_matches_definitions(stem: str) -> None:
    shipped = cantools.database.load_file(str(DBC_DIR / f"{stem}.dbc"))
    built = BUILDERS[stem]()
    assert [(m.frame_id, m.name, m.length, m.cycle_time) for m in shipped.messages] == [
        (m.frame_id, m.name, m.length, m.cycle_time) for m in built.messages]
    for ms, mb in zip(shipped.messages, built.messages):
        assert [(s.name, s.start, s.length, s.byte_order, s.is_signed, s.scale, s.offset) for s in ms.signals] == [
            (s.name, s.start, s.length, s.byte_order, s.is_signed, s.scale, s.offset) for s in mb.signals]


def test_vehicle_dbc_cycle_times_realistic() -> None:
    db = load_dbc("vehicle")
    assert all(10 <= m.cycle_time <= 100 for m in db.messages)
    assert "GenMsgCycleTime" in (DBC_DIR / "vehicle.dbc").read_text()


def test_ivt_example_frame_with_cantools() -> None:
    msg = load_dbc("ivt_s").get_message_by_frame_id(0x521)
    data = msg.encode({"IVT_I_MuxID": 0, "IVT_I_Status": 0, "IVT_I_Counter": 5, "IVT_I": -12345})
    assert data.hex() == "0005ffffcfc7"
    assert msg.decode(bytes.fromhex("0005ffffcfc7"))["IVT_I"] == -12345


@pytest.mark.parametrize("stem", sorted(BUILDERS))
def test_vectorised_codec_agrees_with_cantools(stem: str) -> None:
    rng = np.random.default_rng(1)
    for msg in load_dbc(stem).messages:
        codec = MessageCodec(msg)
        n = 200
        raw = {name: rng.integers(s.raw_min, s.raw_max, n, endpoint=True) for name, s in codec.signals.items()}
        data = codec.pack(raw)
        for k in range(0, n, 17):
            ref = msg.encode({name: int(v[k]) for name, v in raw.items()}, scaling=False, strict=False)
            assert data[k, :msg.length].tobytes() == ref, (msg.name, k)
        back = codec.unpack(data)
        for name in raw:
            np.testing.assert_array_equal(back[name], raw[name])
        phys = codec.decode(data)
        k = 3
        ref_phys = msg.decode(data[k, :msg.length].tobytes(), decode_choices=False)
        for name, v in ref_phys.items():
            assert phys[name][k] == pytest.approx(float(v), abs=1e-9)


def test_bus_database_moves_each_shunt() -> None:
    setup = load_setup("paper")
    db = bus_database(setup, "instrument")
    assert db.get_message_by_name("IVT_Battery_Result_I").frame_id == 0x521
    assert db.get_message_by_name("IVT_Hpcu_Result_I").frame_id == 0x531
    assert db.get_message_by_name("IVT_Hpcu_Msg_Command").frame_id == 0x412
    assert db.get_message_by_name("AD_Torque").frame_id == setup.telemetry.can_id
    ids = [m.frame_id for m in db.messages]
    assert len(ids) == len(set(ids))


def test_eds_pdo_layout_from_canopen_od() -> None:
    od = load_od(7)
    assert od[0x1000].default == 0x00040194
    layout = pdo_layout(7)
    assert [t.cob_id for t in layout.tpdos] == [0x187, 0x287, 0x387]
    assert layout.entries[:10] == [(0x9130, k) for k in range(1, 11)]  # the paper's nine and the gearbox oil
    assert layout.entries[10] == (0x2100, 0)
    assert layout.tpdos[2].length == 6
    assert layout.scale((0x9130, 3)) == pytest.approx(0.1)
    values = np.array([[1, -2, 3, -4, 5, -6, 7, -8, 32767, 1100, 250], [-32768, 0, 0, 0, 0, 0, 0, 0, 9, -1, 251]])
    img = ProcessImage("thermo", 7, np.array([0.0, 0.1]), layout.entries, values)
    frames = layout.pack(img)
    assert len(frames) == 6
    back = {}
    for tp in layout.tpdos:
        sel = frames["arbitration_id"] == tp.cob_id
        assert np.all(frames["dlc"][sel] == tp.length)
        back.update(layout.unpack(tp, frames["data"][sel]))
    for k, e in enumerate(layout.entries):
        np.testing.assert_array_equal(back[e], values[:, k])
    assert EDS_PATH.exists()


def test_register_map_adc() -> None:
    counts, high, low = volts_to_counts(np.array([-0.1, 0.0, 5.0, 10.0, 11.0]))
    assert counts.tolist() == [0, 0, 32768, 65535, 65535]
    assert high.tolist() == [False, False, False, True, True]
    assert low.tolist() == [True, False, False, False, False]
    assert counts_to_volts(np.array([65535]))[0] == pytest.approx(10.0)
    assert INPUT_COUNT == 14


def test_poll_log_validation_and_concat() -> None:
    a = PollLog("p", 1, 4, 0, [0.0, 0.02], np.zeros((2, 14)), [0, POLL_TIMEOUT])
    b = PollLog("p", 1, 4, 0, [0.01], np.ones((1, 14)), [6])
    c = PollLog.concat([a, b])
    assert c.times.tolist() == [0.0, 0.01, 0.02]
    assert c.status.tolist() == [0, 6, -1]
    with pytest.raises(DataError):
        PollLog("p", 1, 5, 0, [0.0], np.zeros((1, 2)), [0])
    with pytest.raises(DataError):
        PollLog("p", 1, 4, 0, [0.0, 1.0], np.zeros((1, 2)), [0])


def test_bus_load_matches_frame_table() -> None:
    from benchtwin.chain.acquisition import _bus_load
    from benchtwin.wire.frames import FRAME_DTYPE, FrameTable

    rng = np.random.default_rng(0)
    f = np.zeros(5000, dtype=FRAME_DTYPE)
    f["timestamp"] = np.sort(rng.uniform(0, 2.0, 5000))
    f["dlc"] = rng.integers(0, 9, 5000)
    f["is_extended"] = rng.random(5000) < 0.3
    t = FrameTable("x", f, 500_000)
    assert _bus_load(t) == pytest.approx(t.bus_load(), rel=1e-12)


def test_merge_frames_equals_stable_sort() -> None:
    from benchtwin.wire.frames import FRAME_DTYPE
    from benchtwin.wire.merge import insert_frames, merge_frames

    rng = np.random.default_rng(1)
    parts = []
    for k, period in enumerate((0.02, 0.02, 0.002, 0.1)):
        t = np.round(np.arange(0, 20, period) + rng.uniform(0, period), 3)
        f = np.zeros(t.size, dtype=FRAME_DTYPE)
        f["timestamp"], f["arbitration_id"] = t, k
        parts.append(f)
    parts.append(parts[0][::-1].copy())  # an unsorted part
    allf = np.concatenate(parts)
    ref = allf[np.argsort(allf["timestamp"], kind="stable")]
    got = merge_frames(parts)
    np.testing.assert_array_equal(got["timestamp"], ref["timestamp"])
    assert np.all(np.diff(got["timestamp"]) >= 0) and len(got) == len(ref)
    ins = insert_frames(parts[2], parts[3])
    ref2 = np.concatenate([parts[2], parts[3]])
    np.testing.assert_array_equal(ins, ref2[np.argsort(ref2["timestamp"], kind="stable")])


@settings(max_examples=120, deadline=None)
@given(st.integers(0, 63), st.integers(1, 64), st.booleans(), st.booleans(), st.data())
def test_codec_any_single_signal_layout_matches_cantools(start: int, length: int, big: bool, signed: bool,
                                                         data: st.DataObject) -> None:
    from cantools.database.can import Message, Signal

    sig = Signal("S", start, length, "big_endian" if big else "little_endian", signed)
    try:
        msg = Message(0x123, "M", 8, [sig], strict=True)
    except Exception:
        assume(False)  # the layout does not fit in 8 bytes
        return
    codec = MessageCodec(msg)
    lay = codec.signals["S"]
    raw = data.draw(st.integers(lay.raw_min, lay.raw_max))
    packed = codec.pack({"S": np.array([raw])})
    assert packed[0].tobytes() == msg.encode({"S": raw}, scaling=False)
    assert int(codec.unpack(packed)["S"][0]) == raw
    assert msg.decode(packed[0].tobytes(), scaling=False)["S"] == raw


@pytest.mark.parametrize(("start", "length", "big"), [(6, 63, True), (0, 63, False), (7, 64, True), (0, 64, False)])
def test_codec_wide_signed_signals_match_cantools(start: int, length: int, big: bool) -> None:
    """Found by the property above: a 63-bit signed signal overflowed the sign extension (1 << 63 is no int64)."""
    from cantools.database.can import Message, Signal

    msg = Message(0x123, "M", 8, [Signal("S", start, length, "big_endian" if big else "little_endian", True)],
                  strict=True)
    codec = MessageCodec(msg)
    lay = codec.signals["S"]
    for raw in (lay.raw_min, -1, 0, 1, lay.raw_max):
        packed = codec.pack({"S": np.array([raw])})
        assert packed[0].tobytes() == msg.encode({"S": raw}, scaling=False)
        assert int(codec.unpack(packed)["S"][0]) == raw == msg.decode(packed[0].tobytes(), scaling=False)["S"]


def test_counter_flags_patterns() -> None:
    from benchtwin.recording import Flag
    from benchtwin.wire.quality import counter_flags as _counter_flags

    def fl(seq: list[int]) -> list[str]:
        f = _counter_flags(np.array(seq), 4)
        return ["L" if v & Flag.LOST_FRAME else "D" if v & Flag.DUPLICATE else "O" if v & Flag.OUT_OF_ORDER else "."
                for v in f]

    assert fl([14, 15, 0, 1, 2]) == list(".....")  # wrap-around
    assert fl([1, 2, 4, 5]) == list("..L.")  # one lost
    assert fl([1, 2, 2, 3]) == list("..D.")  # duplicate
    assert fl([1, 3, 2, 4]) == list(".OO.")  # reorder: not a loss
    assert fl([1, 3, 3, 2, 4]) == list(".ODO.")  # reorder with a duplicate
    assert fl([5, 9, 10]) == list(".L.")  # three lost
