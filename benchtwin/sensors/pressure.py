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
from dataclasses import dataclass

import numpy as np

from benchtwin.config.setup import ChannelErrors, FaultSpec, LinkErrors, PressureConfig
from benchtwin.roles import unit_of_role
from benchtwin.sensors.base import Delivered, Device, ModbusEndpoint, TruthChannel
from benchtwin.sensors.blocks import Block
from benchtwin.sensors.imperfections import DeviceClock, faulty_clock, in_spans, measure, with_stuck
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
from benchtwin.wire.quality import FLAG, DecodeSink, mark_after

__all__ = ["PA_PER_BAR", "PressureModule", "decode_pressure_polls", "encode_pressure", "poll_snapshots",
           "pressure_from_counts"]

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


def pressure_from_counts(counts: np.ndarray, cfg: PressureConfig) -> np.ndarray:
    """The acquisition's conversion: raw counts -> bar."""
    return counts_to_volts(counts) * cfg.full_scale_bar / cfg.full_scale_v


def _unwrap_u32(raw: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Unwrap a uint32 millisecond counter (wraps every 49.7 days; a clock that starts before zero
    starts near 2^32) over the good polls; failed polls keep whatever they hold."""
    out = raw.astype(np.int64).copy()
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return out
    g = out[idx]
    d = np.diff(g)
    g = g + np.concatenate([[0], np.cumsum(np.where(d < -(1 << 31), 1 << 32, 0) - np.where(d > 1 << 31, 1 << 32, 0))])
    if g[0] >= 1 << 31:  # read as a signed clock
        g = g - (1 << 32)
    out[idx] = g
    return out


#: an answer this much older than its neighbours' (poll time minus module uptime) came late (LATE)
LATE_S = 0.012
#: a persistent change of the answers' age by this much is a step of the module's clock
CLOCK_STEP_S = 0.01
#: a drift of the age this far (ppm) from the recording's own over a minute is a clock drifting
CLOCK_DRIFT_PPM = 40.0
#: a run of this many timed-out polls in a row is the server down (single timeouts are the network)
RESTART_RUN = 3


def _block_medians(t: np.ndarray, x: np.ndarray, block_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block index of each sample, and per non-empty block its centre time and median."""
    k = np.floor((t - t[0]) / block_s).astype(np.int64)
    counts = np.bincount(k)
    order = np.lexsort((x, k))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    has = np.flatnonzero(counts)
    return k, t[0] + (has + 0.5) * block_s, x[order][starts[has] + counts[has] // 2]


def poll_clock_evidence(t: np.ndarray, up: np.ndarray, update_period_s: float, declared_ppm: float = 0.0,
                        block_s: float = 1.0
                        ) -> tuple[np.ndarray, list[tuple[float, float]], list[tuple[float, float]]]:
    """Late answers, clock steps and clock drift from the age of good answers (poll time ``t`` minus uptime ``up``).

    The age of an answer is its latency plus the time since the module's last register update: it moves in
    steps of one update period as the two clocks slide apart (a tick each time their drift adds up to one
    period). Per 1-s block: a persistent change of the median age over 5 blocks by more than
    :data:`CLOCK_STEP_S` is a clock step (a rise that falls back within a minute is a stretch of late
    answers instead); after removing steps, an answer more than :data:`LATE_S` older than the running
    median is late; the time between two one-period ticks gives the drift (one period per interval),
    and an interval whose drift differs from the ``declared_ppm`` of the setup by more than
    :data:`CLOCK_DRIFT_PPM` is a clock drifting.

    Returns
    -------
    late, steps, drifts
        Mask of late answers; ``(time, size)`` of each clock step; ``(start, end)`` of each drifting span.
    """
    age = t - up
    if t.size < 50:
        return np.zeros(t.size, bool), [], []
    k, tb, m = _block_medians(t, age, block_s)
    # the acquisition's own timing jitter (a busy logger, a live network): the thresholds never fall below a
    # multiple of it, so a loaded machine's scatter is not taken for a slow server or a clock step
    blk0 = np.searchsorted(np.flatnonzero(np.bincount(k)), k)
    dev = age - m[blk0]
    jitter = 1.4826 * float(np.median(np.abs(dev - np.median(dev))))
    judged = judge_age_medians(tb, m, jitter, update_period_s, declared_ppm, block_s)
    late = judged.late(t, age, blk0)
    return late, judged.steps, judged.drifts


@dataclass
class AgeJudgement:
    """What :func:`judge_age_medians` finds from the per-block medians of the answers' age."""

    #: ``(time, size)`` of each clock step
    steps: list[tuple[float, float]]
    #: ``(start, end)`` of each drifting span
    drifts: list[tuple[float, float]]
    #: an answer this much older than the running median is late
    late_s: float
    #: block centre times, and per block the steps' level and the running median after removing it (None: no
    #: block to take it from)
    tb: np.ndarray
    level: np.ndarray
    base_b: np.ndarray | None
    block_s: float

    def late(self, t: np.ndarray, age: np.ndarray, blk: np.ndarray) -> np.ndarray:
        """Mask of late answers among good answers at times ``t`` with ages ``age`` in blocks ``blk`` (the
        index of each answer's block among the non-empty ones); per answer: any part of the log gives the same."""
        if self.base_b is None:
            return np.zeros(t.size, bool)
        late = age - self.level[blk] - np.interp(t, self.tb, self.base_b) > self.late_s
        for ts, _ in self.steps:  # around a step the level is uncertain: those answers are flagged CLOCK instead
            late &= np.abs(t - ts) > 1.5 * self.block_s
        return late


def judge_age_medians(tb: np.ndarray, m: np.ndarray, jitter: float, update_period_s: float,
                      declared_ppm: float = 0.0, block_s: float = 1.0) -> AgeJudgement:
    """Clock steps, stretches of slow answers and clock drift from the per-block medians ``m`` (centre times ``tb``)
    of the answers' age, and the level a late answer is judged against (see :func:`poll_clock_evidence`).

    ``jitter``: the acquisition's own timing scatter (a scaled median absolute deviation of the answers' age about
    their block's median); the thresholds never fall below a multiple of it.
    """
    late_s = max(LATE_S, 8.0 * jitter)
    step_s = max(CLOCK_STEP_S, 4.0 * jitter)
    w = 5
    steps: list[tuple[float, float]] = []
    slow: list[tuple[float, float]] = []
    if m.size > 2 * w:
        from numpy.lib.stride_tricks import sliding_window_view

        fwd = np.median(sliding_window_view(m, w), axis=1)  # fwd[j] = median(m[j:j+w])
        c = np.zeros(m.size)
        c[w:m.size - w + 1] = fwd[w:] - fwd[:-w]
        cand = np.flatnonzero(np.abs(c) > step_s)
        groups = np.split(cand, np.flatnonzero(np.diff(cand) > 1) + 1) if cand.size else []
        found = []
        for g in groups:  # one change per group: the middle of its plateau (full size for w blocks around it)
            for sign in (1.0, -1.0):
                gs = g[np.sign(c[g]) == sign]
                if gs.size:
                    top = gs[np.abs(c[gs]) >= 0.8 * np.max(np.abs(c[gs]))]
                    i = int(top[top.size // 2])
                    found.append((float(tb[i] - 0.5 * block_s), float(c[i])))
        found.sort()
        used = set()
        for a, (ta, ca) in enumerate(found):  # a rise that falls back: a stretch of slow answers, not a clock
            if a in used or ca <= 0:
                continue
            for b in range(a + 1, len(found)):
                tb_, cb = found[b]
                if b not in used and cb < 0 and tb_ - ta < 60.0 and abs(ca + cb) < 0.5 * ca:
                    used |= {a, b}
                    slow.append((ta, tb_))
                    break
        steps = [s for j, s in enumerate(found) if j not in used]
    level = np.zeros(tb.size)
    for ts, size in steps:
        level += np.where(tb >= ts, size, 0.0)
    mc = m - level
    in_slow = np.zeros(tb.size, bool)
    for a, b in slow:
        in_slow |= (tb >= a - block_s) & (tb <= b + block_s)
    ref = np.flatnonzero(~in_slow)
    base_b = None
    if ref.size:
        from scipy.ndimage import median_filter

        base_b = np.interp(tb, tb[ref], median_filter(mc[ref], size=21, mode="nearest"))
    # drift: one-period ticks of the age, away from steps and slow answers
    quiet = ~in_slow
    for ts, _ in steps:
        quiet &= np.abs(tb - ts) > w * block_s
    d = np.diff(mc)
    tick = quiet[1:] & quiet[:-1] & (np.abs(np.abs(d) - update_period_s) < 0.4 * update_period_s)
    tt, sign = tb[1:][tick] - 0.5 * block_s, np.sign(d[tick])
    drifts: list[tuple[float, float]] = []
    for j in range(tt.size - 1):
        a, b = float(tt[j]), float(tt[j + 1])
        if not quiet[(tb >= a) & (tb <= b)].all():
            continue  # a step or slow answers in between: the interval says nothing of the rate
        ppm = -sign[j + 1] * update_period_s / (b - a) * 1e6  # the module ahead: its uptime gains, age falls
        if abs(ppm - declared_ppm) > CLOCK_DRIFT_PPM:
            if drifts and a <= drifts[-1][1]:
                drifts[-1] = (drifts[-1][0], b)
            else:
                drifts.append((a, b))
    return AgeJudgement(steps, drifts, late_s, tb, level, base_b, block_s)


def decode_pressure_polls(log_: PollLog, cfg: PressureConfig | None, sink: DecodeSink, drops: np.ndarray) -> None:
    """Decode the poll log of the pressure module into the five brake-pressure channels (bar).

    The time base is the module's uptime registers where polled, else the poll times; a failed poll
    holds the last good values, flagged TIMEOUT or PROTOCOL_ERROR; status bits and the transducer's
    output limit flag SATURATED. Counts go to ``sink.counts["modbus"]``. Runs of timeouts (the server
    down), late answers (LATE) and the module's clock stepping or drifting (CLOCK) are judged from the log
    (:func:`poll_clock_evidence`) and reported to the sink as faults.
    """
    n = len(log_)
    ok = log_.status == POLL_OK
    timeouts = int(np.sum(log_.status == POLL_TIMEOUT))
    exc = log_.status[(log_.status != POLL_OK) & (log_.status != POLL_TIMEOUT)]
    codes, cnt = np.unique(exc, return_counts=True)
    sink.counts.setdefault("modbus", {})[log_.device] = {
        "polls": n, "timeouts": timeouts, "exceptions": {int(c): int(k) for c, k in zip(codes, cnt)}}
    if n == 0 or log_.first_register != 0 or log_.count <= REG_RAW + len(CHANNELS) - 1:
        if n:
            sink.protocol_error(f"modbus:{log_.device} unexpected register block", n)
        return
    # time base: the module's uptime registers where polled, else the poll times
    if log_.count > REG_UPTIME_LO:
        raw = log_.values[:, REG_UPTIME_HI].astype(np.int64) << 16 | log_.values[:, REG_UPTIME_LO]
        up = _unwrap_u32(raw, ok) / 1000.0
    else:
        up = log_.times.copy()
    last_good = np.maximum.accumulate(np.where(ok, np.arange(n), -1))
    has = last_good >= 0
    lg = np.clip(last_good, 0, None)
    t = np.where(ok, up, up[lg] + (log_.times - log_.times[lg]))
    t = np.where(has, t, log_.times - (log_.times[ok][0] - up[ok][0] if ok.any() else 0.0))
    flags = np.zeros(n, dtype=np.uint16)
    flags[log_.status == POLL_TIMEOUT] |= FLAG["TIMEOUT"]
    flags[(log_.status != POLL_OK) & (log_.status != POLL_TIMEOUT)] |= FLAG["PROTOCOL_ERROR"]
    mark_after(flags, log_.times, drops, FLAG["TRANSPORT_DROP"])
    _poll_faults(log_, ok, up, flags, cfg, sink)
    # keep timestamps monotonic (a held sample never goes back in time)
    t = np.maximum.accumulate(t)
    status = log_.values[lg, REG_STATUS].astype(np.int64) if log_.count > REG_STATUS else np.zeros(n, np.int64)
    for k, (_trace, role) in enumerate(CHANNELS):
        counts = log_.values[lg, REG_RAW + k]
        v = pressure_from_counts(counts, cfg) if cfg is not None else counts.astype(np.float64)
        v = np.where(has, v, np.nan)
        f = flags.copy()
        f[((status >> k) & 1).astype(bool) | ((status >> (8 + k)) & 1).astype(bool)] |= FLAG["SATURATED"]
        if cfg is not None:  # at the transducer's output limit
            v_max = pressure_from_counts(volts_to_counts(np.array([cfg.output_max_v]))[0], cfg)[0]
            f[v >= v_max - 1e-9] |= FLAG["SATURATED"]
        sink.add(role, unit_of_role(role), t, v, f, log_.device)
    if ok.any():
        sink.counts.setdefault("clock_offsets_s", {})["pressure->acquisition"] = float(
            np.median(log_.times[ok] - up[ok]))


def _poll_faults(log_: PollLog, ok: np.ndarray, up: np.ndarray, flags: np.ndarray, cfg: PressureConfig | None,
                 sink: DecodeSink) -> None:
    """Server restarts (runs of timeouts), late answers and clock faults of the module, into flags and the sink."""
    tout = (log_.status == POLL_TIMEOUT).astype(np.int8)
    if tout.any():
        edges = np.flatnonzero(np.diff(np.concatenate([[0], tout, [0]])))
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a >= RESTART_RUN:
                sink.fault("modbus_restart", log_.device, log_.times[a:b])
    if log_.count <= REG_UPTIME_LO or np.count_nonzero(ok) < 50:
        return
    idx = np.flatnonzero(ok)
    period = 1.0 / cfg.update_hz if cfg is not None else 0.005
    declared = cfg.link.clock_drift_ppm if cfg is not None else 0.0
    late, steps, drifts = poll_clock_evidence(log_.times[idx], up[idx], period, declared)
    if late.any():
        flags[idx[late]] |= FLAG["LATE"]
        sink.fault("modbus_slow", log_.device, log_.times[idx[late]])
    for ts, _size in steps:
        flags[np.abs(log_.times - ts) <= 1.0] |= FLAG["CLOCK"]
        sink.fault("clock_step", log_.device, np.array([ts]))
    for a, b in drifts:
        flags[(log_.times >= a) & (log_.times < b)] |= FLAG["CLOCK"]
        sink.fault("clock_drift", log_.device, np.array([a]), np.array([b]))


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
        from benchtwin.sensors.pressure_polls import decode_pressure_poll_blocks

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
