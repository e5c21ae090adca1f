"""Device models: what each instrument of the bench puts on its wire, from the Trace (the truth).

:func:`encode` runs every sensor of a setup over a Trace and returns the
:class:`~benchtwin.chain.frames.DeviceOutputs` (CAN frame tables per bus, Modbus register snapshots,
CANopen process images), with the imperfections of the setup file and random draws from the
campaign seed split per device. The per-device encoders (``encode_ivt``, ``encode_telemetry``,
``encode_thermo``, ``encode_pressure``, ``encode_can_device``) are pure functions of
(trace, device config, generator), so a live scheduler can encode a time slice at a time.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Any

import numpy as np

from benchtwin.chain.frames import DeviceOutputs, FrameTable
from benchtwin.chain.merge import merge_frames
from benchtwin.config.setup import SetupConfig
from benchtwin.errors import DataError
from benchtwin.sensors.imperfections import device_rng
from benchtwin.sensors.ivt import encode_ivt
from benchtwin.sensors.pressure import encode_pressure
from benchtwin.sensors.telemetry import encode_telemetry
from benchtwin.sensors.thermocouple import encode_thermo
from benchtwin.sensors.vehicle import encode_can_device
from benchtwin.trace import Trace

__all__ = ["device_names", "encode"]


def device_names(setup: SetupConfig) -> list[str]:
    """Names of the devices of a setup (also the keys of the per-device random streams)."""
    names = [f"ivt_{p}" for p in setup.ivt]
    for key in ("pressure", "telemetry", "thermo", "vehicle_can", "dyno"):
        if getattr(setup, key) is not None:
            names.append(key)
    return names


def _workers(workers: int | None) -> int:
    return max(1, min(4, os.cpu_count() or 1)) if workers is None else max(1, int(workers))


def encode(trace: Trace, setup: SetupConfig, seed: int | None = 0, *, workers: int | None = None) -> DeviceOutputs:
    """Encode every sensor of ``setup`` over ``trace``.

    Parameters
    ----------
    trace:
        The truth (must hold the TRACE_CHANNELS the configured sensors read).
    setup:
        The bench.
    seed:
        Campaign seed; each device draws from its own stream split from it.
    workers:
        Threads encoding devices in parallel (numpy releases the GIL in the heavy loops); the
        result does not depend on it. Default: the CPU count, at most 4.

    Raises
    ------
    DataError
        If the trace is too short.
    MissingChannelError
        If a configured sensor's channel is absent from the trace.
    """
    if len(trace) < 2:
        raise DataError("trace needs at least two samples to encode")
    jobs: list[tuple[str, str, Callable[[], Any]]] = []  # (kind, bus or name, job)
    for place, cfg in setup.ivt.items():
        jobs.append(("can", cfg.bus, partial(encode_ivt, trace, place, cfg, device_rng(seed, f"ivt_{place}"))))
    if setup.telemetry is not None:
        jobs.append(("can", setup.telemetry.bus,
                     partial(encode_telemetry, trace, setup.telemetry, device_rng(seed, "telemetry"))))
    if setup.vehicle_can is not None:
        jobs.append(("can", setup.vehicle_can.bus, partial(encode_can_device, trace, "vehicle", setup.vehicle_can,
                                                          device_rng(seed, "vehicle_can"))))
    if setup.dyno is not None:
        jobs.append(("can", setup.dyno.bus, partial(encode_can_device, trace, "dyno", setup.dyno,
                                                   device_rng(seed, "dyno"))))
    if setup.thermo is not None:
        jobs.append(("canopen", "thermo", partial(encode_thermo, trace, setup.thermo, device_rng(seed, "thermo"))))
    if setup.pressure is not None:
        jobs.append(("modbus", setup.pressure.device,
                     partial(encode_pressure, trace, setup.pressure, device_rng(seed, "pressure"))))
    n = _workers(workers)
    if n == 1:
        results = [job() for _, _, job in jobs]
    else:
        with ThreadPoolExecutor(max_workers=n, thread_name_prefix="encode") as pool:
            results = list(pool.map(lambda j: j[2](), jobs))
    out = DeviceOutputs()
    per_bus: dict[str, list[np.ndarray]] = {b: [] for b in setup.buses}
    for (kind, key, _), res in zip(jobs, results):
        if kind == "can":
            per_bus[key].append(res)
        elif kind == "canopen":
            out.canopen[key] = res
        else:
            out.modbus[key] = res
    for bus, parts in per_bus.items():
        out.can[bus] = FrameTable(bus, merge_frames(parts), setup.bitrate(bus))
    return out
