"""One suite, run back to back over every transport (python-can back2back_test style).

Each subclass changes only ``TRANSPORT``; the socketcan one (marked ``vcan``, on vcan0 and vcan1)
skips cleanly where the kernel has no AF_CAN or no vcan interfaces (as on the development and CI
machines) and runs under a kernel with vcan through ``make test-vcan``.
"""

from __future__ import annotations

import threading
import time

import can
import numpy as np
import pytest
from live_synth import MIN_EDS
from vcan_env import skip_without_vcan

from benchtwin.chain.live.canopen_node import ThermoAcquisition
from benchtwin.chain.live.session import LiveSession
from benchtwin.chain.transports import get_transport
from benchtwin.config.setup import IvtConfig
from benchtwin.sensors.ivt import IvtDevice

pytestmark = pytest.mark.live


class _Collector:
    """Reads a client bus in a thread until told to stop."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.msgs: list[can.Message] = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            m = self.bus.recv(0.05)
            if m is not None:
                self.msgs.append(m)

    def stop(self, quiet_s: float = 0.3, n_expected: int | None = None, timeout: float = 10.0) -> list[can.Message]:
        end = time.monotonic() + timeout
        last = -1
        while time.monotonic() < end:
            if n_expected is not None and len(self.msgs) >= n_expected:
                break
            if len(self.msgs) == last:
                break
            last = len(self.msgs)
            time.sleep(quiet_s)
        self._stop.set()
        self._t.join()
        return self.msgs


class _Back2Back:
    TRANSPORT = "virtual"
    SPEEDUP = 10.0

    @pytest.fixture(autouse=True)
    def _available(self):
        if self.TRANSPORT == "socketcan":
            skip_without_vcan(("vcan0", "vcan1"))  # the transport's default interfaces of the two buses
        reason = get_transport(self.TRANSPORT).unavailable_reason()
        if reason is not None:
            pytest.skip(f"transport {self.TRANSPORT!r} unavailable here: {reason}")

    def _session(self, outputs, **kw) -> LiveSession:
        return LiveSession(outputs, transport=self.TRANSPORT, speedup=self.SPEEDUP, eds=MIN_EDS, **kw).start()

    def _timed_session(self, outputs) -> LiveSession:
        # real-time policy where the test may take it (see live_synth.PACING_BOUNDS_MS)
        return self._session(outputs, realtime_priority=10)

    def _wait(self, session: LiveSession, n: int) -> None:
        assert session.wait_for_clients(n, 5.0)

    def test_frames_complete_in_order_and_paced(self, small_outputs):
        """Every frame, in order, with its bytes; the pacing report is filled in. How well the pacing holds is a
        benchmark (benchmarks/bench_live.py), not a test: it depends on how busy the machine is."""
        with self._timed_session(small_outputs) as s:
            tr = s.transport
            cols = {b: _Collector(tr.open_client(b)) for b in ("powertrain", "instrument")}
            self._wait(s, 2)
            rep = s.run()
            for bus, col in cols.items():
                table = small_outputs.can[bus].frames
                # the instrument bus also carries the thermo node's TPDOs
                got = [m for m in col.stop(n_expected=len(table)) if m.arbitration_id not in (0x185, 0x285)]
                assert len(got) == len(table), bus
                ids = np.array([m.arbitration_id for m in got])
                assert np.array_equal(ids, table["arbitration_id"]), f"{bus}: order or ids differ"
                assert [bytes(m.data) for m in got] == [r["data"][:r["dlc"]].tobytes() for r in table]
                assert [m.dlc for m in got] == table["dlc"].tolist()
                # arrival order follows the plan: received timestamps never go back
                t_rx = np.array([m.timestamp for m in got])
                assert np.all(np.diff(t_rx) >= 0)
        assert rep.completed and rep.lost == 0
        assert np.isfinite(rep.pacing_p50_ms) and rep.pacing_p99_ms >= rep.pacing_p50_ms >= 0
        load = rep.streams["can:powertrain"].bus_load
        assert load == pytest.approx(small_outputs.can["powertrain"].bus_load(2.0 - 0.001), rel=0.01)

    def test_client_frames_reach_the_device_and_other_clients(self, small_outputs):
        with self._session(small_outputs) as s:
            a = s.transport.open_client("powertrain")
            b = s.transport.open_client("powertrain")
            self._wait(s, 2)
            msg = can.Message(arbitration_id=0x7DF, is_extended_id=False, data=[2, 1, 0x0C, 0, 0, 0, 0, 0])
            a.send(msg)
            got = b.recv(2.0)
            assert got is not None and got.arbitration_id == 0x7DF and bytes(got.data) == bytes(msg.data)
            if self.TRANSPORT == "socketcand":  # our endpoint's device side sees client frames
                dev = s.transport.device_bus("powertrain").recv(2.0)
                assert dev is not None and dev.arbitration_id == 0x7DF
            ext = can.Message(arbitration_id=0x18DAF110, is_extended_id=True, data=[1, 2, 3])
            a.send(ext)
            got = b.recv(2.0)
            assert got is not None and got.is_extended_id and got.arbitration_id == 0x18DAF110
            assert bytes(got.data) == b"\x01\x02\x03"

    def test_ivt_command_channel(self, small_outputs):
        ivt = IvtDevice(IvtConfig(result_base_id=0x521, command_id=0x411, response_id=0x511))
        with self._session(small_outputs, ivt={"instrument": {"battery": ivt}}) as s:
            cl = s.transport.open_client("instrument", can_filters=[{"can_id": 0x500, "can_mask": 0x700}])
            self._wait(s, 1)

            def command(data: bytes) -> bytes:
                cl.send(can.Message(arbitration_id=0x411, is_extended_id=False, data=data))
                end = time.monotonic() + 3.0
                while time.monotonic() < end:
                    m = cl.recv(0.5)
                    if m is not None and m.arbitration_id == 0x511:
                        return bytes(m.data)
                raise AssertionError("no answer")

            assert command(b"\x34\x00\x01\x00")[:2] == b"\xb4\x00"  # stop
            assert command(b"\x20\x01\x00\x14")[:4] == b"\xa0\x01\x00\x14"  # current: triggered
            assert ivt.modes[0] == 1 and not ivt.running
            assert command(b"\x34\x01\x01\x00")[:2] == b"\xb4\x01"  # run
            assert command(b"\x55")[:2] == b"\xff\x55"  # unknown command
            assert command(b"\x30")[:1] == b"\xb0"  # reset errors
            col = _Collector(cl)
            rep = s.run()
            results = [m for m in col.stop() if m.arbitration_id == 0x521]
            assert results == []  # triggered mode: no cyclic results
            resp = s.responders["instrument"]
            assert resp.counters["suppressed"] == int(np.sum(small_outputs.can["instrument"].frames["arbitration_id"]
                                                             == 0x521))
            assert rep.lost == 0
            # a trigger returns the newest result (the last one of the run)
            assert command(b"\x31\x00\x01")[:3] == b"\xb1\x00\x01"
            end = time.monotonic() + 3.0
            trig = None
            while time.monotonic() < end and trig is None:
                m = cl.recv(0.5)
                if m is not None and m.arbitration_id == 0x521:
                    trig = m
            last = small_outputs.can["instrument"].frames
            last = last[last["arbitration_id"] == 0x521][-1]
            # same value and status, the shunt's own counter (nothing was sent before: 0)
            assert trig is not None and bytes(trig.data[2:6]) == last["data"][2:6].tobytes()
            assert trig.data[0] == 0 and trig.data[1] & 0x0F == 0

    def test_canopen_pdo_and_sdo(self, small_outputs):
        image = small_outputs.canopen["thermo"]
        with self._session(small_outputs) as s:
            acq = ThermoAcquisition(5, MIN_EDS, s.transport.open_client("instrument"))
            self._wait(s, 1)
            s.run()
            assert acq.wait_for_pdos(2 * len(image.times), 5.0)
            _t, v, cob = acq.log.as_arrays()
            assert set(cob.tolist()) == {0x185, 0x285}
            got1 = v[cob == 0x185][:, :4]
            got2 = v[cob == 0x285][:, 4:]
            np.testing.assert_array_equal(got1, image.values[:, :4])
            np.testing.assert_array_equal(got2, image.values[:, 4:])
            # SDO returns the newest value of the process image
            assert acq.sdo_read(0x6401, 3) == int(image.values[-1, 2])
            assert acq.sdo_read(0x1000) == 0x00020194
            acq.close()


class TestVirtual(_Back2Back):
    TRANSPORT = "virtual"


class TestSocketcand(_Back2Back):
    TRANSPORT = "socketcand"
    SPEEDUP = 20.0


@pytest.mark.vcan
class TestSocketcan(_Back2Back):
    TRANSPORT = "socketcan"


def test_socketcand_endpoint_disconnects_a_client_that_falls_too_far_behind():
    import socket as _socket

    from live_synth import synthetic_frames

    from benchtwin.chain.transports.socketcand import SocketcandServer, format_frames

    srv = SocketcandServer(["bus"], max_backlog_bytes=200_000, arm_delay_s=0.0).start()
    try:
        lazy = _socket.create_connection(srv.address)
        lazy.setsockopt(_socket.SOL_SOCKET, _socket.SO_RCVBUF, 4096)
        lazy.sendall(b"< open bus >< rawmode >")
        good = can.Bus(interface="socketcand", host="127.0.0.1", port=srv.address[1], channel="bus")
        assert srv.wait_for_clients(2, 5.0)
        payload = format_frames(synthetic_frames(1.0, 20000.0, [0x123]), 1.0)
        got = 0
        for _ in range(10):  # ~7 MB; the lazy client never reads
            srv.broadcast("bus", payload)
            while good.recv(0.0) is not None:
                got += 1
        end = time.monotonic() + 10
        while got < 200000 and time.monotonic() < end:
            if good.recv(0.5) is not None:
                got += 1
        stats = srv.stats()
        assert stats["clients_dropped"] == 1 and stats["frames_dropped_bytes"] > 0
        assert got == 200000  # the client that keeps up got everything
        good.shutdown()
        lazy.close()
    finally:
        srv.close()
