"""The acquisition: decode what the bench received (CAN frames, PDOs, Modbus polls) into a Recording.

:func:`acquire` is the one decoder of the project. Batch mode calls it with the frame tables and
poll logs read from the raw logs (or straight from the sensors' outputs); the live recorder calls
it with what it received from the transports. It never raises on bad traffic: malformed frames
(wrong DLC, bad IVT-S mux byte), unknown identifiers, Modbus exception answers and timeouts,
counter gaps, duplicates, reordering, PDO gaps and transport drops are counted in
``Recording.meta`` and flagged on the samples they affect (:class:`~benchtwin.recording.Flag`),
and every good sample is kept.

Decoding is vectorised: frames are grouped per identifier with one stable sort, and each group is
unpacked column-wise from the DBC/EDS layouts (:mod:`benchtwin.chain.codec` compiled from the
cantools Signal definitions of the IVT-S, AD module, vehicle and dyno messages;
:mod:`benchtwin.chain.canopen_pdo` from the EDS TPDO mapping read with canopen).

Channels keep the time base of their source (the device's clock as stamped on the frame, the
pressure module's uptime registers). ``meta["clock_offsets_s"]`` reports the offsets between
sources detected by cross-correlation: key ``"a->b"`` is the time to add to ``a``'s timestamps to
line them up with ``b``'s (vehicle speed on the vehicle CAN vs the dyno roller speed; CAN motor
power vs the HPCU shunt's power), and ``"pressure->acquisition"`` the median of poll time minus
module uptime. On recordings of an hour or more, ``meta["clock_drift_ppm"]`` gives the relative
drift of the same pairs: the slope of the offsets found in consecutive 15-minute windows.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.chain.canopen_pdo import AI_OVERLOAD_NEG, AI_OVERLOAD_POS, pdo_layout
from benchtwin.chain.codec import MessageCodec
from benchtwin.chain.dbc import build_ad_module, build_ivt, ivt_node_name
from benchtwin.chain.frames import POLL_OK, POLL_TIMEOUT, FrameTable, PollLog, TransportEvent
from benchtwin.chain.modbus_map import (
    CHANNELS,
    REG_RAW,
    REG_STATUS,
    REG_UPTIME_HI,
    REG_UPTIME_LO,
    volts_to_counts,
)
from benchtwin.config.setup import IVT_PLACES, SetupConfig
from benchtwin.recording import Channel, Flag, Recording
from benchtwin.roles import unit_of_role
from benchtwin.segments import Segment
from benchtwin.sensors.ivt import (
    STATUS_MEAS_ERROR,
    STATUS_OCS,
    STATUS_OUT_OF_RANGE,
    STATUS_SYS_ERROR,
)
from benchtwin.sensors.pressure import pressure_from_counts
from benchtwin.sensors.telemetry import torque_from_code
from benchtwin.sensors.vehicle import SIGNAL_MAP, message_codecs

__all__ = ["AcquisitionInput", "acquire", "detect_lag"]

log = logging.getLogger(__name__)

_F = {f.name: int(f) for f in Flag}


@dataclass
class AcquisitionInput:
    """Everything an acquisition received, ready to decode.

    Attributes
    ----------
    can:
        Bus name -> frames received (PDO frames included on their bus).
    polls:
        Modbus device name -> poll log.
    events:
        Transport events (drops, reconnects) to flag.
    segments:
        The campaign's segment table (on the acquisition clock).
    meta:
        Extra metadata carried into the Recording.
    """

    can: dict[str, FrameTable] = field(default_factory=dict)
    polls: dict[str, PollLog] = field(default_factory=dict)
    events: list[TransportEvent] = field(default_factory=list)
    segments: list[Segment] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------- helpers


def _counter_flags(counter: np.ndarray, bits: int) -> np.ndarray:
    """LOST_FRAME / DUPLICATE / OUT_OF_ORDER from a cyclic counter (per sample, arrival order).

    A repeated counter is a duplicate; the other samples are then judged without the duplicates.
    """
    n = counter.shape[0]
    flags = np.zeros(n, dtype=np.uint16)
    if n < 2:
        return flags
    c8 = counter.astype(np.uint8)
    step = (c8[1:] - c8[:-1]) & np.uint8((1 << bits) - 1)
    if np.all(step == 1):  # the usual case: nothing lost, doubled or reordered
        return flags
    c_all = counter.astype(np.int16)
    dup = np.zeros(n, bool)
    dup[1:] = step == 0
    if dup.any():
        keep = np.flatnonzero(~dup)
        flags[keep] = _counter_flags(c_all[keep], bits)
        flags[dup] |= _F["DUPLICATE"]
        return flags
    m = 1 << bits
    mask = np.int16(m - 1)
    c = c_all
    d1 = np.zeros(n, dtype=np.int16)
    d1[1:] = (c[1:] - c[:-1]) & mask
    ooo = np.zeros(n, bool)
    ooo[1:] = d1[1:] > m // 2
    gap = (d1 >= 2) & (d1 <= m // 2)
    gap[0] = False
    # a reorder looks like "skip one, go back one, skip one": do not call those losses
    nxt_back = np.zeros(n, bool)
    nxt_back[:-1] = ooo[1:] & (((c[:-1] - c[1:]) & mask) == 1)
    d2 = np.zeros(n, dtype=np.int16)
    d2[2:] = (c[2:] - c[:-2]) & mask
    prev_ooo = np.zeros(n, bool)
    prev_ooo[1:] = ooo[:-1]
    reordered_gap = gap & nxt_back
    lost = gap & ~nxt_back & ~(prev_ooo & (d2 == 1))
    flags[lost] |= _F["LOST_FRAME"]
    flags[ooo | reordered_gap] |= _F["OUT_OF_ORDER"]
    return flags


def _timing_flags(t: np.ndarray, period_s: float) -> np.ndarray:
    """LOST_FRAME where the spacing exceeds 1.5 periods (streams without a counter)."""
    flags = np.zeros(t.shape[0], dtype=np.uint16)
    if t.shape[0] > 1 and period_s > 0:
        late = np.diff(t) > 1.5 * period_s
        flags[1:][late] |= _F["LOST_FRAME"]
    return flags


def _mark_after(flags: np.ndarray, t: np.ndarray, bad_times: np.ndarray, bit: int) -> None:
    """Flag the first sample at or after each of ``bad_times`` with ``bit`` (in place)."""
    if bad_times.size == 0 or t.size == 0:
        return
    idx = np.searchsorted(t, bad_times, side="left")
    idx = idx[idx < t.size]
    flags[idx] |= bit


class _Sink:
    """Collects decoded channels and counts for the Recording."""

    def __init__(self) -> None:
        self.rec = Recording()
        self.counts: dict[str, Any] = {"protocol_errors": {}, "unknown_ids": {}, "frames": {}}

    def add(self, name: str, unit: str, t: np.ndarray, v: np.ndarray, flags: np.ndarray, source: str) -> None:
        self.rec.add(Channel(name, unit, t, v, flags, source))

    def protocol_error(self, where: str, n: int) -> None:
        if n:
            self.counts["protocol_errors"][where] = self.counts["protocol_errors"].get(where, 0) + int(n)


def _events_for(events: list[TransportEvent], names: set[str]) -> np.ndarray:
    ends = []
    for e in events:
        if (e.source in names or e.source == "*") and e.kind in ("drop", "overrun"):
            ends.append(e.end_s if np.isfinite(e.end_s) else e.time_s)
    return np.asarray(ends, dtype=np.float64)


# ---------------------------------------------------------------------------------------------- CAN buses


@dataclass
class _Handler:
    kind: str
    name: str
    length: int
    info: Any = None
    period_s: float = 0.0


def _handlers(setup: SetupConfig, bus: str) -> dict[int, _Handler]:
    out: dict[int, _Handler] = {}
    for place, cfg in setup.ivt.items():
        if cfg.bus != bus:
            continue
        db = build_ivt(ivt_node_name(place), cfg.result_base_id, cfg.command_id, cfg.response_id, cfg.cycle_ms)
        for k, cid in enumerate(cfg.result_ids):
            codec = MessageCodec(db.get_message_by_frame_id(cid))
            out[cid] = _Handler("ivt", f"ivt_{place}", codec.length, (place, k, codec))
        out[cfg.command_id] = _Handler("ivt_cmd", f"ivt_{place}", 0, place)
        out[cfg.response_id] = _Handler("ivt_resp", f"ivt_{place}", 0, place)
    tel = setup.telemetry
    if tel is not None and tel.bus == bus:
        codec = MessageCodec(build_ad_module("AD_Torque", tel.can_id).messages[0])
        out[tel.can_id] = _Handler("ad", "telemetry", codec.length, (tel, codec), 1.0 / tel.rate_hz)
    th = setup.thermo
    if th is not None and th.bus == bus:
        layout = pdo_layout(th.node_id)
        for tp in layout.tpdos:
            out[tp.cob_id] = _Handler("pdo", "thermo", tp.length, (layout, tp), tp.event_ms / 1000.0)
    for stem, key in (("vehicle", "vehicle_can"), ("dyno", "dyno")):
        dev = getattr(setup, key)
        if dev is None or dev.bus != bus:
            continue
        for codec in message_codecs(stem):
            out[codec.frame_id] = _Handler("dbc", key, codec.length, (stem, codec),
                                           (codec.message.cycle_time or 0) / 1000.0)
    return out


def _group(frames: np.ndarray, handlers: dict[int, _Handler]) -> tuple[dict[int, np.ndarray], dict[int, int]]:
    """Indices of the frames of each known id (time order) and counts of unknown ids."""
    ids = np.ascontiguousarray(frames["arbitration_id"])
    keys = sorted(handlers)
    lut = np.zeros(0x801, dtype=np.uint8 if len(keys) < 255 else np.uint16)  # 0: unknown
    for k, cid in enumerate(keys):
        lut[cid] = k + 1
    code = lut[np.minimum(ids, 0x800)]
    ext = frames["is_extended"]
    if ext.any():
        code[ext] = 0
    order = np.argsort(code, kind="stable")  # radix sort on a small integer key
    counts = np.bincount(code, minlength=len(keys) + 1)
    bounds = np.concatenate([[0], np.cumsum(counts)])
    groups = {cid: order[bounds[k + 1]:bounds[k + 2]] for k, cid in enumerate(keys) if counts[k + 1]}
    unknown = order[:bounds[1]]
    u_ids, u_counts = np.unique(ids[unknown], return_counts=True)
    return groups, {int(i): int(c) for i, c in zip(u_ids, u_counts)}


def _good_and_proto(dlc: np.ndarray, idx: np.ndarray, length: int, extra_bad: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, int]:
    """Split a stream into good frames and the PROTOCOL_ERROR flag of the good frame after each bad one."""
    bad = dlc[idx] != length if length else np.zeros(idx.shape[0], bool)
    if extra_bad is not None:
        bad = bad | extra_bad
    good = idx[~bad]
    proto = np.zeros(good.shape[0], dtype=np.uint16)
    nbad = int(bad.sum())
    if nbad:
        before = np.cumsum(bad)[~bad]
        prev = np.concatenate([[0], before[:-1]])
        proto[before > prev] = _F["PROTOCOL_ERROR"]
    return good, proto, nbad


def _decode_bus(table: FrameTable, setup: SetupConfig, sink: _Sink, drops: np.ndarray) -> None:
    frames = table.frames
    handlers = _handlers(setup, table.bus)
    groups, unknown = _group(frames, handlers)
    sink.counts["frames"][table.bus] = len(table)
    if unknown:
        sink.counts["unknown_ids"][table.bus] = {f"0x{k:X}": v for k, v in unknown.items()}
    # contiguous columns once; every stream then gathers 8-byte words, not structured records
    ts = np.ascontiguousarray(frames["timestamp"])
    dlc = np.ascontiguousarray(frames["dlc"])
    words = np.ascontiguousarray(frames["data"]).view("<u8")[:, 0]
    ivt: dict[str, dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
    dbc_parts: dict[str, list] = {}
    for cid, idx in groups.items():
        h = handlers[cid]
        if h.kind == "ivt":
            place, k, codec = h.info
            names = list(codec.signals)  # MuxID, Status, Counter, value (DBC signal order)
            mux_name = next(n for n in names if n.endswith("_MuxID"))
            w_all = words[idx]
            mux_bad = codec.unpack_words(w_all, [mux_name])[mux_name] != k
            good, proto, nbad = _good_and_proto(dlc, idx, h.length, mux_bad)
            sink.protocol_error(f"{table.bus}:0x{cid:X}", nbad)
            raw = codec.unpack_words(w_all[~mux_bad & (dlc[idx] == h.length)] if nbad else w_all)
            counter = raw[next(n for n in names if n.endswith("_Counter"))]
            status = raw[next(n for n in names if n.endswith("_Status"))]
            value = raw[next(n for n in names if not n.endswith(("_MuxID", "_Counter", "_Status")))]
            flags = proto | _counter_flags(counter, 4)
            flags[(status & STATUS_OUT_OF_RANGE) != 0] |= _F["OUT_OF_RANGE"] | _F["SATURATED"]
            flags[(status & (STATUS_MEAS_ERROR | STATUS_SYS_ERROR)) != 0] |= _F["STATUS_ERROR"]
            n_ocs = int(np.count_nonzero(status & STATUS_OCS))
            if n_ocs:  # over-current detection is an event of the circuit, not a measurement error
                ocs = sink.counts.setdefault("ivt_ocs_frames", {})
                ocs[f"ivt_{place}"] = ocs.get(f"ivt_{place}", 0) + n_ocs
            t = ts[good]
            _mark_after(flags, t, drops, _F["TRANSPORT_DROP"] | _F["LOST_FRAME"])
            ivt.setdefault(place, {})[k] = (t, value, flags)
        elif h.kind in ("ivt_cmd", "ivt_resp"):
            key = "ivt_commands" if h.kind == "ivt_cmd" else "ivt_answers"
            d = sink.counts.setdefault(key, {})
            d[h.name] = d.get(h.name, 0) + int(idx.shape[0])
            if h.kind == "ivt_resp":
                unk = int(np.sum((words[idx] & np.uint64(0xFF)) == 0xFF))
                if unk:
                    sink.protocol_error(f"{table.bus}:0x{cid:X} unknown-command answers", unk)
        elif h.kind == "ad":
            tel, codec = h.info
            good, proto, nbad = _good_and_proto(dlc, idx, h.length)
            sink.protocol_error(f"{table.bus}:0x{cid:X}", nbad)
            raw = codec.unpack_words(words[good])
            code, counter, clip = raw["AD_Torque_Vout"], raw["AD_Torque_Counter"], raw["AD_Torque_Clip"]
            flags = proto | _counter_flags(counter, 4)
            flags[clip != 0] |= _F["SATURATED"]
            t = ts[good]
            _mark_after(flags, t, drops, _F["TRANSPORT_DROP"] | _F["LOST_FRAME"])
            sink.add("shaft_torque_nm", unit_of_role("shaft_torque_nm"), t, torque_from_code(code, tel), flags,
                     "telemetry")
        elif h.kind == "pdo":
            layout, tp = h.info
            good, proto, nbad = _good_and_proto(dlc, idx, h.length)
            sink.protocol_error(f"{table.bus}:0x{cid:X}", nbad)
            t = ts[good]
            base = proto | _timing_flags(t, h.period_s)
            _mark_after(base, t, drops, _F["TRANSPORT_DROP"] | _F["LOST_FRAME"])
            vals = layout.unpack_words(tp, words[good])
            th = setup.thermo
            for (index, sub), raw in vals.items():
                if index == 0x9130:
                    if sub > len(th.places):
                        continue
                    name, source = th.places[sub - 1], "thermo"
                elif index == 0x2100:
                    name, source = "thermo_cold_junction_degc", "thermo"
                else:
                    continue
                v = raw * layout.scale((index, sub))
                flags = base.copy()
                hi, lo = raw == AI_OVERLOAD_POS, raw == AI_OVERLOAD_NEG
                flags[hi | lo] |= _F["OUT_OF_RANGE"] | _F["SATURATED"]
                v = np.where(hi, th.range_max_degc, np.where(lo, th.range_min_degc, v))
                sink.add(name, "degC", t, v, flags, source)
        elif h.kind == "dbc":
            stem, codec = h.info
            good, proto, nbad = _good_and_proto(dlc, idx, h.length)
            sink.protocol_error(f"{table.bus}:0x{cid:X}", nbad)
            dbc_parts.setdefault(h.name, []).append((stem, codec, ts[good], words[good], proto, h.period_s))
    for place, results in ivt.items():
        _ivt_channels(place, results, sink)
    for device, parts in dbc_parts.items():
        for stem, codec, t, w, proto, period in parts:
            _dbc_channels(stem, codec, t, w, proto, period, drops, device, sink)


def _ivt_channels(place: str, results: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]], sink: _Sink) -> None:
    _, _, role_i, role_u = IVT_PLACES[place]
    prefix = role_i[: -len("_current_a")]
    names = {0: (role_i, "A", 1e-3), 1: (role_u, "V", 1e-3), 2: (f"ivt_{place}_u2_v", "V", 1e-3),
             3: (f"ivt_{place}_u3_v", "V", 1e-3), 4: (f"ivt_{place}_temp_degc", "degC", 0.1),
             5: (f"{prefix}_power_w", "W", 1.0), 6: (f"ivt_{place}_charge_as", "As", 1.0),
             7: (f"ivt_{place}_energy_wh", "Wh", 1.0)}
    for k, (t, value, flags) in results.items():
        name, unit, scale = names[k]
        sink.add(name, unit_of_role(name) or unit, t, value * scale, flags, f"ivt_{place}")


def _dbc_channels(stem: str, codec: MessageCodec, t: np.ndarray, words: np.ndarray, proto: np.ndarray,
                  period: float, drops: np.ndarray, device: str, sink: _Sink) -> None:
    sources = SIGNAL_MAP[stem]
    raw = codec.unpack_words(words)
    counters = [n for n in codec.signals if sources[n].trace is None]
    base = proto.copy()
    if counters:
        base |= _counter_flags(raw[counters[0]], codec.signals[counters[0]].length)
    else:
        base |= _timing_flags(t, period)
    _mark_after(base, t, drops, _F["TRANSPORT_DROP"] | _F["LOST_FRAME"])
    for name, r in raw.items():
        src = sources[name]
        if src.role is None:
            continue
        sig = codec.signals[name]
        v = codec.to_physical(name, r)
        flags = base.copy()
        if src.nan_raw_max:
            v[r == sig.raw_max] = np.nan
        elif not src.hold:
            at_limit = (r == sig.raw_max) | ((r == sig.raw_min) if sig.signed else False)
            flags[at_limit] |= _F["SATURATED"]
        sink.add(src.role, unit_of_role(src.role), t, v, flags, device)


# ---------------------------------------------------------------------------------------------- Modbus


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


def _decode_polls(log_: PollLog, setup: SetupConfig, sink: _Sink, drops: np.ndarray) -> None:
    cfg = setup.pressure
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
    flags[log_.status == POLL_TIMEOUT] |= _F["TIMEOUT"]
    flags[(log_.status != POLL_OK) & (log_.status != POLL_TIMEOUT)] |= _F["PROTOCOL_ERROR"]
    _mark_after(flags, log_.times, drops, _F["TRANSPORT_DROP"])
    # keep timestamps monotonic (a held sample never goes back in time)
    t = np.maximum.accumulate(t)
    status = log_.values[lg, REG_STATUS].astype(np.int64) if log_.count > REG_STATUS else np.zeros(n, np.int64)
    for k, (_trace, role) in enumerate(CHANNELS):
        counts = log_.values[lg, REG_RAW + k]
        v = pressure_from_counts(counts, cfg) if cfg is not None else counts.astype(np.float64)
        v = np.where(has, v, np.nan)
        f = flags.copy()
        f[((status >> k) & 1).astype(bool) | ((status >> (8 + k)) & 1).astype(bool)] |= _F["SATURATED"]
        if cfg is not None:  # at the transducer's output limit
            v_max = pressure_from_counts(volts_to_counts(np.array([cfg.output_max_v]))[0], cfg)[0]
            f[v >= v_max - 1e-9] |= _F["SATURATED"]
        sink.add(role, unit_of_role(role), t, v, f, log_.device)
    if ok.any():
        sink.counts.setdefault("clock_offsets_s", {})["pressure->acquisition"] = float(
            np.median(log_.times[ok] - up[ok]))


# ---------------------------------------------------------------------------------------------- alignment


def detect_lag(t_a: np.ndarray, x_a: np.ndarray, t_b: np.ndarray, x_b: np.ndarray, *, rate_hz: float = 100.0,
               max_lag_s: float = 2.0, min_correlation: float = 0.6,
               window: tuple[float, float] | None = None) -> float | None:
    """Time to add to ``a``'s timestamps to line signal ``a`` up with ``b``.

    Normalised cross-correlation (Pearson coefficient per lag) of ``a`` over the common span
    (or ``window`` of ``a``'s time) against ``b`` shifted by up to ``+-max_lag_s`` on a ``rate_hz``
    grid, refined by a parabola through the peak. Returns None if the signals do not overlap
    enough, are flat, or the best correlation is below ``min_correlation`` (not the same quantity).
    """
    if window is not None:  # cut to the window first: the rest of the work is then small
        a0, a1 = np.searchsorted(t_a, [window[0] - max_lag_s, window[1] + max_lag_s])
        b0, b1 = np.searchsorted(t_b, [window[0] - 2 * max_lag_s, window[1] + 2 * max_lag_s])
        t_a, x_a, t_b, x_b = t_a[a0:a1], x_a[a0:a1], t_b[b0:b1], x_b[b0:b1]
    good_a, good_b = np.isfinite(x_a), np.isfinite(x_b)
    t_a, x_a, t_b, x_b = t_a[good_a], x_a[good_a], t_b[good_b], x_b[good_b]
    if t_a.size < 10 or t_b.size < 10:
        return None
    lo, hi = max(t_a[0], t_b[0]) + max_lag_s, min(t_a[-1], t_b[-1]) - max_lag_s
    if window is not None:
        lo, hi = max(lo, window[0]), min(hi, window[1])
    if hi - lo < 4 * max_lag_s:
        return None
    if hi - lo > 3600.0:  # the central hour of a long recording is plenty
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 1800.0, mid + 1800.0
    m = round(max_lag_s * rate_hz)
    grid = np.arange(lo, hi, 1.0 / rate_hz)
    a = np.interp(grid, t_a, x_a)
    a = a - a.mean()
    ext = np.concatenate([grid[0] - np.arange(m, 0, -1) / rate_hz, grid, grid[-1] + np.arange(1, m + 1) / rate_hz])
    b = np.interp(ext, t_b, x_b)
    n = a.size
    ea = float(np.dot(a, a))
    if ea == 0:
        return None
    from scipy.signal import correlate

    cov = correlate(b, a, mode="valid", method="fft")  # cov[j] = sum a[i] b[i + j], j = 0..2m
    cs, cs2 = np.concatenate([[0.0], np.cumsum(b)]), np.concatenate([[0.0], np.cumsum(b * b)])
    s1 = cs[n:n + 2 * m + 1] - cs[:2 * m + 1]
    s2 = cs2[n:n + 2 * m + 1] - cs2[:2 * m + 1]
    var = s2 - s1 * s1 / n
    with np.errstate(invalid="ignore", divide="ignore"):
        r = cov / np.sqrt(np.clip(var, 1e-300, None) * ea)
    k = int(np.nanargmax(r))
    if not r[k] >= min_correlation:
        return None
    frac = 0.0
    if 0 < k < r.size - 1:
        den = r[k - 1] - 2 * r[k] + r[k + 1]
        frac = 0.5 * (r[k - 1] - r[k + 1]) / den if den != 0 else 0.0
    return float((k - m + frac) / rate_hz)


#: window (s) at each end of a long recording used to estimate the relative clock drift
DRIFT_WINDOW_S = 900.0


def _pairs(rec: Recording) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Signal pairs that measure one quantity on two sources: (key, t_a, x_a, t_b, x_b)."""
    out = []
    if "vehicle_speed_kmh" in rec and "dyno_speed_kmh" in rec:
        a, b = rec["vehicle_speed_kmh"], rec["dyno_speed_kmh"]
        out.append(("vehicle_can->dyno", a.timestamps, a.values, b.timestamps, b.values))
    if "em_torque_nm" in rec and "em_speed_rpm" in rec:
        power_name = "hpcu_power_w" if "hpcu_power_w" in rec else "battery_power_w"
        if power_name in rec:
            tq, sp, p = rec["em_torque_nm"], rec["em_speed_rpm"], rec[power_name]
            mech = tq.values * np.interp(tq.timestamps, sp.timestamps, sp.values) * (2 * np.pi / 60.0)
            out.append((f"vehicle_can->{p.source}", tq.timestamps, mech, p.timestamps, p.values))
    return out


def _clock_offsets(rec: Recording) -> tuple[dict[str, float], dict[str, float]]:
    """Offsets (s) and, on recordings long enough, relative drifts (ppm) between sources."""
    offsets: dict[str, float] = {}
    drifts: dict[str, float] = {}
    for key, t_a, x_a, t_b, x_b in _pairs(rec):
        lag = detect_lag(t_a, x_a, t_b, x_b)
        if lag is None:
            continue
        offsets[key] = lag
        t0, t1 = max(t_a[0], t_b[0]), min(t_a[-1], t_b[-1])
        n_win = int((t1 - t0) // DRIFT_WINDOW_S)
        if n_win >= 4:  # offset per window, drift = slope of a straight line through them
            edges = np.linspace(t0, t1, n_win + 1)
            pts = [(0.5 * (a + b), detect_lag(t_a, x_a, t_b, x_b, window=(a, b), rate_hz=20.0))
                   for a, b in pairwise(edges)]
            pts = [(c, lag_w) for c, lag_w in pts if lag_w is not None]
            if len(pts) >= 3 and pts[-1][0] - pts[0][0] >= 2 * DRIFT_WINDOW_S:
                c, lw = np.array(pts).T
                drifts[key] = float(np.polyfit(c, lw, 1)[0] * 1e6)
    return offsets, drifts


# ---------------------------------------------------------------------------------------------- saturation


def _saturation_limits(setup: SetupConfig) -> dict[str, tuple[float | None, float | None]]:
    """Recording role -> (min, max) of the output saturations configured in the setup."""
    out: dict[str, tuple[float | None, float | None]] = {}

    def take(role: str, err: Any) -> None:
        if err is not None and (err.saturation_min is not None or err.saturation_max is not None):
            out[role] = (err.saturation_min, err.saturation_max)

    for place, cfg in setup.ivt.items():
        _, _, role_i, role_u = IVT_PLACES[place]
        take(role_i, cfg.current_errors)
        take(role_u, cfg.voltage_errors)
    if setup.pressure is not None:
        for _trace, role in CHANNELS:
            take(role, setup.pressure.errors)
    if setup.telemetry is not None:
        take("shaft_torque_nm", setup.telemetry.errors)
    if setup.thermo is not None:
        for place in setup.thermo.places:
            take(place, setup.thermo.errors)
    for dev in (setup.vehicle_can, setup.dyno):
        if dev is not None:
            for role, err in dev.errors.items():
                take(role, err)
    return out


# ---------------------------------------------------------------------------------------------- entry


def _bus_load(table: FrameTable) -> float:
    """FrameTable.bus_load (same bit counts: worst-case stuffing) from a histogram of (DLC, IDE)."""
    f = table.frames
    if len(f) < 2:
        return 0.0
    span = float(f["timestamp"][-1] - f["timestamp"][0])
    if span <= 0:
        return float("nan")
    key = (np.minimum(f["dlc"], 15).astype(np.uint8) << 1) | f["is_extended"].view(np.uint8)
    hist = np.bincount(key, minlength=32)
    dlc = np.arange(32) // 2
    ext = np.arange(32) % 2 == 1
    base = np.where(ext, 67.0, 47.0) + 8.0 * dlc
    stuffed = np.where(ext, 54.0, 34.0) + 8.0 * dlc
    bits = float(np.sum(hist * (base + np.floor((stuffed - 1.0) / 4.0))))
    return bits / (table.bitrate * span)


def acquire(data: AcquisitionInput | Any, setup: SetupConfig, *, segments: list[Segment] | None = None,
            meta: dict[str, Any] | None = None, seed: int | None = 0, align: bool = True) -> Recording:
    """Decode everything received into a :class:`~benchtwin.recording.Recording`.

    Parameters
    ----------
    data:
        An :class:`AcquisitionInput` (frame tables incl. PDO frames, poll logs, transport events),
        the sensors' :class:`~benchtwin.chain.frames.DeviceOutputs` (delivered first with
        :func:`benchtwin.chain.batch.deliver`), or a folder of raw logs (read with
        :func:`benchtwin.chain.batch.read_logs`).
    setup:
        The bench (buses, ids, scalings).
    segments:
        Segment table (overrides ``data.segments``).
    meta:
        Extra metadata for the Recording.
    seed:
        Campaign seed (only used to deliver DeviceOutputs: poll faults).
    align:
        Detect clock offsets between sources.
    """
    if isinstance(data, (str, Path)):
        from benchtwin.chain.batch import read_logs

        data, _ = read_logs(data, setup)
    elif not isinstance(data, AcquisitionInput):
        from benchtwin.chain.batch import deliver

        data = deliver(data, setup, seed=seed)
    sink = _Sink()
    for bus, table in data.can.items():
        drops = _events_for(data.events, {bus})
        try:
            _decode_bus(table, setup, sink, drops)
        except Exception as exc:  # never lose the other buses because one is broken
            log.error("bus %s could not be decoded: %s", bus, exc)
            sink.protocol_error(f"{bus}: decoding failed ({exc})", max(1, len(table)))
    for device, plog in data.polls.items():
        drops = _events_for(data.events, {device})
        try:
            _decode_polls(plog, setup, sink, drops)
        except Exception as exc:
            log.error("poll log %s could not be decoded: %s", device, exc)
            sink.protocol_error(f"modbus:{device}: decoding failed ({exc})", max(1, len(plog)))
    rec = sink.rec
    for role, (lo, hi) in _saturation_limits(setup).items():
        if role in rec:
            ch = rec[role]
            span = (hi - lo) if lo is not None and hi is not None else max(abs(lo or 0.0), abs(hi or 0.0), 1.0)
            tol = 1e-3 * span
            at = np.zeros(len(ch), dtype=bool)
            if hi is not None:
                at |= ch.values >= hi - tol
            if lo is not None:
                at |= ch.values <= lo + tol
            ch.flags[at] |= _F["SATURATED"]
    rec.segments = list(segments if segments is not None else data.segments)
    m = dict(data.meta)
    m.update(meta or {})
    m["setup"] = setup.name
    m["sources"] = rec.sources()
    offsets = dict(sink.counts.pop("clock_offsets_s", {}))
    drifts: dict[str, float] = {}
    if align:
        found, drifts = _clock_offsets(rec)
        offsets.update(found)
    m["clock_offsets_s"] = offsets
    m["clock_drift_ppm"] = drifts
    flagged = {}
    for name, ch in rec.channels.items():
        for fl in (Flag.LOST_FRAME, Flag.DUPLICATE, Flag.OUT_OF_ORDER):
            k = int(np.count_nonzero(ch.flags & int(fl)))
            if k:
                flagged.setdefault(name, {})[fl.name.lower()] = k
        bad = int(np.count_nonzero(ch.flags & int(Flag.bad())))
        if bad:
            flagged.setdefault(name, {})["bad"] = bad
    sink.counts["flagged_samples"] = flagged
    m.update(sink.counts)
    m["transport_events"] = [{"time_s": e.time_s, "source": e.source, "kind": e.kind, "end_s": e.end_s,
                              "detail": e.detail} for e in data.events]
    m["bus_load"] = {bus: _bus_load(t) for bus, t in data.can.items()}
    rec.meta = m
    return rec
