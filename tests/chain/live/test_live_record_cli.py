"""``benchtwin serve`` and ``benchtwin record`` as a user runs them: two processes, one Recording.

The recorder writes the Recording (MF4, reloadable), the raw bus logs (MF4 bus logging) and the poll
logs, and the Recording equals the batch Recording of the same run (same frames on the CAN channels).
Bad arguments end with a one-line error, never a traceback.
"""

from __future__ import annotations

import json
import subprocess
import sys

import can
import numpy as np
import pytest
from live_synth import TIMING_JUDGED, serve_ok_but_for_speed
from vcan_env import quick_campaign_seed, quick_slice_dir, skip_without_vcan

from benchtwin.chain.acquisition import acquire
from benchtwin.chain.batch import deliver
from benchtwin.chain.live.modbus_server import free_port
from benchtwin.chain.transports.socketcan import af_can_unavailable_reason
from benchtwin.cli import main
from benchtwin.config.setup import load_setup
from benchtwin.recording import Flag, Recording
from benchtwin.sensors import encode
from benchtwin.sensors.synthetic import synthetic_trace
from benchtwin.trace import Trace

pytestmark = pytest.mark.live

LOST = np.uint16(Flag.LOST_FRAME)

#: speed-up of the socketcan round trip (see ROUND_TRIPS)
SOCKETCAN_SPEEDUP = 0.5


#: per transport: the setup, what serve plays, the speed-up, record's --idle. socketcand: the ideal bench on
#: a 2 s synthetic run. socketcan: the paper bench on a slice of the quick campaign (vcan_env.QUICK_SLICE,
#: played with `serve --trace`, encoded with the campaign's seed) on vcan0..vcan2, which `make test-vcan`
#: runs in a software-emulated guest: the speed-up is low enough that the receivers keep up (vcan has no
#: flow control; the guest plays even slower than asked, which loses nothing), and only what arrived is
#: judged, never timing
ROUND_TRIPS = {
    "socketcand": {"setup": "ideal", "speedup": 2.0, "idle": 1.0},
    "socketcan": {"setup": "paper", "speedup": SOCKETCAN_SPEEDUP, "idle": 10.0},
}


def _play(transport: str, tmp_path) -> tuple[list[str], Trace, int]:
    """serve's arguments saying what to play, that Trace, and the sensor seed serve encodes it with."""
    if transport == "socketcand":
        return ["--synthetic", "2"], synthetic_trace(2.0), 0
    d = quick_slice_dir(tmp_path)
    seed = quick_campaign_seed()
    return ["--trace", str(d), "--seed", str(seed)], Trace.load(d), seed


def _serve_then_record(tmp_path, case, play, out):
    """socketcand: serve waits for record's three clients (bus, bus, bus), then plays."""
    port, mb_port = free_port(), free_port()
    sp = str(case["speedup"])
    serve = subprocess.Popen(
        [sys.executable, "-m", "benchtwin.cli", "serve", *play, "--setup", case["setup"], "--port", str(port),
         "--modbus-port", str(mb_port), "--speedup", sp, "--wait-clients", "3", "--wait-timeout", "30",
         "--segments-out", str(tmp_path / "segments.json"), "--report", str(tmp_path / "serve_report.json")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        rec = subprocess.run(
            [sys.executable, "-m", "benchtwin.cli", "record", "--setup", case["setup"], "--port", str(port),
             "--modbus-port", str(mb_port), "--speedup", sp, "--idle", str(case["idle"]), "--out", str(out)],
            capture_output=True, text=True, timeout=120)
        s_out, s_err = serve.communicate(timeout=60)
    finally:
        if serve.poll() is None:
            serve.kill()
            serve.wait()
    return rec.returncode, rec.stdout, rec.stderr, serve.returncode, s_out, s_err


def _record_then_serve(tmp_path, case, play, out):
    """socketcan: the kernel interfaces exist before either side, so record listens first, then serve plays."""
    mb_port = free_port()
    sp = str(case["speedup"])
    cmap = "vehicle=vcan0,instrument=vcan1,dyno=vcan2"
    rec = subprocess.Popen(
        [sys.executable, "-m", "benchtwin.cli", "record", "--setup", case["setup"], "--transport", "socketcan",
         "--channel-map", cmap, "--modbus-port", str(mb_port), "--speedup", sp, "--idle", str(case["idle"]),
         "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    serve = None
    try:
        first = rec.stdout.readline()  # "recording ..." once every bus is open (slow to come in the guest)
        assert first.startswith("recording"), first + rec.stderr.read()
        serve = subprocess.run(
            [sys.executable, "-m", "benchtwin.cli", "serve", *play, "--setup", case["setup"], "--transport",
             "socketcan", "--channel-map", cmap, "--modbus-port", str(mb_port), "--speedup", sp,
             "--segments-out", str(tmp_path / "segments.json"), "--report", str(tmp_path / "serve_report.json")],
            capture_output=True, text=True, timeout=1500)
        r_out, r_err = rec.communicate(timeout=300)
    finally:
        if rec.poll() is None:
            rec.kill()
            rec.wait()
    return rec.returncode, first + r_out, r_err, serve.returncode, serve.stdout, serve.stderr


@pytest.mark.parametrize("transport", ["socketcand", pytest.param("socketcan", marks=pytest.mark.vcan)])
def test_serve_and_record_in_two_processes(tmp_path, transport):
    if transport == "socketcan":
        skip_without_vcan()
    case = ROUND_TRIPS[transport]
    play, trace, seed = _play(transport, tmp_path)
    out = tmp_path / "live.mf4"
    run = _serve_then_record if transport == "socketcand" else _record_then_serve
    r_rc, r_out, r_err, s_rc, s_out, s_err = run(tmp_path, case, play, out)
    assert r_rc == 0, r_err
    # serve exits 1 when a frame could not be sent, or (on a loaded machine) when the speed-up was not held
    assert serve_ok_but_for_speed(s_rc, s_err), s_out + s_err
    assert "wrote" in r_out and "Traceback" not in r_err
    pacing = json.loads((tmp_path / "serve_report.json").read_text())["pacing"]
    assert pacing["completed"] and pacing["lost"] == 0, s_out
    assert all(st["sent"] == st["items"] for st in pacing["streams"].values()), s_out
    live = Recording.load(out)
    setup = load_setup(case["setup"])
    batch = acquire(deliver(encode(trace, setup, seed=seed), setup), setup)
    # every frame served was received: the raw bus logs have the batch's frame counts (PDOs included)
    raw = out.with_name("live_raw")
    for bus in setup.buses:
        with can.MF4Reader(str(raw / f"{bus}.mf4")) as reader:
            # the live thermo module's boot-up message and heartbeats (NMT error control) come on top
            n = sum(1 for m in reader if m.arbitration_id != 0x700 + setup.thermo.node_id)
        assert n == int(batch.meta["frames"][bus]), bus
    assert (raw / f"{setup.pressure.device}.polls.npz").exists()
    assert (tmp_path / "live.mf4.spool" / "vehicle.frames").stat().st_size > 0
    # the Recording equals the batch one: same channels; every CAN/PDO channel the same samples, values and
    # flags (the same frames, decoded by the same decoder); the Modbus channels are polled at other instants
    assert set(live.channels) == set(batch.channels)
    compared = 0
    for name, b in batch.channels.items():
        lv = live.channels[name]
        assert lv.unit == b.unit, name
        if b.source == setup.pressure.device:
            continue
        assert len(lv) == len(b), name
        np.testing.assert_array_equal(lv.values, b.values, err_msg=name)
        if TIMING_JUDGED:
            np.testing.assert_array_equal(lv.flags, b.flags, err_msg=name)
        else:
            # a stream without a counter is judged by its arrival spacing (a gap over 1.5 periods sets
            # LOST_FRAME, a repeated payload under a quarter period DUPLICATE); a software-emulated guest that
            # plays slower than the speed-up stretches and bunches the arrivals. Every other flag must be equal,
            # and every lost frame of the batch flagged live too
            spacing = np.uint16(int(Flag.LOST_FRAME) | int(Flag.DUPLICATE))
            np.testing.assert_array_equal(lv.flags & ~spacing, b.flags & ~spacing, err_msg=name)
            assert np.all(lv.flags[(b.flags & LOST) != 0] & LOST), name
        compared += 1
    assert compared > 10
    for name in ("battery_current_a", "shaft_torque_nm", "vehicle_speed_kmh", "engine_coolant_in_degc"):
        assert len(live[name]) > 0, name


@pytest.mark.parametrize("argv", [
    ["record", "--setup", "ideal", "--port", "1", "--out", "x.txt"],
    ["record", "--setup", "ideal", "--port", "1", "--out", "x.mf4", "--buses", "nosuchbus"],
    ["record", "--setup", "ideal", "--port", "1", "--out", "x.mf4", "--speedup", "0"],
    ["serve", "--setup", "ideal", "--synthetic", "1", "--trace", "somewhere"],
    pytest.param(["serve", "--setup", "ideal", "--synthetic", "1", "--transport", "socketcan"],
                 marks=pytest.mark.skipif(af_can_unavailable_reason() is None,
                                          reason="the kernel has SocketCAN here: serve would start")),
])
def test_bad_arguments_end_with_one_line(argv, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("benchtwin: error:")


def test_record_without_a_server_ends_cleanly(capsys, tmp_path):
    assert main(["record", "--setup", "ideal", "--port", str(free_port()), "--connect-timeout", "0.5",
                 "--out", str(tmp_path / "x.mf4")]) == 2
    err = capsys.readouterr().err
    assert "cannot connect" in err and "Traceback" not in err


def test_serve_records_in_process_on_the_embedded_virtual_bus(tmp_path, capsys):
    out = tmp_path / "embedded.mf4"
    rc = main(["serve", "--synthetic", "2", "--setup", "ideal", "--transport", "virtual", "--speedup", "4",
               "--modbus-port", "0", "--record", str(out)])
    cap = capsys.readouterr()
    assert serve_ok_but_for_speed(rc, cap.err), cap.err
    assert "wrote" in cap.out
    live = Recording.load(out)
    setup = load_setup("ideal")
    batch = acquire(deliver(encode(synthetic_trace(2.0), setup, seed=0), setup), setup)
    for name in ("battery_current_a", "vehicle_speed_kmh", "engine_coolant_in_degc", "shaft_torque_nm"):
        np.testing.assert_array_equal(live[name].values, batch[name].values, err_msg=name)


def test_record_stopped_with_ctrl_c_keeps_and_decodes_what_it_received(tmp_path):
    import signal
    import time

    port, mb_port = free_port(), free_port()
    serve = subprocess.Popen(
        [sys.executable, "-m", "benchtwin.cli", "serve", "--synthetic", "20", "--setup", "ideal", "--port", str(port),
         "--modbus-port", str(mb_port), "--speedup", "2", "--wait-clients", "3", "--wait-timeout", "30"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    out = tmp_path / "cut.mf4"
    rec = subprocess.Popen(
        [sys.executable, "-m", "benchtwin.cli", "record", "--setup", "ideal", "--port", str(port), "--modbus-port",
         str(mb_port), "--speedup", "2", "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert rec.stdout.readline().startswith("recording")
        time.sleep(2.0)
        rec.send_signal(signal.SIGINT)
        r_out, r_err = rec.communicate(timeout=60)
    finally:
        for p in (rec, serve):
            if p.poll() is None:
                p.kill()
                p.wait()
    assert rec.returncode == 0, r_err
    assert "stopped (interrupted)" in r_out and "Traceback" not in r_err
    live = Recording.load(out)
    assert live.meta["stop_reason"] == "interrupted"
    speed = live["vehicle_speed_kmh"]
    # the speed is sent every 20 ms: the whole 20 s run is 1,000 samples; stopped after about 2 s of wall time
    # at 2x (some 200 samples on a quiet machine, more when it is busy), it holds part of the run, not all of it
    assert 20 < len(speed) < 950
