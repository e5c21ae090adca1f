"""An IVT-S in triggered mode, live: the recorder triggers it, the emulated shunt answers with its newest
result (the shunt's own state machine), and the decoded current follows the truth."""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.chain.acquisition import acquire
from benchtwin.chain.batch import deliver
from benchtwin.chain.live.bench import capture_to_input, recorder_from_setup, session_from_setup
from benchtwin.config.setup import load_setup
from benchtwin.sensors import encode
from benchtwin.sensors.synthetic import synthetic_trace

pytestmark = pytest.mark.live

SPEEDUP = 2.0


def test_triggered_shunt_answers_the_recorders_triggers(tmp_path):
    base = load_setup("ideal")
    ivt = dict(base.ivt)
    ivt["battery"] = ivt["battery"].model_copy(update={"mode": "triggered", "trigger_period_ms": 50,
                                                       "results": ["I", "U1"]})
    setup = base.model_copy(update={"ivt": ivt})
    trace = synthetic_trace(3.0)
    outputs = encode(trace, setup, seed=0)
    with session_from_setup(outputs, setup, transport="socketcand", speedup=SPEEDUP, modbus_port=0) as s:
        rec = recorder_from_setup(setup, tmp_path / "spool", port=s.transport.port, modbus=False, canopen=False,
                                  speedup=SPEEDUP).start()
        s.wait_for_clients(len(setup.buses), 5.0)
        s.run()
        cap = rec.stop(rec.wait(idle_s=0.5, duration_s=10.0))
        counters = s.responders["instrument"].counters
    assert cap.stats["ivt_triggers_sent"] > 0
    assert counters["triggers"] == cap.stats["ivt_triggers_sent"]
    assert counters["triggered_sent"] > 0.8 * 2 * counters["triggers"]  # I and U1 per trigger (once measured)
    live = acquire(capture_to_input(cap), setup)
    cur = live["battery_current_a"]
    assert len(cur) == pytest.approx(counters["triggered_sent"] / 2, abs=2)
    # values: answers carry the newest encoded result, so they lie on the encoded current
    batch = acquire(deliver(outputs, setup), setup)["battery_current_a"]
    lo, hi = batch.values.min(), batch.values.max()
    assert np.all((cur.values >= lo) & (cur.values <= hi))
    assert set(np.round(cur.values, 6)) <= set(np.round(batch.values, 6))


def test_gate_follows_the_shunts_state():
    import can

    from benchtwin.chain.live.ivt_commands import IvtCommandResponder
    from benchtwin.config.setup import IvtConfig
    from benchtwin.sensors.ivt import IvtDevice
    from benchtwin.wire.frames import FRAME_DTYPE

    dev = IvtDevice(IvtConfig(cycle_ms=20))
    with can.Bus(interface="virtual", channel="bt-gate-test") as bus, \
            can.Bus(interface="virtual", channel="bt-gate-test") as tester:
        resp = IvtCommandResponder({"ivt_battery": dev}, bus)
        f = np.zeros(50, dtype=FRAME_DTYPE)
        f["timestamp"] = np.arange(50) * 0.02
        f["arbitration_id"] = 0x521
        f["dlc"] = 6
        assert len(resp.gate(f)) == 50  # cyclic as encoded
        for cmd in (b"\x34\x00", b"\x20\x02\x00\x64", b"\x34\x01"):  # stop, I cyclic every 100 ms, run
            resp(can.Message(arbitration_id=0x411, is_extended_id=False, data=cmd))
            answer = tester.recv(1.0)
            assert answer.arbitration_id == 0x511 and answer.data[0] == cmd[0] | 0x80
        kept = resp.gate(f)
        np.testing.assert_allclose(np.diff(kept["timestamp"]), 0.1)  # decimated to the new cycle
        resp(can.Message(arbitration_id=0x411, is_extended_id=False, data=b"\x34\x00"))  # stop
        tester.recv(1.0)
        assert len(resp.gate(f)) == 0
        other = f.copy()
        other["arbitration_id"] = 0x100  # not the shunt's: untouched
        assert len(resp.gate(other)) == 50
        resp(can.Message(arbitration_id=0x411, is_extended_id=False, data=b""))  # empty command
        assert resp.counters["malformed"] == 1
