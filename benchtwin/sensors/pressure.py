"""SPA100 brake pressure transducers on a 16-bit Modbus TCP analogue module (register map:
:mod:`benchtwin.chain.modbus_map`), and the acquisition's polling of it in batch mode.

Transducer: 0..full_scale_bar -> 0..full_scale_v (SPA100: 0-100 bar -> 0-5 V), linear, with the
configured errors (in bar); its output saturates at ``output_max_v`` (the acquisition flags readings
there as SATURATED). Module: 16-bit converter over 0-10 V, registers updated at
``update_hz`` on the module's clock (uptime in registers 12-13). Acquisition: polls input registers
0..13 at ``poll_hz`` on its own (plant) clock; each answer holds the last update before the request
reached the module; configured timeouts and exception responses give a :class:`PollLog` status.
"""

from __future__ import annotations

import numpy as np

from benchtwin.chain.frames import POLL_OK, POLL_TIMEOUT, PollLog, RegisterSnapshots
from benchtwin.chain.modbus_map import (
    CHANNELS,
    INPUT_COUNT,
    REG_COUNTER,
    REG_PRESSURE,
    REG_RAW,
    REG_STATUS,
    REG_UPTIME_HI,
    REG_UPTIME_LO,
    counts_to_volts,
    volts_to_counts,
)
from benchtwin.config.setup import PressureConfig
from benchtwin.sensors.imperfections import DeviceClock, measure
from benchtwin.trace import Trace

__all__ = ["PA_PER_BAR", "encode_pressure", "poll_snapshots", "pressure_from_counts"]

PA_PER_BAR = 1e5


def encode_pressure(trace: Trace, cfg: PressureConfig, rng: np.random.Generator) -> RegisterSnapshots:
    """The module's input registers 0..13 at every update (module clock)."""
    clock = DeviceClock.of(cfg.link)
    t_dev = clock.ticks(float(trace.time_s[0]), float(trace.time_s[-1]) + 1e-9, 1.0 / cfg.update_hz)
    t = clock.to_plant(t_dev)
    n = t.shape[0]
    regs = np.zeros((n, INPUT_COUNT), dtype=np.uint16)
    status = np.zeros(n, dtype=np.int64)
    for k, (trace_name, _role) in enumerate(CHANNELS):
        bar = measure(trace.time_s, trace[trace_name] / PA_PER_BAR, t, cfg.errors, rng, latency_s=cfg.link.latency_s)
        volts = np.minimum(bar / cfg.full_scale_bar * cfg.full_scale_v, cfg.output_max_v)  # transducer saturation
        counts, high, low = volts_to_counts(volts)
        regs[:, REG_RAW + k] = counts
        scaled = np.rint(counts_to_volts(counts) * cfg.full_scale_bar / cfg.full_scale_v * 100.0)
        regs[:, REG_PRESSURE + k] = np.clip(scaled, 0, 65535).astype(np.uint16)
        status |= high.astype(np.int64) << k
        status |= low.astype(np.int64) << (8 + k)
    regs[:, REG_STATUS] = status.astype(np.uint16)
    regs[:, REG_COUNTER] = (np.arange(n) & 0xFFFF).astype(np.uint16)
    uptime = np.rint(t_dev * 1000.0).astype(np.int64) & 0xFFFFFFFF
    regs[:, REG_UPTIME_HI] = (uptime >> 16).astype(np.uint16)
    regs[:, REG_UPTIME_LO] = (uptime & 0xFFFF).astype(np.uint16)
    return RegisterSnapshots(cfg.device, cfg.unit_id, 0, t_dev, regs, "input")


def poll_snapshots(snap: RegisterSnapshots, cfg: PressureConfig, rng: np.random.Generator, start_s: float,
                   end_s: float) -> PollLog:
    """Batch polling: what a Modbus client polling at ``poll_hz`` from ``start_s`` to ``end_s`` would log.

    Each request is sent at ``k / poll_hz`` (acquisition clock = plant clock), reaches the module
    half a round trip later, and is logged when the answer arrives (``+ poll_latency_s``). A request
    that times out is logged ``poll_timeout_s`` after it was sent, and the poll slots that fall in
    that wait are skipped (a Modbus client waits for one answer at a time).
    """
    clock = DeviceClock.of(cfg.link)
    t_req = np.arange(np.ceil(start_s * cfg.poll_hz), np.ceil(end_s * cfg.poll_hz)) / cfg.poll_hz
    t_at_module = clock.to_device(t_req + 0.5 * cfg.poll_latency_s)
    idx = np.searchsorted(snap.times, t_at_module, side="right") - 1
    n = t_req.shape[0]
    status = np.full(n, POLL_OK, dtype=np.int16)
    status[idx < 0] = POLL_TIMEOUT  # module not up yet
    r = rng.random(n)
    status[r < cfg.timeout_prob] = POLL_TIMEOUT
    status[(r >= cfg.timeout_prob) & (r < cfg.timeout_prob + cfg.exception_prob)] = cfg.exception_code
    t_log = t_req + cfg.poll_latency_s
    keep = np.ones(n, dtype=bool)
    timed_out = np.flatnonzero((status == POLL_TIMEOUT) & (idx >= 0))
    busy_until = -np.inf
    for i in timed_out:  # timeouts are rare: a short loop
        if t_req[i] < busy_until:
            keep[i] = False  # this slot fell inside an earlier wait
            continue
        busy_until = t_req[i] + cfg.poll_timeout_s
        t_log[i] = busy_until
        hi = np.searchsorted(t_req, busy_until, side="left")
        keep[i + 1:hi] = False
    values = snap.registers[np.clip(idx, 0, None)].copy()
    values[status != POLL_OK] = 0
    return PollLog(snap.device, snap.unit_id, 4, snap.first_register, t_log[keep], values[keep], status[keep])


def pressure_from_counts(counts: np.ndarray, cfg: PressureConfig) -> np.ndarray:
    """The acquisition's conversion: raw counts -> bar."""
    return counts_to_volts(counts) * cfg.full_scale_bar / cfg.full_scale_v
