"""The rounding draws as units of their own on the threads: each draw the one ``dithered`` makes in turn from the
seeded generator, and the draws' changes put together in the draws' order (not in the order the threads end)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate
from benchtwin.identification._rounding import dithered, dithered_with, drawn
from benchtwin.identification.uncertainty import RESOLUTION_SEED, _run_units, components, splits
from benchtwin.recording import Channel, Recording

BUDGET = {"x": {"gain_frac": 0.01, "offset": 0.0, "resolution": 0.05},
          "y": {"gain_frac": 0.0, "offset": 0.0, "resolution": 0.2}}


def _rec() -> Recording:
    t = np.arange(2000) * 0.01
    x = 10.0 + np.sin(t) + 0.003 * np.cos(7.0 * t)
    y = 3.0 + 0.5 * np.sin(0.3 * t)
    rec = Recording({"x": Channel("x", "Nm", t, x), "y": Channel("y", "Nm", t, y)})
    rec.meta["declared_uncertainty"] = BUDGET
    return rec


def _toy(rec: Recording) -> IdentificationResult:
    """theta: a nonlinear function of both channels (each draw gives another value)."""
    v = float(np.mean(rec["x"].values ** 2)) - float(np.mean(np.sqrt(rec["y"].values)))
    fit = FitResult({"theta": ParameterEstimate("theta", v, 0.01, (v - 0.02, v + 0.02), 1.0, 2000)}, 1.0, 1.0, 0.0,
                    2000)
    return IdentificationResult(fits={"toy": fit})


def test_a_draw_made_ahead_is_the_draw_dithered_makes_in_turn() -> None:
    rec = _rec()
    comp = next(c for c in components(rec, ["x", "y"]) if c.kind == "resolution")
    rng_a, rng_b = np.random.default_rng(5), np.random.default_rng(5)
    shared: dict = {}
    ahead = [drawn(rec, comp, rng_b, shared) for _ in range(3)]
    for draw in ahead:
        want = dithered(rec, comp, rng_a)
        got = dithered_with(rec, comp, shared, draw)
        for role in ("x", "y"):
            np.testing.assert_array_equal(got[role].values, want[role].values)
            assert not np.array_equal(got[role].values, rec[role].values)


def test_the_draws_on_two_threads_are_put_together_in_the_draws_order() -> None:
    rec = _rec()
    nominal = _toy(rec)
    params = {"toy.theta": nominal.fits["toy"].params["theta"]}
    tasks = [(["toy"], params, comp, _toy, splits(nominal.fits, ["toy"])) for comp in components(rec, ["x", "y"])]
    res_comp = next(c for c in components(rec, ["x", "y"]) if c.kind == "resolution")
    rng = np.random.default_rng(RESOLUTION_SEED)
    theta0 = params["toy.theta"].value
    want = [_toy(dithered(rec, res_comp, rng)).fits["toy"].params["theta"].value - theta0 for _ in range(6)]
    assert len(set(want)) == 6  # every draw its own change: a reordering shows
    with ThreadPoolExecutor(max_workers=2) as pool:
        done = _run_units(pool, rec, tasks, 6)
    kinds = [t[2].kind for t in tasks]
    deltas, reruns, failed, notes = done[kinds.index("resolution")]
    assert deltas["toy.theta"] == want and reruns == 6 and failed == [] and notes == []
    gain = done[kinds.index("gain")][0]["toy.theta"]
    assert len(gain) == 1 and gain[0] != 0.0  # the gain's unit is its own, in the tasks' order
