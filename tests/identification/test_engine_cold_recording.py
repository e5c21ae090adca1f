"""The cold-start factor and the coolant's warm-up identified from a synthetic Recording with known values."""

from __future__ import annotations

import numpy as np
from _synth_a import SPECS

from benchtwin.identification.engine_cold import fit_warmup, identify_cold_fuel
from benchtwin.identification.fuel_map import fuel_map_gps, map_pmf
from benchtwin.recording import Channel, Recording
from benchtwin.roles import unit_of_role

# a Willans engine: fuel MEP = 1.2 bar + 2.4 BMEP (about 40 % efficient at load), as a BSFC map
_SPEED = np.array([1000.0, 2000.0, 3000.0, 4000.0])
_BMEP = np.array([1.0, 4.0, 8.0, 14.0])
_MAP = {"map_speed_rpm": _SPEED, "map_bmep_bar": _BMEP,
        "map_bsfc": np.tile((3.6e9 / SPECS.fuel_lhv_j_per_kg * (1.2 + 2.4 * _BMEP) / _BMEP)[:, None], (1, 4))}
K, T_WARM, H, G, C, T_REG = 0.002, 80.0, 5e-6, 4.5e-4, 0.0104, 88.0


def _recording(seed: int = 1) -> Recording:
    """The coolant cools from 50 degC for 60 min with the engine off (the electric tests), then the engine fires:
    60 s load steps, off for 60 s every 10 minutes; 10 Hz, 2 h."""
    rng = np.random.default_rng(seed)
    dt = 0.1
    t = np.arange(0.0, 7200.0, dt)
    step = (t // 60).astype(int)
    on = ((step % 10 != 9) & (t >= 3600.0)).astype(float)
    speed = np.where(on > 0, 1500.0 + 500.0 * (step % 4), 0.0)
    torque = np.where(on > 0, 40.0 + 30.0 * (step % 5), 0.0)
    m = map_pmf(_MAP, SPECS.fuel_lhv_j_per_kg)
    assert m is not None
    warm = np.where(on > 0, fuel_map_gps(*m, SPECS.engine_displacement_m3, SPECS.engine_strokes,
                                         SPECS.fuel_lhv_j_per_kg, speed, torque), 0.0)
    temp = np.empty_like(t)
    fuel = np.empty_like(t)
    tc = 50.0
    for i in range(t.size):  # the truth: the lump of engine_cold's docstring, the factor 1 + k max(0, 80 - T)
        temp[i] = tc
        fuel[i] = warm[i] * (1.0 + K * max(T_WARM - tc, 0.0))
        heat = max(fuel[i] * 1e-3 * SPECS.fuel_lhv_j_per_kg - torque[i] * speed[i] * np.pi / 30.0, 0.0)
        tc = min(tc + dt * (H * heat - G * tc + C), max(T_REG, tc))
    rec = Recording()
    sig = {"engine_speed_rpm": speed + rng.normal(0, 2.0, t.size), "engine_torque_nm": torque,
           "fuel_mass_flow_gps": fuel + rng.normal(0, 0.003, t.size), "engine_on": on,
           "engine_coolant_out_degc": temp + rng.normal(0, 0.05, t.size)}
    for role, x in sig.items():
        rec.add(Channel(role, unit_of_role(role), t, x, None, "ecu"))
    return rec


def test_factor_and_warmup_from_a_recording() -> None:
    rec = _recording()
    cf = identify_cold_fuel(rec, SPECS, _MAP)
    # 10 s blocks, fuel noise 0.003 g/s on ~1-3 g/s flows: the ratio's noise is ~1e-3 per block; the engine is
    # below 65 degC for ~25 min (dozens of cold blocks): k within 5 % of 0.002, the hinge within 3 K
    assert cf.status == "ok" and bool(cf.data["use"][0])
    assert abs(cf.value("k") - K) < 1e-4
    assert abs(float(cf.data["T_warm_degc"][0]) - T_WARM) <= 3.0
    wu = fit_warmup(rec, SPECS)
    # 20 s blocks, end minus start: 0.05 K noise gives 0.0035 K/s per block. g rests on ~180 engine-off blocks over a
    # cooling from 50 to ~35 degC (spread ~4 K): SE(g) ~ 0.0035 / (sqrt(180) 4 K) ~ 6.5e-5, 15 % of 4.5e-4, so 40 %
    # (3 SE; a lump without its loss term is 100 % off); h rests on the firing hour (heat ~10-40 kW): SE well under
    # 1 %, 5 % allowed; T_env = c / g: a 15 % g error on a (T - T_env) ~ 20 K lever gives ~3 K, 5 K allowed
    assert abs(wu.value("h") / H - 1.0) < 0.05
    assert abs(wu.value("g") / G - 1.0) < 0.4
    assert abs(wu.value("T_env_degc") - C / G) < 5.0
    assert abs(float(wu.data["T_reg_degc"][0]) - T_REG) < 1.0
