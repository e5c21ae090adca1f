"""Cross-process: ``benchtwin serve`` in one process; unmodified clients in others.

- ``python -m can.logger -i socketcand`` (python-can's own logger and socketcand client) records the
  vehicle bus to a candump-format log, and ``cantools decode`` with the DBC the package writes turns
  it into the right values;
- a plain pymodbus client reads the pressure module;
- a canopen RemoteNode on python-can's own socketcand client reads the thermo module by PDO and SDO.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time

import can
import cantools
import numpy as np
import pytest
from live_synth import serve_ok_but_for_speed, wait_for_line
from pymodbus.client import ModbusTcpClient

from benchtwin.chain.live.canopen_node import ThermoAcquisition
from benchtwin.chain.live.modbus_server import free_port
from benchtwin.config.setup import load_setup
from benchtwin.sensors import encode, write_bus_dbcs
from benchtwin.sensors.synthetic import synthetic_trace
from benchtwin.wire.canopen_pdo import EDS_PATH
from benchtwin.wire.modbus_map import INPUT_COUNT, REG_COUNTER, holding_defaults

pytestmark = pytest.mark.live

DURATION_S = 2.0
SPEEDUP = 2.0


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("xproc")
    port, mb_port = free_port(), free_port()
    serve = subprocess.Popen(
        [sys.executable, "-m", "benchtwin.cli", "serve", "--synthetic", str(DURATION_S), "--setup", "ideal",
         "--transport", "socketcand", "--port", str(port), "--modbus-port", str(mb_port), "--speedup", str(SPEEDUP),
         "--wait-clients", "2", "--wait-timeout", "20", "--linger", "2.5"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1)
    lines: list[str] = []
    logger = None
    try:
        wait_for_line(serve, r"^endpoints:", 60, lines)
        log_path = tmp / "vehicle.log"
        logger = subprocess.Popen(
            [sys.executable, "-m", "can.logger", "-i", "socketcand", "-c", "vehicle", "--bus-kwargs",
             "host=127.0.0.1", f"port={port}", "-f", str(log_path)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        inst = can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="instrument")
        setup = load_setup("ideal")
        thermo = ThermoAcquisition(setup.thermo.node_id, EDS_PATH, inst)
        mb = ModbusTcpClient("127.0.0.1", port=mb_port, timeout=2)
        assert mb.connect()
        wait_for_line(serve, r"^playing", 30, lines)
        counters, holding = [], None
        while True:  # poll while it plays
            r = mb.read_input_registers(0, count=INPUT_COUNT, device_id=setup.pressure.unit_id)
            if not r.isError():
                counters.append(r.registers[REG_COUNTER])
            if holding is None:
                holding = mb.read_holding_registers(100, count=10, device_id=setup.pressure.unit_id)
            time.sleep(0.02)
            if len(counters) > 10 and counters[-1] == counters[-2] == counters[-3]:
                break  # the run ended: the module holds its last update
            if len(counters) > 1000:
                break
        out_of_range = mb.read_input_registers(INPUT_COUNT, count=1, device_id=setup.pressure.unit_id)
        mb.close()
        sdo_values = [thermo.sdo_read(0x9130, k) for k in range(1, 4)]  # during --linger
        pdo_count = len(thermo.log.times)
        pdo_t, pdo_v, pdo_cob = thermo.log.as_arrays()
        thermo.close()
        inst.shutdown()
        rest, err = serve.communicate(timeout=60)
        lines.append(rest)
        time.sleep(0.3)
        logger.send_signal(signal.SIGINT)
        logger.communicate(timeout=20)
        yield {"tmp": tmp, "log": log_path, "setup": setup, "serve_out": "".join(lines), "serve_err": err,
               "rc": serve.returncode, "counters": counters, "holding": holding, "out_of_range": out_of_range,
               "sdo": sdo_values, "pdo_count": pdo_count, "pdo": (pdo_t, pdo_v, pdo_cob)}
    finally:
        for p in (serve, logger):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()


@pytest.fixture(scope="module")
def truth():
    setup = load_setup("ideal")
    trace = synthetic_trace(DURATION_S)
    return trace, encode(trace, setup, seed=0)


def test_serve_reports_pacing_and_bus_load(served):
    assert serve_ok_but_for_speed(served["rc"], served["serve_err"]), served["serve_err"]
    out = served["serve_out"]
    assert "socketcand tcp://127.0.0.1:" in out and "modbus:brake_pressure: tcp://127.0.0.1:" in out
    assert re.search(r"bus load per bus .*vehicle \d+\.\d %", out)
    assert re.search(r"^all\s+(\d+)\s+\1\s+0\s", out, re.M)  # sent == items, 0 lost


def test_can_logger_and_cantools_decode(served, truth, tmp_path):
    _, outputs = truth
    text = served["log"].read_text()
    rows = re.findall(r"^\((\d+\.\d+)\) vehicle ([0-9A-F]{3})#([0-9A-F]*)", text, re.M)
    table = outputs.can["vehicle"].frames
    assert len(rows) == len(table)  # complete
    assert [int(r[1], 16) for r in rows] == table["arbitration_id"].tolist()  # in order
    assert [bytes.fromhex(r[2]) for r in rows] == [r["data"][:r["dlc"]].tobytes() for r in table]
    # arrival times keep the plan: plant spacing / speed-up
    t = np.array([float(r[0]) for r in rows])
    lag = (t - t[0]) - (table["timestamp"] - table["timestamp"][0]) / SPEEDUP
    assert np.abs(lag - np.median(lag)).max() < 0.01
    dbc = write_bus_dbcs(served["setup"], tmp_path)["vehicle"]
    dec = subprocess.run([sys.executable, "-m", "cantools", "decode", "--single-line", str(dbc)], input=text,
                         capture_output=True, text=True, timeout=60, check=True).stdout
    speeds = [float(m) for m in re.findall(r"VehicleSpeed: ([-\d.]+) km/h", dec)]
    db = cantools.database.load_file(str(dbc))
    msg = db.get_message_by_name("VEH_Speed")
    expect = [db.decode_message(msg.frame_id, r["data"][:r["dlc"]].tobytes())["VehicleSpeed"]
              for r in table if r["arbitration_id"] == msg.frame_id]
    assert len(speeds) == len(expect) > 10
    np.testing.assert_allclose(speeds, expect, atol=1e-9)
    trace, _ = truth
    ts = table["timestamp"][table["arbitration_id"] == msg.frame_id]
    truth_kmh = np.interp(ts, trace.time_s, trace["vehicle_speed_mps"]) * 3.6
    np.testing.assert_allclose(speeds, truth_kmh, atol=0.5)  # DBC resolution + one plant step of motion


def test_plain_pymodbus_client_reads_the_pressure_module(served):
    counters = served["counters"]
    assert len(counters) > 10 and counters == sorted(counters) and counters[-1] > counters[0]
    setup = served["setup"]
    expect = holding_defaults(setup.pressure.full_scale_bar, setup.pressure.full_scale_v)
    assert served["holding"].registers == [expect[100 + k] for k in range(10)]
    assert served["out_of_range"].isError() and served["out_of_range"].exception_code == 2


def test_remote_node_reads_the_thermo_module_by_pdo_and_sdo(served, truth):
    _, outputs = truth
    image = outputs.canopen["thermo"]
    _t, v, cob = served["pdo"]
    n_tpdo = len(set(cob.tolist()))
    assert n_tpdo >= 2 and served["pdo_count"] == n_tpdo * len(image.times)
    col = image.entries.index((0x9130, 1))
    np.testing.assert_array_equal(v[cob == 0x185][:, 0], image.values[:, col])
    last = [int(image.values[-1, image.entries.index((0x9130, k))]) for k in range(1, 4)]
    assert served["sdo"] == last
