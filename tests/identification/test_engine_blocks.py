"""The engine's cold-start blocks, coolant warm-up and BSFC bootstrap by runs: the same numbers, memory by a run.

:func:`cold_blocks` and :func:`fit_warmup` read the grid a run of whole blocks at a time (``grid_runs``) and keep per
block only what their fits use; ``fit_bsfc_map`` takes the bootstrap's minima a block of fine points and a few
replicates at a time. Checked here: on a two-hour Recording with bad samples, read from lazy channels that refuse a
whole read, both readers give the very numbers of the whole-grid path (``gather`` over the whole Recording) with runs
of 5, 37, 300 and 1234.5 s; the map's parameters are those of all points and replicates at once with blocks of 333
or 1,024 fine points and 7 or 16 replicates (to a BLAS kernel's rounding); and the peak traced allocation of the
two readers grows from the Recording laid twice to four times by less than one run's reads plus the warm-up's
coolant readings (the whole-grid path, one run as long as the Recording, grows by some thirty times that and fails
the bound). About 15 s.
"""

from __future__ import annotations

import functools
import tracemalloc
from collections.abc import Iterator

import numpy as np
import pytest
from _synth_a import SPECS
from test_engine_cold_recording import _MAP, _recording

import benchtwin.identification.engine as eng
import benchtwin.identification.engine_cold as ec
from benchtwin.identification._signals import Grid, gather
from benchtwin.recording import Channel, Flag, LazyChannel, Recording

#: the run length the bound is derived for (the shipped one; the whole-grid mutant changes the module's)
RUN_S = ec.RUN_S

_base = functools.cache(_recording)  # its simulation loop once (the copies below copy its arrays)


def _whole_runs(rec: Recording, names: list[str], rate_hz: float, per: int, *, optional: tuple[str, ...] = (),
                what: str = "identification") -> Iterator[Grid]:
    """The whole-grid path: ``gather`` over the whole Recording, one grid."""
    yield gather(rec, names, rate_hz, optional=optional, what=what)


def _copies(copies: int, *, lazy: bool) -> Recording:
    """The cold-start Recording laid end to end ``copies`` times, with bad samples; lazy channels refuse whole reads."""
    base = _base()
    t0 = base["engine_speed_rpm"].timestamps
    period = float(t0[-1] - t0[0]) + 0.1
    out = Recording()
    for name, c in base.channels.items():
        v = c.values.copy()
        fl = np.zeros(v.size, dtype=np.uint16)
        if name == ec.COOLANT_ROLE:
            v[(t0 > 1000.0) & (t0 < 1030.0)] = np.nan  # a coolant dropout: whole warm-up blocks left out
        if name == "fuel_mass_flow_gps":
            fl[(t0 > 4000.0) & (t0 < 4003.0)] = int(Flag.bad())  # flagged fuel samples
        tt = np.concatenate([t0 + k * period for k in range(copies)])
        ch = Channel(name, c.unit, tt, np.tile(v, copies), np.tile(fl, copies), c.source)
        if lazy:
            def whole(ch: Channel = ch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
                raise AssertionError(f"{ch.name} read whole")

            def part(a: int, b: int, ch: Channel = ch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
                return ch.timestamps[a:b].copy(), ch.values[a:b].copy(), ch.flags[a:b].copy()

            ch = LazyChannel(name, c.unit, c.source, len(ch), whole, block_loader=part)
        out.add(ch)
    return out


def test_the_cold_blocks_and_the_warmup_by_runs_are_the_whole_grids(monkeypatch: pytest.MonkeyPatch) -> None:
    with monkeypatch.context() as m:
        m.setattr(ec, "grid_runs", _whole_runs)
        whole_b = ec.cold_blocks(_copies(1, lazy=False), SPECS, _MAP)
        whole_w = ec.fit_warmup(_copies(1, lazy=False), SPECS)
    # the dropout and the flags reach both: fewer blocks than the Recording's 720 and 360
    assert 100 < whole_b["ratio"].size < 700 and np.all(np.isfinite(whole_b["ratio"]))
    assert whole_w.n_points < 358
    for run_s in (5.0, 37.0, 300.0, 1234.5):
        monkeypatch.setattr(ec, "RUN_S", run_s)
        blocks = ec.cold_blocks(_copies(1, lazy=True), SPECS, _MAP)
        for k, v in whole_b.items():
            assert np.array_equal(blocks[k], v), (run_s, k)
        wu = ec.fit_warmup(_copies(1, lazy=True), SPECS)
        assert wu.n_points == whole_w.n_points
        for k, p in whole_w.params.items():
            assert repr(wu.params[k]) == repr(p), (run_s, k)
        assert np.array_equal(wu.data["T_reg_degc"], whole_w.data["T_reg_degc"])


def test_the_bootstrap_by_replicate_blocks_is_all_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(4)
    n = rng.uniform(1000.0, 4000.0, 60)
    t = rng.uniform(20.0, 300.0, 60)
    b = eng.bmep_bar(t, SPECS)
    pmf = 1.2 + 2.4 * b + 0.05 * (b - 8.0) ** 2 + rng.normal(0.0, 0.1, b.size)  # a curved Willans surface, noisy
    f = pmf * 1e5 * SPECS.engine_displacement_m3 / (np.pi * SPECS.engine_strokes) * n * np.pi / 30.0 \
        / SPECS.fuel_lhv_j_per_kg * 1e3
    monkeypatch.setattr(eng, "BOOT_BLOCK", 10**9)
    monkeypatch.setattr(eng, "FINE_BLOCK", 10**9)
    ref = eng.fit_bsfc_map(SPECS, n, t, f, n_boot=100)
    assert ref.params["bsfc_min"].ci95[1] > ref.params["bsfc_min"].ci95[0]  # the replicates differ
    for fine, boot in ((10**9, 7), (1024, 16), (333, 7)):
        monkeypatch.setattr(eng, "BOOT_BLOCK", boot)
        monkeypatch.setattr(eng, "FINE_BLOCK", fine)
        fit = eng.fit_bsfc_map(SPECS, n, t, f, n_boot=100)
        for k, p in ref.params.items():
            _assert_same_estimate(fit.params[k], p, (fine, boot, k))


#: a block's product ``op @ y[:, j:j + b]`` may go through another BLAS kernel than the whole product (the kernel
#: depends on the column count and the CPU), which reorders a 60-term dot product: each element then moves by at
#: most ~60 ulp (|error| <= n eps sum|a_i y_i|, Higham 3.1; the terms are all positive here). 1e-12 is 45 times that
#: bound, and far below any real change (a replicate's minimum taken on another fine point moves bsfc_min ~1e-4).
_RTOL = 1e-12


def _assert_same_estimate(a: object, b: object, where: object) -> None:
    """Every field of two ParameterEstimates equal: floats within ``_RTOL``, everything else exactly."""
    for name, va in vars(a).items():
        vb = getattr(b, name)
        if isinstance(va, float) or (isinstance(va, tuple) and va and isinstance(va[0], float)):
            np.testing.assert_allclose(va, vb, rtol=_RTOL, atol=0.0, err_msg=f"{where} {name}")
        else:
            assert va == vb, (where, name)


def _peak(rec: Recording) -> int:
    """Peak traced bytes of the cold blocks and the warm-up beyond what they return."""
    tracemalloc.start()
    try:
        out = (ec.cold_blocks(rec, SPECS, _MAP), ec.fit_warmup(rec, SPECS))
        current, peak = tracemalloc.get_traced_memory()
        del out
        return peak - current
    finally:
        tracemalloc.stop()


def _check() -> None:
    # two and four copies: each channel then spans several of the time index's read blocks (64 Ki samples; its
    # build holds two), so what differs is what grows with the campaign
    two, four = _copies(2, lazy=True), _copies(4, lazy=True)
    p1, p3 = _peak(two), _peak(four)
    n_ch, seconds = len(two.channels), 7200.0
    # one run: every channel read over RUN_S (+ margins, 10 Hz, timestamp, value, flags: 18 B a sample) and the
    # run's grid (10 Hz, 8 B a channel and the masks); the warm-up keeps its 1 Hz coolant readings (8 B a second,
    # twice while they are joined for their percentile) over the two extra copies
    run_bytes = (RUN_S + 2.0) * 10.0 * n_ch * (18 + 10)
    bound = run_bytes + 2 * 2 * seconds * 8
    assert p3 - p1 < bound, (p1, p3, int(bound))


def test_the_peak_does_not_grow_with_the_campaign() -> None:
    _check()


def test_the_whole_grid_fails_the_same_bound(monkeypatch: pytest.MonkeyPatch) -> None:
    """The bound is tight enough to catch one run as long as the Recording."""
    monkeypatch.setattr(ec, "RUN_S", 1e9)
    monkeypatch.setattr(ec, "GRID_RUN", 10**9)
    with pytest.raises(AssertionError, match=r"\(\d+, \d+, \d+\)"):
        _check()
