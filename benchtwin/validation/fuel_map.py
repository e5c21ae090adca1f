"""Reading the identified BSFC map as a fuel mean effective pressure (moved to :mod:`benchtwin.identification.fuel_map`,
where the cold-start factor's identification reads it too)."""

from benchtwin.identification.fuel_map import fuel_map_gps, map_pmf

__all__ = ["fuel_map_gps", "map_pmf"]
