"""A family run reads the Trace where it lies: its spans and the encoder's chunks are views, not copies, and the
converter's estimates are those of the run that copied them (and fitted the dyno's slip on the row-wise design)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import benchtwin.chain.alignment as alignment
import benchtwin.sensors.encoder as encoder
import benchtwin.validation.run as run
from benchtwin.config import load_campaign, load_vehicle, scenario_path
from benchtwin.config.setup import load_setup
from benchtwin.emulator import simulate_campaign
from benchtwin.validation.families import span_view


def _slip_fit_rows(t_a: np.ndarray, x_a: np.ndarray, t_b: np.ndarray, x_b: np.ndarray,
                   forces: list[tuple[np.ndarray, np.ndarray]], lag0: float, lo: float, hi: float, rate_hz: float,
                   search_s: float) -> float:
    """The slip fit as it was written before (main 01c45a7): the design as one n x k array, reduced along its rows."""
    lo, hi = alignment._central_hour(lo, hi)
    if hi - lo < 20.0:
        return lag0
    grid = np.arange(lo, hi, 1.0 / rate_hz)
    a = np.interp(grid, t_a, x_a)
    lags = lag0 + np.arange(-round(search_s * rate_hz), round(search_s * rate_hz) + 1) / rate_hz
    ssr = np.empty(lags.size)
    for j, lag in enumerate(lags):
        b = np.interp(grid + lag, t_b, x_b)
        design = np.column_stack([b, np.ones_like(b)] + [b * np.interp(grid + lag, tf, f) for tf, f in forces])
        good = np.isfinite(a) & np.all(np.isfinite(design), axis=1)
        if good.sum() < 10 * design.shape[1]:
            return lag0
        dg, ag = design[good], a[good]
        dn = dg / np.maximum(np.abs(dg).max(axis=0), 1e-300)
        coef = np.linalg.lstsq(dn.T @ dn, dn.T @ ag, rcond=None)[0]
        ssr[j] = float(np.sum((ag - dn @ coef) ** 2)) / ag.size
    k = int(np.argmin(ssr))
    frac = 0.0
    if 0 < k < ssr.size - 1:
        den = ssr[k - 1] - 2 * ssr[k] + ssr[k + 1]
        frac = 0.5 * (ssr[k - 1] - ssr[k + 1]) / den if den > 0 else 0.0
    return float(lags[k] + frac / rate_hz)


def test_the_slip_fit_column_by_column_is_the_row_wise_fit_bit_for_bit() -> None:
    # a speed that follows the rollers 0.12 s late with a force-dependent slip, gaps (NaN) in every input, and
    # force columns of very different sizes (the scaling matters): the same lag to the last bit
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 400.0, 0.01)
    roller = 40 + 20 * np.sin(t / 9.0) + 5 * np.sin(t / 2.3)
    front, rear = 3000 * np.cos(t / 7.0), 50 * np.sin(t / 3.0) + 1e4
    x_a = np.interp(t - 0.12, t, roller) * (1 + 2e-5 * front) + rng.normal(0, 0.05, t.size)
    for x in (x_a, roller, front, rear):
        x[rng.integers(0, t.size, 300)] = np.nan
    forces = [(t, front), (t, rear)]
    for lag0 in (0.0, 0.1, -0.05):
        got = alignment._slip_fit(t, x_a, t, roller, forces, lag0, 5.0, 395.0, 20.0, 0.3)
        assert got == _slip_fit_rows(t, x_a, t, roller, forces, lag0, 5.0, 395.0, 20.0, 0.3)
        assert abs(got + 0.12) < 0.02  # and it finds the lag: a is 0.12 s late (a grid step at 20 Hz is 0.05 s)


def test_joined_pieces_of_one_array_are_a_view_else_a_copy() -> None:
    x = np.arange(100.0)
    j = encoder._joined(x[10:20], x[20:40])
    assert np.shares_memory(j, x) and np.array_equal(j, x[10:40]) and not j.flags.writeable
    k = encoder._joined(j[5:], x[40:50])  # a view of a view, then the next piece
    assert np.shares_memory(k, x) and np.array_equal(k, x[15:50])
    cols = np.arange(300.0).reshape(100, 3)[:, 1]  # a column of a 2-D array, as some of the plant's channels
    s = encoder._joined(cols[:40], cols[40:70])
    assert np.shares_memory(s, cols) and np.array_equal(s, cols[:70])
    y = np.arange(100.0)
    for a, b in ((x[:10], y[10:20]), (x[:10], x[11:20]), (x[:10], x[10:30:2])):  # other memory, a gap, a stride
        out = encoder._joined(a, b)
        assert not np.shares_memory(out, x) and np.array_equal(out, np.concatenate([a, b]))


def _quick():
    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    return vehicle, campaign, simulate_campaign(vehicle, campaign), load_setup(scenario_path("setups", "paper.toml"))


def test_a_family_run_copies_no_trace_channel(monkeypatch: pytest.MonkeyPatch) -> None:
    vehicle, campaign, trace, setup = _quick()
    fed: list = []
    joins: list[bool] = []
    real_batch, real_join = run.run_batch, encoder._joined

    def batch(sl, *args, **kwargs):
        fed.append(sl)
        return real_batch(sl, *args, **kwargs)

    def join(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        out = real_join(a, b)
        joins.append(bool(np.shares_memory(out, a)))
        return out

    monkeypatch.setattr(run, "run_batch", batch)
    monkeypatch.setattr(encoder, "_joined", join)
    monkeypatch.setattr(run, "FAMILY_CHUNK_S", 100.0)  # several chunks in a span of the quick campaign
    run.validate(vehicle, setup, campaign, trace=trace, families=["torque_converter"], profile="realistic",
                 chain_checks=False)
    assert fed and all(np.shares_memory(sl.channels[k], trace.channels[k]) for sl in fed for k in trace.channels)
    assert len(joins) > 57 and all(joins)  # every channel and the time base at each later chunk: views


def test_span_view_is_slice_time() -> None:
    _, _, trace, _ = _quick()
    for a, b in ((0.0, 1e9), (trace.segments[1].start_s, trace.segments[3].end_s), (12.345, 200.0)):
        v, s = span_view(trace, a, b), trace.slice_time(a, b)
        assert np.array_equal(v.time_s, s.time_s) and v.segments == s.segments
        assert all(np.array_equal(v.channels[k], s.channels[k], equal_nan=True) for k in s.channels)


def test_the_converter_family_identifies_as_the_run_that_copied(monkeypatch: pytest.MonkeyPatch) -> None:
    # the fast run (views, the slip fit column by column) against the run as it was on main 01c45a7 (spans and
    # chunks copied, the row-wise slip fit): the same estimates, intervals, notes and clock offsets
    vehicle, campaign, trace, setup = _quick()

    def ident() -> str:
        rep = run.validate(vehicle, setup, campaign, trace=trace, families=["torque_converter"], profile="realistic",
                           chain_checks=False)
        d = rep.identification.to_dict()
        d["meta"].pop("seconds")
        return json.dumps([d, [(c.name, c.identified, c.error) for c in rep.checks], rep.chain["clock_offsets_s"]],
                          sort_keys=True, default=str)

    fast = ident()
    monkeypatch.setattr(run, "span_view", lambda tr, a, b: tr.slice_time(a, b))
    monkeypatch.setattr(encoder, "_joined", lambda a, b: np.concatenate([a, b]))
    monkeypatch.setattr(alignment, "_slip_fit", _slip_fit_rows)
    assert '"torque_converter' in fast and "vehicle_can->dyno" in fast
    assert fast == ident()
