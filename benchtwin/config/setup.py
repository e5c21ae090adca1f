"""The setup file: the bench's sensors, their ranges, rates, buses, addresses and imperfections.

A setup file (``scenarios/setups/*.toml``) loads into :class:`SetupConfig`. Each sensor has its
measured-quantity errors (:class:`ChannelErrors`, in the unit the sensor measures: A, V, bar, Nm,
degC, or the vehicle signal's own unit) and its link errors (:class:`LinkErrors`: latency, clock,
frame faults). Everything left out is ideal; ``scenarios/setups/ideal.toml`` is the ideal chain.

Saturation is the sensor's range (``current_range_a``, ``range_bar``, the telemetry's +-10 V, the
thermo module's range): values beyond it are clipped and flagged, as on the real device.

Kept whole: one model per setup-file section, read together (a split would scatter the file format's reference).
"""

from __future__ import annotations

import difflib
import math
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from benchtwin.config._base import StrictModel, load_model, scenario_path
from benchtwin.errors import ConfigError

__all__ = [
    "DYNO_ROLES",
    "FAULT_KINDS",
    "IVT_PLACES",
    "K_TEL_STEPS",
    "THERMO_PLACES",
    "VEHICLE_CAN_ROLES",
    "BusConfig",
    "ChannelErrors",
    "DynoConfig",
    "FaultSpec",
    "IvtConfig",
    "LinkErrors",
    "PressureConfig",
    "SetupConfig",
    "ShaftConfig",
    "StuckInterval",
    "TelemetryConfig",
    "ThermoConfig",
    "VehicleCanConfig",
    "load_setup",
]

#: IVT-S places of the paper -> (trace current, trace voltage, recording current role, voltage role)
IVT_PLACES: dict[str, tuple[str, str, str, str]] = {
    "battery": ("battery_current_a", "battery_voltage_v", "battery_current_a", "battery_voltage_v"),
    "hpcu": ("hpcu_hv_current_a", "hpcu_hv_voltage_v", "hpcu_current_a", "hpcu_voltage_v"),
    "dcdc": ("dcdc_lv_current_a", "dcdc_lv_voltage_v", "dcdc_lv_current_a", "dcdc_lv_voltage_v"),
    "lv_battery": ("lv_battery_current_a", "lv_battery_voltage_v", "lv_battery_current_a", "lv_battery_voltage_v"),
}

#: thermocouple places (trace channel = role name): the paper's nine, then the gearbox oil sump (issue 9: the
#: gearbox's spin loss falls with the oil temperature, which a test engineer logs to identify it)
THERMO_PLACES: tuple[str, ...] = (
    "engine_coolant_in_degc", "engine_coolant_out_degc", "battery_coolant_in_degc", "battery_coolant_out_degc",
    "battery_temp_degc", "hpcu_coolant_in_degc", "hpcu_coolant_out_degc", "motor_coolant_in_degc",
    "motor_coolant_out_degc", "gearbox_oil_degc",
)

#: telemetry gains selectable on the rotary switch (paper, Table 2)
K_TEL_STEPS: tuple[int, ...] = (250, 500, 1000, 2000, 4000, 8000)

#: Recording roles the vehicle CAN tap carries (``vehicle.dbc``): the keys allowed under ``[vehicle_can.errors]``
#: (kept here because config sits below the sensors; a test checks it against the sensors' signal map)
VEHICLE_CAN_ROLES: tuple[str, ...] = (
    "engine_speed_rpm", "engine_torque_nm", "engine_on", "em_speed_rpm", "em_torque_nm", "fuel_mass_flow_gps",
    "gear_target", "gear_actual", "lockup_closed", "k0_closed", "pedal_pct", "brake_pedal_pct",
    "vehicle_speed_kmh", "displayed_soc_pct", "hybrid_mode",
)

#: Recording roles the dyno broadcast carries (``dyno.dbc``): the keys allowed under ``[dyno.errors]``
DYNO_ROLES: tuple[str, ...] = ("dyno_speed_kmh", "dyno_set_speed_kmh", "dyno_force_front_n", "dyno_force_rear_n")

#: host names of the loopback interface, the only place the emulated bench listens
LOOPBACK_HOSTS: tuple[str, ...] = ("127.0.0.1", "localhost", "::1")

#: the longest time any setup key may name (latencies, clock offsets, stuck intervals): one day
MAX_TIME_S = 86_400.0


class StuckInterval(StrictModel):
    """The sensor output freezes at its last value from ``start_s`` to ``end_s`` (plant time)."""

    start_s: float = Field(ge=0, le=MAX_TIME_S)
    end_s: float = Field(gt=0, le=MAX_TIME_S)

    @model_validator(mode="after")
    def _order(self) -> StuckInterval:
        if not self.end_s > self.start_s:
            raise ValueError(f"end_s ({self.end_s}) must be after start_s ({self.start_s})")
        return self


class ChannelErrors(StrictModel):
    """Errors of one measured quantity, in the unit the sensor measures (A, V, bar, Nm, degC, ...).

    The measured value is ``(1 + gain_error_frac) * filtered(true) + offset + noise``, then
    quantised to ``quantisation_step`` (on top of the wire's own resolution), clipped to
    ``saturation_min``/``saturation_max`` if set (an output stage that saturates before the device's
    range; the acquisition flags readings at these limits SATURATED) and then to the device's range.
    """

    noise_std: float = Field(0.0, ge=0, description="white noise standard deviation")
    offset: float = Field(0.0, description="constant offset")
    gain_error_frac: float = Field(0.0, gt=-1, description="relative gain error (0.01 = +1 %)")
    quantisation_step: float = Field(0.0, ge=0, description="extra quantisation step (0: the wire's own only)")
    bandwidth_hz: float = Field(0.0, ge=0, description="-3 dB bandwidth of the sensor (0: unlimited)")
    filter_order: Literal[1, 2] = Field(1, description="1: first-order lag, 2: second-order low-pass")
    damping: float = Field(0.707, gt=0, description="damping ratio of the second-order filter")
    stuck: list[StuckInterval] = Field(default_factory=list, description="intervals where the output freezes")
    saturation_min: float | None = Field(None, description="the sensor output clips here (below its range)")
    saturation_max: float | None = Field(None, description="the sensor output clips here (below its range)")

    @model_validator(mode="after")
    def _saturation(self) -> ChannelErrors:
        if self.saturation_min is not None and self.saturation_max is not None and \
                not self.saturation_max > self.saturation_min:
            raise ValueError("saturation_max must be above saturation_min")
        return self

    @property
    def ideal(self) -> bool:
        """True when the channel adds no error."""
        return (self.noise_std == 0 and self.offset == 0 and self.gain_error_frac == 0 and self.quantisation_step == 0
                and self.bandwidth_hz == 0 and not self.stuck and self.saturation_min is None
                and self.saturation_max is None)


class LinkErrors(StrictModel):
    """Timing and delivery errors of one device."""

    latency_s: float = Field(0.0, ge=0, le=10.0, description="delay between measuring and sending")
    clock_offset_s: float = Field(0.0, ge=-MAX_TIME_S, le=MAX_TIME_S, description="device clock minus plant clock "
                                                                                  "at t = 0")
    clock_drift_ppm: float = Field(0.0, gt=-1e5, lt=1e5, description="device clock rate error, ppm")
    drop_prob: float = Field(0.0, ge=0, lt=1, description="probability that a frame is lost")
    duplicate_prob: float = Field(0.0, ge=0, lt=1, description="probability that a frame is sent twice")
    reorder_prob: float = Field(0.0, ge=0, lt=1, description="probability that a frame swaps with the next one")

    @property
    def ideal(self) -> bool:
        """True when the link adds no error."""
        return (self.latency_s == 0 and self.clock_offset_s == 0 and self.clock_drift_ppm == 0 and self.drop_prob == 0
                and self.duplicate_prob == 0 and self.reorder_prob == 0)


class BusConfig(StrictModel):
    """One CAN bus of the bench."""

    bitrate: int = Field(500_000, gt=0, description="nominal bit rate, bit/s")
    description: str = ""


class IvtConfig(StrictModel):
    """One IVT-S shunt (Isabellenhuette) at one place of the HV/LV network."""

    bus: str = "instrument"
    result_base_id: int = Field(0x521, ge=0, le=0x7F8, description="CAN id of the current result; +1..+7 follow")
    command_id: int = Field(0x411, ge=0, le=0x7FF)
    response_id: int = Field(0x511, ge=0, le=0x7FF)
    mode: Literal["cyclic", "triggered"] = "cyclic"
    cycle_ms: int = Field(20, ge=1, le=60000, description="cycle time in cyclic mode")
    trigger_period_ms: int = Field(20, ge=1, description="how often the acquisition triggers in triggered mode")
    results: list[Literal["I", "U1", "U2", "U3", "T", "W", "As", "Wh"]] = Field(
        default_factory=lambda: ["I", "U1", "U2", "U3", "T", "W", "As", "Wh"], description="results sent")
    current_range_a: float = Field(1000.0, gt=0)
    voltage_range_v: float = Field(600.0, gt=0)
    adc_bits: int = Field(16, ge=8, le=32, description="the shunt's converter resolution over +-range")
    temperature_degc: float = Field(25.0, ge=-40, le=125, description="shunt temperature reported in T")
    ocs_threshold_a: float | None = Field(None, gt=0, description="over-current detection threshold: status "
                                                                  "bit OCS on the current result (None: off)")
    current_errors: ChannelErrors = Field(default_factory=ChannelErrors)
    voltage_errors: ChannelErrors = Field(default_factory=ChannelErrors)
    link: LinkErrors = Field(default_factory=LinkErrors)

    @property
    def result_ids(self) -> list[int]:
        """CAN ids of the eight results (I, U1, U2, U3, T, W, As, Wh)."""
        return [self.result_base_id + k for k in range(8)]


class PressureConfig(StrictModel):
    """SPA100 transducers on the four calipers and the master cylinder, read by a Modbus TCP module."""

    device: str = "brake_pressure"
    unit_id: int = Field(1, ge=0, le=247)
    host: str = Field("127.0.0.1", description="where the module listens; the emulated bench serves on loopback "
                                               "only (record reaches another host with --modbus-host)")
    port: int = Field(5020, ge=1, le=65535)
    full_scale_bar: float = Field(100.0, gt=0, description="SPA100 range 0..full_scale_bar")
    full_scale_v: float = Field(5.0, gt=0, description="SPA100 output at full scale")
    output_max_v: float = Field(5.25, gt=0, description="transducer output saturates here (105 % FS)")
    update_hz: float = Field(200.0, gt=0, description="module register update rate")
    poll_hz: float = Field(100.0, gt=0, description="acquisition poll rate")
    poll_latency_s: float = Field(0.002, ge=0, description="request-to-answer time of a poll")
    poll_timeout_s: float = Field(0.05, gt=0, description="client timeout: a lost answer blocks polling this long")
    timeout_prob: float = Field(0.0, ge=0, lt=1, description="probability a poll times out")
    exception_prob: float = Field(0.0, ge=0, lt=1, description="probability a poll answers an exception")
    exception_code: int = Field(6, ge=1, le=11, description="exception code answered (6: device busy)")
    errors: ChannelErrors = Field(default_factory=ChannelErrors, description="errors in bar")
    link: LinkErrors = Field(default_factory=LinkErrors)

    @field_validator("host")
    @classmethod
    def _loopback(cls, v: str) -> str:
        if v not in LOOPBACK_HOSTS and not v.startswith("127."):
            raise ValueError("the emulated pressure module serves on loopback only (127.0.0.1); to poll a real "
                             "module on another host keep the setup's host and pass `benchtwin record --modbus-host "
                             "HOST`")
        return v


class ShaftConfig(StrictModel):
    """The propeller shaft and its strain-gauge full bridge (paper eq. 1-12)."""

    youngs_modulus_pa: float = Field(210e9, gt=0)
    poisson: float = Field(0.3, ge=0, lt=0.5)
    gauge_factor: float = Field(2.0, gt=0)
    supply_v: float = Field(5.0, gt=0, description="bridge supply V_s")
    outer_radius_m: float = Field(0.0205036, gt=0)
    inner_radius_m: float = Field(0.0, ge=0)

    @model_validator(mode="after")
    def _radii(self) -> ShaftConfig:
        if not self.inner_radius_m < self.outer_radius_m:
            raise ValueError("inner_radius_m must be smaller than outer_radius_m")
        return self

    @property
    def polar_moment_m4(self) -> float:
        """I_p = pi (R_e^4 - R_i^4) / 2 (eq. 8)."""
        return math.pi * (self.outer_radius_m**4 - self.inner_radius_m**4) / 2.0


class TelemetryConfig(StrictModel):
    """Strain gauge + telemetry + 12-bit AD module for the propeller-shaft torque."""

    bus: str = "instrument"
    can_id: int = Field(0x310, ge=0, le=0x7FF)
    rate_hz: float = Field(500.0, gt=0, description="AD module frame rate")
    k_tel: int = Field(1000, description="telemetry gain (rotary switch)")
    vout_max_v: float = Field(10.0, gt=0, description="telemetry output range +-V")
    resolution_floor_nm: float = Field(0.3, ge=0, description="telemetry noise floor (Table 2: 0.3 Nm)")
    shaft: ShaftConfig = Field(default_factory=ShaftConfig)
    errors: ChannelErrors = Field(default_factory=ChannelErrors, description="errors in Nm at the shaft")
    link: LinkErrors = Field(default_factory=LinkErrors)

    @model_validator(mode="after")
    def _gain(self) -> TelemetryConfig:
        if self.k_tel not in K_TEL_STEPS:
            raise ValueError(f"k_tel {self.k_tel} is not a switch position; allowed: {list(K_TEL_STEPS)}")
        return self


class ThermoConfig(StrictModel):
    """Type K thermocouples on a CANopen thermo module with cold-junction compensation."""

    bus: str = "instrument"
    node_id: int = Field(5, ge=1, le=127)
    pdo_period_ms: int = Field(100, ge=1, le=65535, description="TPDO event timer")
    places: list[str] = Field(default_factory=lambda: list(THERMO_PLACES),
                              description="trace channel of each input, in input order (max 10)")
    not_recorded: list[str] = Field(default_factory=list, description="places not read (a family run's bench): "
                                    "left open on the wire, not decoded; the others read the same, draw for draw")
    cold_junction_degc: float = Field(25.0, ge=-40, le=125, description="terminal temperature")
    cold_junction_error_degc: float = Field(0.0, ge=-50, le=50, description="error of the module's cold-junction "
                                                                            "sensor")
    emf_resolution_uv: float = Field(0.5, ge=0, description="input converter resolution, microvolt")
    range_min_degc: float = -40.0
    range_max_degc: float = 1100.0
    errors: ChannelErrors = Field(default_factory=ChannelErrors, description="errors in degC")
    link: LinkErrors = Field(default_factory=LinkErrors)

    @model_validator(mode="after")
    def _places(self) -> ThermoConfig:
        if any(p not in self.places for p in self.not_recorded):
            raise ValueError(f"not_recorded must name places of the module ({self.places}); got {self.not_recorded}")
        bad = [p for p in self.places if p not in THERMO_PLACES]
        if bad or len(self.places) > 10 or len(set(self.places)) != len(self.places):
            raise ValueError(f"places must be up to 10 distinct of {list(THERMO_PLACES)}; got {self.places}")
        if not self.range_max_degc > self.range_min_degc:
            raise ValueError(f"range_max_degc ({self.range_max_degc}) must be above range_min_degc "
                             f"({self.range_min_degc})")
        return self


def _known_roles(errors: dict[str, Any], allowed: tuple[str, ...], where: str) -> dict[str, Any]:
    for role in errors:
        if role not in allowed:
            close = difflib.get_close_matches(role, allowed, n=1, cutoff=0.6)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise ValueError(f"{role!r} is not a role {where} carries; {hint}allowed: {', '.join(allowed)}")
    return errors


class VehicleCanConfig(StrictModel):
    """The vehicle CAN tap (ECU signals, see ``benchtwin/wire/dbc/vehicle.dbc``)."""

    bus: str = "vehicle"
    errors: dict[str, ChannelErrors] = Field(default_factory=dict,
                                             description="per Recording role, in the role's unit")
    link: LinkErrors = Field(default_factory=LinkErrors)
    not_sent: list[str] = Field(default_factory=list, description="roles the car does not send (a conventional "
                                "car's motor and pack roles): 'not available' on the wire, nothing recorded")
    not_recorded: list[str] = Field(default_factory=list, description="roles not read (a family run's bench): not "
                                    "decoded; a message carrying none of the others is not sent (its draws still "
                                    "taken: the others' are the same, draw for draw)")

    @field_validator("errors", "not_sent", "not_recorded")
    @classmethod
    def _roles(cls, v: dict[str, ChannelErrors] | list[str]) -> dict[str, ChannelErrors] | list[str]:
        _known_roles(dict.fromkeys(v), VEHICLE_CAN_ROLES, "the vehicle CAN")
        return v


class DynoConfig(StrictModel):
    """The chassis dyno's CAN broadcast (``dyno.dbc``, 100 Hz)."""

    bus: str = "dyno"
    errors: dict[str, ChannelErrors] = Field(default_factory=dict,
                                             description="per Recording role, in the role's unit")
    link: LinkErrors = Field(default_factory=LinkErrors)

    @field_validator("errors")
    @classmethod
    def _roles(cls, v: dict[str, ChannelErrors]) -> dict[str, ChannelErrors]:
        return _known_roles(v, DYNO_ROLES, "the dyno")


#: fault kind -> (what it is injected into, what the acquisition judges it from); "ivt": an IVT-S shunt,
#: "counter": a CAN device whose every frame carries a counter (IVT-S, AD module), "can": any CAN device,
#: "pressure": the Modbus module, "thermo": the CANopen thermo module, "telemetry": the AD module, "bus": a bus
FAULT_KINDS: dict[str, tuple[str, str]] = {
    "frame_loss": ("can", "random frames lost over the span (prob): counter gaps, PDO/cycle gaps"),
    "frame_loss_burst": ("counter", "every frame lost over the span: a long gap with the counter jumping"),
    "duplicate": ("can", "frames sent twice (prob): repeated counter, or a second frame within 1/4 cycle"),
    "reorder": ("counter", "frames swapped with the next of their stream (prob): counter going back"),
    "corrupt_payload": ("ivt", "random payload bytes (prob): the IVT-S mux byte does not match the identifier"),
    "wrong_dlc": ("can", "frames with a wrong data length (prob)"),
    "ivt_error": ("ivt", "the shunt reports an error in its status bits (status: 4 measurement, 8 system)"),
    "silent": ("can", "the device sends nothing over the span: a gap with the counter continuing (or no counter)"),
    "modbus_restart": ("pressure", "the Modbus server restarts: every poll over the span times out"),
    "modbus_slow": ("pressure", "the Modbus server answers late (latency_s): poll age against the module's uptime"),
    "transport_disconnect": ("bus", "the transport of a bus disconnects and reconnects: a drop event and no frames"),
    "clock_drift": ("pressure", "the module's clock runs drift_ppm fast over the span: poll time vs uptime slope"),
    "clock_step": ("pressure", "the module's clock steps by offset_s at start_s: poll time vs uptime jumps"),
    "stuck": ("channel", "the channel's value freezes (channel): bit-identical readings where noise is declared"),
    "clip": ("telemetry", "the telemetry output sits at its rail (level high/low): AD module clip bit, held"),
    "open_circuit": ("thermo", "a thermocouple opens (channel): the module reports -0x8000"),
    "log_truncation": ("bus", "the bus log ends at start_s: its time base ends before the other sources"),
}


class FaultSpec(StrictModel):
    """One fault injected on purpose (a ``[[faults]]`` entry of the setup file).

    ``device`` is a device name (``ivt_battery``, ``telemetry``, ``thermo``, ``vehicle_can``, ``dyno`` or
    the pressure module's ``device``), ``bus`` a bus of ``[buses]``; ``channel`` the Recording role for
    ``stuck`` and ``open_circuit``. The fault lasts from ``start_s`` for ``duration_s`` (plant time);
    a ``log_truncation`` has no duration (the log ends at ``start_s``).
    """

    kind: Literal[tuple(FAULT_KINDS)]  # type: ignore[valid-type]
    device: str | None = None
    bus: str | None = None
    channel: str | None = None
    start_s: float = Field(ge=0, description="plant time the fault starts")
    duration_s: float | None = Field(None, gt=0, description="how long it lasts")
    prob: float = Field(0.3, gt=0, le=1, description="frame faults: share of the span's frames hit")
    status: int = Field(4, ge=1, le=15, description="ivt_error: status nibble (4 measurement, 8 system error)")
    latency_s: float = Field(0.03, gt=0, description="modbus_slow: extra answer time")
    drift_ppm: float = Field(100.0, ge=-1000, le=1000, description="clock_drift: extra clock rate")
    offset_s: float = Field(0.1, gt=0, le=10, description="clock_step: the clock jumps forward by this")
    level: Literal["high", "low"] = Field("high", description="clip: which rail")

    @model_validator(mode="after")
    def _fields(self) -> FaultSpec:
        target = FAULT_KINDS[self.kind][0]
        if target == "bus":
            if self.bus is None or self.device is not None:
                raise ValueError(f"fault {self.kind!r} needs bus = <a bus> (and no device)")
        elif self.device is None or self.bus is not None:
            raise ValueError(f"fault {self.kind!r} needs device = <a device> (and no bus)")
        if (self.channel is None) == (self.kind in ("stuck", "open_circuit")):
            raise ValueError(f"fault {self.kind!r} " + ("needs channel = <role>" if self.channel is None
                                                        else "takes no channel"))
        if (self.duration_s is None) != (self.kind == "log_truncation"):
            raise ValueError(f"fault {self.kind!r} " + ("needs duration_s" if self.duration_s is None
                                                        else "takes no duration_s (the log ends at start_s)"))
        return self

    @property
    def end_s(self) -> float:
        """End of the span (infinite for a truncated log)."""
        return math.inf if self.duration_s is None else self.start_s + self.duration_s

    @property
    def target(self) -> str:
        """The device or bus the fault is injected into."""
        return str(self.device if self.device is not None else self.bus)


class SetupConfig(StrictModel):
    """A bench setup: buses and every sensor (see the module docstring)."""

    name: str = "setup"
    description: str = ""
    buses: dict[str, BusConfig] = Field(default_factory=lambda: {
        "vehicle": BusConfig(bitrate=500_000), "instrument": BusConfig(bitrate=1_000_000),
        "dyno": BusConfig(bitrate=500_000)})
    ivt: dict[str, IvtConfig] = Field(default_factory=dict, description="shunt place -> shunt")
    pressure: PressureConfig | None = None
    telemetry: TelemetryConfig | None = None
    thermo: ThermoConfig | None = None
    vehicle_can: VehicleCanConfig | None = None
    dyno: DynoConfig | None = None
    faults: list[FaultSpec] = Field(default_factory=list, description="faults injected on purpose ([[faults]])")

    @model_validator(mode="after")
    def _check(self) -> SetupConfig:
        if not (self.ivt or self.pressure or self.telemetry or self.thermo or self.vehicle_can or self.dyno):
            raise ValueError("the setup has no sensor: give at least one of [ivt.<place>], [pressure], "
                             "[telemetry], [thermo], [vehicle_can], [dyno]")
        for place in self.ivt:
            if place not in IVT_PLACES:
                raise ValueError(f"ivt place {place!r} unknown; allowed: {list(IVT_PLACES)}")
        buses = {f"ivt.{k}": v.bus for k, v in self.ivt.items()}
        for key in ("telemetry", "thermo", "vehicle_can", "dyno"):
            dev = getattr(self, key)
            if dev is not None:
                buses[key] = dev.bus
        for key, bus in buses.items():
            if bus not in self.buses:
                raise ValueError(f"{key}.bus = {bus!r} is not a bus of [buses] ({', '.join(self.buses)})")
        # identifiers must be unique per bus
        used: dict[tuple[str, int], str] = {}

        def claim(bus: str, cid: int, who: str) -> None:
            if (bus, cid) in used:
                raise ValueError(f"CAN id 0x{cid:X} on bus {bus!r} used by {used[(bus, cid)]} and {who}")
            used[(bus, cid)] = who

        for k, v in self.ivt.items():
            for cid in [*v.result_ids, v.command_id, v.response_id]:
                claim(v.bus, cid, f"ivt.{k}")
        if self.telemetry is not None:
            claim(self.telemetry.bus, self.telemetry.can_id, "telemetry")
        if self.thermo is not None:
            for n in range(3):
                claim(self.thermo.bus, 0x180 + 0x100 * n + self.thermo.node_id, "thermo")
        if self.vehicle_can is not None:
            for cid in (0x0A0, 0x0B0, 0x0C0, 0x0D0, 0x0E0, 0x1A0, 0x3A0):
                claim(self.vehicle_can.bus, cid, "vehicle_can")
        if self.dyno is not None:
            for cid in (0x700, 0x701):
                claim(self.dyno.bus, cid, "dyno")
        for k, f in enumerate(self.faults):
            self._check_fault(k, f)
        return self

    def device_kinds(self) -> dict[str, str]:
        """Device name -> ``ivt``, ``telemetry``, ``thermo``, ``vehicle_can``, ``dyno`` or ``pressure``."""
        out = {f"ivt_{p}": "ivt" for p in self.ivt}
        for key in ("telemetry", "thermo", "vehicle_can", "dyno"):
            if getattr(self, key) is not None:
                out[key] = key
        if self.pressure is not None:
            out[self.pressure.device] = "pressure"
        return out

    def _check_fault(self, k: int, f: FaultSpec) -> None:
        where = f"faults[{k}] ({f.kind})"
        target = FAULT_KINDS[f.kind][0]
        if target == "bus":
            if f.bus not in self.buses:
                raise ValueError(f"{where}: bus {f.bus!r} is not a bus of [buses] ({', '.join(self.buses)})")
            return
        kinds = self.device_kinds()
        kind = kinds.get(str(f.device))
        if kind is None:
            raise ValueError(f"{where}: device {f.device!r} is not in this setup ({', '.join(kinds)})")
        ok = {"can": kind != "pressure", "counter": kind in ("ivt", "telemetry"), "ivt": kind == "ivt",
              "pressure": kind == "pressure", "thermo": kind == "thermo", "telemetry": kind == "telemetry",
              "channel": True}[target]
        if not ok:
            need = {"can": "a CAN device", "counter": "a device with a frame counter (an IVT-S or the telemetry)",
                    "ivt": "an IVT-S shunt", "pressure": "the Modbus pressure module", "thermo": "the thermo module",
                    "telemetry": "the telemetry"}[target]
            raise ValueError(f"{where}: device {f.device!r} is not {need}")
        if f.kind == "open_circuit" and self.thermo is not None and f.channel not in self.thermo.places:
            raise ValueError(f"{where}: channel {f.channel!r} is not a thermocouple place ({self.thermo.places})")
        if f.kind == "modbus_slow" and self.pressure is not None and f.latency_s >= self.pressure.poll_timeout_s:
            raise ValueError(f"{where}: latency_s {f.latency_s} must be below poll_timeout_s "
                             f"{self.pressure.poll_timeout_s} (a longer wait is a timeout)")

    def faults_of(self, target: str) -> list[FaultSpec]:
        """The faults injected into one device or bus."""
        return [f for f in self.faults if f.target == target]

    def bitrate(self, bus: str) -> int:
        """Bit rate of a bus."""
        try:
            return self.buses[bus].bitrate
        except KeyError:
            raise ConfigError(f"setup {self.name!r} has no bus {bus!r}") from None


def load_setup(path: str | Path) -> SetupConfig:
    """Load a setup file; a bare name (``paper``) means the shipped ``scenarios/setups/<name>.toml``.

    Raises
    ------
    ConfigError
        File missing or invalid (the message names the file, the key and what is allowed).
    """
    p = Path(path)
    if not p.suffix and not p.exists():
        p = scenario_path("setups", f"{p.name}.toml")
    return load_model(SetupConfig, p)
