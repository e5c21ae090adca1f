"""Contracts shared by every layer: errors, segments, Recording and Trace round trips, CLI."""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin import errors
from benchtwin.cli import main
from benchtwin.recording import Channel, Flag, Recording
from benchtwin.segments import Segment
from benchtwin.trace import Trace


def test_error_tree_matches_builtins() -> None:
    assert issubclass(errors.ConfigError, ValueError)
    assert issubclass(errors.TransportTimeoutError, TimeoutError)
    assert issubclass(errors.TransportError, ConnectionError)
    assert issubclass(errors.MissingChannelError, LookupError)
    assert issubclass(errors.FitFailedError, RuntimeError)
    e = errors.ModbusExceptionError("illegal address", code=2)
    assert e.code == 2 and isinstance(e, errors.BenchtwinError)


def test_recording_round_trip_keeps_units_flags_sources_segments(tmp_path) -> None:
    rec = Recording(meta={"note": "x"})
    rec.add(Channel("battery_current_a", "A", np.arange(5) * 0.02, np.array([1.0, 2, 3, 4, 5]),
                    np.array([0, Flag.LOST_FRAME, 0, 0, Flag.SATURATED]), "ivt_battery"))
    rec.add(Channel("vehicle_speed_kmh", "km/h", np.arange(3) * 0.1, np.array([0.0, 1.5, 3.0]), None, "vehicle_can"))
    rec.segments = [Segment(0.0, 1.0, "ramp_up", "r1", {"gear": 5})]
    back = Recording.load(rec.save(tmp_path / "rec.mf4"))
    assert set(back.channels) == set(rec.channels)
    c = back["battery_current_a"]
    assert c.unit == "A" and c.source == "ivt_battery"
    np.testing.assert_allclose(c.values, rec["battery_current_a"].values)
    np.testing.assert_array_equal(c.flags, rec["battery_current_a"].flags)
    assert back.segments == rec.segments
    assert back.meta["note"] == "x"
    assert list(c.good) == [True, True, True, True, False]


def test_recording_missing_channel_is_clear() -> None:
    with pytest.raises(errors.MissingChannelError, match="no channel 'x'"):
        Recording()["x"]


def test_resample_marks_flagged_and_out_of_span() -> None:
    rec = Recording()
    rec.add(Channel("a", "", np.arange(10.0), np.arange(10.0), np.where(np.arange(10) == 4, 1, 0)))
    rec.add(Channel("b", "", np.arange(2.0, 12.0), np.ones(10)))
    t, v, bad = rec.resample(["a", "b"], 2.0)
    assert t[0] == 2.0 and t[-1] < 9.0
    np.testing.assert_allclose(v["a"], t)
    assert bad[(t >= 4) & (t < 5)].all() and not bad[t < 4].any()


def test_trace_round_trip(tmp_path) -> None:
    tr = Trace(np.arange(100) * 0.01, {"em_torque_nm": np.sin(np.arange(100))},
               [Segment(0, 1, "cycle", "wltc")], {"seed": 3})
    back = Trace.load(tr.save(tmp_path).parent)
    np.testing.assert_allclose(back["em_torque_nm"], tr["em_torque_nm"])
    assert back.segments == tr.segments and back.meta["seed"] == 3
    with pytest.raises(errors.DataError):
        Trace(np.arange(3.0), {"x": np.ones(4)})


def test_cli_without_command_prints_help(capsys) -> None:
    assert main([]) == 1
    assert "benchtwin" in capsys.readouterr().out
