"""A spooled Trace's time window read lazily (``SpooledTrace.slice_time(..., lazy=True)``): each channel's window read
when first asked for, the same numbers as the window read whole; the held-out drives' measurement reads only the
channels it uses (benchtwin.validation.holdout.measured)."""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.errors import MissingChannelError
from benchtwin.segments import Segment
from benchtwin.trace import SpooledTrace, Trace
from benchtwin.validation.holdout import measured

#: what measured() reads, and a few channels it does not
_USED = ("fuel_mass_flow_kgps", "tc_pump_torque_nm", "em_speed_radps", "tc_turbine_speed_radps", "lockup_closed",
         "tc_turbine_torque_nm", "trans_input_torque_nm", "battery_voltage_v", "battery_current_a",
         "displayed_soc_pct", "dyno_speed_mps")
_OTHER = ("engine_speed_radps", "brake_pressure_front_pa", "coolant_temp_degc")


def _pieces(rng: np.random.Generator, n_pieces: int = 3, n: int = 4000) -> list[Trace]:
    out = []
    for k in range(n_pieces):
        t = (k * n + np.arange(n)) * 0.01
        ch = {name: rng.normal(size=n) * 50.0 for name in _USED + _OTHER}
        ch["lockup_closed"] = (rng.random(n) < 0.6).astype(np.float64)
        ch["displayed_soc_pct"] = np.float32(40.0) - np.arange(n, dtype=np.float32) * np.float32(1e-3)  # float32
        out.append(Trace(t, ch, [Segment(float(t[0]), float(t[-1]) + 0.01, "cycle", f"d{k}")], {"k": k}))
    return out


def test_the_lazy_window_holds_the_numbers_of_the_window_read_whole(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every channel, the time base and the segments equal the eager window's (the window's bounds taken the same
    way), and a channel is read once, when first asked for. Mutants: the lazy window reading the whole channel
    (``read(name)``): the shapes differ and the test fails; ``lazy`` ignored: every channel is read at once and the
    reads counted fail."""
    with SpooledTrace() as sp:
        for p in _pieces(np.random.default_rng(1)):
            sp.append(p)
        eager = sp.slice_time(25.3, 91.17)
        reads: list[str] = []
        read = sp.read
        monkeypatch.setattr(sp, "read", lambda name, a=0, b=None: reads.append(name) or read(name, a, b))
        lazy = sp.slice_time(25.3, 91.17, lazy=True)
        assert reads == []
        assert "battery_current_a" in lazy and "nope" not in lazy and list(lazy) == list(eager)
        np.testing.assert_array_equal(lazy["battery_current_a"], eager["battery_current_a"])
        _ = lazy["battery_current_a"]
        assert reads == ["battery_current_a"]  # read once, then kept
        for name in eager:
            got, want = lazy[name], eager[name]
            assert got.dtype == want.dtype and got.shape == want.shape
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(lazy.time_s, eager.time_s)
        assert lazy.segments == eager.segments and lazy.meta == eager.meta and len(lazy) == len(eager)
        with pytest.raises(MissingChannelError):
            _ = lazy["nope"]


def test_measured_on_a_spooled_trace_reads_its_channels_only_and_equals_the_in_memory_one(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The drive's measurement from the spooled truth equals the one from the same truth in memory (cut by its mask,
    every channel), number for number, and reads none of the channels it does not use. Mutant: ``measured`` back
    on ``slice_time(start_s, end_s)``: the channels it does not use are read and the test fails."""
    pieces = _pieces(np.random.default_rng(2))
    whole = Trace(np.concatenate([p.time_s for p in pieces]),
                  {k: np.concatenate([p[k] for p in pieces]) for k in pieces[0].channels},
                  [s for p in pieces for s in p.segments])
    with SpooledTrace() as sp:
        for p in pieces:
            sp.append(p)
        reads: list[str] = []
        read = sp.read
        monkeypatch.setattr(sp, "read", lambda name, a=0, b=None: reads.append(name) or read(name, a, b))
        got = measured(sp, 12.0, 101.5)
    want = measured(whole, 12.0, 101.5)
    assert got == want and "lockup_slip_loss_wh" in got
    assert set(reads) <= set(_USED) and not set(reads) & set(_OTHER)
