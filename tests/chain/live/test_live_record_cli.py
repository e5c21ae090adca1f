"""``benchtwin serve`` and ``benchtwin record`` as a user runs them: two processes, one Recording.

The recorder writes the Recording (MF4, reloadable), the raw bus logs (MF4 bus logging) and the poll
logs, and the Recording equals the batch Recording of the same run (same frames on the CAN channels).
Bad arguments end with a one-line error, never a traceback.
"""

from __future__ import annotations

import subprocess
import sys

import can
import numpy as np
import pytest
from live_synth import serve_ok_but_for_speed

from benchtwin.chain.acquisition import acquire
from benchtwin.chain.batch import deliver
from benchtwin.chain.live.modbus_server import free_port
from benchtwin.cli import main
from benchtwin.config.setup import load_setup
from benchtwin.recording import Recording
from benchtwin.sensors import encode
from benchtwin.sensors.synthetic import synthetic_trace

pytestmark = pytest.mark.live


def test_serve_and_record_in_two_processes(tmp_path):
    port, mb_port = free_port(), free_port()
    serve = subprocess.Popen(
        [sys.executable, "-m", "benchtwin.cli", "serve", "--synthetic", "2", "--setup", "ideal", "--port", str(port),
         "--modbus-port", str(mb_port), "--speedup", "2", "--wait-clients", "3", "--wait-timeout", "30",
         "--segments-out", str(tmp_path / "segments.json")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        out = tmp_path / "live.mf4"
        rec = subprocess.run(
            [sys.executable, "-m", "benchtwin.cli", "record", "--setup", "ideal", "--port", str(port),
             "--modbus-port", str(mb_port), "--speedup", "2", "--idle", "1.0", "--out", str(out)],
            capture_output=True, text=True, timeout=120)
        _s_out, s_err = serve.communicate(timeout=60)
    finally:
        if serve.poll() is None:
            serve.kill()
            serve.wait()
    assert rec.returncode == 0, rec.stderr
    assert serve_ok_but_for_speed(serve.returncode, s_err), s_err
    assert "wrote" in rec.stdout and "Traceback" not in rec.stderr
    live = Recording.load(out)
    setup = load_setup("ideal")
    outputs = encode(synthetic_trace(2.0), setup, seed=0)
    batch = acquire(deliver(outputs, setup), setup)
    assert set(live.channels) == set(batch.channels)
    for name in ("battery_current_a", "shaft_torque_nm", "vehicle_speed_kmh", "engine_coolant_in_degc"):
        np.testing.assert_array_equal(live[name].values, batch[name].values, err_msg=name)
        assert live[name].unit == batch[name].unit
    raw = out.with_name("live_raw")
    for bus in setup.buses:
        with can.MF4Reader(str(raw / f"{bus}.mf4")) as reader:
            # the live thermo module's boot-up message and heartbeats (NMT error control) come on top
            n = sum(1 for m in reader if m.arbitration_id != 0x700 + setup.thermo.node_id)
        assert n == int(batch.meta["frames"][bus]), bus
    assert (raw / f"{setup.pressure.device}.polls.npz").exists()
    assert (tmp_path / "live.mf4.spool" / "vehicle.frames").stat().st_size > 0


@pytest.mark.parametrize("argv", [
    ["record", "--setup", "ideal", "--port", "1", "--out", "x.txt"],
    ["record", "--setup", "ideal", "--port", "1", "--out", "x.mf4", "--buses", "nosuchbus"],
    ["record", "--setup", "ideal", "--port", "1", "--out", "x.mf4", "--speedup", "0"],
    ["serve", "--setup", "ideal", "--synthetic", "1", "--trace", "somewhere"],
    ["serve", "--setup", "ideal", "--synthetic", "1", "--transport", "socketcan"],
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
