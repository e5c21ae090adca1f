"""The device kinds, keyed by the setup section that configures them (as python-can keys its backends).

Each entry names a :class:`~benchtwin.sensors.base.Device` subclass as ``module:Class``; the module is
imported only when a setup uses that section. The order is the order devices are encoded and their
frames merged on a shared bus, so it is part of the reproducibility contract: append new kinds.
"""

from __future__ import annotations

import importlib
from functools import cache

from benchtwin.config.setup import SetupConfig
from benchtwin.errors import ConfigError
from benchtwin.sensors.base import Device

__all__ = ["DEVICE_KINDS", "device_kind", "devices"]

#: setup section -> ``module:Class`` of its device kind
DEVICE_KINDS: dict[str, str] = {
    "ivt": "benchtwin.sensors.ivt:IvtShunt",
    "telemetry": "benchtwin.sensors.telemetry:ShaftTorqueTelemetry",
    "vehicle_can": "benchtwin.sensors.vehicle:VehicleCan",
    "dyno": "benchtwin.sensors.vehicle:DynoCan",
    "thermo": "benchtwin.sensors.thermocouple:ThermoModule",
    "pressure": "benchtwin.sensors.pressure:PressureModule",
}


@cache
def device_kind(section: str) -> type[Device]:
    """The Device class of a setup section.

    Raises
    ------
    ConfigError
        If no kind is registered for the section or its module cannot be imported.
    """
    try:
        target = DEVICE_KINDS[section]
    except KeyError:
        raise ConfigError(f"no device kind for setup section {section!r}; known: {', '.join(DEVICE_KINDS)}") from None
    module, _, cls = target.partition(":")
    try:
        return getattr(importlib.import_module(module), cls)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"device kind {section!r} ({target}) is not available: {exc}") from exc


def devices(setup: SetupConfig) -> list[Device]:
    """Every device of a setup, in registry order."""
    out: list[Device] = []
    for section in DEVICE_KINDS:
        out.extend(device_kind(section).from_setup(setup))
    return out
