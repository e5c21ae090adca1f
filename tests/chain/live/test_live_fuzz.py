"""Fuzzing the live endpoints (issue #11): the socketcand endpoint and the Modbus TCP server.

Garbage from raw TCP clients on 127.0.0.1 (random bytes, partial commands and frames, huge lines,
many connections at once, clients that vanish mid-message); then a well-behaved client (python-can's
socketcand interface, pymodbus' client) must still get correct answers and the server thread must
be alive. Bounded: at most 50 examples per property, no deadline (a shared machine), every wait is
for an answer with a timeout, never a fixed sleep. Bugs the fuzzing found are pinned with @example.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import struct
import time

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from pymodbus.client import ModbusTcpClient

from benchtwin.chain.live.modbus_server import ModbusDeviceServer, RegisterStore
from benchtwin.chain.transports.socketcand_server import SocketcandDeviceBus, SocketcandServer

pytestmark = pytest.mark.live

FUZZ = settings(max_examples=50, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

# ---------------------------------------------------------------------------------------- socketcand

_COMMANDS = [b"< open bus0 >", b"< open nosuch >", b"< rawmode >", b"< echo >", b"< send 123 2 01 02 >",
             b"< send 7FF 8 ff ff ff ff ff ff ff ff >", b"< send 12G 2 zz >", b"< send 123 9 1 2 >", b"< bcmmode >",
             b"< frame 123 1.0 0102 >", b"<", b">", b"< ", b" >", b"\xff\xfe", b"< open \xc3\xa9 >",
             b"< send 1FFFFFFF 1 00 >", b"< send -1 1 00 >", b"< send 123 -1 >", b"< send 123 1 100 >",
             b"< send -7ff 0 >", b"< send 0x12 1 00 >", b"< open bus0 >< rawmode >< send 1_0 1 00 >"]

_chunk = st.one_of(
    st.binary(max_size=64),
    st.sampled_from(_COMMANDS),
    st.sampled_from(_COMMANDS).map(lambda c: c[:max(1, len(c) // 2)]),  # partial command
    st.integers(4000, 200_000).map(lambda n: b"<" + b"a" * n),  # a huge unterminated line
    st.integers(4000, 100_000).map(lambda n: b"x" * n + b"\n"),  # a huge line outside < >
)
_client_script = st.lists(_chunk, min_size=1, max_size=8)


class _LongestLog(logging.Handler):
    """Remembers the longest log message of the endpoint (garbage must not flood the log)."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.longest = 0

    def emit(self, record: logging.LogRecord) -> None:
        self.longest = max(self.longest, len(record.getMessage()))


@pytest.fixture(scope="module")
def can_server():
    server = SocketcandServer(["bus0", "bus1"], "127.0.0.1", 0, arm_delay_s=0.0).start()
    handler = _LongestLog()
    logger = logging.getLogger("benchtwin.chain.transports.socketcand_server")
    logger.addHandler(handler)
    server.log_handler = handler
    yield server
    logger.removeHandler(handler)
    server.close()


def _garbage(port: int, scripts: list[list[bytes]], close: bool) -> list[socket.socket]:
    socks = []
    for script in scripts:
        s = socket.create_connection(("127.0.0.1", port), timeout=5.0)
        socks.append(s)
        for chunk in script:
            with contextlib.suppress(OSError):  # the server may close a bad client mid-script
                s.sendall(chunk)
    if close:
        for s in socks:
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)
            s.close()
        return []
    return socks


def _socketcand_sync(socks: list[socket.socket]) -> None:
    """Wait until the endpoint has handled everything each open garbage client sent (an echo round trip)."""
    for s in socks:
        got = b""
        with contextlib.suppress(OSError):
            s.sendall(b">< echo >")  # '>' closes whatever bracket the garbage left open
            s.settimeout(5.0)
            while b"< echo >" not in got[-65536:]:
                chunk = s.recv(65536)
                if not chunk:
                    break  # the endpoint closed this client
                got += chunk


def _valid(m: can.Message) -> bool:
    top = 0x1FFFFFFF if m.is_extended_id else 0x7FF
    return 0 <= m.arbitration_id <= top and 0 <= m.dlc <= 8 and len(m.data) == m.dlc


def _well_behaved_round_trip(server: SocketcandServer, marker: int) -> None:
    port = server.address[1]
    device = SocketcandDeviceBus(server, "bus0")
    # every frame the garbage put on the bus is a valid CAN frame
    while (m := device.recv(timeout=0)) is not None:
        assert _valid(m), m
    client = can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="bus0")
    try:
        end = time.monotonic() + 20.0
        data = marker.to_bytes(4, "big")
        # device -> client: the frame arrives intact (other clients' garbage frames may arrive too); the
        # client is in raw mode when its constructor returns, the frame is re-sent only if it never comes
        got = None
        while got is None and time.monotonic() < end:
            device.send(can.Message(arbitration_id=0x321, is_extended_id=False, data=data, timestamp=time.time()))
            stop = time.monotonic() + 2.0
            while got is None and time.monotonic() < stop:
                m = client.recv(timeout=0.5)
                assert m is None or _valid(m), m
                if m is not None and m.arbitration_id == 0x321 and bytes(m.data) == data:
                    got = m
        assert got is not None, "the well-behaved client did not get its frame"
        # client -> device
        client.send(can.Message(arbitration_id=0x654, is_extended_id=False, data=data))
        got = None
        while got is None and time.monotonic() < end:
            m = device.recv(timeout=1.0)
            if m is not None and m.arbitration_id == 0x654 and bytes(m.data) == data:
                got = m
        assert got is not None, "the device did not get the client's frame"
    finally:
        client.shutdown()
        device.shutdown()
    assert server._thread is not None and server._thread.is_alive()
    assert server.log_handler.longest < 1000, "garbage flooded the log"


@FUZZ
@given(scripts=st.lists(_client_script, min_size=1, max_size=6), close=st.booleans(), marker=st.integers(0, 2**32 - 1))
@example(scripts=[[b"< open bus0 >", b"< rawmode >", b"< send 123 2 01 02 >", b"\xff\xfe"]], close=False, marker=1)
@example(scripts=[[b"<" + b"a" * 200_000]], close=True, marker=2)
# found: int(x, 16) took "-1" (forwarded as id 0x7FF, -1 to the device side), "-7ff" (as extended
# 0x1FFFF801) and "0x12" (as an extended id); the endpoint now rejects anything but plain hex digits
@example(scripts=[[b"< open bus0 >", b"< rawmode >", b"< send -1 1 00 >", b"< send -7ff 0 >",
                   b"< send 0x12 1 00 >", b"< send 1_0 1 00 >", b"< send 123 +1 00 >"]], close=False, marker=3)
# found: a huge line outside < > went into the log whole (up to 64 KiB per read); now cut to 80 characters
@example(scripts=[[b"x" * 100_000 + b"\n"], [b"\xb7" * 5000 + b"<aaa"]], close=False, marker=4)
def test_socketcand_endpoint_survives_garbage(can_server, scripts, close, marker):
    open_socks = _garbage(can_server.address[1], scripts, close)
    _socketcand_sync(open_socks)
    try:
        _well_behaved_round_trip(can_server, marker)
    finally:
        for s in open_socks:
            s.close()


@FUZZ
@given(n=st.integers(1, 60), half_open=st.booleans())
def test_socketcand_endpoint_survives_many_connections(can_server, n, half_open):
    socks = []
    try:
        for k in range(n):
            s = socket.create_connection(("127.0.0.1", can_server.address[1]), timeout=5.0)
            if half_open and k % 2:
                s.sendall(b"< open bus1 >< rawmode >")  # raw-mode clients that never read
            socks.append(s)
        _well_behaved_round_trip(can_server, n)
    finally:
        for s in socks:
            s.close()


# ---------------------------------------------------------------------------------------- Modbus

UNIT = 1
VALUES = (np.arange(14) * 1000 + 7).tolist()


@pytest.fixture(scope="module")
def modbus_server():
    store = RegisterStore("pressure", UNIT, 0, 14, "input", {100 + k: 100 + k for k in range(10)})
    store.write(VALUES)
    with ModbusDeviceServer([store]) as srv:
        yield srv


def _mbap(tid: int, unit: int, pdu: bytes, length: int | None = None) -> bytes:
    return struct.pack(">HHHB", tid & 0xFFFF, 0, (len(pdu) + 1 if length is None else length) & 0xFFFF, unit) + pdu


_pdu = st.one_of(
    st.binary(max_size=300),
    st.tuples(st.sampled_from([1, 2, 3, 4, 5, 6, 15, 16, 23, 43, 0x80, 0xFF, 0]), st.integers(0, 0xFFFF),
              st.integers(0, 0xFFFF)).map(lambda t: struct.pack(">BHH", *t)),
    st.tuples(st.integers(0, 0xFFFF), st.integers(0, 255), st.binary(max_size=16)).map(
        lambda t: struct.pack(">HH", t[0], t[1]) + t[2]),
)
_mb_chunk = st.one_of(
    st.binary(max_size=64),
    st.tuples(st.integers(0, 0xFFFF), st.integers(0, 255), _pdu).map(lambda t: _mbap(t[0], t[1], t[2])),
    st.tuples(st.integers(0, 0xFFFF), st.integers(0, 255), _pdu, st.integers(0, 0xFFFF)).map(
        lambda t: _mbap(t[0], t[1], t[2], t[3])),  # a lying length field
    st.tuples(st.integers(0, 0xFFFF), _pdu).map(lambda t: _mbap(t[0], UNIT, t[1])[:5]),  # a partial header
    st.integers(4000, 100_000).map(lambda n: b"\x00" * n),
)


def _modbus_answers(srv: ModbusDeviceServer) -> None:
    client = ModbusTcpClient("127.0.0.1", port=srv.port, timeout=5, retries=1)
    try:
        assert client.connect()
        r = client.read_input_registers(0, count=14, device_id=UNIT)
        assert not r.isError() and r.registers == VALUES
        r = client.read_holding_registers(100, count=10, device_id=UNIT)
        assert not r.isError() and r.registers == [100 + k for k in range(10)]
        r = client.read_input_registers(20, count=2, device_id=UNIT)
        assert r.isError() and r.exception_code == 2
    finally:
        client.close()
    assert srv._thread is not None and srv._thread.is_alive()


@FUZZ
@given(scripts=st.lists(st.lists(_mb_chunk, min_size=1, max_size=6), min_size=1, max_size=6), close=st.booleans())
@example(scripts=[[_mbap(1, UNIT, struct.pack(">BHH", 4, 0, 0))]], close=True)  # a read of zero registers
@example(scripts=[[_mbap(1, UNIT, b"", 0xFFFF)]], close=False)  # a length field promising 64 KiB
def test_modbus_server_survives_garbage(modbus_server, scripts, close):
    open_socks = _garbage(modbus_server.port, scripts, close)
    try:
        _modbus_answers(modbus_server)
    finally:
        for s in open_socks:
            s.close()


@FUZZ
@given(n=st.integers(1, 60))
def test_modbus_server_survives_many_connections(modbus_server, n):
    socks = [socket.create_connection(("127.0.0.1", modbus_server.port), timeout=5.0) for _ in range(n)]
    try:
        _modbus_answers(modbus_server)
    finally:
        for s in socks:
            s.close()
