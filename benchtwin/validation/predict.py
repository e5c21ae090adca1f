"""A map-based, backward-facing vehicle model built from an identification result only.

This is the step the paper names as the use of its identification (section 5: "a valuable dataset that
can be later inserted into a map-based vehicle model"), done as FASTSim or CO2MPAS do: from the speed
trace of a drive the model computes, per time step and backwards from the wheels,

1. the wheel force, ``F0 + F1 v + F2 v^2 + m_test dv/dt`` (the dyno's road load identified from the
   coastdown, the test mass from the public specs), plus the hydraulic brake force the recorded caliper
   pressures give through the identified brake gains;
2. the gear: the recorded gear (a replay) or the identified shift lines driven by the recorded pedal, the gear
   engaged one at a time after the identified actuation delay (``shifts.actuation``);
3. the gearbox input torque by eq. 14 with that gear's identified ``eta_m`` and ``C0`` (drive fit when
   the output torque is positive, coast fit when negative); when the temperature-dependent drag
   ``transmission.drag`` was identified and is supported by the data
   (:mod:`benchtwin.identification.transmission_drag`), its ``eta_m`` and ``C0(T_oil)`` at the drive's measured
   oil temperature (a measured boundary input, as the ambient temperature); a gear without a drag group keeps
   its eq. 14 constants (by default its ``C0`` moved by the drag's shared factor from its own points' mean oil
   temperature and speed, :mod:`benchtwin.validation.gearbox`);
4. the torque converter when the lock-up clutch is open (the identified eq. 35-36 curves, solved for the
   pump speed that carries the turbine torque), rigid when it is closed; plus the pump side's inertia torque
   ``J_pump dw_p/dt`` (``J_pump_kgm2`` of ``torque_converter.converter``, identified beside a0..a5 from the
   take-offs' pump acceleration: motor rotor and pump) on the pump speed, lock-up closed or open; standing in
   gear (lock-up open, engine off) the pump side's free run-down against the converter at stall
   (:mod:`benchtwin.validation.standstill`), the motor drawing its zero-torque loss while it turns;
5. the split between engine and motor: a replay of the measured strategy (engine on/off, K0 and the
   engine's CAN torque), the motor taking the rest, so that what is tested are the maps; when the ECU's torque
   was identified against the shaft torque (``engine.can_torque``,
   :mod:`benchtwin.identification.engine_torque`) against the same gearbox model the prediction uses (the drag
   fit on the motor-only points), the split takes the CAN torque corrected by that gain and offset (the fuel map
   is still read at the CAN torque it was identified on; with eq. 14 per gear, fitted with the CAN torque in
   its input, the CAN torque stays);
6. the motor's DC power from the identified loss model ``motor.loss`` (copper, speed and switching terms,
   :mod:`benchtwin.identification.motor_loss`) when it was identified, else from the Willans lines, plus the
   measured 12 V load through the identified DC/DC efficiency;
7. the battery current, terminal voltage and SOC from the identified eq. 30 (alpha, beta, the scaled
   literature maps, ``soc_per_ah``), with the RC branches of ``battery.rc`` when that fit kept one;
8. the fuel flow from the identified BSFC map (as a fuel mean effective pressure over speed x BMEP,
   linear towards zero load) with the cold-start factor on a predicted coolant (:mod:`.cold_start`), plus the
   identified fuel of an engine start (``engine.start_fuel``, when used) per start of the replayed strategy; CO2.

It reads nothing but an :class:`~benchtwin.identification._fit.IdentificationResult`, the public
:class:`~benchtwin.config.specs.VehicleSpecs` and the measured inputs of the drive
(:class:`DriveInputs`); the vehicle file's parameters never enter. What the maps cannot know is left
out and said so in :attr:`Prediction.notes`: the engine's rotating inertia when K0 closes it onto the pump
side and the energy of an engine start (neither identified), the motor's and pump's when the converter fit
did not identify ``J_pump_kgm2``, the fuel of an engine start when ``engine.start_fuel`` is not used, the
converter's idle-speed holding at crawling speed.
"""

from __future__ import annotations

import math

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import IdentificationError
from benchtwin.identification._fit import FitResult, IdentificationResult
from benchtwin.identification.engine_torque import ENGINE_TORQUE_KEY, corrected_engine_torque
from benchtwin.identification.fuel_map import fuel_map_gps
from benchtwin.identification.keys import FitKey
from benchtwin.identification.motor_loss import LOSS_TERMS, loss_w
from benchtwin.identification.shift_delay import SHIFT_DELAY_KEY
from benchtwin.identification.torque_converter_table import table_pump, table_torques
from benchtwin.validation._pack_steps import battery_steps as _battery_steps
from benchtwin.validation._pack_steps import battery_steps_rc as _battery_steps_rc
from benchtwin.validation._pack_steps import rc_model, rc_model_note
from benchtwin.validation.cold_start import cold_start_model, start_fuel_model
from benchtwin.validation.drive import CO2_G_PER_G_DIESEL, DIESEL_DENSITY_KG_PER_L, DriveInputs, Prediction
from benchtwin.validation.gearbox import GearboxModel
from benchtwin.validation.shift_lines import shift_line_gears
from benchtwin.validation.standstill import rundown_speed

__all__ = ["CO2_G_PER_G_DIESEL", "DIESEL_DENSITY_KG_PER_L", "DriveInputs", "MapVehicle", "Prediction"]

_RPM = np.pi / 30.0
_KMH = 1.0 / 3.6


def _fit(result: IdentificationResult, name: str, *params: str) -> FitResult | None:
    f = result.fits.get(name)
    if f is None or not all(p in f.params and math.isfinite(f.value(p)) for p in params):
        return None
    return f


class MapVehicle:
    """The vehicle model assembled from identified maps and the public specs.

    Parameters
    ----------
    result:
        The identification result (only its fits are read).
    specs:
        Public specification: ratios, wheel radius, displacement, cells in series, test mass, LHV.

    motor_model:
        ``"auto"`` (the loss model ``motor.loss`` when identified and closer to the steady points than the Willans
        lines, :func:`~benchtwin.identification.motor_loss.add_loss_fit`; else the Willans lines), ``"loss"`` (the
        loss model; an error when it was not identified) or ``"willans"`` (the paper's lines).
    converter_model:
        ``"auto"`` (the table ``torque_converter.table`` when identified and closer to the converter points than eq.
        35-36, :mod:`~benchtwin.identification.torque_converter_table`; else eq. 35-36), ``"table"`` (an error when
        it was not identified) or ``"eq35"`` (the paper's quadratics).
    pump_inertia:
        Add the pump side's inertia torque ``J_pump dw_p/dt`` to the torque the motor gives (``J_pump_kgm2`` of
        the converter fit, when identified, positive and its 95 % interval above zero); ``False``: left out.
    standstill:
        Count the pump side's free run-down at standstill (:mod:`~benchtwin.validation.standstill`: the motor's
        zero-torque draw while the pump runs down against the converter at stall, ``J_pump`` and the stall
        capacity identified); ``False``: pump and motor stand still with the car.
    move_ungrouped_c0:
        Move the eq. 14 ``C0`` of a gear without a drag group by the drag's shared oil-temperature and speed factor
        (:class:`~benchtwin.validation.gearbox.GearboxModel`); on by default (on the high-fidelity truth it brings the
        NEDC's electric energy within the 2 % goal on both benches, docs/fidelity.md); ``False``: constant ``C0``.

    Raises
    ------
    IdentificationError
        When a map the model cannot do without (road load, transmission, motor, battery) is missing.
    """

    def __init__(self, result: IdentificationResult, specs: VehicleSpecs, *, motor_model: str = "auto",
                 converter_model: str = "auto", pump_inertia: bool = True, standstill: bool = True,
                 move_ungrouped_c0: bool = True) -> None:
        self.specs = specs
        self.notes: list[str] = []
        if motor_model not in ("auto", "loss", "willans"):
            raise ValueError(f"motor_model {motor_model!r}: allowed are 'auto', 'loss' and 'willans'")
        if converter_model not in ("auto", "table", "eq35"):
            raise ValueError(f"converter_model {converter_model!r}: allowed are 'auto', 'table' and 'eq35'")
        self.loss_model: tuple[np.ndarray, tuple[float, float]] | None = None
        lf = _fit(result, "motor.loss", *LOSS_TERMS)
        usable = lf is not None and lf.status == "ok"
        better = usable and bool(np.all(np.asarray(lf.data.get("better_than_willans", [True]))))
        if (usable and motor_model == "loss") or (better and motor_model == "auto"):
            rng = np.asarray(lf.data.get("speed_range_radps", [0.0, np.inf]), float)
            self.loss_model = (np.array([lf.value(k) for k in LOSS_TERMS]), (float(rng[0]), float(rng[1])))
            self.notes.append("motor DC power from the loss model motor.loss (T w + P0 + k_w w + k_w2 w^2 + k_cu T^2 "
                              "+ k_sw |T|, speed clamped to the range identified; below it the speed part falls "
                              "linearly to P0 at rest); the Willans lines not used")
        elif motor_model == "loss":  # not usable
            raise IdentificationError("prediction: motor.loss (the motor's loss model) not identified or flagged")
        missing = []
        rl = _fit(result, "road_load", "F0", "F1", "F2")
        if rl is None:
            missing.append("road_load (F0, F1, F2)")
        else:
            self.f0, self.f1, self.f2 = rl.value("F0"), rl.value("F1"), rl.value("F2")
        # transmission: eq. 14 per gear and direction, with the oil-temperature drag (validation/gearbox.py)
        self.gearbox = GearboxModel(result, specs.gear_ratios, move_ungrouped_c0=move_ungrouped_c0)
        self.tx, self.drag = self.gearbox.tx, self.gearbox.drag
        if not self.gearbox.has_drive:
            missing.append("transmission (no gear's eta_m/C0)")
        self.notes += self.gearbox.notes
        mot = _fit(result, "motor.motoring", "e", "W_loss")
        gen = _fit(result, "motor.generating", "e_gen", "W_loss_gen")
        if mot is None:
            missing.append("motor.motoring (e, W_loss)")
        else:
            self.e, self.w_loss = mot.value("e"), mot.value("W_loss")
            self.eta_dcdc = mot.value("eta_dcdc") if "eta_dcdc" in mot.params else float("nan")
        if gen is None:
            if mot is not None:
                self.e_gen, self.w_loss_gen = 1.0 / self.e, -self.w_loss
                self.notes.append("motor.generating not identified: the motoring line mirrored")
        else:
            self.e_gen, self.w_loss_gen = gen.value("e_gen"), gen.value("W_loss_gen")
            if not (mot is not None and 0.5 < self.eta_dcdc <= 1.0) and "eta_dcdc" in gen.params:
                self.eta_dcdc = gen.value("eta_dcdc")
        if not 0.5 < getattr(self, "eta_dcdc", float("nan")) <= 1.0:
            self.eta_dcdc = 1.0
            self.notes.append("eta_dcdc not identified: the 12 V load is counted at 100 %")
        bat = _fit(result, "battery", "alpha")
        if bat is None or not all(k in bat.data for k in ("map_soc", "map_ocv", "map_r_dch", "map_r_ch")):
            missing.append("battery (eq. 30 maps)")
        else:
            self.soc_nodes = np.asarray(bat.data["map_soc"], float)
            self.ocv_cell = np.asarray(bat.data["map_ocv"], float)
            r_d = np.asarray(bat.data["map_r_dch"], float)
            r_c = np.asarray(bat.data["map_r_ch"], float)
            # a direction that was not identified borrows the other's resistance
            self.r_dch = r_d if np.all(np.isfinite(r_d)) else r_c
            self.r_ch = r_c if np.all(np.isfinite(r_c)) else r_d
            k = bat.value("soc_per_ah") if "soc_per_ah" in bat.params else float("nan")
            if not (math.isfinite(k) and k > 0):
                raise IdentificationError("prediction: battery.soc_per_ah (the usable capacity) not identified")
            self.soc_per_ah = k
            self._battery_rc(result)
        if missing:
            raise IdentificationError("prediction needs " + ", ".join(missing))
        self._engine_map(result)
        self.cold, note = cold_start_model(result)
        self.notes.append(note)
        self.start_g, note = start_fuel_model(result)
        self.notes.append(note)
        et = _fit(result, ENGINE_TORQUE_KEY, "gain", "offset")
        self.engine_torque_corr: tuple[float, float] | None = None
        same_gearbox = self.drag is not None and bool(np.all(np.asarray(et.data.get("reference_drag", [False]))))\
            if et is not None else False
        if et is not None and et.status == "ok" and not same_gearbox:
            # the gearbox model is eq. 14 per gear, fitted with the ECU's torque in the input at its engine points:
            # that torque's error is in eta_m and C0, and the CAN torque is the input those fits expect
            self.notes.append(f"{ENGINE_TORQUE_KEY} not used in the split: the gearbox model (eq. 14 per gear) was "
                              "fitted with the engine's CAN torque in its input")
        elif et is not None and et.status == "ok":
            self.engine_torque_corr = (et.value("gain"), et.value("offset"))
            self.notes.append(f"engine torque of the split: the CAN torque corrected by {ENGINE_TORQUE_KEY} (gain "
                              f"{et.value('gain'):.4f}, offset {et.value('offset'):+.2f} Nm, identified against the "
                              "shaft torque); the fuel map read at the CAN torque")
        conv = _fit(result, "torque_converter.converter", *(f"a{i}" for i in range(6)))
        coup = _fit(result, "torque_converter.coupling", "a6", "a7", "a8")
        self.tc_a = None
        if conv is not None:
            a = [conv.value(f"a{i}") for i in range(6)]
            a += self._coupling_a678(coup) if coup is not None else [a[0], a[1], a[2]]
            self.tc_a = np.asarray(a, float)
            self.tc_gamma = conv.value("gamma_coupling") if "gamma_coupling" in conv.params else 0.85
        else:
            self.notes.append("torque converter not identified: treated as rigid when open")
        self.j_pump = self._pump_inertia(conv) if pump_inertia else 0.0
        self.tc_table: FitResult | None = None
        tab = result.fits.get("torque_converter.table")
        usable = tab is not None and tab.status == "ok" and "sr_nodes" in tab.data
        better = usable and bool(np.all(np.asarray(tab.data.get("better_than_eq35", [False]))))
        if (usable and converter_model == "table") or (better and converter_model == "auto"):
            self.tc_table = tab
            self.notes.append("torque converter (drive) from the identified table torque_converter.table (binned, "
                              "monotone TR and T_p / w_p^2 over SR); eq. 35-36 only for overrun")
        elif converter_model == "table":
            raise IdentificationError("prediction: torque_converter.table (the converter's curves) not identified")
        self.j_over_c = self._stall_time_scale(standstill)
        ff = _fit(result, "brakes.front", "m_f")
        fr = _fit(result, "brakes.rear", "m_r")
        self.brake = ((ff.value("m_f"), ff.value("c_f") if "c_f" in ff.params else 0.0),
                      (fr.value("m_r"), fr.value("c_r") if "c_r" in fr.params else 0.0)) if ff and fr else None
        if self.brake is None:
            self.notes.append("brake gains not identified: hydraulic braking force taken as zero")
        self.shift_lines: dict[tuple[int, str], tuple[float, float]] = {}
        for name, f in result.fits.items():
            if not name.startswith("shifts.") or f.status != "ok":
                continue
            if _fit(result, name, "c0_kmh", "c1_kmh_per_pct") is None:
                continue
            key = FitKey.parse(name)
            self.shift_lines[(int(key.gear), str(key.direction))] = (f.value("c0_kmh"), f.value("c1_kmh_per_pct"))
        sd = _fit(result, SHIFT_DELAY_KEY, "delay_s")
        ok = sd is not None and sd.status == "ok"
        self.shift_delay_s = sd.value("delay_s") if ok else 0.0
        self.notes.append(f"shift lines: the gear engaged {self.shift_delay_s:.2f} s after the lines' target, one gear "
                          "at a time (shifts.actuation)" if ok else
                          "shift lines: actuation delay (shifts.actuation) not identified, the target gear engaged")

    def _coupling_a678(self, coup: FitResult) -> list[float]:
        """a6..a8 as the pump side pays them (``data["pump_side_a678"]``, the fit on the pump rows) when identified.

        The reported curve is fitted to the turbine torque (free of pump inertia); the model needs what the motor
        delivers in coupling mode (docs/models.md: on the second vehicle's WLTC 35.7 / 59.5 Wh against 51.5 Wh).
        """
        ps = np.asarray(coup.data.get("pump_side_a678", []), dtype=float)
        if ps.size == 3 and np.all(np.isfinite(ps)):
            self.notes.append("torque converter coupling mode (eq. 36) from the fit on the pump rows (what the motor "
                              "delivers); the identification reports the fit on the turbine torque")
            return [float(x) for x in ps]
        return [coup.value(f"a{i}") for i in (6, 7, 8)]

    def _pump_inertia(self, conv: FitResult | None) -> float:
        """The identified pump-side inertia (kg m^2), 0 when not identified or not told from zero (with a note)."""
        est = conv.params.get("J_pump_kgm2") if conv is not None else None
        j = est.value if est is not None else float("nan")
        if est is None or not (math.isfinite(j) and j > 0 and est.ci95[0] > 0):
            self.notes.append("pump-side inertia (J_pump_kgm2 of torque_converter.converter) not identified or not "
                              "above zero: the motor's and pump's inertia torque left out")
            return 0.0
        self.notes.append(f"pump-side inertia torque J_pump dw_p/dt on the motor (J_pump {j:.3f} kg m^2 from "
                          "torque_converter.converter; the engine's inertia behind K0 not identified, left out)")
        return float(j)

    def _stall_time_scale(self, standstill: bool) -> float:
        """``J_pump / c`` (s rad/s) of the run-down at standstill, NaN (with a note) when not counted."""
        if not standstill:
            return float("nan")
        c = float("nan")
        if self.tc_table is not None:
            c = float(table_torques(self.tc_table, np.array([1.0]), np.array([0.0]))[0][0])
        elif self.tc_a is not None:
            c = float(self.tc_a[0])
        if not (self.j_pump > 0 and math.isfinite(c) and c > 0):
            self.notes.append("pump run-down at standstill left out (needs the pump-side inertia and the converter's "
                              "stall capacity): motor and pump stand still with the car")
            return float("nan")
        self.notes.append(f"standstill in gear (lock-up open, engine off): the pump side runs down freely against "
                          f"the converter at stall, J_pump / c = {self.j_pump / c:.1f} s rad/s (c the stall "
                          "capacity identified), the motor drawing its zero-torque loss while it turns")
        return self.j_pump / c

    # ------------------------------------------------------------------ engine
    def _engine_map(self, result: IdentificationResult) -> None:
        f = result.fits.get("engine.bsfc")
        self.pmf = None
        if f is None or not all(k in f.data for k in ("map_speed_rpm", "map_bmep_bar", "map_bsfc")):
            self.notes.append("BSFC map not identified: no fuel predicted")
            return
        sg = np.asarray(f.data["map_speed_rpm"], float)
        bg = np.asarray(f.data["map_bmep_bar"], float)
        z = np.asarray(f.data["map_bsfc"], float)
        if z.shape != (bg.size, sg.size):
            z = z.T
        q = 3.6e9 / self.specs.fuel_lhv_j_per_kg
        with np.errstate(invalid="ignore"):
            pmf = z * bg[:, None] / q  # fuel mean effective pressure, bar (rows BMEP, columns speed)
        keep = np.all(np.isfinite(pmf), axis=1) & (bg > 0)
        if keep.sum() < 2:
            self.notes.append("BSFC map has fewer than two usable BMEP rows: no fuel predicted")
            return
        self.pmf_speed, self.pmf_bmep, self.pmf = sg, bg[keep], pmf[keep]

    def fuel_gps(self, speed_rpm: np.ndarray, torque_nm: np.ndarray) -> np.ndarray:
        """Fuel mass flow (g/s) of the firing engine from the identified map.

        The map is read as fuel MEP over speed x BMEP (bilinear, speed clamped to the map); below its
        lowest BMEP row the fuel MEP goes on linearly to zero load (the Willans form of a diesel), and
        a motoring engine (torque <= 0) burns the zero-load flow.
        """
        if self.pmf is None:
            return np.zeros_like(np.asarray(speed_rpm, float))
        sp = self.specs
        return fuel_map_gps(self.pmf_speed, self.pmf_bmep, self.pmf, sp.engine_displacement_m3, sp.engine_strokes,
                            sp.fuel_lhv_j_per_kg, speed_rpm, torque_nm)

    # ------------------------------------------------------------------ transmission and converter
    def input_torque_nm(self, gear: np.ndarray, out_torque_nm: np.ndarray, oil_degc: np.ndarray | None = None,
                        input_speed_radps: np.ndarray | None = None) -> np.ndarray:
        """Gearbox input torque from the output torque: :meth:`GearboxModel.input_torque_nm`."""
        return self.gearbox.input_torque_nm(gear, out_torque_nm, oil_degc, input_speed_radps)

    def pump_nm(self, w_t: np.ndarray, t_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pump speed and torque that carry turbine torque ``t_t`` at turbine speed ``w_t`` (converter open).

        Drive (``t_t > 0``): the coupling mode where its pump speed gives SR at or above Gamma, else the converter
        mode; with the table (``converter_model``) its curves instead. Overrun (``t_t < 0``): the coupling mode
        with the pump slower than the turbine, as the plant has it.
        """
        if self.tc_a is None:
            return w_t.copy(), t_t.copy()
        a, gam = self.tc_a, self.tc_gamma
        w_p = w_t.copy()
        t_p = t_t.copy()
        pos = t_t > 0

        def root(qa: float, qb: np.ndarray, qc: np.ndarray) -> np.ndarray:
            disc = np.maximum(qb**2 - 4 * qa * qc, 0.0)
            return (-qb + np.sqrt(disc)) / (2 * qa) if qa > 0 else np.full_like(qb, np.nan)

        wt, tt = w_t[pos], t_t[pos]
        if self.tc_table is not None:
            w_p[pos], t_p[pos] = table_pump(self.tc_table, wt, tt)
            pos = np.zeros_like(pos)  # the drive side is done
            wt, tt = w_t[pos], t_t[pos]
        # coupling mode: T_t = T_p = a6 wp^2 + a7 wp wt + a8 wt^2
        x_c = root(a[6], a[7] * wt, a[8] * wt**2 - tt)
        ok_c = np.isfinite(x_c) & (x_c > 0) & (wt >= gam * np.where(x_c > 0, x_c, np.inf))
        # converter mode: T_t = a3 wp^2 + a4 wp wt + a5 wt^2
        x_v = root(a[3], a[4] * wt, a[5] * wt**2 - tt)
        wp = np.where(ok_c, x_c, x_v)
        wp = np.where(np.isfinite(wp), np.maximum(wp, wt), wt)
        tp = np.where(ok_c, tt, a[0] * wp**2 + a[1] * wp * wt + a[2] * wt**2)
        w_p[pos], t_p[pos] = wp, np.maximum(tp, 0.0)
        # overrun (the turbine drives the pump): the coupling mode carries it with the pump slower than the turbine
        # (SR above 1), T_p = T_t = a6 wp^2 + a7 wp wt + a8 wt^2 < 0; rigid only where that has no root
        neg = t_t < 0
        wt, tt = w_t[neg], t_t[neg]
        disc = (a[7] * wt) ** 2 - 4 * a[6] * (a[8] * wt**2 - tt)
        with np.errstate(invalid="ignore", divide="ignore"):
            x_o = (-a[7] * wt + np.sqrt(np.where(disc >= 0, disc, np.nan))) / (2 * a[6]) if a[6] > 0 \
                else np.full_like(wt, np.nan)
        ok_o = np.isfinite(x_o) & (x_o > 0) & (x_o <= wt)
        w_p[neg] = np.where(ok_o, x_o, wt)
        return w_p, t_p

    # ------------------------------------------------------------------ shift lines
    def shift_gears(self, drive: DriveInputs) -> np.ndarray:
        """Gears from the identified shift lines (hysteresis between up and down lines), the recorded pedal, engaged
        after the identified actuation delay (``shifts.actuation``, when identified)."""
        return shift_line_gears(self.shift_lines, len(self.specs.gear_ratios), drive.speed_kmh, drive.pedal_pct,
                                drive.gear, delay_s=self.shift_delay_s, dt_s=drive.dt_s)

    # ------------------------------------------------------------------ battery
    def _battery_rc(self, result: IdentificationResult) -> None:
        """Use ``battery.rc`` (eq. 30 with R_0 and RC branches) when its fit kept a branch, else eq. 30."""
        self.rc = rc_model(result.fits.get("battery.rc"))
        if self.rc is not None:
            self.ocv_cell, self.r_dch, self.r_ch = self.rc["ocv"], self.rc["r_dch"], self.rc["r_ch"]
        self.notes.append(self.rc["note"] if self.rc is not None else rc_model_note(result.fits.get("battery.rc")))

    def battery(self, p_w: np.ndarray, dt_s: float, soc0_pct: float, temp_degc: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Current, terminal voltage and displayed SOC for the battery power ``p_w`` (eq. 30, or with RC branches
        when ``battery.rc`` kept one, at the pack temperature ``temp_degc`` (default the fit's mean); coulomb
        counting)."""
        f8 = np.float64
        arrs = [np.ascontiguousarray(a, dtype=f8) for a in (p_w, self.soc_nodes, self.ocv_cell, self.r_dch, self.r_ch)]
        if self.rc is None:
            return _battery_steps(arrs[0], float(dt_s), float(soc0_pct), *arrs[1:], float(self.specs.n_cells_series),
                                  float(self.soc_per_ah))
        rc = self.rc
        temp = np.full(arrs[0].size, rc["temp_mean_degc"]) if temp_degc is None else temp_degc
        return _battery_steps_rc(arrs[0], float(dt_s), float(soc0_pct), *arrs[1:], float(self.specs.n_cells_series),
                                 float(self.soc_per_ah), *(np.ascontiguousarray(rc[k], dtype=f8) for k in (
                                     "r_rc", "tau_rc", "r_lit_dch", "r_lit_ch")), rc["beta_temp_per_k"],
                                 rc["t_ref_degc"], np.ascontiguousarray(temp, dtype=f8))

    # ------------------------------------------------------------------ motor
    def motor_power_w(self, torque_nm: np.ndarray, speed_radps: np.ndarray) -> np.ndarray:
        """Motor DC power (W): the loss model when the model uses it, else the Willans lines per side."""
        t, w = np.asarray(torque_nm, float), np.asarray(speed_radps, float)
        if self.loss_model is not None:
            return t * w + loss_w(self.loss_model[0], t, w, self.loss_model[1], to_standstill=True)
        return np.where(t >= 0, (t * w + self.w_loss) / self.e, self.e_gen * t * w + self.w_loss_gen)

    # ------------------------------------------------------------------ the drive
    def run(self, drive: DriveInputs, *, gear_source: str = "recorded") -> Prediction:
        """Predict fuel, electric energy and SOC of one drive.

        Parameters
        ----------
        drive:
            The measured inputs.
        gear_source:
            ``recorded`` (replay the engaged gear) or ``shift_lines`` (the identified shift lines).
        """
        sp = self.specs
        notes = list(self.notes)
        dt = drive.dt_s
        v = drive.speed_kmh * _KMH
        # acceleration: central difference smoothed over 1 s (the speed trace is quantised)
        k = max(round(1.0 / dt), 1)
        v_s = np.convolve(np.pad(v, (k // 2, k - 1 - k // 2), mode="edge"), np.ones(k) / k, mode="valid") \
            if k > 1 else v
        a = np.gradient(v_s, dt)
        v_kmh = drive.speed_kmh
        moving = v > 0.05
        f_road = np.where(moving, self.f0 + self.f1 * v_kmh + self.f2 * v_kmh**2, 0.0)
        f_need = f_road + sp.test_mass_kg * a
        f_brake = np.zeros_like(v)
        if self.brake is not None:
            (mf, cf), (mr, cr) = self.brake
            tq = (np.where(drive.brake_front_bar > 0.3, mf * drive.brake_front_bar + cf, 0.0)
                  + np.where(drive.brake_rear_bar > 0.3, mr * drive.brake_rear_bar + cr, 0.0))
            f_brake = np.where(moving, np.maximum(tq, 0.0) / sp.wheel_radius_m, 0.0)
        f_pt = np.where(moving, f_need + f_brake, 0.0)
        if gear_source == "shift_lines":
            if not self.shift_lines:
                raise IdentificationError("prediction: no shift line identified")
            gear = self.shift_gears(drive)
            notes.append("gear from the identified shift lines")
        elif gear_source == "recorded":
            gear = drive.gear.astype(int)
            notes.append("gear replayed from the recording")
        else:
            raise ValueError(f"gear_source {gear_source!r}: allowed are 'recorded' and 'shift_lines'")
        gear = np.clip(gear, 0, len(sp.gear_ratios))
        t_out = f_pt * sp.wheel_radius_m / sp.final_drive_ratio
        t_out = np.where(gear > 0, t_out, 0.0)
        ratio = np.array([0.0, *list(sp.gear_ratios)])[gear]
        w_t = v / sp.wheel_radius_m * sp.final_drive_ratio * ratio
        t_t = self.input_torque_nm(gear, t_out, drive.oil_degc, w_t)
        t_t = np.where(moving & (gear > 0), t_t, 0.0)
        lock = drive.lockup_closed > 0.5
        w_p, t_p = w_t.copy(), t_t.copy()
        open_ = ~lock & (gear > 0) & moving
        if open_.any():
            w_p[open_], t_p[open_] = self.pump_nm(w_t[open_], t_t[open_])
        # the pump side's inertia torque (motor rotor and pump), on the pump speed smoothed as the vehicle speed
        w_ps = np.convolve(np.pad(w_p, (k // 2, k - 1 - k // 2), mode="edge"), np.ones(k) / k, mode="valid") \
            if k > 1 else w_p
        t_j = np.where(moving & (gear > 0), self.j_pump * np.gradient(w_ps, dt), 0.0)  # neutral: the pump runs free
        on = drive.engine_on > 0.5
        k0 = drive.k0_closed > 0.5
        free = ~moving & (gear > 0) & ~lock & ~on
        if free.any() and math.isfinite(self.j_over_c):
            w_p = np.where(free, rundown_speed(free, dt, self.j_over_c, float(np.max(w_p))), w_p)
        t_e = np.where(on, drive.engine_torque_nm, 0.0)
        t_e_split = t_e
        if self.engine_torque_corr is not None:
            t_e_split = np.where(on, corrected_engine_torque(*self.engine_torque_corr, drive.engine_torque_nm), 0.0)
        w_e = np.where(on & k0, w_p, drive.engine_speed_rpm * _RPM)
        t_m = np.where(k0, t_p + t_j - t_e_split, t_p + t_j)
        w_m = w_p
        p_el = self.motor_power_w(t_m, w_m)
        p_el = np.where((w_m < 1.0) & (np.abs(t_m) < 0.5), 0.0, p_el)
        p_bat = p_el + drive.p_lv_w / self.eta_dcdc
        i_b, v_b, soc = self.battery(p_bat, dt, drive.initial_soc_pct, drive.battery_degc)
        fuel = np.where(on, self.fuel_gps(w_e / _RPM, t_e), 0.0)
        if self.cold is not None and drive.initial_coolant_degc is not None:  # the factor on the predicted coolant
            fuel, _coolant = self.cold.run(fuel, t_e * w_e, on, dt, drive.initial_coolant_degc, sp.fuel_lhv_j_per_kg)
        n_starts = int(np.count_nonzero(np.diff(on.astype(int)) == 1))  # the replayed strategy's starts
        start_g = n_starts * self.start_g if self.start_g is not None else 0.0
        fuel_g = float(np.sum(fuel) * dt) + start_g
        notes.append("engine on/off, K0 and engine torque replayed from the recording (the strategy's split)")
        notes.append("not modelled (not in the public specs): the engine's rotating inertia and start energy"
                     + ("" if self.start_g is not None else "; fuel of engine starts")
                     + ("" if self.j_pump > 0 else "; the motor's and pump's inertia"))
        series = {"t_s": drive.t_s, "gear": gear.astype(float), "motor_torque_nm": t_m, "motor_speed_rpm": w_m / _RPM,
                  "engine_torque_nm": t_e, "engine_torque_split_nm": t_e_split, "engine_speed_rpm": w_e / _RPM,
                  "fuel_gps": fuel,
                  "battery_current_a": i_b, "battery_voltage_v": v_b, "soc_pct": soc, "motor_elec_power_w": p_el,
                  "wheel_force_n": f_pt}
        series["tc_slip_loss_w"] = np.where(open_, t_p * w_p - t_t * w_t, 0.0)  # the converter's slip loss
        series.update(turbine_torque_nm=t_t, turbine_speed_radps=w_t, pump_inertia_power_w=t_j * w_p)
        return Prediction(fuel_g=fuel_g, co2_g=fuel_g * CO2_G_PER_G_DIESEL,
                          electric_wh=float(np.sum(v_b * i_b) * dt / 3600.0), final_soc_pct=float(soc[-1]),
                          distance_km=float(np.sum(v) * dt / 1000.0), series=series, notes=notes,
                          engine_starts=n_starts, start_fuel_g=start_g)
