"""The RC extension of the battery fit (``battery.rc``) on synthetic packs with known branches.

The synthetic pack is eq. 30 (the literature maps scaled by alpha and beta) minus two RC branches, integrated
here with the exact response of a branch to a current held over each 0.1 s step, independently of the fit.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from _synth_b import SPECS, battery_recording

from benchtwin.identification.battery import identify_battery, load_literature_maps
from benchtwin.identification.battery_rc import filtered_current, fit_battery_rc
from benchtwin.recording import Channel, Recording
from benchtwin.segments import Segment
from benchtwin.validation._pack_steps import battery_steps, battery_steps_rc, rc_model

#: per cell: R0 scales (alpha, beta_dch, beta_ch), then R1/tau1, R2/tau2 (the shipped hifi file's orders)
TRUTH = {"alpha": 1.008, "beta_discharge": 1.15, "beta_charge": 1.25, "r1_ohm": 6e-4, "tau1_s": 8.0,
         "r2_ohm": 5e-4, "tau2_s": 120.0}
SOC_PER_AH = 4.0
RATE = 10.0


def _branch(t: np.ndarray, i: np.ndarray, tau: float) -> np.ndarray:
    """u/R of one RC branch, state 0 at the start, the current held over each step (exact for a held current)."""
    out = np.zeros_like(i)
    for j in range(1, i.size):
        a = math.exp(-(t[j] - t[j - 1]) / tau)
        out[j] = a * out[j - 1] + (1.0 - a) * i[j]
    return out


def _current(duration_s: float, sign: int, mean_a: float, seed: int) -> np.ndarray:
    """A drive's current: a mean with steps every 20-90 s (traffic, gradients) and a small ripple, one sign."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * RATE)
    i = np.empty(n)
    k = 0
    while k < n:
        m = int(rng.uniform(20.0, 90.0) * RATE)
        i[k:k + m] = mean_a * rng.uniform(0.3, 1.8)
        k += m
    i += 0.1 * mean_a * np.sin(np.arange(n) / RATE * 2 * np.pi / 5.0)
    return sign * np.abs(i)


def rc_recording(truth: dict[str, float], *, noise_v: float, seed: int = 0, temp_rise_k: float = 0.0
                 ) -> tuple[Recording, dict]:
    """A depletion (SOC 95 -> ~20 %) and a charge drive (20 -> ~35 %) of a two-RC pack; the arrays too.

    With ``temp_rise_k`` the pack warms linearly from 23 degC by that much over the two tests, logged as
    ``battery_temp_degc``, and ``R_0 = (beta + beta_temp_per_k (25 - T)) R_lit`` (``truth["beta_temp_per_k"]``).
    """
    maps = load_literature_maps()
    n = SPECS.n_cells_series
    parts = []
    t0, s0 = 0.0, 95.0
    segs = []
    for name, dur, sign, mean, soc0 in (("deplete", 1800.0, 1, 40.0, 95.0), ("charge", 900.0, -1, 15.0, 20.0)):
        i = _current(dur, sign, mean, seed + len(segs))
        t = t0 + np.arange(i.size) / RATE
        s0 = soc0
        q = np.r_[0.0, np.cumsum(-0.5 * (i[1:] + i[:-1]) * np.diff(t))] / 3600.0
        s = s0 + SOC_PER_AH * q
        parts.append((t, i, s))
        segs.append(Segment(float(t[0]), float(t[-1] + 1.0 / RATE), "constant_drive", name, {}))
        t0 = t[-1] + 60.0
    t, i, s = (np.concatenate([p[k] for p in parts]) for k in range(3))
    # the branches start at rest in each test (a minute's pause between them is 7 tau1 but only 0.5 tau2: rest
    # both by starting each test from 0, as the fit's gap rule does)
    x1 = np.concatenate([_branch(p[0], p[1], truth["tau1_s"]) for p in parts])
    x2 = np.concatenate([_branch(p[0], p[1], truth["tau2_s"]) for p in parts])
    temp = 23.0 + temp_rise_k * (t - t[0]) / (t[-1] - t[0])
    k_t = truth.get("beta_temp_per_k", 0.0) * (25.0 - temp)
    r0 = np.where(i > 0, (truth["beta_discharge"] + k_t) * maps.r_discharge(s),
                  (truth["beta_charge"] + k_t) * maps.r_charge(s))
    v_cell = truth["alpha"] * maps.ocv(s) - i * r0 - truth["r1_ohm"] * x1 - truth["r2_ohm"] * x2
    rng = np.random.default_rng(seed + 100)
    v = v_cell * n + noise_v * rng.standard_normal(t.size)
    rec = Recording(segments=segs)
    rec.add(Channel("battery_voltage_v", "V", t, v, source="ivt_battery"))
    rec.add(Channel("battery_current_a", "A", t, i, source="ivt_battery"))
    rec.add(Channel("displayed_soc_pct", "%", t, s, source="vehicle_can"))
    if temp_rise_k:
        rec.add(Channel("battery_temp_degc", "degC", t, temp, source="thermo"))
    return rec, {"t": t, "i": i, "s": s, "x1": x1, "x2": x2, "v": v, "v_cell": v_cell, "temp": temp}


def _theory_se(arr: dict, truth: dict[str, float], noise_v: float) -> dict[str, float]:
    """Standard errors of every parameter for white voltage noise: sigma^2 (J^T J)^-1 with the model's Jacobian at
    the truth (finite differences of this file's own branch integration), per cell."""
    maps = load_literature_maps()
    t, i, s = arr["t"], arr["i"], arr["s"]
    cols = [maps.ocv(s), -i * maps.r_discharge(s) * (i > 0), -i * maps.r_charge(s) * (i < 0), -arr["x1"], -arr["x2"]]
    gap = np.r_[0, np.flatnonzero(np.diff(t) > 1.0) + 1, t.size]
    for k, name in ((0, "tau1_s"), (1, "tau2_s")):
        tau, r = truth[name], truth[f"r{k + 1}_ohm"]
        h = 1e-3 * tau
        d = np.concatenate([(_branch(t[a:b], i[a:b], tau + h) - _branch(t[a:b], i[a:b], tau - h)) / (2 * h)
                            for a, b in itertools.pairwise(gap)])
        cols.append(-r * d)
    J = np.column_stack(cols)
    sigma = noise_v / SPECS.n_cells_series
    se = np.sqrt(np.diag(np.linalg.inv(J.T @ J))) * sigma
    names = ["alpha", "beta_discharge", "beta_charge", "r1_ohm", "r2_ohm", "tau1_s", "tau2_s"]
    return dict(zip(names, se, strict=True))


@pytest.fixture(scope="module")
def noisy():
    rec, arr = rc_recording(TRUTH, noise_v=0.2, seed=1)
    eq30 = identify_battery(rec, SPECS, refine_displayed_soc=False)
    return rec, arr, eq30, fit_battery_rc(eq30, SPECS.n_cells_series)


def test_filtered_current_is_the_exact_branch_response():
    t = np.arange(0.0, 100.0, 0.1)
    i = np.where(t >= 10.0, 50.0, 0.0)
    x = filtered_current(t, i, 8.0)
    # a step of 50 A at t = 10 s: 50 (1 - exp(-(t - t_step) / tau)), the step held from the sample at 10 s
    k = np.searchsorted(t, 10.0 - 1e-9)
    expect = np.where(t >= 10.0, 50.0 * (1.0 - np.exp(-(t - t[k - 1]) / 8.0)), 0.0)
    np.testing.assert_allclose(x, expect, atol=1e-9)


def test_two_branches_recovered_within_the_noise_bound(noisy):
    _rec, arr, eq30, rc = noisy
    assert rc.status == "ok", rc.reasons
    assert int(rc.data["n_branches"]) == 2
    se = _theory_se(arr, TRUTH, 0.2)
    for name, truth in TRUTH.items():
        err = rc.value(name) - truth
        # 4 standard errors of the white-noise theory: a 1-in-15,000 miss per parameter
        assert abs(err) < 4.0 * se[name], (name, rc.value(name), truth, se[name])
        lo, hi = rc.params[name].ci95
        assert lo < truth < hi, (name, lo, truth, hi)
    # the residual is the noise: RMS within its chi-square band (n ~ 27,000: +-4 sigma of sqrt(2/n) relative)
    n = arr["t"].size
    assert abs(rc.rmse / 0.2 - 1.0) < 4.0 * math.sqrt(0.5 / n) + 1e-3
    # eq. 30 alone cannot follow the branches: its residual is many times the noise, its betas absorb R1 + R2
    assert eq30.rmse > 3 * 0.2
    assert eq30.value("beta_discharge") > TRUTH["beta_discharge"] * 1.2


def test_one_branch_is_not_enough(noisy):
    """Mutant 'drop a branch': one RC branch leaves a residual far above the noise and a wrong voltage."""
    _rec, _arr, eq30, _rc = noisy
    one = fit_battery_rc(eq30, SPECS.n_cells_series, n_branches=1)
    n = eq30.n_points
    # the two-branch fit's residual is the noise within 4 sigma of the chi-square band; one branch is far outside
    assert one.rmse / 0.2 - 1.0 > 10 * (4.0 * math.sqrt(0.5 / n) + 1e-3)


def test_the_pack_without_branches_keeps_eq30():
    """On the paper-form pack (no RC branch) the extension finds no branch and the prediction keeps eq. 30."""
    rec, truth = battery_recording(noise_v=0.2, seed=5)
    eq30 = identify_battery(rec, SPECS)
    rc = fit_battery_rc(eq30, SPECS.n_cells_series)
    assert int(rc.data["n_branches"]) == 0
    assert rc.status == "flagged"
    assert rc_model(rc) is None
    np.testing.assert_allclose(rc.value("alpha"), truth["alpha"], rtol=1e-3)


def test_prediction_pack_follows_the_branches(noisy):
    """battery_steps_rc driven by the synthetic pack's power gives back its current and voltage; eq. 30 does not."""
    _rec, arr, _eq30, rc = noisy
    m = rc_model(rc)
    assert m is not None
    sl = slice(0, int(1800 * RATE))  # the depletion test, from rest
    i, v_cell = arr["i"][sl], arr["v_cell"][sl]
    n = SPECS.n_cells_series
    p = v_cell * n * i
    maps = load_literature_maps()
    # the true pack (truth's maps and branches) gives back the current and voltage to rounding
    no_temp = (maps.r_discharge_ohm, maps.r_charge_ohm, 0.0, 25.0, np.zeros(p.size - 1))
    _i, v_t, _s = battery_steps_rc(p[1:], 0.1, float(arr["s"][0]), maps.soc_pct,
                                   TRUTH["alpha"] * maps.ocv_v, TRUTH["beta_discharge"] * maps.r_discharge_ohm,
                                   TRUTH["beta_charge"] * maps.r_charge_ohm, float(n), SOC_PER_AH,
                                   np.array([TRUTH["r1_ohm"], TRUTH["r2_ohm"]]),
                                   np.array([TRUTH["tau1_s"], TRUTH["tau2_s"]]), *no_temp)
    v_true = v_cell[1:] * n
    assert np.sqrt(np.mean((v_t - v_true) ** 2)) < 0.05  # SOC counted per step vs trapezoid: a few mV
    # the identified pack: within the noise-propagated bound of a few tenths of a volt
    _i, v_id, _s = battery_steps_rc(p[1:], 0.1, float(arr["s"][0]), maps.soc_pct, m["ocv"], m["r_dch"], m["r_ch"],
                                    float(n), SOC_PER_AH, m["r_rc"], m["tau_rc"], *no_temp)
    rms_rc = float(np.sqrt(np.mean((v_id - v_true) ** 2)))
    # eq. 30 refitted on the same data (the betas absorb the branches) misses the relaxation
    eq = identify_battery(_rec_of(arr), SPECS, refine_displayed_soc=False)
    _i, v_eq, _s = battery_steps(p[1:], 0.1, float(arr["s"][0]), maps.soc_pct, eq.data["map_ocv"],
                                 eq.data["map_r_dch"], eq.data["map_r_ch"], float(n), SOC_PER_AH)
    rms_eq = float(np.sqrt(np.mean((v_eq - v_true) ** 2)))
    assert rms_rc < 0.2
    assert rms_eq > 4 * rms_rc


def _rec_of(arr: dict) -> Recording:
    rec = Recording(segments=[Segment(float(arr["t"][0]), float(arr["t"][-1]) + 1.0, "constant_drive", "x", {})])
    rec.add(Channel("battery_voltage_v", "V", arr["t"], arr["v"], source="ivt_battery"))
    rec.add(Channel("battery_current_a", "A", arr["t"], arr["i"], source="ivt_battery"))
    rec.add(Channel("displayed_soc_pct", "%", arr["t"], arr["s"], source="vehicle_can"))
    return rec


def test_a_branch_below_the_scatter_is_not_kept():
    """A branch the data resolve (tiny interval) but that moves the pack voltage by ~5 mV against 30 mV of noise
    is not material: no branch is kept (mutant: without the materiality rule a 1-uohm branch is kept)."""
    truth = dict(TRUTH, r1_ohm=1.2e-6, r2_ohm=0.0)
    rec, _arr = rc_recording(truth, noise_v=0.03, seed=7)
    eq30 = identify_battery(rec, SPECS, refine_displayed_soc=False)
    rc = fit_battery_rc(eq30, SPECS.n_cells_series)
    assert int(rc.data["n_branches"]) == 0, rc.reasons
    assert any("not material" in r for r in rc.reasons)


def test_from_a_recording_on_every_sample(noisy):
    """identify_battery_rc takes every usable sample (both tests here) and gives the fit on the eq. 30 samples."""
    rec, _arr, _eq30, rc = noisy
    from benchtwin.identification.battery_rc import identify_battery_rc

    got = identify_battery_rc(rec, SPECS, rate_hz=RATE)
    assert got.n_points == rc.n_points  # the 60 s between the tests holds no sample
    for name in TRUTH:
        np.testing.assert_allclose(got.value(name), rc.value(name), rtol=1e-3, err_msg=name)


def test_temperature_term_recovered_and_used_by_the_prediction():
    """A pack whose R_0 falls 2.5 %/K as it warms 15 K: the term is recovered within its interval, and the prediction
    at the logged temperature follows the voltage where the mean temperature does not (mutant: the prediction
    ignoring the temperature term fails the last assertion)."""
    truth = dict(TRUTH, beta_temp_per_k=0.025 * TRUTH["beta_discharge"])
    rec, arr = rc_recording(truth, noise_v=0.2, seed=11, temp_rise_k=15.0)
    from benchtwin.identification.battery_rc import identify_battery_rc

    rc = identify_battery_rc(rec, SPECS, rate_hz=RATE)
    p = rc.params["beta_temp_per_k"]
    assert p.ci95[0] < truth["beta_temp_per_k"] < p.ci95[1], (p.value, p.ci95)
    assert abs(rc.value("beta_discharge") / truth["beta_discharge"] - 1.0) < 0.02
    m = rc_model(rc)
    n = SPECS.n_cells_series
    sl = slice(0, int(1800 * RATE))
    pw = arr["v_cell"][sl] * n * arr["i"][sl]
    maps = load_literature_maps()
    args = (pw[1:], 0.1, float(arr["s"][0]), maps.soc_pct, m["ocv"], m["r_dch"], m["r_ch"], float(n), SOC_PER_AH,
            m["r_rc"], m["tau_rc"], m["r_lit_dch"], m["r_lit_ch"], m["beta_temp_per_k"], m["t_ref_degc"])
    _i, v_logged, _s = battery_steps_rc(*args, arr["temp"][sl][1:])
    _i, v_mean, _s = battery_steps_rc(*args, np.full(pw.size - 1, m["temp_mean_degc"]))
    v_true = arr["v_cell"][sl][1:] * n
    rms_logged = float(np.sqrt(np.mean((v_logged - v_true) ** 2)))
    rms_mean = float(np.sqrt(np.mean((v_mean - v_true) ** 2)))
    assert rms_logged < 0.2
    assert rms_mean > 2 * rms_logged


def test_branch_filter_reused_over_taus_equals_the_one_shot_filter():
    """The search's filter keeps the grid's step, cuts and zero-started blocks across time constants; every value
    must be the one-shot ``_filtered_blocks``'s, bit for bit (uniform grid with gaps; a non-uniform grid falls back
    to the exact loop), for taus in any order (a value cached from the previous tau would differ)."""
    from benchtwin.identification.battery_rc import _BranchFilter, _filtered_blocks

    rng = np.random.default_rng(3)
    t = np.arange(0.0, 600.0, 0.1)
    t = np.r_[t[:2000], t[2100:4000] + 0.0, t[4500:]]  # two gaps longer than 1 s: three blocks
    i = rng.normal(0.0, 40.0, t.size)
    uneven = np.cumsum(rng.uniform(0.05, 0.2, 3000))
    i2 = rng.normal(0.0, 40.0, uneven.size)
    for tt, ii in ((t, i), (uneven, i2)):
        f = _BranchFilter(tt, ii)
        for tau in (8.0, 400.0, 1.5, 8.0, 39.99):
            np.testing.assert_array_equal(f(tau), _filtered_blocks(tt, ii, tau))
    assert _BranchFilter(t, i).h is not None and len(_BranchFilter(t, i).blocks) == 3
    assert _BranchFilter(uneven, i2).h is None


def test_the_rc_fit_is_handed_eq30s_samples_only(noisy, monkeypatch):
    """identify_battery_rc keeps of the eq. 30 fit only the four sample arrays the RC fit reads: its design matrix,
    fitted values and maps (a campaign's rows each) are not alive beside the RC search, and the fit is the one on the
    whole eq. 30 result, bit for bit (mutant: eq. 30's data kept whole)."""
    import benchtwin.identification.battery_rc as battery_rc

    rec = noisy[0]
    seen = {}
    real = battery_rc.fit_battery_rc

    def spy(eq30, n_cells, **kw):
        seen["keys"] = set(eq30.data)
        return real(eq30, n_cells, **kw)

    monkeypatch.setattr(battery_rc, "fit_battery_rc", spy)
    got = battery_rc.identify_battery_rc(rec, SPECS, rate_hz=RATE)
    assert seen["keys"] == {"t", "v_meas", "current", "soc"}
    whole = identify_battery(rec, SPECS, rate_hz=RATE, segment_kinds=None)
    assert len(whole.data) > len(seen["keys"])
    want = real(whole, SPECS.n_cells_series)
    assert {k: (p.value, p.std_error, p.ci95) for k, p in got.params.items()} == \
        {k: (p.value, p.std_error, p.ci95) for k, p in want.params.items()}
    for k, a in want.data.items():
        np.testing.assert_array_equal(got.data[k], a, err_msg=k)
