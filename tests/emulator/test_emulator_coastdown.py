"""Coastdown on the dyno in road-load mode gives back F0, F1, F2, and the rollers see only the parasitic loss."""

from __future__ import annotations

import numpy as np


def _coast(trace):
    seg = next(s for s in trace.segments if s.kind == "coastdown")
    part = trace.slice_time(seg.settings["coast_start_s"], seg.end_s)
    v_kmh = 3.6 * part["vehicle_speed_mps"]
    mask = (part["gear_actual"] == 0) & (v_kmh > 15.0) & (v_kmh < 125.0)
    return part, mask


def test_coastdown_returns_road_load_coefficients_within_1_percent(quick_trace, vehicle) -> None:
    part, mask = _coast(quick_trace)
    assert mask.sum() > 1000
    v = part["vehicle_speed_mps"]
    accel = np.gradient(v, part.time_s)  # from the speed trace, not the accel channel
    force = -vehicle.specs.test_mass_kg * accel[mask]
    vk = 3.6 * v[mask]
    coef, *_ = np.linalg.lstsq(np.column_stack([np.ones_like(vk), vk, vk**2]), force, rcond=None)
    rl = vehicle.road_load
    np.testing.assert_allclose(coef, [rl.f0_n, rl.f1_n_per_kmh, rl.f2_n_per_kmh2], rtol=0.01)


def test_dyno_applies_target_minus_parasitic_loss(quick_trace, vehicle) -> None:
    part, mask = _coast(quick_trace)
    vk = 3.6 * part["vehicle_speed_mps"][mask]
    rl = vehicle.road_load
    parasitic = rl.parasitic_f0_n + rl.parasitic_f1_n_per_kmh * vk + rl.parasitic_f2_n_per_kmh2 * vk**2
    rollers = part["dyno_force_front_n"][mask] + part["dyno_force_rear_n"][mask]
    np.testing.assert_allclose(rollers, -parasitic, rtol=1e-9, atol=1e-6)
    target = rl.f0_n + rl.f1_n_per_kmh * vk + rl.f2_n_per_kmh2 * vk**2
    np.testing.assert_allclose(part["road_load_force_n"][mask], target, rtol=1e-12)
