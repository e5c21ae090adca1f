"""report.html: one self-contained file with the verdict and the figures, opened by a headless browser."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from benchtwin.config.specs import VehicleSpecs
from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate
from benchtwin.identification.figures import render_figures_png
from benchtwin.validation.html import render_html, write_html
from benchtwin.validation.report import Check, ValidationReport

SPECS = VehicleSpecs(gear_ratios=[5.36, 3.25, 2.26, 1.64, 1.22, 1.00, 0.87, 0.72, 0.61], final_drive_ratio=2.65,
                     wheel_radius_m=0.352, engine_displacement_m3=1.95e-3, n_cells_series=96,
                     em_rotor_radius_m=0.085, em_rotor_volume_m3=3.405e-3, test_mass_kg=2000.0)


def _motor_result() -> IdentificationResult:
    rng = np.random.default_rng(1)
    n = rng.uniform(800, 5000, 120)
    t = rng.uniform(10, 250, 120)
    p = {k: ParameterEstimate(k, v, 0.0, (v, v), 0.99, 120) for k, v in (("e", 0.95), ("W_loss", 650.0))}
    ng, tg = np.linspace(800, 5000, 20), np.linspace(10, 250, 20)
    N, T = np.meshgrid(ng, tg)
    P = T * N * np.pi / 30
    fit = FitResult(p, 0.99, 0.99, 1.0, 120, data={"speed_rpm": n, "torque_nm": t, "map_speed_rpm": ng,
                                                    "map_torque_nm": tg, "map_eta": 0.95 * P / (P + 650.0)})
    return IdentificationResult(fits={"motor.motoring": fit})


def _report(passed: bool = True) -> ValidationReport:
    checks = [Check("motor", "motor.motoring.e", 0.9501, 0.95, 1e-4, 1e-3, "rel", "-", True, "0.1 %"),
              Check("prediction", "wltc.fuel", 291.0, 291.5, -0.0016, 0.02, "rel", "g", passed, "issue goal <2 %")]
    rep = ValidationReport(checks=checks, identification=_motor_result(),
                           chain={"plant_seconds": 10.0, "bus_load": {"vehicle": 0.31},
                                  "clock_offsets_s": {"dyno": 0.12}, "flagged_samples": {"em_torque_nm": 3},
                                  "clipped_samples": {}},
                           timings_s={"simulate": 1.0}, meta={"vehicle": "v", "setup": "s", "profile": "ideal"})
    rep.prediction = {"held_out": "wltc", "notes": ["gear replayed"], "drives": [{
        "name": "wltc", "gear_source": "recorded", "notes": [],
        "predicted": {"fuel_g": 291.0, "co2_g": 919.6, "electric_wh": 2645.0, "final_soc_pct": 27.0,
                      "initial_soc_pct": 51.3},
        "measured": {"fuel_g": 303.5, "co2_g": 959.1, "electric_wh": 2695.0, "final_soc_pct": 26.6,
                     "initial_soc_pct": 51.4, "distance_km": 23.3, "engine_starts": 20.0, "fuel_firing_g": 291.5},
        "errors": {"fuel": -0.041, "electric": -0.0185, "co2": -0.041, "soc_points": 0.44}}]}
    return rep


def test_motor_map_figure_draws_full_load_and_hull() -> None:
    pngs = render_figures_png(_motor_result(), specs=SPECS.model_copy(update={"em_max_torque_nm": 440.0,
                                                                               "em_max_power_w": 90e3}))
    assert pngs["fig11_motor_efficiency_map"].startswith(b"\x89PNG")


def test_html_is_self_contained() -> None:
    text = render_html(_report(), SPECS)
    assert "Verdict: PASS" in text and "2 checks, 2 passed, 0 failed" in text
    assert re.search(r'<img [^>]*src="data:image/png;base64,[A-Za-z0-9+/=]{100,}"', text)
    assert not re.search(r'(src|href)="(https?:|//|file:)', text)  # no external asset
    assert "fuel without 20 engine starts" in text and "em_torque_nm" in text  # prediction and chain sections
    assert "Verdict: FAIL" in render_html(_report(passed=False), SPECS, figures=False)


@pytest.mark.skipif(shutil.which("chromium") is None, reason="chromium is not installed (apt-get install chromium)")
def test_headless_browser_sees_verdict_and_a_figure(tmp_path) -> None:
    page = write_html(_report(), tmp_path / "report.html", SPECS)
    profile = tmp_path / "profile"
    cmd = ["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={profile}",
           "--dump-dom", page.resolve().as_uri()]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    dom = out.stdout
    assert "Verdict: PASS" in dom
    imgs = re.findall(r'<img [^>]*src="data:image/png;base64,([^"]*)"', dom)
    assert imgs and all(len(b) > 0 for b in imgs)
