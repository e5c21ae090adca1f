"""Honest intervals: the truth lies inside the reported 95 % total interval, and intervals widen with noise.

The quick campaign goes once through the ideal chain (plant -> sensors -> wire formats -> acquisition);
what remains of the bench is each wire's resolution. Each example then gives that Recording the paper
bench's imperfections as the GUM models them: every declared gain and offset error drawn uniformly
within its data-sheet half-width (one draw per declaration: the five pressure transducers share one,
as in the emulator) and white noise of the declared standard deviation; the Recording declares the
paper bench's budget. Identification (transmission, motor, road load, brakes, battery) must then report
intervals that hold the truth.

Why the number of examples (binomial): if each interval held the truth with probability 0.95,
independently, a family of n intervals would show fewer than 90 % inside with probability
``binom.cdf(ceil(0.9 n) - 1, n, 0.95)``: 0.018 for n = 80, 0.0072 for n = 120, 0.0012 for n = 200
(computed in :func:`test_false_failure_probability_is_small`). With 40 examples the families hold 80
(motor: the generating Willans line; the motoring fit is flagged on the quick campaign) to 160
(transmission drive: gears 4 and 5) intervals; coast fits 40-80. The type B terms are rectangular
half-widths times ``k / sqrt(3) = 1.13``, so an interval dominated by them holds the truth with a
probability near 1, which keeps the real false-failure chance far below those figures. A mutant that
drops the type B term leaves the statistical interval, which misses the drawn gain errors most of the
time (the test asserts that too, so it shows its power).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import binom

from benchtwin.chain.acquisition import declared_uncertainty
from benchtwin.config import load_vehicle, scenario_path
from benchtwin.config.setup import SetupConfig, load_setup
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.emulator import simulate_campaign
from benchtwin.identification._fit import linear_fit
from benchtwin.identification.run import identify_all
from benchtwin.recording import Recording
from benchtwin.sensors.registry import devices
from benchtwin.validation.coverage import interval_coverage, shift_line_coverage
from benchtwin.validation.families import FAMILIES
from benchtwin.validation.run import validate

#: families with scalar truths that the quick campaign's ideal Recording identifies
METHODS = ["transmission", "motor", "road_load", "brakes", "battery"]
#: examples of the coverage test (see the module docstring for the binomial)
N_EXAMPLES = 40
#: required share of intervals holding the truth, per family
MIN_COVERAGE = 0.90


@pytest.fixture(scope="module")
def bench(quick_ideal_9at: tuple) -> tuple:
    """(vehicle, ideal Recording of the quick campaign, the paper bench's budget, its noise per role).

    The Recording is tests/conftest.py's ``quick_ideal_9at`` (the shipped vehicle, seed 1), shared with the
    identification tests; it is only read here (:func:`imperfect` builds new channels).
    """
    vehicle, rec = quick_ideal_9at
    paper = load_setup(scenario_path("setups", "paper.toml"))
    budget = declared_uncertainty(devices(paper), set(rec.channels))
    for role, d in rec.meta["declared_uncertainty"].items():  # the ideal wire's steps stay in the Recording
        if role in budget:
            budget[role]["resolution"] = max(budget[role]["resolution"], d["resolution"])
        else:
            budget[role] = dict(d)
    noise = {role: err.noise_std for d in devices(paper) for role, (err, _l, _x) in d.error_budget().items()
             if err is not None and err.noise_std > 0 and role in rec}
    return vehicle, rec, budget, noise


def imperfect(rec: Recording, budget: dict, noise: dict[str, float], seed: int, noise_scale: float = 1.0,
              systematic: bool = True) -> Recording:
    """The Recording with drawn gain and offset errors (one per declaration) and scaled white noise."""
    rng = np.random.default_rng(seed)
    draws: dict[str, tuple[float, float]] = {}
    channels = dict(rec.channels)
    for role in sorted(budget):
        if role not in rec:
            continue
        d = budget[role]
        key = d.get("group") or role
        if key not in draws:
            draws[key] = (rng.uniform(-1, 1) * d["gain_frac"], rng.uniform(-1, 1) * d["offset"])
        gain, offset = draws[key] if systematic else (0.0, 0.0)
        ch = rec.channels[role]
        z = np.random.default_rng([seed, len(role), sum(map(ord, role))]).standard_normal(len(ch))
        values = ch.values * (1.0 + gain) + offset + noise_scale * noise.get(role, 0.0) * z
        channels[role] = replace(ch, values=values)
    meta = dict(rec.meta)
    meta["declared_uncertainty"] = budget
    return Recording(channels=channels, segments=rec.segments, meta=meta, start_time=rec.start_time)


def test_false_failure_probability_is_small() -> None:
    """The binomial behind N_EXAMPLES: a family of n >= 80 exactly-95 % intervals fails < 2 % of the time."""
    for n, bound in ((80, 0.02), (120, 0.008), (160, 0.003)):
        assert binom.cdf(math.ceil(MIN_COVERAGE * n) - 1, n, 0.95) < bound


@pytest.mark.slow
def test_total_interval_covers_truth_per_family(bench) -> None:
    vehicle, rec, budget, noise = bench
    inside_total: dict[str, list[bool]] = defaultdict(list)
    inside_stat: dict[str, list[bool]] = defaultdict(list)
    for seed in range(N_EXAMPLES):
        res = identify_all(imperfect(rec, budget, noise, seed), vehicle.specs, methods=METHODS)
        assert res.meta["type_b"]["declared"] and not res.meta["type_b"]["failed"]
        for row in interval_coverage(res, vehicle):
            inside_total[row.family].append(row.inside_total)
            inside_stat[row.family].append(row.inside_stat)
    cover = {f: float(np.mean(v)) for f, v in inside_total.items()}
    stat = {f: float(np.mean(v)) for f, v in inside_stat.items()}
    counts = {f: len(v) for f, v in inside_total.items()}
    assert set(cover) >= {"transmission.drive", "transmission.coast", "motor", "road_load", "brakes", "battery"}, counts
    low = {f: c for f, c in cover.items() if c < MIN_COVERAGE}
    assert not low, f"total-interval coverage below {MIN_COVERAGE:.0%}: {low} (n: {counts}; statistical: {stat})"
    # the statistical interval alone is not honest here: the test can fail a budget without type B
    assert min(stat.values()) < MIN_COVERAGE, stat


@settings(max_examples=40, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1), sigma=st.floats(0.01, 1.0), ratio=st.floats(1.5, 20.0),
       u_b=st.floats(0.0, 0.5), serial=st.booleans())
def test_intervals_widen_as_noise_grows(seed: int, sigma: float, ratio: float, u_b: float, serial: bool) -> None:
    """The same noise draws scaled up (common random numbers) through the shared least squares: the
    statistical interval widens in proportion to the noise (its residuals scale exactly), and the total
    interval, with the same type B term, widens too and always holds the statistical one."""
    rng = np.random.default_rng(seed)
    x = np.linspace(20.0, 400.0, 200)
    eps = rng.standard_normal(x.size)
    A = np.column_stack([np.ones_like(x), x])
    widths = []
    for s in (sigma, sigma * ratio):
        fit = linear_fit(A, 3.0 + 0.97 * x + s * eps, ["C0", "eta"], serial=serial)
        for p in fit.params.values():
            p.combine_type_b({"declared": u_b * {"C0": 3.0, "eta": 0.97}[p.name] * 0.01})
            assert p.ci95_total[0] <= p.ci95[0] and p.ci95_total[1] >= p.ci95[1] and p.u_total >= p.std_error
        widths.append([(p.ci95[1] - p.ci95[0], p.ci95_total[1] - p.ci95_total[0]) for p in fit.params.values()])
    for (w_stat0, w_tot0), (w_stat1, w_tot1) in zip(*widths, strict=True):
        assert w_stat1 == pytest.approx(ratio * w_stat0, rel=1e-6)
        assert w_tot1 > w_tot0


#: plant seeds of the shift-line coverage test: 20 campaigns x 16 lines x (c0, c1) = 640 intervals
SHIFT_SEEDS = range(1000, 1020)


def shift_lines_over_seeds(vehicle: VehicleConfig, setup: SetupConfig, seeds: Iterable[int]) -> dict[str, list]:
    """``up.c0_kmh`` ... ``down.c1_kmh_per_pct`` -> the :class:`CoverageRow` of every line and seed.

    Each seed is its own campaign of the shifts family (the paper campaign's accelerations, decelerations and
    ramp-downs, :func:`strategies.campaign_for`), simulated, measured and identified with the type B budget. The
    truth is what validation compares the lines with: the vehicle file's ``v0 + slope * pedal`` of each pair.
    """
    from strategies import campaign_for

    out: dict[str, list] = defaultdict(list)
    for seed in seeds:
        campaign = campaign_for(vehicle, FAMILIES["shifts"].kinds, seed=seed)
        res = validate(vehicle, setup, campaign, trace=simulate_campaign(vehicle, campaign), families=["shifts"],
                       type_b=True, chain_checks=False).identification
        assert res.meta["type_b"]["declared"] and not res.meta["type_b"]["failed"]
        rows = shift_line_coverage(res, vehicle)
        assert len(rows) == 4 * (vehicle.n_gears - 1), len(rows)  # every line of the paper campaign identified
        for r in rows:
            out[f"{r.key.split('.')[1].split('_')[0]}.{r.key.rsplit('.', 1)[1]}"].append(r)
    return out


@pytest.mark.slow
def test_shift_line_total_interval_covers_truth() -> None:
    """The shift lines' total intervals hold the truth for >= 90 % of the family's 640 intervals (20 campaigns).

    Not the binomial of the module docstring: a line's miss repeats from seed to seed (the event times' bias,
    RESULTS "Coverage of the engine, converter and shift intervals"), so the 640 are not independent; measured
    2026-11-25 at 600/640 (94 %) total, 280/640 (44 %) statistical. The statistical interval alone fails the
    same bound, so dropping the type B term fails this test."""
    vehicle = load_vehicle(scenario_path("vehicles", "p2_phev_9at.toml"))
    cov = shift_lines_over_seeds(vehicle, load_setup(scenario_path("setups", "paper.toml")), SHIFT_SEEDS)
    total = [r.inside_total for v in cov.values() for r in v]
    stat = [r.inside_stat for v in cov.values() for r in v]
    assert len(total) == 2 * 2 * (vehicle.n_gears - 1) * len(SHIFT_SEEDS)
    per_param = {k: f"{sum(r.inside_total for r in v)}/{len(v)}" for k, v in cov.items()}
    assert np.mean(total) >= MIN_COVERAGE, per_param
    assert np.mean(stat) < MIN_COVERAGE, per_param
