"""The pressure module's poll log decoded whole into the five brake-pressure channels (the reference the block-wise
decoder of :mod:`benchtwin.sensors.pressure_polls` equals bit for bit).
"""

from __future__ import annotations

import numpy as np

from benchtwin.config.setup import PressureConfig
from benchtwin.roles import unit_of_role
from benchtwin.sensors.poll_clock import RESTART_RUN, poll_clock_evidence
from benchtwin.wire.frames import POLL_OK, POLL_TIMEOUT, PollLog
from benchtwin.wire.modbus_map import (
    CHANNELS,
    REG_RAW,
    REG_STATUS,
    REG_UPTIME_HI,
    REG_UPTIME_LO,
    counts_to_volts,
    volts_to_counts,
)
from benchtwin.wire.quality import FLAG, DecodeSink, mark_after

__all__ = ["decode_pressure_polls", "pressure_from_counts"]


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
