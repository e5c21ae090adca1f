"""Signal maps: how a user's log channels become the roles identification asks for.

A signal map is a TOML file::

    [source]
    format = "csv"            # "csv" or "mf4"; default from the file extension
    delimiter = "\\t"          # CSV only; default sniffed (comma, tab, semicolon, space)
    comment = "#"             # CSV lines starting with this are skipped
    header_row = 0            # CSV: index of the header line among the non-comment lines
    time_column = "time_s"    # CSV column / MF4 channel holding time; MF4 default: the master channel
    time_unit = "s"

    [channels.vehicle_speed_kmh]     # the key is a role of benchtwin.roles.ROLES
    column = "speed_mph"             # the user's column or channel name
    unit = "mph"                     # the unit it is in (converted to the role's unit); omitted: an MF4
                                     # channel's own unit, else the role's unit
    scale = 1.0                      # optional, applied after unit conversion (-1 flips a sign)
    offset = 0.0                     # optional, added after scaling

    [specs]                          # optional: benchtwin.config.specs.VehicleSpecs
    n_cells_series = 120
    ...

    [battery]                        # optional hints for the map-free battery mode (pack values)
    capacity_ah = 6.0                # coulomb counting when the log has no SOC signal
    soc_nodes_pct = [20, 50, 80]     # OCV/R nodes (default one node: constant OCV and R)
    min_abs_current_a = 2.0          # leave out near-zero-current samples (relaxation, not OCV)
    min_rest_s = 600                 # rests at least this long give OCV points
    start_soc_pct = 95.0             # the SOC at the log's first sample, when known (anchors the count;
                                     # default: chosen from the data, see identification/soc_reference.py)

Units are converted through a small explicit table (:data:`UNITS`): each unit names its quantity
and its factor and offset to a base unit; a role's unit and the user's unit must be of one quantity.
An unknown role, unit or quantity mismatch is a :class:`~benchtwin.errors.ConfigError` naming the key.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field

from benchtwin.config._base import StrictModel, load_model, validate_data
from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import ConfigError
from benchtwin.roles import ROLES

__all__ = ["UNITS", "BatteryHints", "ChannelMap", "SignalMap", "SourceOptions", "convert_units", "load_signal_map",
           "signal_map_from_dict"]

#: unit -> (quantity, factor, offset): value_in_base = value * factor + offset
UNITS: dict[str, tuple[str, float, float]] = {
    # speed (base m/s)
    "m/s": ("speed", 1.0, 0.0),
    "km/h": ("speed", 1.0 / 3.6, 0.0),
    "kph": ("speed", 1.0 / 3.6, 0.0),
    "mph": ("speed", 0.44704, 0.0),
    # rotational speed (base rad/s)
    "rad/s": ("angular_speed", 1.0, 0.0),
    "rpm": ("angular_speed", 2.0 * np.pi / 60.0, 0.0),
    "1/min": ("angular_speed", 2.0 * np.pi / 60.0, 0.0),
    # torque (base Nm)
    "Nm": ("torque", 1.0, 0.0),
    "N*m": ("torque", 1.0, 0.0),
    "kNm": ("torque", 1000.0, 0.0),
    "lbf*ft": ("torque", 1.3558179483314004, 0.0),
    "ft*lbf": ("torque", 1.3558179483314004, 0.0),
    # power (base W)
    "W": ("power", 1.0, 0.0),
    "kW": ("power", 1000.0, 0.0),
    "hp": ("power", 745.69987158227022, 0.0),
    # voltage, current (base V, A)
    "V": ("voltage", 1.0, 0.0),
    "mV": ("voltage", 1e-3, 0.0),
    "kV": ("voltage", 1e3, 0.0),
    "A": ("current", 1.0, 0.0),
    "mA": ("current", 1e-3, 0.0),
    "kA": ("current", 1e3, 0.0),
    # pressure (base Pa)
    "Pa": ("pressure", 1.0, 0.0),
    "kPa": ("pressure", 1e3, 0.0),
    "MPa": ("pressure", 1e6, 0.0),
    "bar": ("pressure", 1e5, 0.0),
    "mbar": ("pressure", 100.0, 0.0),
    "psi": ("pressure", 6894.757293168361, 0.0),
    # force (base N)
    "N": ("force", 1.0, 0.0),
    "kN": ("force", 1e3, 0.0),
    "lbf": ("force", 4.4482216152605, 0.0),
    # temperature (base K)
    "K": ("temperature", 1.0, 0.0),
    "degC": ("temperature", 1.0, 273.15),
    "°C": ("temperature", 1.0, 273.15),
    "degF": ("temperature", 5.0 / 9.0, 273.15 - 32.0 * 5.0 / 9.0),
    # mass flow (base kg/s)
    "kg/s": ("mass_flow", 1.0, 0.0),
    "g/s": ("mass_flow", 1e-3, 0.0),
    "kg/h": ("mass_flow", 1.0 / 3600.0, 0.0),
    "g/h": ("mass_flow", 1e-3 / 3600.0, 0.0),
    "mg/s": ("mass_flow", 1e-6, 0.0),
    # ratios (base fraction)
    "%": ("ratio", 0.01, 0.0),
    "fraction": ("ratio", 1.0, 0.0),
    # time (base s)
    "s": ("time", 1.0, 0.0),
    "ms": ("time", 1e-3, 0.0),
    "us": ("time", 1e-6, 0.0),
    "min": ("time", 60.0, 0.0),
    "h": ("time", 3600.0, 0.0),
    # states and counts
    "": ("state", 1.0, 0.0),
    "-": ("state", 1.0, 0.0),
}


def convert_units(values: np.ndarray, from_unit: str, to_unit: str, *, key: str = "") -> np.ndarray:
    """Convert ``values`` from ``from_unit`` to ``to_unit`` through :data:`UNITS`.

    Raises
    ------
    ConfigError
        Unknown unit, or the two units measure different quantities; names ``key``.
    """
    where = f"{key}: " if key else ""
    for u in (from_unit, to_unit):
        if u not in UNITS:
            raise ConfigError(f"{where}unknown unit {u!r}; known units: {', '.join(repr(k) for k in UNITS if k)}")
    qa, fa, oa = UNITS[from_unit]
    qb, fb, ob = UNITS[to_unit]
    if qa != qb:
        raise ConfigError(f"{where}unit {from_unit!r} ({qa}) cannot be converted to {to_unit!r} ({qb})")
    values = np.asarray(values, dtype=float)
    if from_unit == to_unit:
        return values.copy()
    return (values * fa + oa - ob) / fb


class SourceOptions(StrictModel):
    """How to read the log file."""

    format: Literal["csv", "mf4"] | None = None
    delimiter: str | None = None
    comment: str = "#"
    header_row: int = Field(default=0, ge=0)
    time_column: str | None = None
    time_unit: str = "s"
    source_name: str = "log"


class ChannelMap(StrictModel):
    """One role's source column and conversion."""

    column: str
    unit: str | None = None
    scale: float = 1.0
    offset: float = 0.0


class BatteryHints(StrictModel):
    """Optional battery facts for the map-free battery mode."""

    capacity_ah: float | None = Field(default=None, gt=0)
    soc_nodes_pct: list[float] | None = None
    min_abs_current_a: float = Field(default=0.0, ge=0)
    min_rest_s: float = Field(default=600.0, gt=0)
    start_soc_pct: float | None = Field(default=None, ge=0, le=100)


class SignalMap(StrictModel):
    """A whole signal map (see the module docstring)."""

    source: SourceOptions = Field(default_factory=SourceOptions)
    channels: dict[str, ChannelMap] = Field(min_length=1)
    specs: VehicleSpecs | None = None
    battery: BatteryHints | None = None

    def check(self, origin: str = "<signal map>") -> SignalMap:
        """Check roles and units; raise :class:`ConfigError` naming the key of each problem."""
        problems = []
        for role, cm in self.channels.items():
            if role not in ROLES:
                problems.append(f"{origin}: key 'channels.{role}': unknown role; roles are: {', '.join(ROLES)}")
                continue
            key = f"{origin}: key 'channels.{role}.unit'"
            if cm.unit is None:
                continue
            try:
                convert_units(np.zeros(1), cm.unit, ROLES[role][0], key=key)
            except ConfigError as exc:
                problems.append(str(exc))
        if self.source.time_unit not in UNITS or UNITS[self.source.time_unit][0] != "time":
            problems.append(f"{origin}: key 'source.time_unit' = {self.source.time_unit!r}: not a time unit "
                            f"(s, ms, us, min, h)")
        if problems:
            raise ConfigError("\n".join(problems))
        return self


def load_signal_map(path: str | Path) -> SignalMap:
    """Load and check a signal map TOML file.

    Parameters
    ----------
    path:
        The TOML file.

    Raises
    ------
    ConfigError
        File missing, invalid TOML, unknown key, unknown role or unit; the message names the key.
    """
    return load_model(SignalMap, path).check(str(path))


def signal_map_from_dict(data: dict[str, Any], origin: str = "<signal map>") -> SignalMap:
    """Validate a signal map given as a mapping (same checks as :func:`load_signal_map`).

    Parameters
    ----------
    data:
        The parsed TOML content.
    origin:
        Name used in error messages.
    """
    return validate_data(SignalMap, data, origin).check(origin)
