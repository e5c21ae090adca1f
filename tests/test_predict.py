"""The map-based vehicle model on synthetic maps with answers computed by hand, and its isolation from the truth."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import IdentificationError
from benchtwin.identification._fit import FitResult, IdentificationResult, ParameterEstimate
from benchtwin.validation.predict import CO2_G_PER_G_DIESEL, DriveInputs, MapVehicle

SPECS = VehicleSpecs(gear_ratios=[5.36, 3.25, 2.26, 1.64, 1.22, 1.00, 0.87, 0.72, 0.61], final_drive_ratio=2.65,
                     wheel_radius_m=0.352, engine_displacement_m3=1.95e-3, n_cells_series=96,
                     em_rotor_radius_m=0.085, em_rotor_volume_m3=3.405e-3, test_mass_kg=2000.0)

F0, F1, F2 = 150.0, 0.8, 0.03
ETA_M, C0 = 0.98, 3.0
E, W_LOSS, E_GEN, W_LOSS_GEN, ETA_DCDC = 0.95, 600.0, 0.94, 400.0, 0.9
OCV_CELL, R_CELL, SOC_PER_AH = 3.8, 0.001, 2.5
PMF0, PMF1 = 1.2, 2.5  # fuel MEP = PMF0 + PMF1 * BMEP (bar): a Willans engine


def _fit(params: dict[str, float], **data: np.ndarray) -> FitResult:
    p = {k: ParameterEstimate(k, v, 0.0, (v, v), 1.0, 10) for k, v in params.items()}
    return FitResult(p, 1.0, 1.0, 0.0, 10, data=dict(data))


def synthetic_result() -> IdentificationResult:
    """Identified maps with round numbers: flat battery maps, a linear fuel MEP, one eta_m/C0 for every gear."""
    res = IdentificationResult()
    res.fits["road_load"] = _fit({"F0": F0, "F1": F1, "F2": F2})
    for g in range(1, 10):
        res.fits[f"transmission.gear{g}"] = _fit({"eta_m": ETA_M, "C0": C0})
    res.fits["motor.motoring"] = _fit({"e": E, "W_loss": W_LOSS, "eta_dcdc": ETA_DCDC})
    res.fits["motor.generating"] = _fit({"e_gen": E_GEN, "W_loss_gen": W_LOSS_GEN})
    soc = np.array([0.0, 100.0])
    res.fits["battery"] = _fit({"alpha": 1.0, "soc_per_ah": SOC_PER_AH}, map_soc=soc, map_ocv=np.full(2, OCV_CELL),
                               map_r_dch=np.full(2, R_CELL), map_r_ch=np.full(2, R_CELL))
    sg, bg = np.linspace(800, 4500, 8), np.linspace(1.0, 20.0, 6)
    q = 3.6e9 / SPECS.fuel_lhv_j_per_kg
    bsfc = q * (PMF0 + PMF1 * bg[:, None]) / bg[:, None] * np.ones((1, sg.size))
    res.fits["engine.bsfc"] = _fit({"bsfc_min": float(bsfc.min())}, map_speed_rpm=sg, map_bmep_bar=bg, map_bsfc=bsfc)
    return res


def cruise(n: int = 600, speed_kmh: float = 60.0, gear: int = 6, engine_torque_nm: float = 0.0,
           p_lv_w: float = 400.0, soc0: float = 50.0) -> DriveInputs:
    on = 1.0 if engine_torque_nm else 0.0
    z = np.zeros(n)
    return DriveInputs(t_s=np.arange(n) * 0.1, speed_kmh=np.full(n, speed_kmh), gear=np.full(n, gear),
                       lockup_closed=np.ones(n), k0_closed=np.full(n, on), engine_on=np.full(n, on),
                       engine_torque_nm=np.full(n, engine_torque_nm), engine_speed_rpm=z, pedal_pct=np.full(n, 20.0),
                       brake_front_bar=z, brake_rear_bar=z, p_lv_w=np.full(n, p_lv_w), initial_soc_pct=soc0,
                       name="cruise")


def _by_hand(speed_kmh: float, gear: int, engine_torque_nm: float, p_lv_w: float, duration_s: float
             ) -> tuple[float, float, float]:
    """Fuel (g), battery energy (Wh) and SOC change (points) of a steady cruise, from the maps above."""
    v = speed_kmh / 3.6
    force = F0 + F1 * speed_kmh + F2 * speed_kmh**2
    i_g = SPECS.gear_ratios[gear - 1]
    t_out = force * SPECS.wheel_radius_m / SPECS.final_drive_ratio
    t_in = t_out / (i_g * ETA_M) + C0
    w = v / SPECS.wheel_radius_m * SPECS.final_drive_ratio * i_g
    t_m = t_in - engine_torque_nm
    p_el = (t_m * w + W_LOSS) / E if t_m >= 0 else E_GEN * t_m * w + W_LOSS_GEN
    p_bat = p_el + p_lv_w / ETA_DCDC
    pc = p_bat / SPECS.n_cells_series
    current = (OCV_CELL - math.sqrt(OCV_CELL**2 - 4 * R_CELL * pc)) / (2 * R_CELL)
    volts = (OCV_CELL - current * R_CELL) * SPECS.n_cells_series
    fuel = 0.0
    if engine_torque_nm:
        bmep = 4 * math.pi * engine_torque_nm / SPECS.engine_displacement_m3 / 1e5
        p_fuel = (PMF0 + PMF1 * bmep) * 1e5 * SPECS.engine_displacement_m3 / (4 * math.pi) * w
        fuel = p_fuel / SPECS.fuel_lhv_j_per_kg * 1e3 * duration_s
    return fuel, volts * current * duration_s / 3600.0, -SOC_PER_AH * current * duration_s / 3600.0


def test_electric_cruise_matches_the_hand_calculation() -> None:
    model = MapVehicle(synthetic_result(), SPECS)
    drive = cruise()
    pred = model.run(drive)
    fuel, e_wh, dsoc = _by_hand(60.0, 6, 0.0, 400.0, 60.0)
    assert pred.fuel_g == 0.0 and fuel == 0.0
    assert pred.electric_wh == pytest.approx(e_wh, rel=1e-9)
    assert pred.final_soc_pct - 50.0 == pytest.approx(dsoc, rel=1e-3)
    assert pred.distance_km == pytest.approx(1.0, rel=1e-9)


@pytest.mark.parametrize("engine_torque_nm", [80.0, 200.0])
def test_hybrid_cruise_fuel_and_charge_by_hand(engine_torque_nm: float) -> None:
    """The engine's replayed torque burns map fuel; above the demand the motor generates and the battery charges."""
    model = MapVehicle(synthetic_result(), SPECS)
    pred = model.run(cruise(engine_torque_nm=engine_torque_nm, gear=5, speed_kmh=80.0))
    fuel, e_wh, dsoc = _by_hand(80.0, 5, engine_torque_nm, 400.0, 60.0)
    assert pred.fuel_g == pytest.approx(fuel, rel=1e-9)
    assert pred.co2_g == pytest.approx(fuel * CO2_G_PER_G_DIESEL, rel=1e-12)
    assert pred.electric_wh == pytest.approx(e_wh, rel=1e-9)
    assert pred.final_soc_pct - 50.0 == pytest.approx(dsoc, rel=1e-3)
    if engine_torque_nm == 200.0:
        assert e_wh < 0 and pred.final_soc_pct > 50.0  # charging


def test_shift_lines_pick_the_gear() -> None:
    res = synthetic_result()
    for g, (up, down) in enumerate(zip([15, 25, 35, 45, 55, 65, 80, 95], [8, 17, 26, 36, 46, 55, 67, 82]), start=1):
        res.fits[f"shifts.up_{g}_{g + 1}"] = _fit({"c0_kmh": float(up), "c1_kmh_per_pct": 0.0})
        res.fits[f"shifts.down_{g + 1}_{g}"] = _fit({"c0_kmh": float(down), "c1_kmh_per_pct": 0.0})
    model = MapVehicle(res, SPECS)
    drive = cruise(speed_kmh=60.0, gear=3)
    gears = model.shift_gears(drive)
    assert set(gears.tolist()) == {6}  # 55 <= 60 < 65: sixth, reached from the third at once
    pred = model.run(drive, gear_source="shift_lines")
    assert pred.electric_wh == pytest.approx(_by_hand(60.0, 6, 0.0, 400.0, 60.0)[1], rel=1e-9)


def test_a_missing_map_is_named() -> None:
    res = synthetic_result()
    del res.fits["road_load"]
    with pytest.raises(IdentificationError, match="road_load"):
        MapVehicle(res, SPECS)


def test_the_model_never_reads_the_vehicle_file() -> None:
    """predict.py imports nothing that knows the truth: only the public specs and identification results."""
    src = Path(__file__).resolve().parents[1] / "benchtwin" / "validation" / "predict.py"
    tree = ast.parse(src.read_text(encoding="utf-8"))
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module)
        elif isinstance(node, ast.Import):
            imported.update(a.name for a in node.names)
    ours = {m for m in imported if m.startswith("benchtwin")}
    allowed = ("benchtwin.config.specs", "benchtwin.errors", "benchtwin.identification",
               "benchtwin.validation._pack_steps",  # the model's own compiled pack steps
               "benchtwin.validation.drive",  # its input and output classes, which import nothing of benchtwin
               "benchtwin.validation.shift_lines", "benchtwin.validation.standstill",  # its pieces, numpy only
               "benchtwin.validation.cold_start",  # its piece reading identification results only
               "benchtwin.validation.gearbox")  # its gearbox, from identification results only
    assert ours and all(m.startswith(allowed) for m in ours), ours
    for piece in ("drive.py", "shift_lines.py", "standstill.py", "cold_start.py", "gearbox.py"):
        piece_src = (src.parent / piece).read_text(encoding="utf-8")
        imports = [line for line in piece_src.splitlines() if line.startswith(("from", "import"))]
        assert all(not line.split()[1].startswith("benchtwin") or line.split()[1].startswith(
            ("benchtwin.identification.", "benchtwin.errors")) for line in imports), piece
    assert "VehicleConfig" not in src.read_text(encoding="utf-8")
    # and it runs on an IdentificationResult plus VehicleSpecs alone
    assert MapVehicle(synthetic_result(), SPECS).run(cruise()).electric_wh > 0


def _with_loss(better: bool) -> IdentificationResult:
    res = synthetic_result()
    res.fits["motor.loss"] = _fit({"P0": 200.0, "k_w": 2.0, "k_w2": 0.0, "k_cu": 0.03, "k_sw": 1.0},
                                  speed_range_radps=np.array([50.0, 400.0]), better_than_willans=np.array([better]))
    return res


def test_the_loss_model_replaces_the_willans_lines_only_where_it_was_closer() -> None:
    """Electric cruise at 60 km/h in 6th: T_m and w as in _by_hand; the loss model gives P_el = T w + 200 + 2 w
    + 0.03 T^2 + |T| (w inside the identified 50..400 rad/s), and the battery energy follows it; with
    better_than_willans False the auto model keeps the Willans lines, "loss" forces the loss model, and a result
    without motor.loss cannot be forced."""
    v, i_g = 60.0 / 3.6, SPECS.gear_ratios[5]
    t_out = (F0 + F1 * 60.0 + F2 * 60.0**2) * SPECS.wheel_radius_m / SPECS.final_drive_ratio
    t_m = t_out / (i_g * ETA_M) + C0
    w = v / SPECS.wheel_radius_m * SPECS.final_drive_ratio * i_g
    p_loss_model = t_m * w + 200.0 + 2.0 * w + 0.03 * t_m**2 + t_m
    p_willans = (t_m * w + W_LOSS) / E
    drive = cruise()
    for res, mm, expect in ((_with_loss(True), "auto", p_loss_model), (_with_loss(False), "auto", p_willans),
                            (_with_loss(False), "loss", p_loss_model), (_with_loss(True), "willans", p_willans)):
        pred = MapVehicle(res, SPECS, motor_model=mm).run(drive)
        np.testing.assert_allclose(pred.series["motor_elec_power_w"][5:-5], expect, rtol=1e-6, err_msg=mm)
    with pytest.raises(IdentificationError, match=r"motor\.loss"):
        MapVehicle(synthetic_result(), SPECS, motor_model="loss")
    with pytest.raises(ValueError, match="motor_model"):
        MapVehicle(synthetic_result(), SPECS, motor_model="map")


J_PUMP = 0.25  # kg m^2, the converter fit's pump-side inertia in the synthetic result


def _with_converter(j_pump: float, ci_low: float | None = None) -> IdentificationResult:
    res = synthetic_result()
    conv = _fit({**{f"a{i}": 1e-3 for i in range(6)}, "J_pump_kgm2": j_pump})
    if ci_low is not None:
        conv.params["J_pump_kgm2"].ci95 = (ci_low, 2 * j_pump - ci_low)
    res.fits["torque_converter.converter"] = conv
    return res


def _ramp(v0_kmh: float = 20.0, v1_kmh: float = 60.0, ramp_s: float = 20.0, gear: int = 3) -> DriveInputs:
    """10 s at v0, a constant-acceleration ramp to v1, 10 s at v1; electric, lock-up closed, one gear."""
    t = np.arange(0.0, ramp_s + 20.0, 0.1)
    v = np.interp(t, [10.0, 10.0 + ramp_s], [v0_kmh, v1_kmh])
    d = cruise(n=t.size, gear=gear)
    d.t_s, d.speed_kmh = t, v
    return d


def test_pump_inertia_takes_j_dw_dt_from_the_motor() -> None:
    """Known acceleration: the motor gives J_pump k a more torque and 0.5 J (w1^2 - w0^2) more work."""
    drive = _ramp()
    with_j = MapVehicle(_with_converter(J_PUMP), SPECS).run(drive)
    without = MapVehicle(_with_converter(J_PUMP), SPECS, pump_inertia=False).run(drive)
    k = SPECS.final_drive_ratio * SPECS.gear_ratios[2] / SPECS.wheel_radius_m  # pump rad/s per m/s, lock-up closed
    a = (60.0 - 20.0) / 3.6 / 20.0
    mid = (drive.t_s > 12.0) & (drive.t_s < 28.0)  # away from the ramp's ends (the 1 s smoothing)
    dt_m = with_j.series["motor_torque_nm"] - without.series["motor_torque_nm"]
    assert dt_m[mid] == pytest.approx(J_PUMP * k * a, rel=1e-6)
    w = with_j.series["motor_speed_rpm"] * np.pi / 30.0
    work_j = float(np.sum(dt_m * w) * 0.1)
    w0, w1 = k * 20.0 / 3.6, k * 60.0 / 3.6
    expected = 0.5 * J_PUMP * (w1**2 - w0**2)
    # sum of w_i J dw_i over 0.1 s samples against the integral of J w dw: within a sample w moves by dw = k a dt,
    # so the sum is off by at most J (w1 - w0) k a dt; and the 1 s smoothing rounds each of the two corners of the
    # speed trace (|w_s - w| <= k a / 8 s for 1 s): at most J (k a)^2 (1/8 s)(1 s) each (0.56 % here in all)
    bound = J_PUMP * (w1 - w0) * k * a * 0.1 + 2 * J_PUMP * (k * a) ** 2 * 0.125
    assert abs(work_j - expected) <= bound
    assert np.sum(with_j.series["pump_inertia_power_w"]) * 0.1 == pytest.approx(work_j, rel=1e-9)
    assert with_j.electric_wh > without.electric_wh  # the battery pays for the spin-up
    assert any("J_pump" in n for n in with_j.notes)


@pytest.mark.parametrize("ci_low", [-0.05, None])
def test_pump_inertia_left_out_when_not_told_from_zero(ci_low: float | None) -> None:
    """An interval reaching zero, or no converter fit, leaves the inertia out (and the notes say so)."""
    res = _with_converter(J_PUMP, ci_low) if ci_low is not None else synthetic_result()
    model = MapVehicle(res, SPECS)
    assert model.j_pump == 0.0
    assert any("inertia torque left out" in n for n in model.notes)
    drive = _ramp()
    assert model.run(drive).electric_wh == MapVehicle(res, SPECS, pump_inertia=False).run(drive).electric_wh


def test_coupling_mode_takes_the_pump_side_fit_when_identified() -> None:
    """The model's a6..a8 are the pump rows' fit (``data["pump_side_a678"]``) when present, else the reported ones."""
    res = _with_converter(J_PUMP)
    res.fits["torque_converter.coupling"] = _fit({"a6": 0.04, "a7": -0.035, "a8": -0.005},
                                                 pump_side_a678=np.array([0.03, -0.028, -0.002]))
    model = MapVehicle(res, SPECS)
    np.testing.assert_array_equal(model.tc_a[6:], [0.03, -0.028, -0.002])
    assert any("pump rows" in n for n in model.notes)
    del res.fits["torque_converter.coupling"].data["pump_side_a678"]
    np.testing.assert_array_equal(MapVehicle(res, SPECS).tc_a[6:], [0.04, -0.035, -0.005])


def _stop(stop_s: float = 60.0, engine_on: float = 0.0) -> DriveInputs:
    """10 s at 20 km/h in first gear, converter open, then standing ``stop_s`` in gear with the brakes held."""
    t = np.arange(0.0, 10.0 + stop_s, 0.1)
    d = cruise(n=t.size, speed_kmh=20.0, gear=1)
    d.t_s, d.speed_kmh = t, np.where(t < 10.0, 20.0, 0.0)
    d.lockup_closed = np.zeros(t.size)
    d.pedal_pct = np.where(t < 10.0, 20.0, 0.0)
    d.engine_on = np.where(t < 10.0, 0.0, engine_on)
    return d


def test_standstill_run_down_draws_the_zero_torque_loss_until_the_pump_stops() -> None:
    """J dw/dt = -a0 w^2 from the stop: the pump is below 1 rad/s after (J/a0)(1 - 1/w0), the motor drawing
    W_loss / e until then (Willans at zero torque); engine on at the stop: no run-down."""
    a0 = 0.025
    res = _with_converter(J_PUMP)
    res.fits["torque_converter.converter"].params["a0"].value = a0
    drive = _stop()
    on, off = MapVehicle(res, SPECS).run(drive), MapVehicle(res, SPECS, standstill=False).run(drive)
    stand = drive.speed_kmh == 0.0
    extra_j = float(np.sum((on.series["motor_elec_power_w"] - off.series["motor_elec_power_w"])[stand]) * 0.1)
    w0 = float(np.max(on.series["motor_speed_rpm"][~stand])) * np.pi / 30.0  # the run-down's start (the drive's top)
    turning_s = J_PUMP / a0 * (1.0 - 1.0 / w0)  # 10 s here, inside the 60 s stop
    assert 9.0 < turning_s < 10.0
    # the samples count the draw from their middles: within one 0.1 s sample of the integral
    assert abs(extra_j - W_LOSS / E * turning_s) <= W_LOSS / E * 0.1
    w = on.series["motor_speed_rpm"][stand] * np.pi / 30.0
    t = (np.arange(w.size) + 0.5) * 0.1
    assert w == pytest.approx(1.0 / (1.0 / w0 + t * a0 / J_PUMP), rel=1e-9)
    assert on.electric_wh > off.electric_wh
    assert np.all(off.series["motor_elec_power_w"][stand] == 0.0)
    assert any("runs down freely" in n for n in on.notes)
    fired = _stop(engine_on=1.0)  # the engine at idle holds the pump: not the free run-down
    assert MapVehicle(res, SPECS).run(fired).electric_wh == MapVehicle(res, SPECS, standstill=False).run(
        fired).electric_wh


def test_loss_model_speed_part_falls_linearly_to_p0_at_rest_below_the_identified_range() -> None:
    """``to_standstill``: below w_lo the speed part k_w w + k_w2 w^2 is the chord from 0 (at rest) to its value at
    w_lo, by hand; inside the range and without the option the clamped polynomial as before."""
    from benchtwin.identification.motor_loss import loss_w

    c = (150.0, 3.0, 0.01, 0.03, 2.0)  # P0, k_w, k_w2, k_cu, k_sw
    lo, hi = 80.0, 500.0
    s_lo = 3.0 * lo + 0.01 * lo**2  # 304 W
    t = np.array([0.0, 0.0, 0.0, 20.0, 20.0, 0.0])
    w = np.array([0.0, 40.0, 80.0, 40.0, 200.0, -40.0])
    want = np.array([150.0, 150.0 + s_lo / 2, 150.0 + s_lo, 150.0 + s_lo / 2 + 0.03 * 400 + 40,
                     150.0 + 3.0 * 200 + 0.01 * 200**2 + 0.03 * 400 + 40, 150.0 + s_lo / 2])
    np.testing.assert_allclose(loss_w(c, t, w, (lo, hi), to_standstill=True), want, rtol=1e-12)
    clamped = loss_w(c, t, w, (lo, hi))
    np.testing.assert_allclose(clamped[:4], [150.0 + s_lo, 150.0 + s_lo, 150.0 + s_lo, 150.0 + s_lo + 52.0])
    # a convex speed loss (friction ~w, eddy ~w^2) lies under the chord, touching it at rest and at w_lo
    wq = np.linspace(0.0, lo, 9)
    assert np.all(150.0 + 3.0 * wq + 0.01 * wq**2 <= loss_w(c, 0 * wq, wq, (lo, hi), to_standstill=True) + 1e-9)


def test_standstill_run_down_with_the_loss_model_draws_p0_plus_the_speed_part_on_the_pump_speed() -> None:
    """Loss model P0 + k_w w (k_w2 = 0: the chord below 50 rad/s is the line itself) on the free run-down
    w(t) = 1 / (1/w0 + t c/J): the draw until w = 1 rad/s is, in closed form, P0 T1 + k_w (J/c) ln(w0) with
    T1 = (J/c)(1 - 1/w0); holding the speed part at its 50 rad/s value instead would add ~0.9 kJ here."""
    a0 = 0.025
    res = _with_loss(True)
    conv = _fit({**{f"a{i}": 1e-3 for i in range(6)}, "J_pump_kgm2": J_PUMP})
    conv.params["a0"].value = a0
    res.fits["torque_converter.converter"] = conv
    drive = _stop()
    on, off = MapVehicle(res, SPECS).run(drive), MapVehicle(res, SPECS, standstill=False).run(drive)
    stand = drive.speed_kmh == 0.0
    extra_j = float(np.sum((on.series["motor_elec_power_w"] - off.series["motor_elec_power_w"])[stand]) * 0.1)
    w0 = float(np.max(on.series["motor_speed_rpm"][~stand])) * np.pi / 30.0
    jc = J_PUMP / a0
    t1 = jc * (1.0 - 1.0 / w0)
    want = 200.0 * t1 + 2.0 * jc * math.log(w0)
    # midpoint sampling of a convex, decreasing w(t): within one 0.1 s sample of the top draw (P0 + k_w w0)
    assert abs(extra_j - want) <= (200.0 + 2.0 * w0) * 0.1
    t50 = jc * (1.0 / 50.0 - 1.0 / w0)  # the pump reaches the range's lower end
    held = 200.0 * t1 + 2.0 * jc * math.log(w0 / 50.0) + 2.0 * 50.0 * (t1 - t50)
    assert held - want > 10 * (200.0 + 2.0 * w0) * 0.1  # the clamped form is far outside the bound above


def test_identified_start_fuel_added_per_replayed_start() -> None:
    """Three rises of the replayed engine_on (one already on at the drive's start is no start) add 3 x m."""
    drive = cruise(engine_torque_nm=80.0, gear=5, speed_kmh=80.0)
    on = np.ones(drive.t_s.size)
    for a in (100, 250, 450):  # off for 5 s three times: three starts after the one already on at t = 0
        on[a:a + 50] = 0.0
    drive.engine_on = on
    drive.k0_closed = on.copy()
    drive.engine_torque_nm = 80.0 * on
    base = MapVehicle(synthetic_result(), SPECS).run(drive)
    n_rises = int(np.count_nonzero(np.diff(on) > 0.5))
    assert n_rises == 3 and base.start_fuel_g == 0.0 and base.engine_starts == 3
    res = synthetic_result()
    res.fits["engine.start_fuel"] = _fit({"m_g": 0.6}, use=np.array([True]), n_starts=np.array([300]))
    pred = MapVehicle(res, SPECS).run(drive)
    assert pred.start_fuel_g == pytest.approx(3 * 0.6, rel=1e-12)
    assert pred.fuel_g == pytest.approx(base.fuel_g + 1.8, rel=1e-12)
    res.fits["engine.start_fuel"].flag("too few starts")  # a flagged fit is not used
    assert MapVehicle(res, SPECS).run(drive).fuel_g == pytest.approx(base.fuel_g, rel=1e-12)
