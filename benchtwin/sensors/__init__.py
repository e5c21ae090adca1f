"""Device models: what each instrument of the bench puts on its wire, from the Trace (the truth).

Every device kind is a :class:`~benchtwin.sensors.base.Device` subclass in its own module, named in
:data:`~benchtwin.sensors.registry.DEVICE_KINDS` by its setup section. :func:`encode` runs every device
of a setup over a Trace and returns the :class:`~benchtwin.wire.frames.DeviceOutputs` (CAN frame tables
per bus, Modbus register snapshots, CANopen process images), with the imperfections of the setup file and
random draws from the campaign seed split per device and block of plant time; :class:`ChunkEncoder` does
the same over a Trace fed chunk by chunk, with the same bytes. :func:`bus_database` is every CAN layout on one
bus of a setup, as one cantools Database.
"""

from __future__ import annotations

from pathlib import Path

import cantools
from cantools.database.can import Database, Message, Node

from benchtwin.config.setup import SetupConfig
from benchtwin.errors import DataError
from benchtwin.sensors.base import Device
from benchtwin.sensors.encoder import ChunkEncoder
from benchtwin.sensors.registry import devices, setup_for_trace
from benchtwin.trace import Trace
from benchtwin.wire.frames import DeviceOutputs

__all__ = ["ChunkEncoder", "Device", "bus_database", "device_names", "devices", "encode", "setup_for_trace",
           "write_bus_dbcs"]


def device_names(setup: SetupConfig) -> list[str]:
    """Names of the devices of a setup (also the keys of the per-device random streams)."""
    return [d.name for d in devices(setup)]


def encode(trace: Trace, setup: SetupConfig, seed: int | None = 0, *, workers: int | None = None) -> DeviceOutputs:
    """Encode every device of ``setup`` over the whole ``trace``: the one-chunk case of :class:`ChunkEncoder`.

    Parameters
    ----------
    trace:
        The truth (must hold the TRACE_CHANNELS the configured sensors read).
    setup:
        The bench.
    seed:
        Campaign seed; each device draws from its own stream per block of plant time, split from it.
    workers:
        Threads encoding devices in parallel; the result does not depend on it. Default 1
        (:class:`ChunkEncoder`).

    Raises
    ------
    DataError
        If the trace is too short.
    MissingChannelError
        If a configured sensor's channel is absent from the trace.
    """
    if len(trace) < 2:
        raise DataError("trace needs at least two samples to encode")
    return ChunkEncoder(setup, seed, workers=workers).feed(trace, final=True)


def bus_database(setup: SetupConfig, bus: str) -> Database:
    """Every CAN layout on one bus of a setup, as one cantools Database (what a user loads to decode a log).

    IVT-S messages are renamed per place (``IVT_Hpcu_Result_I``) and moved to the shunt's ids; the
    thermo module's TPDOs come from its EDS mapping.

    Parameters
    ----------
    setup:
        The bench.
    bus:
        Bus name.
    """
    messages: list[Message] = []
    nodes: dict[str, Node] = {"BENCH": Node("BENCH")}
    for d in devices(setup):
        db = d.database() if d.bus == bus else None
        if db is None:
            continue
        messages.extend(db.messages)
        for node in db.nodes:
            nodes.setdefault(node.name, node)
    return Database(messages, list(nodes.values()), version=f"benchtwin-{setup.name}-{bus}")


def write_bus_dbcs(setup: SetupConfig, directory: str | Path) -> dict[str, Path]:
    """Write ``<bus>.dbc`` for every bus of the setup into ``directory``; return bus -> path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    out = {}
    for bus in setup.buses:
        path = directory / f"{bus}.dbc"
        cantools.database.dump_file(bus_database(setup, bus), str(path))
        out[bus] = path
    return out
