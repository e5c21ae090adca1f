"""The fast type B propagation (shared rounding levels, two threads, reused resampling) gives the budget of the
plain re-runs exactly, on the quick campaign through the paper bench (about 10 s on 2 cores); so does the one of a
Recording read by blocks from the acquisition's chunk files, on two threads and on one (about 15 s more)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchtwin.identification import _reuse, uncertainty
from benchtwin.identification.run import DEFAULT_METHODS, METHODS, _reads, _rerun, identify_all
from benchtwin.identification.uncertainty import RESOLUTION_DRAWS, RESOLUTION_SEED, Component, components
from benchtwin.recording import Recording


@pytest.fixture(scope="module")
def quick_paper():
    from benchtwin.chain.batch import run_batch
    from benchtwin.config._base import scenario_path
    from benchtwin.config.campaign import load_campaign
    from benchtwin.config.setup import load_setup
    from benchtwin.config.vehicle import load_vehicle
    from benchtwin.emulator import simulate_campaign

    vehicle = load_vehicle(scenario_path("vehicles", "p2_phev_9at.toml"))
    trace = simulate_campaign(vehicle, load_campaign(scenario_path("campaigns", "quick.toml")))
    return vehicle, run_batch(trace, load_setup(scenario_path("setups", "paper.toml")), seed=1), trace


def _plain_dither(rec: Recording, comp: Component, rng: np.random.Generator) -> Recording:
    """One rounding draw written out plainly (every draw on its own, as the module docstring describes it)."""
    channels = dict(rec.channels)
    for role, q in zip(comp.roles, comp.steps, strict=True):
        ch = rec.channels[role]
        fin = ch.good
        if not fin.any():
            continue
        lo = float(ch.values[fin].min())
        idx = np.floor((ch.values[fin] - lo) / (uncertainty.BIN_STEPS * q) + rng.uniform(0.0, 1.0)).astype(np.int64)
        errors = rng.uniform(-0.5 * q, 0.5 * q, int(idx.max()) + 1)
        moved = ch.values.copy()
        moved[fin] += errors[idx]
        channels[role] = ch.with_values(moved)
    return Recording(channels=channels, segments=rec.segments, meta=rec.meta, start_time=rec.start_time)


def _plain_budget(rec: Recording, specs, nominal) -> dict[str, dict[str, float]]:
    """Parameter -> source -> contribution, by re-running each method once per component, one after the other."""
    out: dict[str, dict[str, float]] = {}
    for m in METHODS:
        if m.name not in DEFAULT_METHODS or m.name not in nominal.meta["ran"]:
            continue
        params = {f"{fk}.{pk}": p for fk, fit in nominal.fits.items()
                  if fk == m.name or fk.startswith(m.name + ".") for pk, p in fit.params.items()}
        run = _rerun(m.name, specs, {})
        for comp in components(rec, _reads(m.name)):
            rng = np.random.default_rng(RESOLUTION_SEED)
            deltas: dict[str, list[float]] = {}
            for _ in range(RESOLUTION_DRAWS if comp.kind == "resolution" else 1):
                if comp.kind == "resolution":
                    moved = _plain_dither(rec, comp, rng)
                else:
                    moved = uncertainty.perturbed(rec, comp)
                other = run(moved).parameters()
                for key, p in params.items():
                    q = other.get(key)
                    if q is not None and math.isfinite(q.value) and math.isfinite(p.value):
                        deltas.setdefault(key, []).append(q.value - p.value)
            for key, d in deltas.items():
                out.setdefault(key, {})[comp.source] = float(np.sqrt(np.mean(np.square(d))))
    return out


def test_fast_type_b_equals_the_plain_reruns(quick_paper, monkeypatch) -> None:
    vehicle, rec, _ = quick_paper
    monkeypatch.setattr(uncertainty, "WORKERS", 2)  # the threaded path, also on a one-core runner
    fast = identify_all(rec, vehicle.specs, type_b=True)
    assert fast.meta["type_b"]["failed"] == []
    nominal = identify_all(rec, vehicle.specs, type_b=False)
    plain = _plain_budget(rec, vehicle.specs, nominal)
    # the converter's own calibration components come with the estimates and are kept beside the declared ones
    own = {key: p.type_b for key, p in nominal.parameters().items() if p.type_b}
    assert own and all(k.startswith("torque_converter.") for k in own)
    got = {key: p.type_b for key, p in fast.parameters().items() if p.type_b}
    assert len(plain) > 40 and any("resolution" in b for b in plain.values())
    assert got == {key: {**own.get(key, {}), **plain.get(key, {})} for key in plain.keys() | own.keys()}  # exactly
    # one thread gives the same budgets and total intervals (repr: exact, and NaN equals NaN)
    monkeypatch.setattr(uncertainty, "WORKERS", 1)
    one = identify_all(rec, vehicle.specs, type_b=True)
    assert repr({k: (p.type_b, p.ci95_total) for k, p in one.parameters().items()}) == \
        repr({k: (p.type_b, p.ci95_total) for k, p in fast.parameters().items()})


def test_type_b_of_a_recording_read_by_blocks_is_the_same_on_two_threads_and_one(quick_paper, monkeypatch) -> None:
    """The chunk-file Recording ``validate --out`` identifies: its re-runs, method by method on two threads sharing
    what the unmoved channels give (``_reuse``), give every budget of the one-thread re-runs and of the in-memory
    Recording exactly, and leave no channel in memory."""
    from benchtwin.chain.stream import run_chunked, trace_pieces
    from benchtwin.config._base import scenario_path
    from benchtwin.config.setup import load_setup
    from benchtwin.recording import LazyChannel

    vehicle, in_memory, trace = quick_paper
    rec = run_chunked(trace_pieces(trace), load_setup(scenario_path("setups", "paper.toml")), seed=1,
                      keep_chunks=True)
    with rec:
        assert all(isinstance(c, LazyChannel) for c in rec.channels.values())
        runs = {}
        # the store's bound biting (64 KB: a few blocks' results kept, the rest computed again) changes nothing
        for workers, bound in ((2, _reuse.STORE_BYTES), (1, _reuse.STORE_BYTES), ("2, bounded", 64 * 2**10)):
            monkeypatch.setattr(uncertainty, "WORKERS", 2 if workers == "2, bounded" else workers)
            monkeypatch.setattr(_reuse, "STORE_BYTES", bound)
            res = identify_all(rec, vehicle.specs, type_b=True)
            assert res.meta["type_b"]["failed"] == [] and res.meta["type_b"]["reruns"] > 60
            assert rec.loaded() == set()  # each method's channels went before the next's
            runs[workers] = repr({k: (p.value, p.type_b, p.ci95_total) for k, p in res.parameters().items()})
        assert "resolution" in runs[2] and runs[2] == runs[1] == runs["2, bounded"]
    # and the same as the in-memory Recording's (the batch chain's: the same samples)
    monkeypatch.setattr(uncertainty, "WORKERS", 2)
    res = identify_all(in_memory, vehicle.specs, type_b=True)
    assert repr({k: (p.value, p.type_b, p.ci95_total) for k, p in res.parameters().items()}) == runs[2]
