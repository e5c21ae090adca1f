"""``benchtwin plan``: predicted standard errors against the spread over seeds, excitation flags, the command."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from benchtwin.cli import main
from benchtwin.config import load_campaign, load_setup, load_vehicle, scenario_path
from benchtwin.emulator.cache import cached_campaign
from benchtwin.recording import Channel, Flag, Recording
from benchtwin.sensors.base import TruthChannel
from benchtwin.studies.plan import plan_campaign
from benchtwin.studies.plan_noise import (
    poll_faults,
    reading_variance,
    sandwich_covariance,
    truth_recording,
    window_mean_variance,
)
from benchtwin.trace import Trace
from benchtwin.validation.run import validate


@pytest.mark.parametrize("sigma, q", [(0.3, 0.1), (1.0, 1.0), (0.05, 0.0)])
def test_reading_variance_of_a_fine_step_is_noise_plus_sheppard(sigma: float, q: float) -> None:
    y = np.linspace(-3.0, 3.0, 7)
    assert np.allclose(reading_variance(sigma, q, y), sigma**2 + q**2 / 12.0)
    assert reading_variance(0.0, q, y).tolist() == [0.0] * 7


def test_reading_variance_of_a_coarse_step_matches_monte_carlo() -> None:
    sigma, q, n = 0.3, 2.1, 400_000
    rng = np.random.default_rng(1)
    noise = rng.normal(0.0, sigma, n)
    for y in (0.0, 0.6, 1.0, 13.7):
        r = q * np.rint((y + noise) / q)
        d2 = (r - r.mean()) ** 2
        mc, se = float(d2.mean()), float(d2.std() / math.sqrt(n))  # the sample variance and its standard error
        assert abs(float(reading_variance(sigma, q, np.array([y]))[0]) - mc) < 5 * se + 1e-9
    # averaged over the position in the step, sigma << q gives q sigma / sqrt(pi) (two steps straddle the noise)
    assert reading_variance(0.05, 2.1) == pytest.approx(2.1 * 0.05 / math.sqrt(math.pi), rel=0.02)


def test_reading_variance_is_the_two_cdfs_per_step_form_bit_for_bit() -> None:
    # one normal CDF per step edge (an inner edge is the upper edge of one step and the lower of the next) must give
    # the very floats of two CDFs per step (stats.norm.cdf), the form the plans were recorded with
    from scipy import stats

    sigma, q = 0.2, 0.25
    y = np.append(np.random.default_rng(3).normal(0.0, 40.0, 5000), [0.0, -0.0, q / 2, -q / 2, 1e6])
    k = np.arange(-int(6 * sigma / q) - 2, int(6 * sigma / q) + 3)
    d = (y / q - np.rint(y / q))[:, None]
    p = stats.norm.cdf((k + 0.5 - d) * q / sigma) - stats.norm.cdf((k - 0.5 - d) * q / sigma)
    ref = np.clip(p @ (k * q) ** 2 - (p @ (k * q)) ** 2, 0.0, None)
    assert np.array_equal(reading_variance(sigma, q, y), ref)


def test_sandwich_with_equal_rows_is_the_textbook_covariance() -> None:
    A = np.column_stack([np.ones(5), np.arange(5.0)])
    s2 = np.full(5, 0.04)
    assert np.allclose(sandwich_covariance(A, None, s2), 0.04 * np.linalg.inv(A.T @ A))
    # weights equal to the inverse variances give (A' W A)^-1
    s2 = np.array([1.0, 2.0, 4.0, 1.0, 0.5])
    assert np.allclose(sandwich_covariance(A, 1.0 / s2, s2), np.linalg.inv(A.T @ (A / s2[:, None])))


def test_failing_polls_are_known_per_role() -> None:
    """The paper bench's pressure module fails a poll with 0.0005 + 0.0002 (its setup file); the ideal bench never."""
    paper = poll_faults(load_setup(scenario_path("setups", "paper.toml")))
    assert paper["brake_pressure_rl_bar"] == pytest.approx(0.0007) and "shaft_torque_nm" not in paper
    assert poll_faults(load_setup(scenario_path("setups", "ideal.toml"))) == {}


def test_truth_recording_keeps_the_bench_clock_and_flags() -> None:
    trace = Trace(np.arange(0.0, 10.0, 0.01), {"shaft_torque_nm": np.arange(0.0, 10.0, 0.01) * 3.0,
                                               "gear": np.repeat([1.0, 2.0], 500)})
    ts = np.array([0.005, 2.0, 7.5])
    flags = np.array([0, int(Flag.SATURATED), 0], dtype=np.uint16)
    rec = Recording()
    rec.add(Channel("shaft_torque_nm", "Nm", ts, np.array([9.0, 9.0, 9.0]), flags, "telemetry"))
    rec.add(Channel("gear_actual", "", ts, np.zeros(3), None, "vehicle"))
    rec.add(Channel("other", "", ts, np.ones(3), None, "x"))
    truth = {"shaft_torque_nm": TruthChannel("shaft_torque_nm", 1.0, False, 2.1),
             "gear_actual": TruthChannel("gear", 1.0, True, 1.0)}
    out = truth_recording(rec, trace, truth)
    assert np.allclose(out["shaft_torque_nm"].values, ts * 3.0)  # interpolated truth at the bench's timestamps
    assert out["gear_actual"].values.tolist() == [1.0, 1.0, 2.0]  # states held, not interpolated
    assert out["shaft_torque_nm"].flags.tolist() == flags.tolist() and out["other"].values.tolist() == [1.0] * 3


def test_window_mean_variance_counts_only_good_readings() -> None:
    ts = np.arange(10.0)
    flags = np.zeros(10, dtype=np.uint16)
    flags[3] = int(Flag.SATURATED)
    rec = Recording()
    rec.add(Channel("x", "", ts, np.zeros(10), flags, "s"))
    var = np.arange(1.0, 11.0)
    got = window_mean_variance(rec, "x", var, np.array([0.0, 5.0]), np.array([5.0, 10.0]))
    # window [0, 5): readings 0, 1, 2, 4 (3 flagged): (1 + 2 + 3 + 5) / 4^2; window [5, 10): (6 + ... + 10) / 5^2
    assert got.tolist() == pytest.approx([11.0 / 16.0, 40.0 / 25.0])


@pytest.mark.slow
def test_predicted_battery_errors_agree_with_the_spread_over_seeds() -> None:
    """The planned standard error of each eq. 30 parameter against the std of its estimates over 40 seeds.

    The seeds vary the sensor noise on one plant run (the fixed quick-campaign Trace), which is what the
    plan predicts. With N = 40 estimates the sample std ``s`` of a normal estimate has
    ``(N-1) s^2 / sigma^2 ~ chi2(39)``: its two-sided 99 % interval is ``s / sigma`` in [0.716, 1.296]
    (``sqrt(chi2.ppf(0.005, 39) / 39)``, ``sqrt(chi2.ppf(0.995, 39) / 39)``), inside the factor 1.5 checked
    (a correct prediction leaves it with a probability of 0.1 % per parameter).
    """
    n = 40
    lo, hi = (math.sqrt(stats.chi2.ppf(a, n - 1) / (n - 1)) for a in (0.005, 0.995))
    assert lo > 1 / 1.5 and hi < 1.5
    vehicle, setup, campaign = load_vehicle(), load_setup(scenario_path("setups", "paper.toml")), \
        load_campaign("quick.toml")
    trace, _ = cached_campaign(vehicle, campaign)
    plan = plan_campaign(vehicle, setup, campaign, trace=trace, families=["battery"])
    names = ["alpha", "beta_discharge", "beta_charge"]
    est = {k: [] for k in names}
    for seed in range(1000, 1000 + n):
        rep = validate(vehicle, setup, campaign.model_copy(update={"seed": seed}), trace=trace, families=["battery"])
        fit = rep.identification.fits["battery"]
        for k in names:
            est[k].append(fit.value(k))
    for k in names:
        p = plan.get(f"battery.{k}")
        assert p.identifiable and p.se > 0
        ratio = float(np.std(est[k], ddof=1)) / p.se
        assert 1 / 1.5 < ratio < 1.5, (k, ratio, p.se)


def _campaign_without(tmp_path: Path) -> Path:
    """The quick campaign's two ramp-ups only, the gear-4 one without its brake steps (no coast points)."""
    text = scenario_path("campaigns", "quick.toml").read_text(encoding="utf-8")
    head, *tests = text.split("[[tests]]")
    keep = [t.replace("brake_steps_pct = [5.0, 10.0]\n", "") for t in tests if 'kind = "ramp_up"' in t]
    assert len(keep) == 2 and all("brake_steps_pct" not in t for t in keep)
    path = tmp_path / "no_coast.toml"
    path.write_text(head.replace('name = "quick"', 'name = "no_coast"') + "".join("[[tests]]" + t for t in keep),
                    encoding="utf-8")
    return path


def test_a_gear_without_coast_points_is_flagged_with_the_test_to_add(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("BENCHTWIN_CACHE", str(tmp_path / "cache"))
    path = _campaign_without(tmp_path)
    assert main(["plan", "--setup", "paper", "--campaign", str(path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    rows = {p["name"]: p for p in doc["parameters"]}
    for name in ("transmission.gear4_coast.eta_m", "transmission.gear4_coast.C0"):
        assert rows[name]["identifiable"] is False and rows[name]["se"] is None
        assert "coast points in gear 4" in rows[name]["reason"]
        assert rows[name]["suggestion"] == "add brake_steps_pct = [5.0, 10.0, 20.0] to the ramp_up test in gear 4"
    # the drive side of gear 4 and gear 5 stay identifiable, with a finite predicted error
    for name in ("transmission.gear4.eta_m", "transmission.gear5.C0"):
        assert rows[name]["identifiable"] is True and rows[name]["se"] > 0
    # no constant drive: the battery is not excited; no acceleration: no upshift line
    assert rows["battery.alpha"]["identifiable"] is False and "constant_drive" in rows["battery.alpha"]["suggestion"]
    assert rows["shifts.up_1_2.*"]["identifiable"] is False and "acceleration" in rows["shifts.up_1_2.*"]["suggestion"]
    # no brake steps anywhere: the motor's generating region is never visited
    assert rows["motor.generating.*"]["identifiable"] is False
    assert "brake_steps_pct" in rows["motor.generating.*"]["suggestion"]
    # a gear no test drives in names a ramp-up in that gear
    assert 'gear = 7' in rows["transmission.gear7.eta_m"]["suggestion"]


def test_plan_table_and_bad_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("BENCHTWIN_CACHE", str(tmp_path / "cache"))
    path = _campaign_without(tmp_path)
    assert main(["plan", "--setup", "paper", "--campaign", str(path)]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("transmission.gear4_coast.C0"))
    assert " NO " in line and "brake_steps_pct" in line
    bad = tmp_path / "bad.toml"
    bad.write_text("tests = [\n", encoding="utf-8")
    assert main(["plan", "--setup", "paper", "--campaign", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.toml" in err[0] and "not valid TOML" in err[0]
    assert main(["plan", "--setup", "missing_setup", "--campaign", "quick"]) == 2
    assert "missing_setup" in capsys.readouterr().err


def test_reading_lag_line_follows_a_drifting_clock() -> None:
    """A 100 Hz channel read through a clock that drifts 125 ppm after a 15 ms lag, over 2,000 s.

    The readings are the truth at ``t - (0.015 + 125e-6 t)``, quantised to 2 Nm: the line must give the lag to
    a millisecond and a half (the search's step is 1 ms) at both ends; a single lag cannot (0.015 s at the
    start, 0.265 s at the end), so a fit that ignored the drift fails by 0.1 s or more. Time: about 2 s.
    """
    from benchtwin.studies.plan_noise import ChannelNoise
    from benchtwin.studies.plan_windows import reading_lag_line

    t = np.arange(0.0, 2_000.0, 0.01)
    x = 500.0 * np.sin(2 * np.pi * t / 7.0) + 300.0 * np.sin(2 * np.pi * t / 3.1)
    lag = 0.015 + 125e-6 * t
    y = 2.0 * np.rint(np.interp(t - lag, t, x) / 2.0)
    truth = Channel("shaft_torque_nm", "Nm", t, x, None, "telemetry")
    rec = Channel("shaft_torque_nm", "Nm", t, y, None, "telemetry")
    a, b = reading_lag_line(truth, rec, ChannelNoise(sigma=0.0, q=2.0, gain=0.0, offset=0.0), chunk_s=500.0)
    for at in (0.0, 2_000.0):
        assert abs((a + b * at) - (0.015 + 125e-6 * at)) < 1.5e-3, (a, b)
