"""Bad input on the live chain: the recorder keeps going or ends cleanly, flags it, and loses nothing.

- malformed and unknown frames injected on a served bus (wrong DLC, bad IVT-S mux byte, unknown id);
- garbage sent to the socketcand endpoint;
- Modbus exception responses and unanswered polls;
- the socketcand endpoint closed in the middle of the run.
"""

from __future__ import annotations

import socket
import threading
import time

import can
import numpy as np
import pytest

from benchtwin.chain.acquisition import acquire
from benchtwin.chain.batch import deliver
from benchtwin.chain.live.bench import capture_to_input, session_from_setup
from benchtwin.chain.live.recorder import LiveRecorder, ModbusPollSpec, open_acquisition_bus, read_frame_spool
from benchtwin.config.setup import load_setup
from benchtwin.recording import Flag
from benchtwin.sensors import encode
from benchtwin.sensors.synthetic import synthetic_trace
from benchtwin.wire.canopen_pdo import EDS_PATH
from benchtwin.wire.modbus_map import INPUT_COUNT

pytestmark = pytest.mark.live

SPEEDUP = 4.0


@pytest.fixture(scope="module")
def run_inputs():
    setup = load_setup("ideal")
    return setup, encode(synthetic_trace(3.0), setup, seed=0)


def _recorder(setup, session, tmp_path, *, modbus_first: int = 0, poll_hz: float = 100.0) -> LiveRecorder:
    buses = {b: open_acquisition_bus("socketcand", b, port=session.transport.port) for b in setup.buses}
    p = setup.pressure
    return LiveRecorder(buses, tmp_path / "spool", speedup=SPEEDUP,
                        modbus=[ModbusPollSpec(p.device, port=session.modbus.port, unit_id=p.unit_id,
                                               first_register=modbus_first, count=INPUT_COUNT, poll_hz=poll_hz,
                                               timeout_s=0.2)],
                        canopen={"thermo": (setup.thermo.node_id, EDS_PATH, setup.thermo.bus)}).start()


def test_malformed_frames_and_garbage_are_flagged_and_the_rest_is_kept(run_inputs, tmp_path):
    setup, outputs = run_inputs
    with session_from_setup(outputs, setup, transport="socketcand", speedup=SPEEDUP, modbus_port=0) as s:
        rec = _recorder(setup, s, tmp_path)
        injector = can.Bus(interface="socketcand", host="127.0.0.1", port=s.transport.port, channel="instrument")
        raw = socket.create_connection(("127.0.0.1", s.transport.port))
        assert raw.recv(64) == b"< hi >"
        s.wait_for_clients(len(setup.buses) + 1, 5.0)
        bad = [
            can.Message(arbitration_id=0x521, is_extended_id=False, data=b"\x00\x01\x02"),  # wrong DLC
            can.Message(arbitration_id=0x521, is_extended_id=False, data=b"\x05\x01\x00\x00\x00\x10"),  # bad mux
            can.Message(arbitration_id=0x6AB, is_extended_id=False, data=b"\x01\x02"),  # unknown id
        ]

        def inject():
            time.sleep(0.2)
            for m in bad:
                injector.send(m)
            # garbage on the endpoint: not a command, a bad send, an unknown command, an unopened bus
            raw.sendall(b"hello\n< send 12G 2 zz >< send 123 9 1 2 >< bogus >< open nosuchbus >")

        th = threading.Thread(target=inject)
        th.start()
        report = s.run()
        th.join()
        garbage_answer = raw.recv(256)
        closed = raw.recv(256) == b""  # the endpoint closed the client that sent a malformed command
        raw.close()
        injector.shutdown()
        cap = rec.stop(rec.wait(idle_s=0.5, duration_s=10.0))
        endpoint = s.transport.stats()
    assert report.completed and report.lost == 0
    assert endpoint["malformed_commands"] >= 2 and b"< error" in garbage_answer and closed
    # the injected frames were recorded with the rest ...
    n_served = len(outputs.can["instrument"]) + cap.stats["pdos"]["thermo"]
    # plus the live thermo module's boot-up message and heartbeats (NMT error control)
    n_nmt = int(np.count_nonzero(cap.can["instrument"].frames["arbitration_id"] == 0x700 + setup.thermo.node_id))
    assert cap.stats["frames"]["instrument"] == n_served + n_nmt + len(bad)
    live = acquire(capture_to_input(cap), setup)
    batch = acquire(deliver(outputs, setup), setup)
    # ... and are counted as protocol errors / unknown ids, without losing a good sample
    assert live.meta["protocol_errors"].get("instrument:0x521", 0) == 2  # wrong DLC, bad mux byte
    assert live.meta["unknown_ids"].get("instrument", {}).get("0x6AB") == 1
    for name in ("battery_current_a", "shaft_torque_nm", "engine_coolant_in_degc"):
        assert len(live[name]) == len(batch[name]), name  # every good frame became a sample
        # the decoder marks the sample where a malformed frame arrived; nothing else is lost
        assert int(live[name].good.sum()) >= int(batch[name].good.sum()) - len(bad), name
        np.testing.assert_array_equal(live[name].values, batch[name].values)


def test_modbus_exceptions_and_timeouts_are_logged_and_flagged(run_inputs, tmp_path):
    setup, outputs = run_inputs
    s = session_from_setup(outputs, setup, transport="socketcand", speedup=SPEEDUP, modbus_port=0)
    s.modbus_faults[setup.pressure.device] = {"exception_prob": 0.2, "exception_code": 6, "timeout_prob": 0.05,
                                              "no_answer_s": 0.3, "seed": 1}
    with s:
        rec = _recorder(setup, s, tmp_path, poll_hz=50.0)
        s.wait_for_clients(len(setup.buses), 5.0)
        s.run()
        cap = rec.stop(rec.wait(idle_s=0.5, duration_s=10.0))
        faults = s.stats()["modbus_faults"][setup.pressure.device]
    plog = cap.polls[setup.pressure.device]
    st = plog.status
    assert faults["exceptions"] > 0 and faults["no_answer"] > 0
    assert np.count_nonzero(st == 6) == faults["exceptions"]  # every exception answer logged with its code
    assert np.count_nonzero(st == -1) >= 1  # unanswered polls logged as timeouts
    assert not [e for e in cap.events if e.kind == "drop"]  # a timeout is not a transport drop
    assert np.count_nonzero(st == 0) > 0.5 * len(st)
    live = acquire(capture_to_input(cap), setup)
    ch = live["brake_pressure_fl_bar"]
    assert live.meta["modbus"][setup.pressure.device]["exceptions"].get("6", live.meta["modbus"][
        setup.pressure.device]["exceptions"].get(6)) == faults["exceptions"]
    assert np.count_nonzero(ch.flags & int(Flag.PROTOCOL_ERROR | Flag.TIMEOUT)) > 0
    # every answered poll is a good sample, unless the checks that judge the live timing (the module's clock,
    # a value frozen while the server was starved on a loaded machine) flagged it; never an answer lost
    answered, good = np.count_nonzero(st == 0), np.count_nonzero(ch.good)
    timing = np.count_nonzero((ch.flags & int(Flag.CLOCK | Flag.STALE) != 0)
                              & (ch.flags & int(Flag.PROTOCOL_ERROR | Flag.TIMEOUT) == 0))
    assert good <= answered <= good + timing


def test_out_of_map_polls_answer_exception_2(run_inputs, tmp_path):
    setup, outputs = run_inputs
    with session_from_setup(outputs, setup, transport="socketcand", speedup=SPEEDUP, modbus_port=0,
                            end_s=0.5) as s:
        rec = _recorder(setup, s, tmp_path, modbus_first=10)
        s.wait_for_clients(len(setup.buses), 5.0)
        s.run()
        cap = rec.stop(rec.wait(idle_s=0.3, duration_s=5.0))
    st = cap.polls[setup.pressure.device].status
    assert len(st) > 5 and np.all(st == 2)


def test_endpoint_closed_mid_run_loses_nothing_already_recorded(run_inputs, tmp_path):
    setup, outputs = run_inputs
    s = session_from_setup(outputs, setup, transport="socketcand", speedup=SPEEDUP, modbus_port=0).start()
    try:
        rec = _recorder(setup, s, tmp_path)
        s.wait_for_clients(len(setup.buses), 5.0)
        threading.Timer(0.3, s.transport.close).start()  # the endpoint goes away mid-run
        report = s.run()
        reason = rec.wait(idle_s=2.0, duration_s=10.0)
        cap = rec.stop(reason)
    finally:
        s.close()
    assert reason == "dropped"
    assert not report.completed or report.lost > 0  # the server side noticed it too
    drops = {e.source for e in cap.events if e.kind == "drop"}
    assert set(setup.buses) <= drops
    for bus in ("vehicle", "dyno"):
        got = cap.can[bus].frames
        sent = outputs.can[bus].frames
        assert 0 < len(got) < len(sent)
        # a prefix of what was served, byte for byte: nothing received was lost
        assert np.array_equal(got["arbitration_id"], sent["arbitration_id"][:len(got)])
        assert np.array_equal(got["data"], sent["data"][:len(got)])
        # and the spool on disk holds exactly the same
        spooled = read_frame_spool(tmp_path / "spool" / f"{bus}.frames")
        assert np.array_equal(spooled.frames, got)
    live = acquire(capture_to_input(cap), setup)
    assert {e["source"] for e in live.meta["transport_events"] if e["kind"] == "drop"} >= set(setup.buses)
    assert len(live["vehicle_speed_kmh"]) > 0


@pytest.mark.parametrize("garbage", [b"< open \xff\xfe >", b"< \xc3\xa9t\xc3\xa9 >", b"\x00\x01\x02 < send 1 1 \xff >",
                                     b"<" + b"x" * 10_000])
def test_socketcand_endpoint_survives_non_ascii_and_garbage(garbage: bytes) -> None:
    """A client sending bytes outside ASCII gets an error answer or is closed; the endpoint keeps serving others."""
    import socket as _socket

    from benchtwin.chain.transports.socketcand import SocketcandServer

    srv = SocketcandServer(["bus"], arm_delay_s=0.0).start()
    try:
        bad = _socket.create_connection(srv.address, timeout=5)
        assert bad.recv(64) == b"< hi >"
        bad.sendall(garbage)
        for _ in range(3):  # a later client is greeted and can open the bus
            good = _socket.create_connection(srv.address, timeout=5)
            assert good.recv(64) == b"< hi >"
            good.sendall(b"< open bus >")
            assert good.recv(64) == b"< ok >"
            good.close()
        bad.close()
    finally:
        srv.close()
