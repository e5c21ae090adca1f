"""The unmodified tools on vcan: can-utils' ``cansend``/``candump`` and python-can's ``can.logger``.

- a frame sent with ``cansend`` reaches a python-can ``socketcan`` bus and ``candump``;
- the frames benchtwin's ``socketcan`` transport puts on vcan0/vcan1 (a live session of the small
  synthetic run) are all seen, in order and with their ids and bytes, by ``candump`` and in the log
  file of ``python -m can.logger -i socketcan -c vcan0``.

Only where the kernel has SocketCAN and the vcan interfaces exist (``make test-vcan``); elsewhere
they skip with the one reason of :mod:`vcan_env`.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time

import can
import pytest
from live_synth import MIN_EDS
from vcan_env import skip_without_vcan

from benchtwin.chain.live.session import LiveSession

pytestmark = [pytest.mark.live, pytest.mark.vcan]

#: a frame that no test table carries: sent until a tool shows it, so the tool is known to be listening
PROBE_ID = 0x7FF
#: candump -L: ``(1700000000.123456) vcan0 123#DEADBEEF``; python-can's .log writer adds `` R`` or `` T`` (frames
#: sent from this machine, as everything on a vcan is)
CANDUMP_LINE = re.compile(r"^\((\d+\.\d+)\) (\S+) ([0-9A-F]{3}|[0-9A-F]{8})#([0-9A-F]*)(?: [RT])?\s*$")


@pytest.fixture(autouse=True)
def _vcan():
    skip_without_vcan(("vcan0", "vcan1"))
    if shutil.which("candump") is None or shutil.which("cansend") is None:
        pytest.skip("can-utils (candump, cansend) not installed")


def _default_sigint() -> None:
    """In the child: Ctrl-C (SIGINT) back to its default, so that the tool stops as it would in a terminal.

    A test run started in the background (the guest's init script) ignores SIGINT, the children inherit
    that, and Python then installs no KeyboardInterrupt handler: can.logger would never stop and flush.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _cansend(iface: str, frame: str) -> None:
    subprocess.run(["cansend", iface, frame], check=True, timeout=30)


class _Candump:
    """``candump -L`` on some interfaces, its lines read in a thread."""

    def __init__(self, *ifaces: str) -> None:
        self.proc = subprocess.Popen(["candump", "-L", *ifaces], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, bufsize=1, preexec_fn=_default_sigint)
        self.rows: list[tuple[str, int, bytes]] = []
        self._t = threading.Thread(target=self._read, daemon=True)
        self._t.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            m = CANDUMP_LINE.match(line)
            if m:
                self.rows.append((m.group(2), int(m.group(3), 16), bytes.fromhex(m.group(4))))

    def wait_ready(self, iface: str, timeout: float = 60.0) -> None:
        """Send the probe frame until candump shows it."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            _cansend(iface, f"{PROBE_ID:03X}#00")
            time.sleep(0.3)
            if any(r[1] == PROBE_ID for r in self.rows):
                return
        raise AssertionError(f"candump on {iface} showed nothing within {timeout} s")

    def wait_rows(self, n: int, timeout: float) -> list[tuple[str, int, bytes]]:
        end = time.monotonic() + timeout
        last, quiet_since = -1, time.monotonic()
        while time.monotonic() < end:
            rows = self.data_rows()
            if len(rows) >= n:
                break
            if len(rows) != last:
                last, quiet_since = len(rows), time.monotonic()
            elif time.monotonic() - quiet_since > 5.0:
                break
            time.sleep(0.1)
        return self.data_rows()

    def data_rows(self) -> list[tuple[str, int, bytes]]:
        return [r for r in self.rows if r[1] != PROBE_ID]

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._t.join(timeout=5)


def test_cansend_reaches_python_can_and_candump():
    bus = can.Bus(interface="socketcan", channel="vcan0")
    dump = _Candump("vcan0")
    try:
        dump.wait_ready("vcan0")
        while bus.recv(0.1) is not None:  # the probes
            pass
        _cansend("vcan0", "123#DEADBEEF")
        _cansend("vcan0", "18DAF110#0102030405060708")
        got = [bus.recv(10.0), bus.recv(10.0)]
        assert all(m is not None for m in got)
        assert (got[0].arbitration_id, got[0].is_extended_id, bytes(got[0].data)) == (0x123, False, b"\xde\xad\xbe\xef")
        assert (got[1].arbitration_id, got[1].is_extended_id, bytes(got[1].data)) == (0x18DAF110, True,
                                                                                      bytes(range(1, 9)))
        rows = dump.wait_rows(2, 30.0)
    finally:
        dump.stop()
        bus.shutdown()
    assert rows == [("vcan0", 0x123, b"\xde\xad\xbe\xef"), ("vcan0", 0x18DAF110, bytes(range(1, 9)))]


def _table_rows(table, iface: str) -> list[tuple[str, int, bytes]]:
    return [(iface, int(r["arbitration_id"]), r["data"][:r["dlc"]].tobytes()) for r in table]


def test_transport_frames_seen_by_candump_and_can_logger(small_outputs, tmp_path):
    log = tmp_path / "vcan0.log"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    logger = subprocess.Popen([sys.executable, "-m", "can.logger", "-i", "socketcan", "-c", "vcan0", "-f", str(log)],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                              preexec_fn=_default_sigint)
    dump = _Candump("vcan0", "vcan1")
    try:
        out = []
        end = time.monotonic() + 300  # python-can's start-up under software emulation takes a while
        while time.monotonic() < end:
            line = logger.stdout.readline()
            if not line:
                break
            out.append(line)
            if line.startswith("Can Logger"):  # printed once its bus is open
                break
        assert any(s.startswith("Can Logger") for s in out), "".join(out)
        dump.wait_ready("vcan0")
        dump.wait_ready("vcan1")
        # the session's buses take the socketcan transport's default interfaces: powertrain vcan0, instrument vcan1
        with LiveSession(small_outputs, transport="socketcan", speedup=10.0, eds=MIN_EDS).start() as s:
            assert s.transport.interface("powertrain") == "vcan0"
            assert s.transport.interface("instrument") == "vcan1"
            rep = s.run()
        pt = _table_rows(small_outputs.can["powertrain"].frames, "vcan0")
        inst = _table_rows(small_outputs.can["instrument"].frames, "vcan1")
        rows = dump.wait_rows(len(pt) + len(inst), 60.0)
        time.sleep(1.0)  # the logger writes what it has received
    finally:
        dump.stop()
        if logger.poll() is None:
            logger.send_signal(signal.SIGINT)
        try:
            logger_rest = logger.communicate(timeout=60)[0]
        except subprocess.TimeoutExpired:
            logger.kill()
            logger_rest = "(killed: did not stop on SIGINT)" + logger.communicate()[0]
    assert rep.completed and rep.lost == 0
    # candump: every frame of both buses, each bus in order (the thermo node's TPDOs, boot-up message and
    # heartbeats, NMT error control at 0x700 + node id, also ride on vcan1)
    assert [r for r in rows if r[0] == "vcan0"] == pt
    assert [r for r in rows if r[0] == "vcan1" and r[1] not in (0x185, 0x285) and not 0x700 < r[1] < 0x780] == inst
    assert len({r for r in rows if r[0] == "vcan1" and r[1] in (0x185, 0x285)}) > 0
    # can.logger's candump-format log: the vcan0 frames, complete and in order
    logged = []
    for line in log.read_text().splitlines():
        m = CANDUMP_LINE.match(line)
        if m and int(m.group(3), 16) != PROBE_ID:
            logged.append((m.group(2), int(m.group(3), 16), bytes.fromhex(m.group(4))))
    text = log.read_text() if log.exists() else "(no log file)"
    assert logged == pt, "".join(out) + logger_rest + f"\n{len(text.splitlines())} log lines:\n" + text[:600]
