"""The coastdown search reads its grid by blocks: the same fit at any block size, memory not growing with the log.

A synthetic coastdown (40 s run-up, neutral coastdown 130 -> 5 km/h, 100 Hz roller speed) laid end to end 2 and 4
times, with and without its segment table. The fit by blocks of a few points up to the whole grid at once gives the
same numbers (the runs are cut where no candidate point is, so every derivative and run test sees whole runs), and
its peak traced allocation grows from 2x to 4x by less than one copy's grid of one channel: what is allowed to grow
is the fit's points (one per 2 s of coastdown, a few floats each: under 1 % of that). Reading the whole grid at once
(one block as long as the Recording, the former path) grows by two copies of every channel gathered on the grid
(five float64 channels and the masks: over 10 times the bound). About 6 s.
"""

from __future__ import annotations

import dataclasses
import tracemalloc

import numpy as np
import pytest
from _synth_a import SPECS, coastdown_plant, to_recording

import benchtwin.identification.road_load as road_load
from benchtwin.identification.road_load import identify_road_load
from benchtwin.recording import Flag, Recording

RATE_HZ = 100.0  #: the roller speed's rate in ``_synth_a`` (the grid's default rate)
WHOLE = 1 << 40  #: a block longer than any Recording: the whole grid (or piece) at once
BLOCK = 4096  #: the block of the memory test; the copies are laid a whole number of blocks apart


@pytest.fixture(scope="module")
def plant(truth):
    return coastdown_plant(truth)


def _repeated(plant, n: int, *, segments: bool = True) -> Recording:
    t, sig, segs = plant
    # a pause of 5 s or more (the speed jumps back up: not a coastdown), every copy at the same place in its blocks
    # (the open run carried from block to block is then as long in each copy)
    period = np.ceil((float(t[-1] - t[0]) + 5.0) * RATE_HZ / BLOCK) * BLOCK / RATE_HZ
    tt = np.concatenate([t + k * period for k in range(n)])
    ss = {k: np.concatenate([v] * n) for k, v in sig.items()}
    seg = [dataclasses.replace(s, start_s=s.start_s + k * period, end_s=s.end_s + k * period, name=f"{s.name}_{k}")
           for k in range(n) for s in segs]
    return to_recording(tt, ss, segments=seg if segments else [])


def _fit(rec: Recording, block: int, monkeypatch, **kw):
    monkeypatch.setattr(road_load, "BLOCK", block)
    return identify_road_load(rec, SPECS, **kw)


@pytest.mark.parametrize("segments", [True, False])
@pytest.mark.parametrize("method", ["regression", "intervals"])
def test_blocks_equal_the_whole_grid(plant, monkeypatch, segments, method) -> None:
    """Blocks of 97, 1000 and 16384 points (runs carried across many blocks, across a few, within one) give the
    whole grid's runs, points and fit to float rounding; a flagged stretch splits a run in both alike."""
    rec = _repeated(plant, 2, segments=segments)
    ch = rec["dyno_speed_kmh"]
    hit = (ch.timestamps > 150) & (ch.timestamps < 152)
    ch.flags[hit] = int(Flag.PROTOCOL_ERROR)
    whole = _fit(rec, WHOLE, monkeypatch, method=method)
    assert whole.data["n_runs"][0] == 3 and whole.n_excluded >= 150
    for block in (97, 1000, 16384):
        got = _fit(rec, block, monkeypatch, method=method)
        assert got.data["n_runs"][0] == 3 and got.n_excluded == whole.n_excluded
        assert got["F0"].segments == whole["F0"].segments
        np.testing.assert_array_equal(got.data["runs_s"], whole.data["runs_s"])
        np.testing.assert_array_equal(got.data["v_kmh"], whole.data["v_kmh"])
        np.testing.assert_allclose(got.data["force_n"], whole.data["force_n"], rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose([got.value(k) for k in ("F0", "F1", "F2")],
                                   [whole.value(k) for k in ("F0", "F1", "F2")], rtol=1e-10)


def _peak(rec: Recording) -> float:
    """Peak traced bytes of the fit beyond what was allocated before it."""
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        identify_road_load(rec, SPECS)
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def test_peak_does_not_grow_with_the_recording(plant, monkeypatch) -> None:
    """No segment table (the whole span is searched): the peak at 4x exceeds the one at 2x by less than one
    copy's grid of one float64 channel."""
    t = plant[0]
    bound = (t[-1] - t[0]) * RATE_HZ * 8.0
    two, four = _repeated(plant, 2, segments=False), _repeated(plant, 4, segments=False)
    monkeypatch.setattr(road_load, "BLOCK", BLOCK)
    identify_road_load(two, SPECS)  # caches (time indexes, imports) built outside the measure
    growth = _peak(four) - _peak(two)
    assert growth < bound, (growth, bound)
