"""Signal roles: the channel names and units a Recording carries and identification needs.

The acquisition names decoded channels by role; identification asks for roles, never for bus
signals. A real car's log is brought to the same roles by a signal map (TOML), so identification
runs unchanged on it. Units are engineering units as a test engineer reads them on a bench.
"""

from __future__ import annotations

__all__ = ["PLAUSIBLE", "ROLES", "plausible_range", "unit_of_role"]

#: role name -> (unit, description)
ROLES: dict[str, tuple[str, str]] = {
    # vehicle CAN / OBD
    "vehicle_speed_kmh": ("km/h", "vehicle speed from the vehicle CAN"),
    "engine_speed_rpm": ("rpm", "engine speed"),
    "engine_torque_nm": ("Nm", "engine torque"),
    "fuel_mass_flow_gps": ("g/s", "fuel mass flow"),
    "em_speed_rpm": ("rpm", "electric motor speed (torque converter pump speed)"),
    "em_torque_nm": ("Nm", "electric motor torque"),
    "displayed_soc_pct": ("%", "displayed state of charge"),
    "gear_target": ("", "target gear (0 neutral)"),
    "gear_actual": ("", "actual gear (0 neutral)"),
    "pedal_pct": ("%", "accelerator pedal position"),
    "brake_pedal_pct": ("%", "brake pedal"),
    "k0_closed": ("", "K0 clutch closed (1) or open (0)"),
    "lockup_closed": ("", "lock-up clutch closed (1) or open (0)"),
    "hybrid_mode": ("", "0 Hybrid, 1 Electric, 2 E-Save, 3 Charge"),
    "engine_on": ("", "engine firing (1) or off (0)"),
    # IVT-S shunts
    "battery_current_a": ("A", "HV battery current (positive discharge)"),
    "battery_voltage_v": ("V", "HV battery voltage"),
    "battery_power_w": ("W", "HV battery power (positive discharge)"),
    "hpcu_current_a": ("A", "HPCU high-voltage side current (positive into the HPCU)"),
    "hpcu_voltage_v": ("V", "HPCU high-voltage side voltage"),
    "dcdc_lv_current_a": ("A", "DC/DC low-voltage side current"),
    "dcdc_lv_voltage_v": ("V", "DC/DC low-voltage side voltage"),
    "lv_battery_current_a": ("A", "12 V battery current (positive discharge)"),
    "lv_battery_voltage_v": ("V", "12 V battery voltage"),
    # propeller shaft telemetry
    "shaft_torque_nm": ("Nm", "propeller shaft torque (strain gauge + telemetry)"),
    # SPA100 brake pressures
    "brake_pressure_fl_bar": ("bar", "front-left caliper pressure"),
    "brake_pressure_fr_bar": ("bar", "front-right caliper pressure"),
    "brake_pressure_rl_bar": ("bar", "rear-left caliper pressure"),
    "brake_pressure_rr_bar": ("bar", "rear-right caliper pressure"),
    "master_cylinder_bar": ("bar", "master cylinder pressure"),
    # chassis dyno
    "dyno_speed_kmh": ("km/h", "roller speed"),
    "dyno_set_speed_kmh": ("km/h", "dyno speed set point"),
    "dyno_force_front_n": ("N", "front roller tractive force"),
    "dyno_force_rear_n": ("N", "rear roller tractive force"),
    # thermocouples
    "engine_coolant_in_degc": ("degC", "engine coolant inlet"),
    "engine_coolant_out_degc": ("degC", "engine coolant outlet"),
    "battery_coolant_in_degc": ("degC", "HV battery coolant inlet"),
    "battery_coolant_out_degc": ("degC", "HV battery coolant outlet"),
    "battery_temp_degc": ("degC", "HV battery surface"),
    "hpcu_coolant_in_degc": ("degC", "HPCU coolant inlet"),
    "hpcu_coolant_out_degc": ("degC", "HPCU coolant outlet"),
    "motor_coolant_in_degc": ("degC", "motor coolant inlet"),
    "motor_coolant_out_degc": ("degC", "motor coolant outlet"),
    "gearbox_oil_degc": ("degC", "gearbox oil (ATF) sump"),
}


#: unit -> (lowest, highest) value any vehicle on a chassis dyno can show: beyond it a sample is a corrupt cell,
#: a wrong scaling or a sensor fault, never a measurement (states: the range of their codes)
PLAUSIBLE: dict[str, tuple[float, float]] = {
    "km/h": (-100.0, 600.0), "rpm": (-30_000.0, 30_000.0), "Nm": (-20_000.0, 20_000.0), "g/s": (-1.0, 200.0),
    "%": (-10.0, 110.0), "A": (-10_000.0, 10_000.0), "V": (-100.0, 2_000.0), "W": (-2e6, 2e6),
    "bar": (-10.0, 1_000.0), "N": (-1e6, 1e6), "degC": (-273.15, 2_000.0), "": (-1.0, 100.0),
}


def plausible_range(role: str) -> tuple[float, float]:
    """The plausible range of a role's values (from its unit; unbounded for an unknown role)."""
    if role not in ROLES:
        return (-float("inf"), float("inf"))
    return PLAUSIBLE.get(ROLES[role][0], (-float("inf"), float("inf")))


def unit_of_role(role: str) -> str:
    """Return the engineering unit of a role (``''`` for states and unknown names)."""
    return ROLES.get(role, ("", ""))[0]
