"""The thermo module is a CANopen NMT slave, checked with an unmodified canopen master over python-can's virtual bus.

Boot-up message, heartbeat from 0x1017, NMT stop / pre-operational / start (no TPDO outside OPERATIONAL),
SDO writes that disable or remap a TPDO take effect, and wrong ones are refused with the CiA 301 abort code.
Every wait is for an event (a frame, an SDO answer) with a generous timeout, never a fixed sleep.
"""

from __future__ import annotations

import time
import uuid

import can
import canopen
import numpy as np
import pytest

from benchtwin.chain.live.canopen_node import (
    ABORT_CANNOT_MAP,
    ABORT_INVALID_VALUE,
    ABORT_NOT_IN_OD,
    ABORT_UNSUPPORTED_ACCESS,
    ThermoNode,
)
from benchtwin.wire.canopen_pdo import EDS_PATH
from benchtwin.wire.frames import ProcessImage

NODE = 5
ENTRIES = [(0x9130, k) for k in range(1, 10)] + [(0x2100, 0)]


class _Frames(can.Listener):
    def __init__(self) -> None:
        self.frames: list[can.Message] = []

    def on_message_received(self, msg: can.Message) -> None:
        self.frames.append(msg)

    def of(self, cob: int) -> list[can.Message]:
        return [m for m in list(self.frames) if m.arbitration_id == cob]

    def wait_for(self, cob: int, n: int = 1, timeout: float = 10.0) -> list[can.Message]:
        end = time.monotonic() + timeout
        while len(self.of(cob)) < n and time.monotonic() < end:
            time.sleep(0.002)
        return self.of(cob)


@pytest.fixture
def bench():
    channel = f"nmt-{uuid.uuid4().hex}"
    master_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    heard = _Frames()
    network = canopen.Network(master_bus)
    network.notifier = can.Notifier(master_bus, [*network.listeners, heard], timeout=0.1)
    remote = canopen.RemoteNode(NODE, str(EDS_PATH))
    remote.sdo.RESPONSE_TIMEOUT = 5.0
    network.add_node(remote)
    image = ProcessImage("thermo", NODE, np.arange(4) * 0.1, ENTRIES,
                         np.array([[100 * r + k for k in range(len(ENTRIES))] for r in range(4)], dtype=np.int64))
    device_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    node = ThermoNode(image, EDS_PATH, device_bus)
    yield node, remote, heard
    node.close()
    network.notifier.stop()
    device_bus.shutdown()
    master_bus.shutdown()


def _sync(remote) -> None:
    """An SDO round trip: everything the device sent before its answer has reached the master's listeners."""
    remote.sdo[0x1000].raw  # noqa: B018


def test_boot_up_heartbeat_and_nmt_states_gate_the_tpdos(bench):
    node, remote, heard = bench
    boot = heard.wait_for(0x700 + NODE)
    assert boot and bytes(boot[0].data) == b"\x00"  # the boot-up message
    assert node.nmt_state == "OPERATIONAL"  # NMT self-start
    remote.sdo[0x1017].raw = 20  # heartbeat every 20 ms
    assert remote.nmt.wait_for_heartbeat(timeout=10.0) == "OPERATIONAL"
    assert node.update(0) == 3
    _sync(remote)
    assert [len(heard.of(c)) for c in (0x185, 0x285, 0x385)] == [1, 1, 1]

    remote.nmt.state = "PRE-OPERATIONAL"
    _sync(remote)  # the NMT command was handled before this SDO answer
    assert node.nmt_state == "PRE-OPERATIONAL"
    assert node.update(1) == 0
    _sync(remote)
    assert len(heard.of(0x185)) == 1  # nothing new outside OPERATIONAL
    assert remote.sdo[0x9130][2].raw == 101  # but SDO serves the current value

    remote.nmt.state = "STOPPED"
    for _ in range(200):  # heartbeats say STOPPED once the command is handled
        if remote.nmt.wait_for_heartbeat(timeout=10.0) == "STOPPED":
            break
    assert node.nmt_state == "STOPPED"
    assert node.update(2) == 0
    with pytest.raises(canopen.SdoCommunicationError):  # STOPPED: no SDO
        remote.sdo.RESPONSE_TIMEOUT = 0.3
        remote.sdo[0x1000].raw  # noqa: B018
    remote.sdo.RESPONSE_TIMEOUT = 5.0

    remote.nmt.state = "OPERATIONAL"
    for _ in range(200):
        if remote.nmt.wait_for_heartbeat(timeout=10.0) == "OPERATIONAL":
            break
    assert node.update(3) == 3
    got = heard.wait_for(0x185, 2)
    assert int.from_bytes(bytes(got[-1].data[:2]), "little", signed=True) == 300


def test_a_reset_boots_again_with_the_eds_configuration(bench):
    node, remote, heard = bench
    heard.wait_for(0x700 + NODE)
    remote.sdo[0x1800][1].raw = 0x80000185
    assert node.cob_ids == [0x285, 0x385]
    remote.nmt.send_command(0x81)  # reset node
    end = time.monotonic() + 10.0
    while time.monotonic() < end and sum(bytes(m.data) == b"\x00" for m in heard.of(0x700 + NODE)) < 2:
        time.sleep(0.002)
    assert sum(bytes(m.data) == b"\x00" for m in heard.of(0x700 + NODE)) == 2  # a second boot-up message
    _sync(remote)
    assert node.cob_ids == [0x185, 0x285, 0x385]
    assert remote.sdo[0x1800][1].raw == 0x185


def test_sdo_writes_disable_and_remap_a_tpdo(bench):
    node, remote, heard = bench
    # disable TPDO1
    remote.sdo[0x1800][1].raw = 0x80000185
    assert node.update(0) == 2
    _sync(remote)
    assert heard.of(0x185) == [] and len(heard.of(0x285)) == 1
    # remap TPDO2 to input 9 and the cold junction (CiA 301: disable, sub 0 = 0, entries, sub 0 = n, enable)
    remote.sdo[0x1801][1].raw = 0x80000285
    remote.sdo[0x1A01][0].raw = 0
    remote.sdo[0x1A01][1].raw = 0x91300910
    remote.sdo[0x1A01][2].raw = 0x21000010
    remote.sdo[0x1A01][0].raw = 2
    remote.sdo[0x1801][1].raw = 0x285
    assert node.update(1) == 2  # TPDO1 stays disabled
    got = heard.wait_for(0x285, 2)
    data = bytes(got[-1].data)
    assert len(data) == 4
    assert int.from_bytes(data[:2], "little") == 108 and int.from_bytes(data[2:], "little") == 109
    assert remote.sdo[0x1A01][0].raw == 2


@pytest.mark.parametrize(("index", "sub", "value", "code"), [
    (0x1800, 1, 0x186, ABORT_INVALID_VALUE),  # a valid PDO's COB-ID cannot change
    (0x1A00, 1, 0x91300510, ABORT_UNSUPPORTED_ACCESS),  # the mapping of a valid PDO cannot change
    (0x1A00, 0, 2, ABORT_UNSUPPORTED_ACCESS),
])
def test_wrong_pdo_writes_are_refused_with_the_cia301_abort_code(bench, index, sub, value, code):
    node, remote, _ = bench
    with pytest.raises(canopen.SdoAbortedError) as exc:
        remote.sdo[index][sub].raw = value
    assert exc.value.code == code
    assert node.cob_ids == [0x185, 0x285, 0x385]


def test_mapping_errors_while_disabled(bench):
    node, remote, _ = bench
    remote.sdo[0x1801][1].raw = 0x80000285
    with pytest.raises(canopen.SdoAbortedError) as exc:  # sub-index 0 must be 0 first
        remote.sdo[0x1A01][1].raw = 0x91300910
    assert exc.value.code == ABORT_UNSUPPORTED_ACCESS
    remote.sdo[0x1A01][0].raw = 0
    for value, code in ((0x12340010, ABORT_NOT_IN_OD), (0x10000020, ABORT_CANNOT_MAP),
                        (0x91300920, ABORT_CANNOT_MAP)):
        with pytest.raises(canopen.SdoAbortedError) as exc:
            remote.sdo[0x1A01][1].raw = value
        assert exc.value.code == code, hex(value)
    assert node.cob_ids == [0x185, 0x385]
