"""The measured inputs of a drive and what the map-based vehicle model predicts for it (:mod:`.predict`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["CO2_G_PER_G_DIESEL", "DIESEL_DENSITY_KG_PER_L", "DriveInputs", "Prediction"]

#: CO2 per gram of diesel burnt (2.64 kg CO2 per litre at 0.832 kg/l is 3.17 g/g; the carbon balance gives 3.16)
CO2_G_PER_G_DIESEL = 3.16
#: diesel density, kg/l (EN 590 reference fuel, about 0.832)
DIESEL_DENSITY_KG_PER_L = 0.832


@dataclass
class DriveInputs:
    """The measured inputs of one drive, on one uniform time base.

    Attributes
    ----------
    t_s:
        Time, s (uniform).
    speed_kmh:
        Vehicle speed.
    gear:
        Engaged gear (0 neutral), replayed when the model is run with ``gear_source="recorded"``.
    lockup_closed, k0_closed, engine_on:
        Clutch and engine states of the measurement (0/1).
    engine_torque_nm, engine_speed_rpm:
        The engine's reported torque and speed (the strategy's split, replayed).
    pedal_pct:
        Accelerator pedal (for the shift lines).
    brake_front_bar, brake_rear_bar:
        Mean caliper pressure per axle (0 when not measured).
    p_lv_w:
        DC/DC low-voltage output power (12 V loads), W.
    initial_soc_pct:
        Displayed SOC at the start of the drive.
    name:
        What the drive is.
    oil_degc:
        Measured gearbox oil temperature (degC), or None when not logged (gaps are filled from the nearest
        reading).
    initial_coolant_degc:
        The engine coolant's first reading (the cold-start model's initial state), or None when not logged.
    battery_degc:
        Measured HV pack temperature (degC), or None when not logged (gaps filled as ``oil_degc``'s).
    """

    t_s: np.ndarray
    speed_kmh: np.ndarray
    gear: np.ndarray
    lockup_closed: np.ndarray
    k0_closed: np.ndarray
    engine_on: np.ndarray
    engine_torque_nm: np.ndarray
    engine_speed_rpm: np.ndarray
    pedal_pct: np.ndarray
    brake_front_bar: np.ndarray
    brake_rear_bar: np.ndarray
    p_lv_w: np.ndarray
    initial_soc_pct: float
    name: str = "drive"
    oil_degc: np.ndarray | None = None
    initial_coolant_degc: float | None = None
    battery_degc: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = np.asarray(self.t_s).size
        for k in ("t_s", "speed_kmh", "gear", "lockup_closed", "k0_closed", "engine_on", "engine_torque_nm",
                  "engine_speed_rpm", "pedal_pct", "brake_front_bar", "brake_rear_bar", "p_lv_w"):
            arr = np.asarray(getattr(self, k), dtype=float)
            if arr.shape != (n,):
                raise ValueError(f"DriveInputs.{k} has shape {arr.shape}, expected ({n},)")
            setattr(self, k, np.nan_to_num(arr, nan=0.0))
        if n < 3:
            raise ValueError("DriveInputs: a drive needs at least 3 samples")
        self.oil_degc = _filled(self.oil_degc, n, "oil_degc")
        self.battery_degc = _filled(self.battery_degc, n, "battery_degc")

    @property
    def dt_s(self) -> float:
        """Time step."""
        return float(np.median(np.diff(self.t_s)))


def _filled(x: np.ndarray | None, n: int, name: str) -> np.ndarray | None:
    """A measured temperature with its gaps filled from the nearest reading; None when it has no reading."""
    if x is None:
        return None
    arr = np.asarray(x, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"DriveInputs.{name} has shape {arr.shape}, expected ({n},)")
    ok = np.isfinite(arr)
    if not ok.any():
        return None
    idx = np.flatnonzero(ok)
    near = idx[np.clip(np.searchsorted(idx, np.arange(n)), 0, idx.size - 1)]
    return np.where(ok, arr, arr[near])


@dataclass
class Prediction:
    """What the map-based model predicts for one drive.

    Attributes
    ----------
    fuel_g, co2_g:
        Fuel burnt and CO2 emitted over the drive.
    electric_wh:
        Battery terminal energy (integral of V I, positive when discharging).
    final_soc_pct:
        Displayed SOC at the end.
    distance_km:
        Distance driven.
    series:
        Time series of the model (``t_s``, ``gear``, ``motor_torque_nm``, ``motor_speed_rpm``,
        ``engine_torque_nm``, ``engine_speed_rpm``, ``fuel_gps``, ``battery_current_a``,
        ``battery_voltage_v``, ``soc_pct``, ``motor_elec_power_w``).
    notes:
        What the model replayed, assumed or could not know.
    engine_starts, start_fuel_g:
        The replayed strategy's engine starts in the drive and the fuel they add (``engine.start_fuel`` per
        start, when identified; included in ``fuel_g``).
    """

    fuel_g: float
    co2_g: float
    electric_wh: float
    final_soc_pct: float
    distance_km: float
    series: dict[str, np.ndarray] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    engine_starts: int = 0
    start_fuel_g: float = 0.0

    @property
    def fuel_l(self) -> float:
        """Fuel volume, litres."""
        return self.fuel_g / 1000.0 / DIESEL_DENSITY_KG_PER_L

    @property
    def co2_g_per_km(self) -> float:
        """CO2 per km driven."""
        return self.co2_g / self.distance_km if self.distance_km > 0 else float("nan")

    def summary(self) -> dict[str, Any]:
        """The scalar results, JSON-ready."""
        return {"fuel_g": self.fuel_g, "fuel_l": self.fuel_l, "co2_g": self.co2_g,
                "co2_g_per_km": self.co2_g_per_km, "electric_wh": self.electric_wh,
                "final_soc_pct": self.final_soc_pct, "distance_km": self.distance_km, "notes": list(self.notes)}
