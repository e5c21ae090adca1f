"""Raw logs (MF4 bus logging, BLF, poll logs) round trips, and the acquisition under bad input and faults."""

from __future__ import annotations

from pathlib import Path

import can
import cantools
import numpy as np
import pytest
from asammdf import MDF

from benchtwin.chain.acquisition import AcquisitionInput, acquire, detect_lag
from benchtwin.chain.batch import deliver, read_logs, run_batch, write_logs
from benchtwin.chain.buslog import (
    DEFAULT_START,
    read_blf,
    read_mf4,
    read_poll_log,
    write_blf,
    write_mf4,
    write_poll_csv,
    write_poll_log,
)
from benchtwin.cli import main
from benchtwin.config import load_setup
from benchtwin.config.setup import ChannelErrors
from benchtwin.errors import DataError
from benchtwin.recording import Flag, Recording
from benchtwin.sensors import encode
from benchtwin.sensors.synthetic import synthetic_trace
from benchtwin.trace import Trace
from benchtwin.wire.frames import FRAME_DTYPE, POLL_TIMEOUT, FrameTable, PollLog, TransportEvent

IDEAL = load_setup("ideal")
PAPER = load_setup("paper")


@pytest.fixture(scope="module")
def trace() -> Trace:
    return synthetic_trace(40.0, 100.0, seed=5)


@pytest.fixture(scope="module")
def received(trace: Trace) -> AcquisitionInput:
    r = deliver(encode(trace, IDEAL, 3), IDEAL, seed=3)
    r.segments = list(trace.segments)
    return r


@pytest.fixture(scope="module")
def logdir(received: AcquisitionInput, tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("logs")
    write_logs(received, IDEAL, d, blf=True, poll_csv=True)
    return d


# ---------------------------------------------------------------- files


def test_mf4_bus_log_read_by_python_can(received: AcquisitionInput, logdir: Path) -> None:
    ref = received.can["vehicle"].frames
    msgs = list(can.MF4Reader(str(logdir / "vehicle.mf4")))
    assert len(msgs) == len(ref)
    start = DEFAULT_START.timestamp()
    for k in (0, 1, len(ref) // 2, len(ref) - 1):
        m = msgs[k]
        assert m.arbitration_id == ref["arbitration_id"][k]
        assert bytes(m.data) == ref["data"][k, :ref["dlc"][k]].tobytes()
        assert m.timestamp - start == pytest.approx(ref["timestamp"][k], abs=1e-6)
    assert np.array_equal(read_mf4(logdir / "vehicle.mf4").frames, ref)


def test_mf4_bus_log_decoded_by_asammdf_with_our_dbc(received: AcquisitionInput, logdir: Path) -> None:
    rec = acquire(received, IDEAL)
    with MDF(logdir / "dyno.mf4") as mdf:
        ext = mdf.extract_bus_logging({"CAN": [(str(logdir / "dyno.dbc"), 0)]})
        names = [n for n in ext.channels_db if n.endswith("RollerSpeed")]
        assert names
        sig = ext.get(names[0])
    np.testing.assert_allclose(sig.samples, rec["dyno_speed_kmh"].values, atol=1e-9)
    np.testing.assert_allclose(sig.timestamps, rec["dyno_speed_kmh"].timestamps, atol=1e-6)


def test_blf_round_trip_with_python_can(received: AcquisitionInput, logdir: Path) -> None:
    ref = received.can["instrument"].frames
    back = read_blf(logdir / "instrument.blf")
    assert len(back) == len(ref)
    np.testing.assert_array_equal(back.frames["arbitration_id"], ref["arbitration_id"])
    np.testing.assert_array_equal(back.frames["data"], ref["data"])
    np.testing.assert_allclose(back.frames["timestamp"], ref["timestamp"], atol=2e-5)
    first = next(iter(can.BLFReader(str(logdir / "instrument.blf"))))
    assert first.arbitration_id == ref["arbitration_id"][0]


def test_cantools_decodes_logged_frames(received: AcquisitionInput, logdir: Path) -> None:
    db = cantools.database.load_file(str(logdir / "vehicle.dbc"))
    rec = acquire(received, IDEAL)
    fr = received.can["vehicle"].frames
    sel = np.flatnonzero(fr["arbitration_id"] == 0x0A0)[:20]
    speeds = [db.decode_message(0x0A0, fr["data"][k, :8].tobytes())["EngSpeed"] for k in sel]
    np.testing.assert_allclose(speeds, rec["engine_speed_rpm"].values[:20], atol=1e-9)
    ivt = cantools.database.load_file(str(logdir / "instrument.dbc"))
    k = int(np.flatnonzero(fr["arbitration_id"] == 0x521)[0]) if (fr["arbitration_id"] == 0x521).any() else None
    inst = received.can["instrument"].frames
    k = int(np.flatnonzero(inst["arbitration_id"] == 0x531)[3])
    dec = ivt.decode_message(0x531, inst["data"][k, :6].tobytes())
    assert dec["IVT_Hpcu_I"] / 1000.0 == pytest.approx(rec["hpcu_current_a"].values[3])
    # the thermo module's TPDOs are in the bus DBC too (derived from the EDS mapping)
    k = int(np.flatnonzero(inst["arbitration_id"] == 0x185)[7])
    dec = ivt.decode_message(0x185, inst["data"][k, :8].tobytes())
    assert dec["Thermo_engine_coolant_in_degc"] == pytest.approx(rec["engine_coolant_in_degc"].values[7])
    k = int(np.flatnonzero(inst["arbitration_id"] == 0x385)[2])
    dec = ivt.decode_message(0x385, inst["data"][k, :6].tobytes())  # inputs 9 and 10 (gearbox oil), cold junction
    assert dec["Thermo_motor_coolant_out_degc"] == pytest.approx(rec["motor_coolant_out_degc"].values[2])
    assert dec["Thermo_gearbox_oil_degc"] == pytest.approx(rec["gearbox_oil_degc"].values[2])
    assert dec["Thermo_Cold_Junction"] == pytest.approx(IDEAL.thermo.cold_junction_degc)


def test_poll_log_files(received: AcquisitionInput, logdir: Path) -> None:
    ref = received.polls["brake_pressure"]
    back = read_poll_log(logdir / "brake_pressure.polls.npz")
    np.testing.assert_array_equal(back.values, ref.values)
    np.testing.assert_array_equal(back.status, ref.status)
    assert (logdir / "brake_pressure.polls.csv").read_text().splitlines()[0].startswith("time_s,unit_id")
    with pytest.raises(DataError):
        read_poll_log(logdir / "vehicle.dbc")


def test_logs_to_recording_equals_in_memory(received: AcquisitionInput, logdir: Path, tmp_path: Path) -> None:
    again, setup = read_logs(logdir)
    assert setup == IDEAL
    a, b = acquire(received, IDEAL), acquire(again, setup)
    assert set(a.channels) == set(b.channels)
    for name in a.channels:
        np.testing.assert_array_equal(a[name].values, b[name].values)
    out = tmp_path / "rec.mf4"
    assert main(["acquire", str(logdir), "--out", str(out)]) == 0
    loaded = Recording.load(out)
    assert loaded["shaft_torque_nm"].unit == "Nm" and len(loaded.segments) == 2
    np.testing.assert_allclose(loaded["battery_current_a"].values, a["battery_current_a"].values)


def test_cli_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["acquire", str(tmp_path / "missing"), "--out", str(tmp_path / "r.mf4")]) == 2
    (tmp_path / "empty").mkdir()
    assert main(["acquire", str(tmp_path / "empty"), "--setup", "ideal", "--out", str(tmp_path / "r.mf4")]) == 2
    err = capsys.readouterr().err
    assert err.count("benchtwin: error:") == 2 and "Traceback" not in err


# ---------------------------------------------------------------- bad input


def _frame(t: float, cid: int, data: bytes, dlc: int | None = None) -> np.ndarray:
    f = np.zeros(1, dtype=FRAME_DTYPE)
    f["timestamp"], f["arbitration_id"] = t, cid
    f["dlc"] = len(data) if dlc is None else dlc
    f["data"][0, :len(data)] = np.frombuffer(data, np.uint8)
    return f


def test_bad_frames_are_flagged_and_nothing_good_is_lost(received: AcquisitionInput) -> None:
    clean = acquire(received, IDEAL)
    inst = received.can["instrument"].frames
    veh = received.can["vehicle"].frames
    bad_inst = [
        _frame(10.0005, 0x521, bytes.fromhex("0000ffffcfc7"), dlc=4),  # wrong DLC
        _frame(12.0005, 0x521, bytes.fromhex("0700ffffcfc7")),  # bad mux byte on the current result
        _frame(13.0, 0x7AB, b"\x01\x02"),  # unknown id
        _frame(13.5, 0x7AB, b"\x01\x02"),
        _frame(14.0, 0x511, bytes([0xFF, 0x99, 0, 0, 0, 0, 0, 0])),  # unknown-command answer
    ]
    bad_veh = [_frame(20.0001, 0x0B0, b"\x00\x00", dlc=2)]
    polls = received.polls["brake_pressure"]
    status = polls.status.copy()
    status[100:110] = POLL_TIMEOUT
    status[200] = 4
    status[201] = 6
    values = polls.values.copy()
    values[status != 0] = 0
    dirty = AcquisitionInput(
        can={"instrument": FrameTable.concat("instrument", [inst, *bad_inst]),
             "vehicle": FrameTable.concat("vehicle", [veh, *bad_veh]),
             "dyno": received.can["dyno"]},
        polls={"brake_pressure": PollLog(polls.device, polls.unit_id, 4, 0, polls.times, values, status)},
        segments=received.segments)
    rec = acquire(dirty, IDEAL)
    m = rec.meta
    assert m["unknown_ids"]["instrument"] == {"0x7AB": 2}
    assert m["protocol_errors"]["instrument:0x521"] == 2
    assert m["protocol_errors"]["vehicle:0xB0"] == 1
    assert "instrument:0x511 unknown-command answers" in m["protocol_errors"]
    assert m["modbus"]["brake_pressure"] == {"polls": len(polls), "timeouts": 10, "exceptions": {4: 1, 6: 1}}
    # every good sample is still there, unchanged
    for name, ch in clean.channels.items():
        got = rec[name]
        assert len(got) == len(ch), name
        ok = (got.flags & (Flag.TIMEOUT | Flag.PROTOCOL_ERROR)) == 0
        if ch.source == "brake_pressure":  # failed polls hold the last good value
            np.testing.assert_array_equal(got.values[ok], ch.values[ok], err_msg=name)
        else:
            np.testing.assert_array_equal(got.values, ch.values, err_msg=name)
    cur = rec["battery_current_a"]
    k10 = np.searchsorted(cur.timestamps, 10.0005)
    k12 = np.searchsorted(cur.timestamps, 12.0005)
    assert cur.flags[k10] & Flag.PROTOCOL_ERROR and cur.flags[k12] & Flag.PROTOCOL_ERROR
    assert np.count_nonzero(cur.flags) == 2
    assert rec["em_torque_nm"].flags[np.searchsorted(rec["em_torque_nm"].timestamps, 20.0001)] & Flag.PROTOCOL_ERROR
    p = rec["brake_pressure_fl_bar"]
    assert np.all(p.flags[100:110] & Flag.TIMEOUT) and p.flags[200] & Flag.PROTOCOL_ERROR
    assert np.all(p.values[100:110] == p.values[99])  # held from the last good poll
    assert np.all(np.diff(p.timestamps) >= 0)


def test_transport_drop_mid_run(received: AcquisitionInput) -> None:
    inst = received.can["instrument"].frames
    keep = (inst["timestamp"] < 15.0) | (inst["timestamp"] >= 17.0)
    polls = received.polls["brake_pressure"]
    pk = (polls.times < 15.0) | (polls.times >= 17.0)
    data = AcquisitionInput(
        can={"instrument": FrameTable("instrument", inst[keep]), "vehicle": received.can["vehicle"]},
        polls={"brake_pressure": PollLog(polls.device, 1, 4, 0, polls.times[pk], polls.values[pk], polls.status[pk])},
        events=[TransportEvent(15.0, "instrument", "drop", 17.0, "socket closed"),
                TransportEvent(15.0, "brake_pressure", "drop", 17.0, "connection reset")])
    rec = acquire(data, IDEAL)
    cur = rec["battery_current_a"]
    assert len(cur) == np.count_nonzero(inst[keep]["arbitration_id"] == 0x521)
    k = np.searchsorted(cur.timestamps, 17.0)
    assert cur.flags[k] & Flag.TRANSPORT_DROP and cur.flags[k] & Flag.LOST_FRAME
    assert np.count_nonzero(cur.flags & Flag.LOST_FRAME) == 1  # the counter gap and the drop are one event
    tq = rec["shaft_torque_nm"]
    assert tq.flags[np.searchsorted(tq.timestamps, 17.0)] & Flag.TRANSPORT_DROP
    th = rec["engine_coolant_in_degc"]
    assert th.flags[np.searchsorted(th.timestamps, 17.0)] & Flag.LOST_FRAME
    assert rec["brake_pressure_fl_bar"].flags[np.searchsorted(rec["brake_pressure_fl_bar"].timestamps, 17.0)] \
        & Flag.TRANSPORT_DROP
    assert rec.meta["transport_events"][0]["detail"] == "socket closed"
    assert "dyno_speed_kmh" not in rec  # a bus that delivered nothing gives no channel, and no crash


def test_garbage_bus_does_not_stop_the_others(received: AcquisitionInput) -> None:
    junk = np.zeros(50, dtype=FRAME_DTYPE)
    junk["timestamp"] = np.arange(50) * 0.01
    junk["arbitration_id"] = 0x1FFFFFFF
    junk["is_extended"] = True
    data = AcquisitionInput(can={"vehicle": received.can["vehicle"], "instrument": FrameTable("instrument", junk)})
    rec = acquire(data, IDEAL)
    assert rec.meta["unknown_ids"]["instrument"] == {"0x1FFFFFFF": 50}
    assert len(rec["vehicle_speed_kmh"]) > 0


# ---------------------------------------------------------------- faults of the paper setup


def test_paper_setup_faults_are_flagged_and_clocks_detected() -> None:
    trace = synthetic_trace(120.0, 100.0, seed=8, excursion=True)
    rec = run_batch(trace, PAPER, seed=4)
    m = rec.meta
    assert m["clock_offsets_s"]["vehicle_can->dyno"] == pytest.approx(0.120, abs=0.003)
    tq = rec["shaft_torque_nm"]
    sat = (tq.flags & Flag.SATURATED) != 0
    assert sat.any()
    truth = np.interp(tq.timestamps[sat], trace.time_s, trace["shaft_torque_nm"])
    assert np.all(np.abs(truth) > 0.95 * 4374)
    cur = rec["battery_current_a"]
    assert np.any(cur.flags & Flag.OUT_OF_RANGE)
    assert np.any(cur.flags & Flag.LOST_FRAME)
    assert m["modbus"]["brake_pressure"]["polls"] > 11000
    # noise of the paper setup is visible but small
    err = cur.values[cur.good] - np.interp(cur.timestamps[cur.good], trace.time_s, trace["battery_current_a"])
    assert 0.0 < np.std(err) < 2.0


def test_paper_reorder_and_duplicate_flags() -> None:
    setup = load_setup("ideal").model_copy(deep=True)
    setup.ivt["battery"].link.duplicate_prob = 0.01
    setup.ivt["battery"].link.reorder_prob = 0.01
    trace = synthetic_trace(60.0, 100.0, seed=2)
    rec = run_batch(trace, setup, seed=9)
    cur = rec["battery_current_a"]
    assert np.any(cur.flags & Flag.DUPLICATE) and np.any(cur.flags & Flag.OUT_OF_ORDER)
    assert not np.any(cur.flags & Flag.LOST_FRAME)  # reorders and duplicates are not losses


def test_detect_lag_recovers_a_known_shift() -> None:
    t = np.arange(0, 200, 0.01)
    x = np.sin(0.3 * t) + 0.5 * np.sin(1.7 * t + 1) + 0.2 * np.sin(5.1 * t)
    lag = detect_lag(t, x, t + 0.237, x)
    assert lag == pytest.approx(0.237, abs=0.002)
    assert detect_lag(t, x, t, np.random.default_rng(0).normal(size=t.size)) is None


def test_slip_aware_lag_removes_the_tyre_slip_from_the_clock_offset() -> None:
    """A wheel speed that slips in proportion to the force (s = F / C_k) against the roller speed 0.237 s later
    on the dyno's clock: the plain cross-correlation reads the slip as a time shift; with the slip in the model
    the shift comes back within the 2 ms the plain one gives without slip (test above)."""
    from benchtwin.chain.alignment import slip_aware_lag

    t = np.arange(0, 600, 0.01)
    v = 15.0 + 8.0 * np.sin(0.05 * t) + 4.0 * np.sin(0.21 * t + 1.0) + 1.5 * np.sin(0.8 * t)  # m/s
    a = 8.0 * 0.05 * np.cos(0.05 * t) + 4.0 * 0.21 * np.cos(0.21 * t + 1.0) + 1.5 * 0.8 * np.cos(0.8 * t)
    force = 2162.0 * a + 170.0 + 0.5 * v**2  # rear axle force, N
    wheel = v * (1.0 + force / (18.0 * 2162.0 * 9.81 * 0.5))
    tb = t + 0.237
    plain = detect_lag(t, wheel, tb, v)
    assert abs(plain - 0.237) > 0.03  # ~ m v / C_k: the slip reads as tens of ms
    lag = slip_aware_lag(t, wheel, tb, v, [(tb, np.zeros_like(v)), (tb, force)], plain)
    assert lag == pytest.approx(0.237, abs=0.002)
    # no slip: the same lag as the plain cross-correlation
    lag0 = detect_lag(t, v, tb, v)
    assert slip_aware_lag(t, v, tb, v, [(tb, force)], lag0) == pytest.approx(0.237, abs=0.002)


def test_write_and_read_single_logs(tmp_path: Path) -> None:
    f = np.zeros(3, dtype=FRAME_DTYPE)
    f["timestamp"] = [0.0, 0.001, 0.002]
    f["arbitration_id"] = [0x100, 0x18FF0001, 0x7FF]
    f["is_extended"] = [False, True, False]
    f["dlc"] = [8, 3, 0]
    f["data"][0] = np.arange(8)
    f["data"][1, :3] = [9, 9, 9]
    t = FrameTable("x", f)
    assert np.array_equal(read_mf4(write_mf4(t, tmp_path / "x.mf4")).frames, f)
    assert np.array_equal(read_blf(write_blf(t, tmp_path / "x.blf")).frames["data"], f["data"])
    log = PollLog("p", 1, 4, 0, [0.0], np.ones((1, 14)), [0])
    write_poll_csv(log, tmp_path / "p.csv")
    assert read_poll_log(write_poll_log(log, tmp_path / "p.npz")).values.sum() == 14
    with pytest.raises(DataError):
        read_mf4(tmp_path / "nope.mf4")


def test_pdo_gaps_and_telemetry_drops_are_lost_frames() -> None:
    setup = load_setup("ideal").model_copy(deep=True)
    setup.thermo.link.drop_prob = 0.05
    setup.telemetry.link.drop_prob = 0.01
    trace = synthetic_trace(30.0, 100.0, seed=4)
    rec = run_batch(trace, setup, seed=2)
    th = rec["engine_coolant_in_degc"]
    gaps = np.diff(th.timestamps) > 0.15
    assert gaps.any()
    np.testing.assert_array_equal((th.flags[1:] & Flag.LOST_FRAME) != 0, gaps)
    tq = rec["shaft_torque_nm"]
    assert np.count_nonzero(tq.flags & Flag.LOST_FRAME) == pytest.approx(0.01 * 30 * 500, rel=0.4)


def test_triggered_ivt_is_decoded_with_its_command_traffic() -> None:
    setup = load_setup("ideal").model_copy(deep=True)
    setup.ivt["hpcu"].mode = "triggered"
    setup.ivt["hpcu"].trigger_period_ms = 100
    trace = synthetic_trace(20.0, 100.0, seed=6)
    rec = run_batch(trace, setup, seed=1)
    cur = rec["hpcu_current_a"]
    assert len(cur) == pytest.approx(20.0 / 0.1, abs=2)
    assert rec.meta["ivt_commands"]["ivt_hpcu"] == len(cur)
    assert rec.meta["ivt_answers"]["ivt_hpcu"] == len(cur)
    truth = np.interp(cur.timestamps, trace.time_s, trace["hpcu_hv_current_a"])
    assert np.abs(cur.values - truth).max() <= 1000 / 2**16 + 0.0005 + 1e-9
    assert not np.any(cur.flags)


def test_pressure_module_clock_before_zero_and_drifting() -> None:
    setup = load_setup("ideal").model_copy(deep=True)
    setup.pressure.link.clock_offset_s = -0.5
    setup.pressure.link.clock_drift_ppm = 200.0
    trace = synthetic_trace(20.0, 100.0, seed=3)
    rec = run_batch(trace, setup, seed=1)
    p = rec["brake_pressure_fl_bar"]
    assert p.timestamps[0] < 0 < p.timestamps[-1] < 20.0
    assert np.all(np.diff(p.timestamps) > 0)
    # the module stamps its own clock: map back to plant time to compare with the truth
    t_plant = (p.timestamps + 0.5) / (1 + 200e-6)
    truth = np.interp(t_plant, trace.time_s, trace["brake_pressure_fl_pa"]) / 1e5
    assert np.abs(p.values - truth).max() < 0.01
    assert rec.meta["clock_offsets_s"]["pressure->acquisition"] == pytest.approx(0.5, abs=0.01)


def test_ivt_over_current_detection_is_counted_not_flagged() -> None:
    setup = load_setup("ideal").model_copy(deep=True)
    setup.ivt["battery"].ocs_threshold_a = 150.0
    trace = synthetic_trace(20.0, 100.0, seed=1)
    rec = run_batch(trace, setup, seed=1)
    cur = rec["battery_current_a"]
    expected = int(np.count_nonzero(np.abs(cur.values) > 150.0 + 0.05))
    assert expected > 0
    assert rec.meta["ivt_ocs_frames"]["ivt_battery"] >= expected
    assert not np.any(cur.flags)


def test_clock_drift_between_sources_is_estimated() -> None:
    setup = load_setup("ideal").model_copy(deep=True, update={"ivt": {}, "telemetry": None, "thermo": None,
                                                               "pressure": None})
    setup.dyno.link.clock_drift_ppm = 100.0
    setup.dyno.link.clock_offset_s = 0.05
    trace = synthetic_trace(4000.0, 20.0, seed=9)
    rec = run_batch(trace, setup, seed=3)
    assert rec.meta["clock_drift_ppm"]["vehicle_can->dyno"] == pytest.approx(100.0, abs=10.0)
    assert rec.meta["clock_offsets_s"]["vehicle_can->dyno"] == pytest.approx(0.05 + 100e-6 * 2000, abs=0.02)


def test_cli_acquire_from_a_saved_trace(tmp_path: Path) -> None:
    trace = synthetic_trace(10.0, 100.0, seed=2)
    trace.save(tmp_path / "trace")
    out = tmp_path / "rec.mf4"
    rc = main(["acquire", "--trace", str(tmp_path / "trace"), "--setup", "paper", "--logs", str(tmp_path / "logs"),
               "--blf", "--out", str(out)])
    assert rc == 0
    names = {p.name for p in (tmp_path / "logs").iterdir()}
    assert {"instrument.mf4", "vehicle.mf4", "dyno.mf4", "instrument.blf", "brake_pressure.polls.npz",
            "instrument.dbc", "thermo_module.eds", "setup.json", "segments.json"} <= names
    rec = Recording.load(out)
    assert rec["vehicle_speed_kmh"].unit == "km/h" and len(rec.segments) == 2
    with pytest.raises(SystemExit):
        main(["acquire", "--trace", str(tmp_path / "trace")])  # --out is required: argparse usage error


def test_read_mf4_written_by_python_can(tmp_path: Path) -> None:
    path = tmp_path / "pc.mf4"
    writer = can.MF4Writer(str(path))
    t0 = DEFAULT_START.timestamp() + 100.0
    for k in range(5):
        writer.on_message_received(can.Message(timestamp=t0 + 0.01 * k, arbitration_id=0x521,
                                               data=bytes([0, k, 0, 0, 1, 2]), is_extended_id=False))
    writer.on_message_received(can.Message(timestamp=t0 + 0.1, arbitration_id=0x18FF0001, data=b"\x01\x02\x03",
                                           is_extended_id=True))
    writer.stop()
    table = read_mf4(path)
    np.testing.assert_allclose(table.frames["timestamp"], [100.0, 100.01, 100.02, 100.03, 100.04, 100.1], atol=1e-5)
    assert table.frames["is_extended"].tolist() == [False] * 5 + [True]
    assert table.frames["arbitration_id"][-1] == 0x18FF0001
    np.testing.assert_array_equal(table.frames["data"][:5, 1], np.arange(5))
    assert table.frames["dlc"].tolist() == [6] * 5 + [3]


def test_blf_only_logs_decode_like_mf4(received: AcquisitionInput, logdir: Path, tmp_path: Path) -> None:
    import shutil

    for p in logdir.iterdir():
        if p.suffix != ".mf4":
            shutil.copy(p, tmp_path / p.name)
    from_blf, _ = read_logs(tmp_path)
    a, b = acquire(received, IDEAL), acquire(from_blf, IDEAL)
    for name in ("battery_current_a", "vehicle_speed_kmh", "engine_coolant_in_degc", "shaft_torque_nm"):
        np.testing.assert_array_equal(a[name].values, b[name].values)
        np.testing.assert_allclose(a[name].timestamps, b[name].timestamps, atol=2e-5)


def test_poll_timeouts_block_the_poller() -> None:
    from benchtwin.sensors.imperfections import device_rng
    from benchtwin.sensors.pressure import encode_pressure, poll_snapshots

    setup = load_setup("ideal").model_copy(deep=True)
    cfg = setup.pressure
    cfg.timeout_prob = 0.01
    trace = synthetic_trace(60.0, 100.0, seed=1)
    snap = encode_pressure(trace, cfg, device_rng(0, "p"))
    log = poll_snapshots(snap, cfg, device_rng(0, "poll"), 0.0, 60.0)
    to = np.flatnonzero(log.status == POLL_TIMEOUT)
    assert to.size > 20
    # the answer after a timeout comes no earlier than the timeout, and the skipped slots are gone
    nxt = to[to + 1 < len(log)] + 1
    assert np.all(log.times[nxt] - log.times[nxt - 1] > 0.0)
    slots = np.round((log.times[nxt] - cfg.poll_latency_s) * cfg.poll_hz)
    starts = np.round((log.times[to[to + 1 < len(log)]] - cfg.poll_timeout_s) * cfg.poll_hz)
    assert np.all(slots - starts >= cfg.poll_timeout_s * cfg.poll_hz)
    assert len(log) < 60.0 * cfg.poll_hz - to.size * (cfg.poll_timeout_s * cfg.poll_hz - 1) + 5


def test_configured_output_saturation_is_applied_and_flagged() -> None:
    setup = load_setup("ideal").model_copy(deep=True)
    setup.ivt["battery"].current_errors.saturation_max = 150.0
    setup.vehicle_can.errors["engine_torque_nm"] = ChannelErrors(saturation_min=-50.0, saturation_max=300.0)
    trace = synthetic_trace(30.0, 100.0, seed=4)
    rec = run_batch(trace, setup, seed=1)
    cur = rec["battery_current_a"]
    truth = np.interp(cur.timestamps, trace.time_s, trace["battery_current_a"])
    sat = (cur.flags & Flag.SATURATED) != 0
    assert cur.values.max() <= 150.0 + 0.02 and np.all(sat[truth > 150.2]) and not np.any(sat[truth < 149.0])
    tq = rec["engine_torque_nm"]
    t_truth = np.interp(tq.timestamps, trace.time_s, trace["engine_torque_nm"])
    tsat = (tq.flags & Flag.SATURATED) != 0
    assert np.all(tsat[(t_truth > 300.5) | (t_truth < -50.5)]) and not np.any(tsat[(t_truth < 299) & (t_truth > -49)])
