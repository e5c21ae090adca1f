"""The device kinds, keyed by the setup section that configures them (as python-can keys its backends).

Each entry names a :class:`~benchtwin.sensors.base.Device` subclass as ``module:Class``; the module is
imported only when a setup uses that section. The order is the order devices are encoded and their
frames merged on a shared bus, so it is part of the reproducibility contract: append new kinds.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable
from functools import cache

from benchtwin.config.setup import IVT_PLACES, SetupConfig
from benchtwin.errors import ConfigError
from benchtwin.sensors.base import Device

__all__ = ["DEVICE_KINDS", "device_kind", "devices", "setup_for_trace"]

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


def setup_for_trace(setup: SetupConfig, absent: Iterable[str]) -> tuple[SetupConfig, list[str]]:
    """The setup a Trace without some channels can feed (a conventional car's: ``trace.meta["absent_channels"]``).

    The rule: an IVT-S place whose current and voltage channels are both absent is removed (a conventional car
    has no pack and no HPCU to put a shunt on); thermocouple places on absent channels are removed (the module
    too, if none is left); the vehicle CAN's roles on absent channels are marked ``not_sent`` (their signals
    carry the DBC's "not available" raw maximum and nothing is recorded for them). Any other device reading an
    absent channel is an error: the setup measures something the car does not have.

    Parameters
    ----------
    setup:
        The bench.
    absent:
        Trace channels the plant does not have.

    Returns
    -------
    tuple
        The setup (``setup`` itself when nothing is absent) and one line per device, place or role taken out.

    Raises
    ------
    ConfigError
        A device other than those reads an absent channel, or nothing is left to measure.
    """
    gone = set(absent)
    if not gone:
        return setup, []
    dropped: list[str] = []
    update: dict[str, object] = {}
    ivt = {}
    for place, cfg in setup.ivt.items():
        ch_i, ch_u = IVT_PLACES[place][:2]
        if ch_i in gone and ch_u in gone:
            dropped.append(f"ivt.{place}: the car has no {ch_i} / {ch_u}")
        elif ch_i in gone or ch_u in gone:
            raise ConfigError(f"setup {setup.name!r}: ivt.{place} reads {ch_i} and {ch_u}, and the car has only one "
                              "of them")
        else:
            ivt[place] = cfg
    update["ivt"] = ivt
    if setup.thermo is not None:
        places = [p for p in setup.thermo.places if p not in gone]
        dropped += [f"thermo place {p}: the car has no such place" for p in setup.thermo.places if p in gone]
        update["thermo"] = setup.thermo.model_copy(update={"places": places}) if places else None
    if setup.vehicle_can is not None:
        from benchtwin.sensors.vehicle import SIGNAL_MAP

        roles = sorted({src.role for src in SIGNAL_MAP["vehicle"].values()
                        if src.role is not None and src.trace in gone} | set(setup.vehicle_can.not_sent))
        dropped += [f"vehicle_can.{r}: not sent by the car" for r in roles if r not in setup.vehicle_can.not_sent]
        update["vehicle_can"] = setup.vehicle_can.model_copy(update={"not_sent": roles})
    out = setup.model_copy(update=update)
    for dev in devices(out):
        if dev.section in ("ivt", "thermo", "vehicle_can"):
            continue
        reads = {tc.trace for tc in dev.truth_channels().values()} & gone
        if reads:
            raise ConfigError(f"setup {setup.name!r}: device {dev.name} reads {', '.join(sorted(reads))}, which the "
                              f"car does not have; remove it from the setup")
    if not devices(out):
        raise ConfigError(f"setup {setup.name!r}: no device is left to measure this car")
    return out, dropped
