"""Every figure renders from a synthetic IdentificationResult into a non-empty PNG."""

from __future__ import annotations

import numpy as np
import pytest
from _synth_b import SPECS, TRANSMISSION_TRUTH, battery_recording, shift_recording, tc_recording

from benchtwin.identification._fit import FitResult, IdentificationResult, linear_fit
from benchtwin.identification.battery import identify_battery
from benchtwin.identification.battery_map_free import identify_battery_map_free
from benchtwin.identification.figures import FIGURES, render_figures
from benchtwin.identification.run import identify_all

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _transmission_fit(eta_m: float, c0: float) -> FitResult:
    c = np.linspace(20.0, 300.0, 40)
    eta = eta_m * (1 - c0 / c)
    fit = linear_fit(np.column_stack([np.ones_like(c), -1 / c]), eta, ["eta_m", "eta_m_C0"])
    fit.add(fit.params["eta_m_C0"].__class__("C0", c0, 0.0, (c0, c0), 1.0, c.size, "Nm"))
    cc = np.linspace(15.0, 330.0, 100)
    fit.data.update(c=c, eta=eta, eta_fit=fit.data["y_fit"], c_curve=cc, eta_curve=eta_m * (1 - c0 / cc))
    return fit


def _motor_fit() -> FitResult:
    rng = np.random.default_rng(0)
    n = rng.uniform(500, 6000, 200)
    t = rng.uniform(10, 300, 200)
    w = n * np.pi / 30
    p_el = (t * w + 1500.0) / 0.95
    V, r = SPECS.em_rotor_volume_m3, SPECS.em_rotor_radius_m
    p_me, p_ma, c_m = t / (2 * V), p_el / V * 2 * np.pi / w, r * w
    fit = linear_fit(np.column_stack([p_ma, -1 / c_m]), p_me, ["C0", "C1"])
    ng, tg = np.linspace(500, 6000, 30), np.linspace(10, 300, 30)
    N, T = np.meshgrid(ng, tg)
    P = T * N * np.pi / 30
    fit.data.update(p_me=p_me, p_ma=p_ma, c_m=c_m, p_me_fit=fit.data["y_fit"], torque_nm=t, speed_rpm=n,
                    map_speed_rpm=ng, map_torque_nm=tg, map_eta=0.95 * P / (P + 1500.0),
                    envelope_speed_rpm=ng, envelope_torque_nm=np.full(ng.size, 300.0))
    return fit


def _bsfc_fit() -> FitResult:
    sg, bg = np.linspace(1000, 4000, 25), np.linspace(1, 20, 20)
    S, B = np.meshgrid(sg, bg)
    z = 205 + 0.00001 * (S - 2000) ** 2 + 0.6 * (B - 14) ** 2
    fit = FitResult({}, 0.97, 0.96, 3.0, 24)
    fit.data.update(map_speed_rpm=sg, map_bmep_bar=bg, map_bsfc=z, map_extrapolated=(B > 18),
                    speed_rpm=np.linspace(1200, 3800, 24), bmep_bar=np.linspace(2, 17, 24))
    return fit


def _brake_fits() -> dict[str, FitResult]:
    p = np.linspace(1, 60, 50)
    front = linear_fit(p[:, None], 95.0 * p, ["m_front"])
    front.data.update(p_bar=p, torque_nm=95.0 * p, p_curve_bar=p, torque_curve_nm=95.0 * p)
    rear = linear_fit(p[:, None], 48.0 * p, ["m_rear"])  # only the least-squares arrays: the figure copes
    sg, dg = np.linspace(0, 120, 13), np.linspace(0.5, 6, 12)
    S, D = np.meshgrid(sg, dg)
    blend = FitResult({}, float("nan"), float("nan"), float("nan"), 100)
    # H4's blending fit: bin edges and per-bin mean shares (rows: deceleration, columns: speed)
    blend.data.update(map_speed_edges_kmh=np.r_[sg, 130.0], map_decel_edges_mps2=np.r_[dg, 6.5],
                      map_regen_share=np.clip(1.5 - D / 4, 0, 1) * (S > 10),
                      map_front_share=np.clip(0.5 + D / 12, 0, 1))
    return {"brakes.front": front, "brakes.rear": rear, "brakes.blending": blend}


@pytest.fixture(scope="module")
def full_result() -> IdentificationResult:
    res = IdentificationResult()
    for g in (3, 5, 7):
        res.fits[f"transmission.gear{g}"] = _transmission_fit(*TRANSMISSION_TRUTH[g])
    res.fits["motor.motoring"] = _motor_fit()
    res.fits["engine.bsfc"] = _bsfc_fit()
    res.fits.update(_brake_fits())
    brec, _ = battery_recording(noise_v=0.3)
    res.fits["battery"] = identify_battery(brec, SPECS)
    rec, _ = tc_recording(noise_nm=1.0)
    tc = identify_all(rec, SPECS, methods=["torque_converter"],
                      options={"torque_converter": {"transmission": TRANSMISSION_TRUTH}})
    res.fits.update(tc.fits)
    srec, _ = shift_recording()
    res.fits.update(identify_all(srec, SPECS, methods=["shifts"]).fits)
    return res


def test_every_figure_renders_a_png(full_result, tmp_path):
    written = render_figures(full_result, tmp_path)
    assert set(written) == set(FIGURES)
    for stem, path in written.items():
        data = path.read_bytes()
        assert data[:8] == PNG_MAGIC, stem
        assert len(data) > 10_000, stem


def test_figures_without_data_are_left_out(tmp_path):
    res = IdentificationResult()
    rec, _ = battery_recording()
    res.fits["battery_map_free"] = identify_battery_map_free(rec, n_cells=SPECS.n_cells_series,
                                                             soc_nodes_pct=[20, 50, 80])
    written = render_figures(res, tmp_path)
    assert list(written) == ["fig16_battery"]
    assert not (tmp_path / "fig18_tc_torque_ratio.png").exists()


def test_a_figure_that_fails_does_not_stop_the_others(full_result, tmp_path):
    bad = IdentificationResult(fits=dict(full_result.fits))
    broken = FitResult({}, 0.9, 0.9, 0.1, 3)
    broken.data.update(sr=np.array([0.1, 0.2]), tr=np.array([1.0]), tr_model=np.array([1.0, 2.0]),
                       gamma=np.array([]))  # inconsistent arrays
    bad.fits["torque_converter.torque_ratio"] = broken
    errors: dict[str, str] = {}
    written = render_figures(bad, tmp_path, errors=errors)
    assert "fig18_tc_torque_ratio" in errors and "fig18_tc_torque_ratio" not in written
    assert "fig16_battery" in written
    with pytest.raises((ValueError, IndexError)):
        render_figures(bad, tmp_path / "strict")
