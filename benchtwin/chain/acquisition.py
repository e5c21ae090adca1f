"""The acquisition: decode what the bench received (CAN frames, PDOs, Modbus polls) into a Recording.

:func:`acquire` is the one decoder of the project. Batch mode calls it with the frame tables and
poll logs read from the raw logs (or straight from the sensors' outputs); the live recorder calls
it with what it received from the transports. It never raises on bad traffic: malformed frames
(wrong DLC, bad IVT-S mux byte), unknown identifiers, Modbus exception answers and timeouts,
counter gaps, duplicates, reordering, PDO gaps and transport drops are counted in
``Recording.meta`` and flagged on the samples they affect (:class:`~benchtwin.recording.Flag`),
and every good sample is kept.

Decoding is vectorised: frames are grouped per identifier with one stable sort, and each group is
unpacked column-wise from the DBC/EDS layouts (:mod:`benchtwin.wire.codec` compiled from the
cantools Signal definitions of the IVT-S, AD module, vehicle and dyno messages;
:mod:`benchtwin.wire.canopen_pdo` from the EDS TPDO mapping read with canopen).

Channels keep the time base of their source (the device's clock as stamped on the frame, the
pressure module's uptime registers). ``meta["clock_offsets_s"]`` reports the offsets between
sources detected by cross-correlation: key ``"a->b"`` is the time to add to ``a``'s timestamps to
line them up with ``b``'s (vehicle speed on the vehicle CAN vs the dyno roller speed; CAN motor
power vs the HPCU shunt's power), and ``"pressure->acquisition"`` the median of poll time minus
module uptime. On recordings of an hour or more, ``meta["clock_drift_ppm"]`` gives the relative
drift of the same pairs (:mod:`benchtwin.chain.alignment`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

import numpy as np

from benchtwin.chain.alignment import clock_offsets, detect_lag
from benchtwin.chain.faults import detect_faults
from benchtwin.config.setup import SetupConfig
from benchtwin.errors import DataError
from benchtwin.recording import Flag, Recording
from benchtwin.segments import Segment
from benchtwin.sensors import devices
from benchtwin.sensors.base import Device, FrameDecoder
from benchtwin.wire.frames import FrameTable, PollLog, TransportEvent
from benchtwin.wire.quality import FLAG, DecodeSink, FrameStream

__all__ = ["AcquisitionInput", "acquire", "declared_uncertainty", "detect_lag"]

log = logging.getLogger(__name__)


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
    start_time:
        Absolute time (UTC) of time 0 (the campaign start in batch, the acquisition start live); the
        Recording and the raw logs carry it as their start time.
    """

    can: dict[str, FrameTable] = field(default_factory=dict)
    polls: dict[str, PollLog] = field(default_factory=dict)
    events: list[TransportEvent] = field(default_factory=list)
    segments: list[Segment] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)
    start_time: datetime | None = None


def _events_for(events: list[TransportEvent], names: set[str]) -> np.ndarray:
    ends = []
    for e in events:
        if (e.source in names or e.source == "*") and e.kind in ("drop", "overrun", "truncated"):
            ends.append(e.end_s if np.isfinite(e.end_s) else e.time_s)
    return np.asarray(ends, dtype=np.float64)


def _group(frames: np.ndarray, ids_known: list[int]) -> tuple[dict[int, np.ndarray], dict[int, int]]:
    """Indices of the frames of each known id (time order) and counts of unknown ids."""
    ids = np.ascontiguousarray(frames["arbitration_id"])
    keys = sorted(ids_known)
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


def _data_words(frames: np.ndarray) -> np.ndarray:
    """The 8 data bytes of every frame as one little-endian 8-byte word: a read-only view on the records."""
    if frames.flags["C_CONTIGUOUS"] and len(frames):
        offset = frames.dtype.fields["data"][1]
        words = np.ndarray((len(frames),), dtype="<u8", buffer=frames.data, offset=offset,
                           strides=(frames.dtype.itemsize,))
        words.flags.writeable = False
        return words
    return np.ascontiguousarray(frames["data"]).view("<u8")[:, 0]


def _decoders(devs: list[Device], bus: str) -> dict[int, FrameDecoder]:
    out: dict[int, FrameDecoder] = {}
    for d in devs:
        if d.bus == bus:
            out.update(d.frame_decoders())
    return out


def _decode_bus(table: FrameTable, devs: list[Device], sink: DecodeSink, drops: np.ndarray) -> None:
    frames = table.frames
    decoders = _decoders(devs, table.bus)
    owner = {cid: d.name for d in devs if d.bus == table.bus for cid in d.frame_decoders()}
    groups, unknown = _group(frames, list(decoders))
    sink.counts["frames"][table.bus] = len(table)
    if unknown:
        sink.counts["unknown_ids"][table.bus] = {f"0x{k:X}": v for k, v in unknown.items()}
    # every stream gathers from views on the records' columns (the data bytes as one 8-byte word): no copy of
    # the bus's columns beside its frame table
    ts = frames["timestamp"]
    dlc = frames["dlc"]
    words = _data_words(frames)
    for cid, idx in groups.items():
        length = decoders[cid].length
        if length:
            wrong = dlc[idx] != length
            if wrong.any():  # judged from the wire: the identifier's layout has another length
                sink.fault("wrong_dlc", owner[cid], ts[idx][wrong])
        decoders[cid].decode(FrameStream(table.bus, cid, ts[idx], dlc[idx], words[idx], drops), sink)


def _flag_saturation(rec: Any, devs: list[Device]) -> None:
    """SATURATED where a channel sits at the output saturation its device's errors configure."""
    for d in devs:
        for role, err in d.saturation().items():
            lo, hi = err.saturation_min, err.saturation_max
            if (lo is None and hi is None) or role not in rec:
                continue
            ch = rec[role]
            span = (hi - lo) if lo is not None and hi is not None else max(abs(lo or 0.0), abs(hi or 0.0), 1.0)
            tol = 1e-3 * span
            at = np.zeros(len(ch), dtype=bool)
            if hi is not None:
                at |= ch.values >= hi - tol
            if lo is not None:
                at |= ch.values <= lo + tol
            ch.flags[at] |= FLAG["SATURATED"]


def _flag_truncations(rec: Any, events: list[TransportEvent], of_bus: dict[str, set[str]]) -> None:
    """A bus log cut short (a ``truncated`` event): its channels' last sample before the cut and any sample in
    the missing span are flagged TRANSPORT_DROP | LOST_FRAME (nothing after the cut is complete)."""
    bit = FLAG["TRANSPORT_DROP"] | FLAG["LOST_FRAME"]
    for e in events:
        if e.kind != "truncated":
            continue
        for name in of_bus.get(e.source, ()):
            ch = rec[name]
            if not len(ch):
                continue
            t = ch.timestamps
            at = (t >= e.time_s) & (t <= e.end_s)
            k = int(np.searchsorted(t, e.time_s, side="right")) - 1
            if 0 <= k < len(t):
                at[k] = True
            ch.flags[at] |= bit


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


def declared_uncertainty(devs: list[Device], roles: set[str]) -> dict[str, dict[str, float]]:
    """The systematic errors the setup declares for each decoded role, for the identification's type B budget.

    Each declared error is read as the half-width of a rectangular distribution (a data sheet's
    "+-0.25 % FS"): the value the setup injects is the size of the error the bench may have, not its sign.

    Returns
    -------
    dict
        Role -> ``{"gain_frac": a_g, "offset": a_o, "resolution": q[, "group": device]}``: half-widths of
        the relative gain error and of the offset (role's unit), and the step of the role's representation
        (the wire's scaling or the converter step, e.g. the 12-bit AD module at the telemetry's K_TEL, or a
        declared extra quantisation, whichever is coarser). ``group`` names the device when one declared
        error table applies to several of its roles (the five pressure transducers): the emulator gives
        them the same gain and offset, so they are fully correlated. Roles with nothing declared are left
        out. The noise is not listed: it is random and the fits' scatter carries it.
    """
    out: dict[str, dict[str, Any]] = {}
    for d in devs:
        steps = {role: tc.resolution for role, tc in d.truth_channels().items()}
        budget = d.error_budget()
        shared: dict[int, list[str]] = {}
        for role, (err, _link, _extra) in budget.items():
            if err is not None and role in roles:
                shared.setdefault(id(err), []).append(role)
        for role in sorted(set(steps) | set(budget)):
            if role not in roles:
                continue
            err = budget.get(role, (None, None, 0.0))[0]
            gain = abs(err.gain_error_frac) if err is not None else 0.0
            offset = abs(err.offset) if err is not None else 0.0
            step = max(float(steps.get(role, 0.0)), err.quantisation_step if err is not None else 0.0)
            if gain > 0 or offset > 0 or step > 0:
                out[role] = {"gain_frac": float(gain), "offset": float(offset), "resolution": float(step)}
                if err is not None and len(shared[id(err)]) > 1:
                    out[role]["group"] = d.name
    return out


def acquire(data: AcquisitionInput, setup: SetupConfig, *, segments: list[Segment] | None = None,
            meta: dict[str, Any] | None = None, align: bool = True) -> Recording:
    """Decode everything received into a :class:`~benchtwin.recording.Recording`.

    Parameters
    ----------
    data:
        An :class:`AcquisitionInput` (frame tables incl. PDO frames, poll logs, transport events),
        the sensors' :class:`~benchtwin.wire.frames.DeviceOutputs` (delivered first with
        :func:`benchtwin.chain.batch.deliver`), or a folder of raw logs (read with
        :func:`benchtwin.chain.batch.read_logs`).
    setup:
        The bench (buses, ids, scalings).
    segments:
        Segment table (overrides ``data.segments``).
    meta:
        Extra metadata for the Recording.
    align:
        Detect clock offsets between sources.

    Raises
    ------
    DataError
        If ``data`` is not an :class:`AcquisitionInput`.
    """
    if not isinstance(data, AcquisitionInput):
        raise DataError(f"acquire() takes an AcquisitionInput, not {type(data).__name__} (read logs with "
                        "benchtwin.chain.batch.read_logs, deliver device outputs with benchtwin.chain.batch.deliver)")
    devs = devices(setup)
    polled = {d.poll_device: d for d in devs if d.poll_device is not None}
    sink = DecodeSink()
    of_bus: dict[str, set[str]] = {}
    for bus, table in data.can.items():
        drops = _events_for(data.events, {bus})
        before = set(sink.rec.channels)
        try:
            _decode_bus(table, devs, sink, drops)
        except Exception as exc:  # never lose the other buses because one is broken
            log.error("bus %s could not be decoded: %s", bus, exc)
            sink.protocol_error(f"{bus}: decoding failed ({exc})", max(1, len(table)))
        of_bus[bus] = set(sink.rec.channels) - before
    _flag_truncations(sink.rec, data.events, of_bus)
    for device, plog in data.polls.items():
        drops = _events_for(data.events, {device})
        dev = polled.get(device)
        if dev is None:
            log.warning("poll log %s belongs to no device of setup %s: not decoded", device, setup.name)
            sink.count("unknown_poll_devices", device, len(plog))
            continue
        try:
            dev.decode_polls(plog, sink, drops)
        except Exception as exc:
            log.error("poll log %s could not be decoded: %s", device, exc)
            sink.protocol_error(f"modbus:{device}: decoding failed ({exc})", max(1, len(plog)))
    rec = sink.rec
    _flag_saturation(rec, devs)
    faults_found = detect_faults(rec, devs, sink.evidence, data.events)
    rec.segments = list(segments if segments is not None else data.segments)
    m = dict(data.meta)
    m.update(meta or {})
    m["setup"] = setup.name
    m["sources"] = rec.sources()
    offsets = dict(sink.counts.pop("clock_offsets_s", {}))
    drifts: dict[str, float] = {}
    if align:
        found, drifts = clock_offsets(rec)
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
    m["faults_detected"] = faults_found
    m["transport_events"] = [{"time_s": e.time_s, "source": e.source, "kind": e.kind, "end_s": e.end_s,
                              "detail": e.detail} for e in data.events]
    m["bus_load"] = {bus: _bus_load(t) for bus, t in data.can.items()}
    m["declared_uncertainty"] = declared_uncertainty(devs, set(rec.channels))
    rec.meta = m
    rec.start_time = data.start_time
    return rec
