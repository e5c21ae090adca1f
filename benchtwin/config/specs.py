"""What identification may know about a vehicle before testing it: its public specification.

These are catalogue data (Table 1 of the paper, a homologation sheet, a tyre size), never the
parameters being identified. For an emulated campaign, validation fills them from the public part
of the vehicle file; for a real car, the user writes them in the ``[specs]`` table of a signal map.

The powertrain layout decides which keys a car has (:data:`LAYOUT_KEYS`):

==============  ==========================================================  ============================
layout          required keys                                               keys it must not have
==============  ==========================================================  ============================
``p2_phev``     every key of the engine, the gearbox, the motor, the pack   (none)
``conventional``  gear ratios, final drive, wheel radius, test mass, engine   pack and motor keys
``bev``         final drive (one fixed ratio), wheel radius, test mass,     engine keys; more than one
                pack cells, rotor geometry                                  gear ratio
==============  ==========================================================  ============================

``layout`` may be left out: it is then inferred from the keys given (engine keys and motor or pack keys:
``p2_phev``; engine keys only: ``conventional``; motor or pack keys only: ``bev``), and a set of keys
that fits no layout is an error naming the missing keys.
"""

from __future__ import annotations

import itertools
from typing import Literal

from pydantic import Field, field_validator, model_validator

from benchtwin.config._base import StrictModel

__all__ = ["ELECTRIC_KEYS", "ENGINE_KEYS", "LAYOUT_KEYS", "Layout", "VehicleSpecs"]

Layout = Literal["p2_phev", "conventional", "bev"]

#: keys that describe the combustion engine
ENGINE_KEYS: tuple[str, ...] = ("engine_displacement_m3",)
#: keys that describe the traction motor and the HV pack
ELECTRIC_KEYS: tuple[str, ...] = ("n_cells_series", "em_rotor_radius_m", "em_rotor_volume_m3")

_COMMON: tuple[str, ...] = ("final_drive_ratio", "wheel_radius_m", "test_mass_kg")

#: keys each layout must give
LAYOUT_KEYS: dict[str, tuple[str, ...]] = {
    "p2_phev": ("gear_ratios", *_COMMON, *ENGINE_KEYS, *ELECTRIC_KEYS),
    "conventional": ("gear_ratios", *_COMMON, *ENGINE_KEYS),
    "bev": (*_COMMON, *ELECTRIC_KEYS),
}

#: keys a layout has no use for (giving them is a contradiction, named in the error)
_FORBIDDEN: dict[str, tuple[str, ...]] = {
    "p2_phev": (),
    "conventional": (*ELECTRIC_KEYS, "em_max_torque_nm", "em_max_power_w", "em_max_speed_rpm"),
    "bev": ENGINE_KEYS,
}


class VehicleSpecs(StrictModel):
    """Public specification of the vehicle under test.

    Attributes
    ----------
    layout:
        ``p2_phev`` (engine, K0, motor and a stepped automatic: the paper's vehicle), ``conventional``
        (engine and a stepped gearbox, no HV pack) or ``bev`` (motor and one fixed ratio, no engine);
        inferred from the keys given when left out.
    gear_ratios:
        Gearbox ratios, 1st gear first (a BEV may give its one reduction ratio here, or leave it out).
    final_drive_ratio:
        Axle ratio (for a BEV: the overall fixed ratio, when ``gear_ratios`` is left out).
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

    layout: Layout | None = None
    gear_ratios: list[float] | None = Field(default=None, min_length=1)
    final_drive_ratio: float | None = Field(default=None, gt=0)
    wheel_radius_m: float | None = Field(default=None, gt=0.1, lt=1.0)
    engine_displacement_m3: float | None = Field(default=None, gt=0, lt=0.02)
    engine_strokes: int = 4
    n_cells_series: int | None = Field(default=None, gt=0)
    em_rotor_radius_m: float | None = Field(default=None, gt=0, lt=0.5)
    em_rotor_volume_m3: float | None = Field(default=None, gt=0, lt=0.1)
    fuel_lhv_j_per_kg: float = Field(default=42.8e6, gt=0)
    test_mass_kg: float | None = Field(default=None, gt=0)
    em_max_torque_nm: float | None = Field(default=None, gt=0)
    em_max_power_w: float | None = Field(default=None, gt=0)
    em_max_speed_rpm: float | None = Field(default=None, gt=0)

    @field_validator("gear_ratios")
    @classmethod
    def _positive_descending(cls, v: list[float] | None) -> list[float] | None:
        if v is None:
            return v
        if any(r <= 0 for r in v):
            raise ValueError("gear ratios must be positive")
        if any(b >= a for a, b in itertools.pairwise(v)):
            raise ValueError("gear ratios must decrease from 1st gear upwards")
        return v

    @model_validator(mode="after")
    def _layout_keys(self) -> VehicleSpecs:
        given = {k for k in self.model_fields_set if getattr(self, k) is not None}
        layout = self.layout
        if layout is None:
            engine = any(k in given for k in ENGINE_KEYS)
            electric = any(k in given for k in ELECTRIC_KEYS)
            layout = "p2_phev" if engine and electric else "conventional" if engine else "bev" if electric else None
            if layout is None:
                raise ValueError("specs describe neither an engine (engine_displacement_m3) nor a motor and pack "
                                 "(n_cells_series, em_rotor_radius_m, em_rotor_volume_m3); give those of the car, "
                                 "or layout = \"p2_phev\" | \"conventional\" | \"bev\"")
        missing = [k for k in LAYOUT_KEYS[layout] if getattr(self, k) is None]
        if missing:
            raise ValueError(f"layout {layout!r} needs key(s) {', '.join(missing)}")
        extra = [k for k in _FORBIDDEN[layout] if k in given]
        if extra:
            raise ValueError(f"layout {layout!r} has no use for key(s) {', '.join(extra)}: remove them, or set "
                             "the layout that has them")
        if layout == "bev" and self.gear_ratios is not None and len(self.gear_ratios) > 1:
            raise ValueError(f"layout 'bev' has one fixed ratio; gear_ratios lists {len(self.gear_ratios)}")
        if self.layout is None:
            # set without re-running this validator (validate_assignment would recurse)
            self.__dict__["layout"] = layout
        return self

    def has(self, *keys: str) -> bool:
        """Whether every one of ``keys`` is given (not ``None``)."""
        return all(getattr(self, k, None) is not None for k in keys)
