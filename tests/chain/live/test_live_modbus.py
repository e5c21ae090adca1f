"""The pressure module's Modbus TCP server: the physics writes the store, a plain pymodbus client reads."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from pymodbus.client import ModbusTcpClient

from benchtwin.chain.live.modbus_server import ModbusDeviceServer, RegisterStore
from benchtwin.chain.live.session import LiveSession
from benchtwin.errors import ConfigError
from benchtwin.wire.frames import DeviceOutputs, RegisterSnapshots

pytestmark = pytest.mark.live


@pytest.fixture
def server():
    snap = RegisterSnapshots("pressure", 3, 0, [0.0, 0.1], np.arange(28).reshape(2, 14))
    store = RegisterStore.for_snapshots(snap, holding={100 + k: 100 for k in range(5)} | {105 + k: 5000
                                                                                          for k in range(5)})
    with ModbusDeviceServer([store]) as srv:
        client = ModbusTcpClient("127.0.0.1", port=srv.port, timeout=2)
        assert client.connect()
        yield srv, store, snap, client
        client.close()


def test_reads_follow_the_store(server):
    srv, store, snap, client = server
    assert srv.host == "127.0.0.1"
    r = client.read_input_registers(0, count=14, device_id=3)
    assert not r.isError() and r.registers == [0] * 14
    store.write(snap.registers[1])
    r = client.read_input_registers(0, count=14, device_id=3)
    assert r.registers == snap.registers[1].tolist()
    r = client.read_input_registers(11, count=2, device_id=3)
    assert r.registers == snap.registers[1, 11:13].tolist()
    r = client.read_holding_registers(100, count=10, device_id=3)
    assert r.registers == [100] * 5 + [5000] * 5


@pytest.mark.parametrize(("fc", "address", "count"), [(4, 10, 5), (4, 14, 1), (3, 0, 2), (3, 108, 4)])
def test_out_of_range_reads_answer_exception_2(server, fc, address, count):
    _, _, _, client = server
    read = client.read_input_registers if fc == 4 else client.read_holding_registers
    r = read(address, count=count, device_id=3)
    assert r.isError() and r.exception_code == 2


def test_writes_are_refused(server):
    _, _store, _, client = server
    r = client.write_register(100, 7, device_id=3)
    assert r.isError()
    assert client.read_holding_registers(100, count=1, device_id=3).registers == [100]


def test_store_validation():
    with pytest.raises(ConfigError):
        RegisterStore("x", 1, 65530, 10)
    with pytest.raises(ConfigError):
        RegisterStore("x", 1, 0, 4, kind="coils")
    with pytest.raises(ConfigError):
        RegisterStore("x", 1, 0, 4, holding={100: 1, 102: 2})
    with pytest.raises(ConfigError):
        ModbusDeviceServer([RegisterStore("x", 1, 0, 4)], host="0.0.0.0")


def test_session_updates_the_registers_as_the_run_plays():
    t = np.arange(0, 1.0, 0.01)
    regs = np.zeros((len(t), 14), dtype=np.uint16)
    regs[:, 11] = np.arange(len(t))
    outputs = DeviceOutputs(modbus={"pressure": RegisterSnapshots("pressure", 1, 0, t, regs)})
    with LiveSession(outputs, speedup=2.0) as s:
        client = ModbusTcpClient("127.0.0.1", port=s.modbus.port, timeout=2)
        client.connect()
        seen = []
        done = threading.Event()

        def poll():
            while not done.is_set():
                r = client.read_input_registers(11, count=1, device_id=1)
                if not r.isError():
                    seen.append(r.registers[0])

        th = threading.Thread(target=poll)
        th.start()
        rep = s.run()
        done.set()
        th.join()
        seen.append(client.read_input_registers(11, count=1, device_id=1).registers[0])
        client.close()
    assert rep.completed and rep.streams["modbus:pressure"].sent == len(t)
    # the poller saw the counter advance monotonically to the last snapshot
    assert len(set(seen)) > 20 and seen == sorted(seen) and seen[-1] == len(t) - 1
