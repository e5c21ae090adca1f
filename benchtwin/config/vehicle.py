"""The vehicle file: every true parameter of the emulated vehicle (the paper's P2 PHEV, or a conventional car).

``specs.layout`` picks the plant: ``p2_phev`` (the default: engine, K0, motor, HV pack, DC/DC) needs the
``[motor]``, ``[battery]`` and ``[hybrid]`` tables; ``conventional`` (engine, torque converter and the stepped
automatic, no motor, no HV pack, the 12 V loads on an engine-driven alternator) must not have them
(:data:`MOTOR_TABLES`). A battery-electric plant is not emulated.

A vehicle file has a ``[specs]`` table with exactly the public specification that identification may
know (:class:`~benchtwin.config.specs.VehicleSpecs`) and one table per subsystem with the true
model parameters that identification must recover (or that only the plant needs). Every key carries
its unit in its name (``f0_n``, ``f1_n_per_kmh``, ``idle_speed_rpm``); a key with the wrong unit suffix
is an unknown key and the loader suggests the right one.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from benchtwin.config._base import StrictModel, load_model, scenario_path
from benchtwin.config.specs import VehicleSpecs

__all__ = [
    "MOTOR_TABLES",
    "BatteryConfig",
    "BrakesConfig",
    "EngineConfig",
    "HighFidelityConfig",
    "HybridConfig",
    "LowVoltageConfig",
    "MotorConfig",
    "RoadLoadConfig",
    "ShiftScheduleConfig",
    "ThermalConfig",
    "TorqueConverterConfig",
    "TransmissionConfig",
    "VehicleConfig",
    "load_vehicle",
]


#: a full-load torque point: a machine's maximum torque is positive at every speed of its curve
FullLoadTorque = Annotated[float, Field(gt=0, le=10_000)]
#: a speed axis point, rpm
Rpm = Annotated[float, Field(ge=0, le=50_000)]


def _increasing(name: str, values: list[float]) -> list[float]:
    if any(b <= a for a, b in itertools.pairwise(values)):
        raise ValueError(f"{name} must increase strictly")
    return values


class RoadLoadConfig(StrictModel):
    """Road-load coefficients the dyno simulates (Table 3) and the vehicle's own parasitic loss on rollers."""

    f0_n: float = Field(ge=0)
    f1_n_per_kmh: float = Field(ge=0)
    f2_n_per_kmh2: float = Field(ge=0)
    parasitic_f0_n: float = Field(default=0.0, ge=0)
    parasitic_f1_n_per_kmh: float = Field(default=0.0, ge=0)
    parasitic_f2_n_per_kmh2: float = Field(default=0.0, ge=0)
    wheel_equivalent_mass_kg: float = Field(default=60.0, ge=0, description="rotating wheels, rollers' view")

    @model_validator(mode="after")
    def _parasitic_below_target(self) -> RoadLoadConfig:
        if self.parasitic_f0_n > self.f0_n:
            raise ValueError("parasitic_f0_n must not exceed f0_n (the dyno cannot pull the car)")
        return self


class EngineConfig(StrictModel):
    """Diesel engine: full load, idle, friction, fuel map (BSFC over speed x BMEP), start cost."""

    idle_speed_rpm: float = Field(gt=0)
    max_speed_rpm: float = Field(gt=0, le=50_000)
    inertia_kgm2: float = Field(gt=0)
    full_load_speed_rpm: list[Rpm] = Field(min_length=2)
    full_load_torque_nm: list[FullLoadTorque] = Field(min_length=2)
    friction_torque_nm: float = Field(ge=0, description="motoring drag at 0 rpm")
    friction_torque_nm_per_krpm: float = Field(ge=0)
    start_fuel_g: float = Field(ge=0)
    start_fuel_duration_s: float = Field(default=0.5, ge=0, le=5.0, description="an engine start's fuel is injected "
                                         "at a constant rate over this time (cranking and run-up); 0: one plant step")
    spin_rate_radps2: float = Field(default=600.0, gt=0, description="free run-up/spin-down rate with K0 open")
    idle_gain_nm_per_radps: float = Field(default=8.0, gt=0, description="conventional layout: the idle "
                                          "controller's gain (the P2 car's is [motor] idle_gain_nm_per_radps)")
    max_wheel_force_n: float = Field(default=1e9, gt=0, description="conventional layout: traction / gearbox "
                                     "torque limiter (the P2 car's is [hybrid] max_wheel_force_n); default none")
    bsfc_speed_rpm: list[float] = Field(min_length=2)
    bsfc_bmep_bar: list[float] = Field(min_length=2)
    bsfc_g_per_kwh: list[list[float]] = Field(min_length=2)

    @field_validator("full_load_speed_rpm", "bsfc_speed_rpm", "bsfc_bmep_bar")
    @classmethod
    def _axis_increasing(cls, v: list[float]) -> list[float]:
        return _increasing("axis", v)

    @model_validator(mode="after")
    def _shapes(self) -> EngineConfig:
        if len(self.full_load_speed_rpm) != len(self.full_load_torque_nm):
            raise ValueError("full_load_speed_rpm and full_load_torque_nm must have the same length")
        if len(self.bsfc_g_per_kwh) != len(self.bsfc_speed_rpm) or any(
            len(row) != len(self.bsfc_bmep_bar) for row in self.bsfc_g_per_kwh
        ):
            raise ValueError("bsfc_g_per_kwh must have one row per bsfc_speed_rpm and one column per bsfc_bmep_bar")
        if any(x <= 0 for row in self.bsfc_g_per_kwh for x in row):
            raise ValueError("bsfc_g_per_kwh values must be > 0")
        if self.idle_speed_rpm >= self.max_speed_rpm:
            raise ValueError("idle_speed_rpm must be below max_speed_rpm")
        return self


class MotorConfig(StrictModel):
    """PMSM in P2 position: torque limits and the Willans line (eq. 18-25), motoring and generating."""

    max_speed_rpm: float = Field(gt=0, le=50_000)
    inertia_kgm2: float = Field(gt=0, description="rotor plus torque converter pump")
    full_load_speed_rpm: list[Rpm] = Field(min_length=2)
    full_load_torque_nm: list[FullLoadTorque] = Field(min_length=2)
    willans_e: float = Field(gt=0, le=1)
    willans_w_loss_w: float = Field(ge=0)
    willans_e_gen: float = Field(gt=0, le=1)
    willans_w_loss_gen_w: float = Field(ge=0)
    idle_speed_rpm: float = Field(default=700.0, ge=0, description="pump speed held with K0 open")
    idle_gain_nm_per_radps: float = Field(default=8.0, ge=0)

    @field_validator("full_load_speed_rpm")
    @classmethod
    def _axis_increasing(cls, v: list[float]) -> list[float]:
        return _increasing("full_load_speed_rpm", v)

    @model_validator(mode="after")
    def _shapes(self) -> MotorConfig:
        if len(self.full_load_speed_rpm) != len(self.full_load_torque_nm):
            raise ValueError("full_load_speed_rpm and full_load_torque_nm must have the same length")
        return self


class TorqueConverterConfig(StrictModel):
    """Quadratic pump/turbine model (eq. 35-36) with coupling speed ratio and lock-up clutch."""

    a_nm_per_radps2: list[float] = Field(min_length=9, max_length=9, description="a0..a8")
    coupling_speed_ratio: float = Field(gt=0, lt=1)
    lockup_min_gear: int = Field(default=2, ge=1)
    lockup_min_speed_kmh: float = Field(default=15.0, ge=0)
    lockup_capacity_nm: float = Field(default=900.0, gt=0)
    lockup_engage_time_s: float = Field(default=0.6, gt=0, description="capacity ramp while engaging")
    pump_inertia_kgm2: float = Field(default=0.0, ge=0, description="pump (impeller) inertia of a conventional "
                                     "car; in the P2 car it is part of [motor] inertia_kgm2")


class TransmissionConfig(StrictModel):
    """Automatic gearbox: eq. 14 per gear (eta_m, C0) and the shift actuation delay."""

    eta_m: list[float] = Field(min_length=1)
    c0_nm: list[float] = Field(min_length=1)
    shift_delay_s: float = Field(gt=0, le=2.0)
    shift_inertia_phase_s: float = Field(default=0.3, gt=0, le=2.0,
                                         description="turbine speed transition with the converter open")

    @field_validator("eta_m")
    @classmethod
    def _eta_range(cls, v: list[float]) -> list[float]:
        if any(not 0.5 < x <= 1.0 for x in v):
            raise ValueError("eta_m values must be in (0.5, 1]")
        return v

    @field_validator("c0_nm")
    @classmethod
    def _c0_positive(cls, v: list[float]) -> list[float]:
        if any(x < 0 for x in v):
            raise ValueError("c0_nm values must be >= 0")
        return v


class ShiftScheduleConfig(StrictModel):
    """Shift lines per gear pair g -> g+1 (km/h as a linear function of pedal %), with hysteresis."""

    up_v0_kmh: list[float] = Field(min_length=1)
    up_slope_kmh_per_pct: list[float] = Field(min_length=1)
    down_v0_kmh: list[float] = Field(min_length=1)
    down_slope_kmh_per_pct: list[float] = Field(min_length=1)

    @model_validator(mode="after")
    def _hysteresis(self) -> ShiftScheduleConfig:
        n = len(self.up_v0_kmh)
        if not (len(self.up_slope_kmh_per_pct) == len(self.down_v0_kmh) == len(self.down_slope_kmh_per_pct) == n):
            raise ValueError("the four shift-line lists must have one entry per gear pair")
        for g in range(n):
            for pedal in (0.0, 100.0):
                up = self.up_v0_kmh[g] + self.up_slope_kmh_per_pct[g] * pedal
                down = self.down_v0_kmh[g] + self.down_slope_kmh_per_pct[g] * pedal
                if down >= up:
                    raise ValueError(f"downshift line of pair {g + 1}-{g + 2} must lie below its upshift line")
        return self


class BrakesConfig(StrictModel):
    """Hydraulic brakes (torque = gain x pressure per axle) and the regenerative blending strategy."""

    gain_front_nm_per_bar: float = Field(gt=0)
    gain_rear_nm_per_bar: float = Field(gt=0)
    max_brake_torque_nm: float = Field(gt=0, description="total wheel brake torque at 100 % brake pedal")
    regen_cutoff_speed_kmh: float = Field(ge=0)
    front_share_base: float = Field(gt=0, lt=1, description="front share of hydraulic torque at low deceleration")
    front_share_per_mps2: float = Field(ge=0)
    front_share_max: float = Field(gt=0, lt=1)
    coast_regen_torque_nm: float = Field(ge=0, description="motor drag at pedal 0 (coast recuperation)")


class BatteryConfig(StrictModel):
    """HV battery: literature cell maps scaled by alpha, beta (eq. 29-30), coulomb counting, usable window."""

    capacity_ah: float = Field(gt=0)
    alpha: float = Field(gt=0)
    beta_discharge: float = Field(gt=0)
    beta_charge: float = Field(gt=0)
    soc_min_frac: float = Field(ge=0, lt=1)
    soc_max_frac: float = Field(gt=0, le=1)
    max_discharge_power_w: float = Field(gt=0)
    max_charge_power_w: float = Field(gt=0)
    discharge_derate_band_pct: float = Field(
        default=5.0, ge=0, le=50, description="BMS: discharge power falls linearly to 0 over this many displayed-SOC "
        "points above 0 % (soc_min); 0: full power down to the floor")
    charge_derate_band_pct: float = Field(
        default=3.0, ge=0, le=50, description="BMS: charge power falls linearly to 0 over this many displayed-SOC "
        "points below 100 % (soc_max)")
    floor_engine_start_pct: float = Field(
        default=1.0, ge=0, le=50, description="BMS: below this displayed SOC the engine starts and K0 closes "
        "whatever the test commands, until the SOC is back above the discharge band")

    @model_validator(mode="after")
    def _window(self) -> BatteryConfig:
        if self.soc_min_frac >= self.soc_max_frac:
            raise ValueError("soc_min_frac must be below soc_max_frac")
        return self


class LowVoltageConfig(StrictModel):
    """DC/DC converter, 12 V battery and the 12 V loads (base load plus random fan/pump duty)."""

    dcdc_efficiency: float = Field(gt=0.5, le=1)
    dcdc_voltage_v: float = Field(gt=6, lt=20)
    battery_capacity_ah: float = Field(gt=0)
    battery_ocv_empty_v: float = Field(gt=0)
    battery_ocv_full_v: float = Field(gt=0)
    battery_resistance_ohm: float = Field(gt=0)
    dcdc_droop_ohm: float = Field(default=0.002, ge=0, description="output voltage drop per ampere")
    battery_initial_soc_frac: float = Field(gt=0, le=1)
    base_load_w: float = Field(ge=0)
    fan_load_w: float = Field(ge=0)
    pump_load_w: float = Field(ge=0)
    mean_switch_interval_s: float = Field(gt=0)


class HybridConfig(StrictModel):
    """Hybrid strategy thresholds for the four modes (Hybrid, Electric, E-Save, Charge)."""

    engine_on_power_w: float = Field(gt=0)
    engine_off_power_w: float = Field(ge=0)
    engine_on_speed_kmh: float = Field(gt=0)
    engine_min_on_time_s: float = Field(ge=0)
    sustain_soc_pct: float = Field(ge=0, le=100)
    sustain_gain_w_per_pct: float = Field(ge=0)
    max_sustain_power_w: float = Field(ge=0)
    electric_kickdown_pedal_pct: float = Field(gt=0, le=100)
    charge_power_w: float = Field(gt=0)
    esave_on_power_w: float = Field(gt=0)
    max_wheel_force_n: float = Field(gt=0, description="traction/gearbox torque limiter on the driver demand")


class ThermalConfig(StrictModel):
    """Lumped thermal models feeding the thermocouple places of the Trace."""

    engine_heat_capacity_j_per_k: float = Field(gt=0)
    engine_coolant_flow_kgps: float = Field(gt=0)
    engine_heat_to_coolant_frac: float = Field(gt=0, le=1)
    engine_radiator_ua_w_per_k: float = Field(ge=0)
    engine_thermostat_degc: float = Field(ge=40, le=130)
    battery_heat_capacity_j_per_k: float = Field(gt=0)
    battery_ua_w_per_k: float = Field(ge=0)
    battery_coolant_flow_kgps: float = Field(gt=0)
    edrive_heat_capacity_j_per_k: float = Field(gt=0)
    edrive_ua_w_per_k: float = Field(ge=0)
    edrive_coolant_flow_kgps: float = Field(gt=0)
    hpcu_share_of_motor_loss: float = Field(ge=0, le=1)
    # assumption (as [high_fidelity.transmission]): 8 l ATF plus the case, cooled by the engine coolant; the
    # paper-form plant's oil lump does not feed back (its gearbox has no temperature dependence)
    gearbox_oil_heat_capacity_j_per_k: float = Field(40000.0, gt=0)
    gearbox_oil_ua_w_per_k: float = Field(40.0, ge=0, description="oil to the engine coolant (heat exchanger)")


class MotorLossConfig(StrictModel):
    """High-fidelity motor and inverter losses (not a Willans line), W as functions of torque T and speed w.

    P_loss = k_cu T^2 (copper, q-axis) + k_d (1 - w_b / w)^2 (d-axis current above base speed w_b)
    + (k_h w + k_e w^2) min(1, w_b / w)^2 (iron: hysteresis and eddy, scaled by the flux squared)
    + k_f w + k_w w^3 (bearing friction, windage) + P_inv0 + k_sw |T| (inverter standby and switching).
    """

    copper_w_per_nm2: float = Field(ge=0)
    d_axis_w: float = Field(ge=0, description="k_d, W: the d-axis copper loss tends to it at high speed")
    base_speed_rpm: float = Field(gt=0)
    hysteresis_w_per_radps: float = Field(ge=0)
    eddy_w_per_radps2: float = Field(ge=0)
    friction_w_per_radps: float = Field(ge=0)
    windage_w_per_radps3: float = Field(ge=0)
    inverter_standby_w: float = Field(ge=0)
    inverter_switching_w_per_nm: float = Field(ge=0)


class BatteryDynamicsConfig(StrictModel):
    """High-fidelity HV cell: two RC branches, temperature-dependent R0, OCV hysteresis, thermal feedback."""

    r1_ohm_per_cell: float = Field(ge=0)
    tau1_s: float = Field(gt=0)
    r2_ohm_per_cell: float = Field(ge=0)
    tau2_s: float = Field(gt=0)
    r0_temp_coeff_per_k: float = Field(ge=0, description="R0 x exp(k (25 degC - T))")
    hysteresis_v_per_cell: float = Field(ge=0)
    hysteresis_charge_ah: float = Field(gt=0, description="charge throughput that moves the hysteresis by 1/e")
    initial_temp_degc: float = Field(ge=-40, le=60)


class TransmissionSpinConfig(StrictModel):
    """High-fidelity gearbox: load-independent spin loss C(w, T_oil) = C0 (1 + k_w w) exp(-k_T (T_oil - T_ref))."""

    spin_per_radps: float = Field(ge=0)
    oil_viscosity_per_k: float = Field(ge=0)
    oil_reference_degc: float = Field(ge=-40, le=150)
    oil_heat_capacity_j_per_k: float = Field(gt=0)
    oil_ua_w_per_k: float = Field(ge=0, description="oil to the engine coolant (heat exchanger)")
    initial_oil_degc: float = Field(ge=-40, le=150)


class ConverterTableConfig(StrictModel):
    """High-fidelity torque converter: K-factor and torque ratio tabulated over the speed ratio."""

    speed_ratio: list[float] = Field(min_length=3)
    k_factor_rpm_per_sqrt_nm: list[float] = Field(min_length=3, description="negative: overrun (T_p < 0)")
    torque_ratio: list[float] = Field(min_length=3)

    @field_validator("speed_ratio")
    @classmethod
    def _axis_increasing(cls, v: list[float]) -> list[float]:
        return _increasing("speed_ratio", v)

    @model_validator(mode="after")
    def _shapes(self) -> ConverterTableConfig:
        if not len(self.speed_ratio) == len(self.k_factor_rpm_per_sqrt_nm) == len(self.torque_ratio):
            raise ValueError("speed_ratio, k_factor_rpm_per_sqrt_nm and torque_ratio must have the same length")
        if any(k == 0 for k in self.k_factor_rpm_per_sqrt_nm):
            raise ValueError("k_factor_rpm_per_sqrt_nm must not be 0 (use a large value for no torque)")
        return self


class EngineWarmupConfig(StrictModel):
    """High-fidelity engine: cold-start fuel penalty from the coolant temperature (fed back from the plant)."""

    cold_penalty_frac: float = Field(ge=0, description="extra fuel at 20 degC coolant, fraction")
    warm_degc: float = Field(gt=20, le=130, description="no penalty from this coolant temperature up")
    initial_coolant_degc: float = Field(ge=-40, le=130)


class TyreSlipConfig(StrictModel):
    """High-fidelity tyres on the rollers: longitudinal slip of the driven axle, s = F_x / (C_k m g share)."""

    slip_stiffness_per_load: float = Field(gt=0, description="C_k / F_z, longitudinal slip stiffness per unit "
                                                             "normal load (per unit slip)")
    driven_axle_load_share: float = Field(gt=0, le=1, description="share of the test mass on the driven axle")


class HighFidelityConfig(StrictModel):
    """Physics of the high-fidelity truth that the paper's model forms do not have (issue 9)."""

    motor: MotorLossConfig
    battery: BatteryDynamicsConfig
    transmission: TransmissionSpinConfig
    torque_converter: ConverterTableConfig
    engine: EngineWarmupConfig
    tyre: TyreSlipConfig | None = None


class VehicleConfig(StrictModel):
    """Every true parameter of the emulated vehicle (one TOML file)."""

    name: str
    specs: VehicleSpecs
    road_load: RoadLoadConfig
    engine: EngineConfig
    motor: MotorConfig | None = None
    torque_converter: TorqueConverterConfig
    transmission: TransmissionConfig
    shift_schedule: ShiftScheduleConfig
    brakes: BrakesConfig
    battery: BatteryConfig | None = None
    low_voltage: LowVoltageConfig
    hybrid: HybridConfig | None = None
    thermal: ThermalConfig
    fidelity: Literal["paper", "high"] = "paper"
    high_fidelity: HighFidelityConfig | None = None

    @model_validator(mode="after")
    def _per_gear_lengths(self) -> VehicleConfig:
        layout = self.specs.layout
        if layout not in ("p2_phev", "conventional"):
            raise ValueError(f"specs.layout = {layout!r}: the emulator's plants are a P2 PHEV (layout = \"p2_phev\") "
                             "and a conventional car (layout = \"conventional\")")
        tables = [t for t in MOTOR_TABLES if getattr(self, t) is not None]
        if layout == "p2_phev" and len(tables) < len(MOTOR_TABLES):
            missing = [t for t in MOTOR_TABLES if t not in tables]
            raise ValueError(f"layout 'p2_phev' needs the table(s) {', '.join(f'[{t}]' for t in missing)}")
        if layout == "conventional":
            if tables:
                raise ValueError(f"layout 'conventional' has no motor or HV pack: remove the table(s) "
                                 f"{', '.join(f'[{t}]' for t in tables)}")
            if self.brakes.coast_regen_torque_nm != 0.0:
                raise ValueError("layout 'conventional' has no motor to recuperate: brakes.coast_regen_torque_nm "
                                 "must be 0")
            if self.fidelity != "paper":
                raise ValueError('layout \'conventional\' is emulated at fidelity = "paper" only')
        n = len(self.specs.gear_ratios or ())
        if len(self.transmission.eta_m) != n or len(self.transmission.c0_nm) != n:
            raise ValueError(f"transmission.eta_m and transmission.c0_nm need one value per gear ({n})")
        if len(self.shift_schedule.up_v0_kmh) != n - 1:
            raise ValueError(f"shift_schedule lists need one value per gear pair ({n - 1})")
        if (self.fidelity == "high") != (self.high_fidelity is not None):
            raise ValueError('fidelity = "high" needs a [high_fidelity] table, and a [high_fidelity] table needs '
                             'fidelity = "high"')
        if self.specs.test_mass_kg is None or self.specs.test_mass_kg <= 0:
            raise ValueError("specs.test_mass_kg must be > 0")
        return self

    @property
    def layout(self) -> str:
        """The plant's layout, ``p2_phev`` or ``conventional`` (from ``specs.layout``)."""
        return str(self.specs.layout)

    @property
    def has_motor(self) -> bool:
        """Whether the vehicle has the P2 motor, its HV pack and the DC/DC (the ``p2_phev`` layout)."""
        return self.motor is not None

    @property
    def n_gears(self) -> int:
        """Number of forward gears."""
        return len(self.specs.gear_ratios or ())


#: the tables of the P2 motor, its HV pack and the hybrid strategy: the p2_phev layout has them, a conventional
#: car does not
MOTOR_TABLES: tuple[str, ...] = ("motor", "battery", "hybrid")


def load_vehicle(path: str | Path | None = None) -> VehicleConfig:
    """Load a vehicle file (default: the shipped ``p2_phev_9at.toml``).

    Raises
    ------
    ConfigError
        The file is missing or invalid; the message names the file, the key and what is allowed.
    """
    return load_model(VehicleConfig, path if path is not None else scenario_path("vehicles", "p2_phev_9at.toml"))
