"""What identification may know about a vehicle before testing it: its public specification.

These are catalogue data (Table 1 of the paper, a homologation sheet, a tyre size), never the
parameters being identified. For an emulated campaign, validation fills them from the public part
of the vehicle file; for a real car, the user writes them in the ``[specs]`` table of a signal map.
"""

from __future__ import annotations

import itertools

from pydantic import Field, field_validator

from benchtwin.config._base import StrictModel

__all__ = ["VehicleSpecs"]


class VehicleSpecs(StrictModel):
    """Public specification of the vehicle under test.

    Attributes
    ----------
    gear_ratios:
        Gearbox ratios, 1st gear first.
    final_drive_ratio:
        Axle ratio.
    wheel_radius_m:
        Dynamic rolling radius of the driven wheels.
    engine_displacement_m3:
        Swept volume (for BMEP), e.g. 1.95e-3.
    engine_strokes:
        4 for a four-stroke engine (BMEP = 4 pi T / V_d).
    n_cells_series:
        Cells in series in the HV pack.
    em_rotor_radius_m, em_rotor_volume_m3:
        Rotor geometry for the normalised Willans line (eq. 18).
    fuel_lhv_j_per_kg:
        Lower heating value of the fuel (diesel about 42.8e6 J/kg).
    test_mass_kg:
        Inertia class / test mass.
    em_max_torque_nm, em_max_power_w, em_max_speed_rpm:
        The motor's catalogue rating (Table 1: 440 Nm, 90 kW, 6000 rpm); optional, used to draw the
        full-load curve T = min(T_max, P_max / omega) beside the efficiency map.
    """

    gear_ratios: list[float] = Field(min_length=1)
    final_drive_ratio: float = Field(gt=0)
    wheel_radius_m: float = Field(gt=0.1, lt=1.0)
    engine_displacement_m3: float = Field(gt=0, lt=0.02)
    engine_strokes: int = 4
    n_cells_series: int = Field(gt=0)
    em_rotor_radius_m: float = Field(gt=0, lt=0.5)
    em_rotor_volume_m3: float = Field(gt=0, lt=0.1)
    fuel_lhv_j_per_kg: float = Field(default=42.8e6, gt=0)
    test_mass_kg: float = Field(gt=0)
    em_max_torque_nm: float | None = Field(default=None, gt=0)
    em_max_power_w: float | None = Field(default=None, gt=0)
    em_max_speed_rpm: float | None = Field(default=None, gt=0)

    @field_validator("gear_ratios")
    @classmethod
    def _positive_descending(cls, v: list[float]) -> list[float]:
        if any(r <= 0 for r in v):
            raise ValueError("gear ratios must be positive")
        if any(b >= a for a, b in itertools.pairwise(v)):
            raise ValueError("gear ratios must decrease from 1st gear upwards")
        return v
