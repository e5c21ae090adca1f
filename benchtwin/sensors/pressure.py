"""SPA100 brake pressure transducers on a 16-bit Modbus TCP analogue module (register map:
:mod:`benchtwin.wire.modbus_map`), and the acquisition's polling of it in batch mode.

Transducer: 0..full_scale_bar -> 0..full_scale_v (SPA100: 0-100 bar -> 0-5 V), linear, with the
configured errors (in bar); its output saturates at ``output_max_v`` (the acquisition flags readings
there as SATURATED). Module: 16-bit converter over 0-10 V, registers updated at
``update_hz`` on the module's clock (uptime in registers 12-13). Acquisition: polls input registers
0..13 at ``poll_hz`` on its own (plant) clock; each answer holds the last update before the request
reached the module; configured timeouts and exception responses give a :class:`PollLog` status.

Injected faults (the setup's ``[[faults]]``): ``stuck`` on a pressure role, ``clock_drift`` and
``clock_step`` of the module's clock (its uptime registers), ``modbus_restart`` (every poll of the span
times out) and ``modbus_slow`` (answers ``latency_s`` late; the client waits, skipping poll slots).
The decoder judges them from the poll log: runs of timeouts, and the age of each answer (poll time
minus the module's uptime) against its neighbours (:func:`poll_clock_evidence`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from benchtwin.config.setup import ChannelErrors, FaultSpec, LinkErrors, PressureConfig
from benchtwin.sensors.base import Delivered, Device, ModbusEndpoint, TruthChannel
from benchtwin.sensors.blocks import Block
from benchtwin.sensors.imperfections import DeviceClock, faulty_clock, in_spans, measure, with_stuck
from benchtwin.sensors.poll_clock import poll_clock_evidence
from benchtwin.sensors.pressure_decode import decode_pressure_polls, pressure_from_counts
from benchtwin.sensors.pressure_polls import decode_pressure_poll_blocks
from benchtwin.trace import Trace
from benchtwin.wire.frames import POLL_OK, POLL_TIMEOUT, PollLog, RegisterSnapshots
from benchtwin.wire.modbus_map import (
    ADC_FULL_SCALE_V,
    CHANNELS,
    INPUT_COUNT,
    REG_COUNTER,
    REG_PRESSURE,
    REG_RAW,
    REG_STATUS,
    REG_UPTIME_HI,
    REG_UPTIME_LO,
    counts_to_volts,
    holding_defaults,
    volts_to_counts,
)
from benchtwin.wire.quality import DecodeSink

__all__ = ["PA_PER_BAR", "PressureModule", "decode_pressure_poll_blocks", "decode_pressure_polls", "encode_pressure",
           "poll_clock_evidence", "poll_snapshots", "pressure_from_counts"]

PA_PER_BAR = 1e5


def encode_pressure(trace: Trace, cfg: PressureConfig, rng: np.random.Generator,
                    faults: Sequence[FaultSpec] = (), blk: Block | None = None) -> RegisterSnapshots:
    """The module's input registers 0..13 at every update (module clock, with its injected clock faults).

    ``blk``: the block of plant time to encode (``trace`` and ``rng`` are then unused); None: the whole ``trace``.
    """
    blk = Block.whole(trace, rng) if blk is None else blk
    trace, rng = blk.trace, blk.rng
    clock = faulty_clock(cfg.link, faults)
    t_dev = clock.ticks(blk.start_s, blk.end_s, 1.0 / cfg.update_hz)
    t = clock.to_plant(t_dev)
    n = t.shape[0]
    regs = np.zeros((n, INPUT_COUNT), dtype=np.uint16)
    status = np.zeros(n, dtype=np.int64)
    for k, (trace_name, role) in enumerate(CHANNELS):
        bar = measure(trace.time_s, trace[trace_name] / PA_PER_BAR, t, with_stuck(cfg.errors, faults, role), rng,
                      latency_s=cfg.link.latency_s, blk=blk, key=role)
        volts = np.minimum(bar / cfg.full_scale_bar * cfg.full_scale_v, cfg.output_max_v)  # transducer saturation
        counts, high, low = volts_to_counts(volts)
        regs[:, REG_RAW + k] = counts
        scaled = np.rint(counts_to_volts(counts) * cfg.full_scale_bar / cfg.full_scale_v * 100.0)
        regs[:, REG_PRESSURE + k] = np.clip(scaled, 0, 65535).astype(np.uint16)
        status |= high.astype(np.int64) << k
        status |= low.astype(np.int64) << (8 + k)
    regs[:, REG_STATUS] = status.astype(np.uint16)
    regs[:, REG_COUNTER] = (blk.counter("updates", n) & 0xFFFF).astype(np.uint16)
    uptime = np.rint(t_dev * 1000.0).astype(np.int64) & 0xFFFFFFFF
    regs[:, REG_UPTIME_HI] = (uptime >> 16).astype(np.uint16)
    regs[:, REG_UPTIME_LO] = (uptime & 0xFFFF).astype(np.uint16)
    return RegisterSnapshots(cfg.device, cfg.unit_id, 0, t_dev, regs, "input")


def poll_snapshots(snap: RegisterSnapshots, cfg: PressureConfig, rng: np.random.Generator, start_s: float,
                   end_s: float, faults: Sequence[FaultSpec] = (), state: dict | None = None) -> PollLog:
    """Batch polling: what a Modbus client polling at ``poll_hz`` from ``start_s`` to ``end_s`` would log.

    Each request is sent at ``k / poll_hz`` (acquisition clock = plant clock), reaches the module
    half a round trip later, and is logged when the answer arrives (``+ poll_latency_s``). A request
    that times out is logged ``poll_timeout_s`` after it was sent, and the poll slots that fall in
    that wait are skipped (a Modbus client waits for one answer at a time). Over a ``modbus_restart``
    every request times out; over a ``modbus_slow`` each answer comes ``latency_s`` later.

    ``state`` carries the client's wait from one span to the next (``busy_until``: a timeout at the end
    of one span skips the first slots of the next); ``snap`` must hold the last update before ``start_s``
    reaches the module (a module with no update yet does not answer).
    """
    state = {} if state is None else state
    clock = faulty_clock(cfg.link, faults)
    t_req = np.arange(np.ceil(start_s * cfg.poll_hz), np.ceil(end_s * cfg.poll_hz)) / cfg.poll_hz
    t_at_module = clock.to_device(t_req + 0.5 * cfg.poll_latency_s)
    idx = np.searchsorted(snap.times, t_at_module, side="right") - 1
    n = t_req.shape[0]
    status = np.full(n, POLL_OK, dtype=np.int16)
    status[idx < 0] = POLL_TIMEOUT  # module not up yet
    r = rng.random(n)
    status[r < cfg.timeout_prob] = POLL_TIMEOUT
    status[(r >= cfg.timeout_prob) & (r < cfg.timeout_prob + cfg.exception_prob)] = cfg.exception_code
    status[in_spans(t_req, faults, "modbus_restart")] = POLL_TIMEOUT  # the server is down: no answer
    latency = np.full(n, cfg.poll_latency_s)
    for f in faults:
        if f.kind == "modbus_slow":
            latency[in_spans(t_req, [f], "modbus_slow")] += f.latency_s
    t_log = t_req + latency
    keep = np.ones(n, dtype=bool)
    timed_out = (status == POLL_TIMEOUT) & (idx >= 0)
    busy_until = state.get("busy_until", -np.inf)
    keep[t_req < busy_until] = False  # slots inside a wait that began in the previous span
    for i in np.flatnonzero(timed_out | (latency >= 1.0 / cfg.poll_hz)):  # rare: a short loop
        if t_req[i] < busy_until:
            keep[i] = False  # this slot fell inside an earlier wait
            continue
        busy_until = t_req[i] + (cfg.poll_timeout_s if timed_out[i] else latency[i])
        t_log[i] = busy_until
        hi = np.searchsorted(t_req, busy_until, side="left")
        keep[i + 1:hi] = False
    state["busy_until"] = busy_until
    values = snap.registers[np.clip(idx, 0, None)].copy()
    values[status != POLL_OK] = 0
    return PollLog(snap.device, snap.unit_id, 4, snap.first_register, t_log[keep], values[keep], status[keep])


class PressureModule(Device):
    """Five SPA100 transducers on the 16-bit Modbus TCP module (setup section ``[pressure]``)."""

    section = "pressure"
    wire = "modbus"

    @property
    def poll_device(self) -> str:
        """The module's device name (its poll log's name)."""
        return self.cfg.device

    def encode(self, blk: Block) -> RegisterSnapshots:
        """The module's input registers at every update of one block."""
        return encode_pressure(blk.trace, self.cfg, blk.rng, self.setup.faults_of(self.cfg.device), blk)

    def clock(self) -> DeviceClock:
        """The module's clock with its injected clock faults."""
        return faulty_clock(self.cfg.link, self.setup.faults_of(self.cfg.device))

    def deliver(self, output: RegisterSnapshots, rng: np.random.Generator, span_s: tuple[float, float],
                state: dict) -> Delivered:
        """The acquisition's polls over ``span_s`` (one block of requests), faults from ``modbus_poll``."""
        return Delivered(polls=poll_snapshots(output, self.cfg, rng, *span_s,
                                              faults=self.setup.faults_of(self.cfg.device), state=state))

    def poll_reach_s(self) -> float:
        """How far past a request the snapshots it reads may lie (plant seconds): half the poll's round trip."""
        return 0.5 * self.cfg.poll_latency_s

    def decode_polls(self, log: PollLog, sink: DecodeSink, drops: np.ndarray) -> None:
        """See :func:`decode_pressure_polls`."""
        decode_pressure_polls(log, self.cfg, sink, drops)

    def decode_poll_blocks(self, log, sink: DecodeSink, drops: np.ndarray, emit, block: int) -> None:
        """See :func:`benchtwin.sensors.pressure_polls.decode_pressure_poll_blocks` (the same channels by blocks)."""
        decode_pressure_poll_blocks(log, self.cfg, sink, drops, emit, block)

    def truth_channels(self) -> dict[str, TruthChannel]:
        """The five pressures (Pa in the Trace, bar recorded), to one step of the module's converter."""
        lsb_bar = ADC_FULL_SCALE_V / 65535 * self.cfg.full_scale_bar / self.cfg.full_scale_v
        return {role: TruthChannel(trace_name, 1e-5, False, lsb_bar) for trace_name, role in CHANNELS}

    def error_budget(self) -> dict[str, tuple[ChannelErrors | None, LinkErrors, float]]:
        """The transducers' errors."""
        return {role: (self.cfg.errors, self.cfg.link, 0.0) for _name, role in CHANNELS}

    def saturation(self) -> dict[str, ChannelErrors]:
        """The five pressures."""
        return {role: self.cfg.errors for _name, role in CHANNELS}

    def modbus_endpoint(self, seed: int | None) -> ModbusEndpoint:
        """Input registers 0..13 (function 4), the configuration block, and the setup's poll faults."""
        c = self.cfg
        return ModbusEndpoint(c.device, c.unit_id, c.port, 4, 0, INPUT_COUNT, c.poll_hz,
                              holding_defaults(c.full_scale_bar, c.full_scale_v),
                              {"exception_prob": c.exception_prob, "exception_code": c.exception_code,
                               "timeout_prob": c.timeout_prob, "seed": seed})
