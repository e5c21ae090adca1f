"""Vehicle CAN (ECU signals) and the chassis dyno's CAN broadcast, encoded from the DBC files.

Every message of ``vehicle.dbc`` and ``dyno.dbc`` is sent at its DBC cycle time on the sender's
clock; each signal is the trace channel converted to the signal's unit (:data:`SIGNAL_MAP`), with
the per-role errors of the setup file, scaled and packed by the vectorised codec. Counters count
up per frame. A NaN dyno set speed (road-load mode) is sent as the raw maximum 0xFFFF.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from benchtwin.config.setup import ChannelErrors, DynoConfig, FaultSpec, LinkErrors, VehicleCanConfig
from benchtwin.roles import unit_of_role
from benchtwin.sensors.base import Device, FrameDecoder, TruthChannel
from benchtwin.sensors.blocks import Block
from benchtwin.sensors.imperfections import (
    DeviceClock,
    draw_as_measured,
    frame_faults,
    frames_faulted,
    measure,
    silent_ticks,
    span_frame_faults,
    with_stuck,
)
from benchtwin.trace import Trace
from benchtwin.wire.codec import MessageCodec
from benchtwin.wire.dbc import load_dbc
from benchtwin.wire.frames import FRAME_DTYPE
from benchtwin.wire.merge import merge_frames
from benchtwin.wire.quality import FLAG, DecodeSink, FrameStream, counter_flags, mark_after, split_bad, timing_flags

if TYPE_CHECKING:
    from cantools.database.can import Database

__all__ = ["SIGNAL_MAP", "DynoCan", "SignalSource", "VehicleCan", "encode_can_device", "message_codecs",
           "unsent_messages"]

RADPS_TO_RPM = 60.0 / (2.0 * np.pi)
MPS_TO_KMH = 3.6


@dataclass(frozen=True)
class SignalSource:
    """Where a DBC signal comes from and which Recording role it becomes.

    ``trace`` is None for counters; ``factor`` converts the trace's SI value to the signal's unit;
    ``hold`` marks discrete states (zero-order hold, no interpolation); ``nan_raw_max`` marks a
    signal whose raw maximum means "not available".
    """

    trace: str | None
    factor: float
    role: str | None
    hold: bool = False
    nan_raw_max: bool = False


def _s(trace: str, factor: float, role: str, hold: bool = False, nan: bool = False) -> SignalSource:
    return SignalSource(trace, factor, role, hold, nan)


_COUNTER = SignalSource(None, 1.0, None)

#: DBC stem -> signal name -> source
SIGNAL_MAP: dict[str, dict[str, SignalSource]] = {
    "vehicle": {
        "EngSpeed": _s("engine_speed_radps", RADPS_TO_RPM, "engine_speed_rpm"),
        "EngTorque": _s("engine_torque_nm", 1.0, "engine_torque_nm"),
        "EngOn": _s("engine_on", 1.0, "engine_on", hold=True),
        "EngCounter": _COUNTER,
        "EmSpeed": _s("em_speed_radps", RADPS_TO_RPM, "em_speed_rpm"),
        "EmTorque": _s("em_torque_nm", 1.0, "em_torque_nm"),
        "EmCounter": _COUNTER,
        "FuelMassFlow": _s("fuel_mass_flow_kgps", 1000.0, "fuel_mass_flow_gps"),
        "GearTarget": _s("gear_target", 1.0, "gear_target", hold=True),
        "GearActual": _s("gear_actual", 1.0, "gear_actual", hold=True),
        "LockupClosed": _s("lockup_closed", 1.0, "lockup_closed", hold=True),
        "K0Closed": _s("k0_closed", 1.0, "k0_closed", hold=True),
        "AccelPedal": _s("pedal_pct", 1.0, "pedal_pct"),
        "BrakePedal": _s("brake_pedal_pct", 1.0, "brake_pedal_pct"),
        "VehicleSpeed": _s("vehicle_speed_mps", MPS_TO_KMH, "vehicle_speed_kmh"),
        "DisplayedSOC": _s("displayed_soc_pct", 1.0, "displayed_soc_pct"),
        "HybridMode": _s("hybrid_mode", 1.0, "hybrid_mode", hold=True),
    },
    "dyno": {
        "RollerSpeed": _s("dyno_speed_mps", MPS_TO_KMH, "dyno_speed_kmh"),
        "SetSpeed": _s("dyno_set_speed_mps", MPS_TO_KMH, "dyno_set_speed_kmh", nan=True),
        "DynoCounter": _COUNTER,
        "ForceFront": _s("dyno_force_front_n", 1.0, "dyno_force_front_n"),
        "ForceRear": _s("dyno_force_rear_n", 1.0, "dyno_force_rear_n"),
    },
}


@cache
def message_codecs(stem: str) -> tuple[MessageCodec, ...]:
    """Compiled codecs of every message of a shipped DBC."""
    return tuple(MessageCodec(m) for m in load_dbc(stem).messages)


def encode_can_device(trace: Trace, stem: str, cfg: VehicleCanConfig | DynoConfig, rng: np.random.Generator,
                      faults: Sequence[FaultSpec] = (), blk: Block | None = None) -> np.ndarray:
    """All frames of the vehicle CAN (``stem='vehicle'``) or the dyno (``'dyno'``), time-sorted.

    ``blk``: the block of plant time to encode (``trace`` and ``rng`` are then unused); None: the whole ``trace``.
    """
    blk = Block.whole(trace, rng) if blk is None else blk
    trace, rng = blk.trace, blk.rng
    clock = DeviceClock.of(cfg.link)
    t0, t1 = blk.start_s, blk.end_s
    parts = []
    sources = SIGNAL_MAP[stem]
    ideal = ChannelErrors()
    unsent = unsent_messages(stem, cfg)
    faulted = frames_faulted(cfg.link, faults)
    for codec in message_codecs(stem):
        period = (codec.message.cycle_time or 100) / 1000.0
        phase = (zlib.crc32(codec.name.encode()) % 97) * 1e-4 % period  # senders are not in phase
        t_dev = silent_ticks(clock.ticks(t0, t1, period, phase), clock, faults)
        t = clock.to_plant(t_dev)
        n = t.shape[0]
        raw = {}
        for name in codec.signals:
            src = sources[name]
            if src.trace is None:
                if codec.frame_id not in unsent:
                    raw[name] = blk.counter(f"{codec.name}.{name}", n)
                continue
            errors = with_stuck(cfg.errors.get(src.role or "", ideal), faults, src.role or "")
            if codec.frame_id in unsent:  # not measured, its draws taken: the other messages' are unchanged
                draw_as_measured(errors, rng, n)
                continue
            x = measure(trace.time_s, trace[src.trace] * src.factor, t, errors, rng, latency_s=cfg.link.latency_s,
                        hold=src.hold, blk=blk, key=f"{codec.name}.{name}")
            raw[name], _ = codec.to_raw(name, x)
        if codec.frame_id in unsent and not faulted:
            continue
        fr = np.zeros(n, dtype=FRAME_DTYPE)
        fr["timestamp"] = t_dev
        fr["arbitration_id"] = codec.frame_id
        fr["dlc"] = codec.length
        if codec.frame_id not in unsent:
            fr["data"] = codec.pack(raw, n)
        parts.append(fr)
    frames = merge_frames(parts)
    # the frame faults draw over every frame, the unsent messages' too (built empty for them); those go after them
    frames = frame_faults(frames, frames["arbitration_id"].astype(np.int64), cfg.link, rng)
    frames = span_frame_faults(frames, frames["arbitration_id"].astype(np.int64), faults, rng, clock)
    if unsent and faulted:
        frames = frames[~np.isin(frames["arbitration_id"], list(unsent))]
    return frames


def unsent_messages(stem: str, cfg: VehicleCanConfig | DynoConfig) -> frozenset[int]:
    """Identifiers of the messages none of whose signals is recorded (``not_recorded``, a family run's bench): such a
    message is not sent; a message with one recorded signal is sent whole."""
    skip = set(getattr(cfg, "not_recorded", ()))
    if not skip:
        return frozenset()
    sources = SIGNAL_MAP[stem]
    out = set()
    for codec in message_codecs(stem):
        roles = {sources[n].role for n in codec.signals if sources[n].trace is not None}
        if roles and roles <= skip:
            out.add(codec.frame_id)
    return frozenset(out)


class _DbcDevice(Device):
    """A device whose every message is described by a shipped DBC and fed from the Trace by :data:`SIGNAL_MAP`."""

    wire = "can"
    #: stem of the shipped DBC
    stem: ClassVar[str]

    def encode(self, blk: Block) -> np.ndarray:
        """Every message at its cycle time on the sender's clock, over one block."""
        return encode_can_device(blk.trace, self.stem, self.cfg, blk.rng, self.setup.faults_of(self.name), blk)

    def database(self) -> Database:
        """The shipped DBC."""
        return load_dbc(self.stem)

    def frame_decoders(self) -> dict[int, FrameDecoder]:
        """One decoder per DBC message."""
        return {c.frame_id: FrameDecoder(c.length, self._decoder(c)) for c in message_codecs(self.stem)}

    def _decoder(self, codec: MessageCodec):
        sources = SIGNAL_MAP[self.stem]
        period = (codec.message.cycle_time or 0) / 1000.0
        counters = [n for n in codec.signals if sources[n].trace is None]
        texts = {}  # the DBC's value tables, in physical values (what the Recording stores)
        for sig in codec.message.signals:
            if sig.choices:
                texts[sig.name] = {round(sig.scale * raw + sig.offset): str(text)
                                   for raw, text in sig.choices.items()}

        not_sent = set(getattr(self.cfg, "not_sent", ())) | set(getattr(self.cfg, "not_recorded", ()))

        def decode(s: FrameStream, sink: DecodeSink) -> None:
            good, proto, nbad = split_bad(s.dlc, codec.length)
            sink.protocol_error(s.where, nbad)
            t = s.t[good]
            raw = codec.unpack_words(s.words[good])
            base = proto.copy()
            if counters:
                base |= counter_flags(raw[counters[0]], codec.signals[counters[0]].length)
            else:
                base |= timing_flags(t, period, s.words[good])
            mark_after(base, t, s.drops, FLAG["TRANSPORT_DROP"] | FLAG["LOST_FRAME"])
            for name, r in raw.items():
                src = sources[name]
                if src.role is None or src.role in not_sent:
                    continue
                sig = codec.signals[name]
                v = codec.to_physical(name, r)
                flags = base.copy()
                if src.nan_raw_max:
                    v[r == sig.raw_max] = np.nan
                elif not src.hold:
                    at_limit = (r == sig.raw_max) | ((r == sig.raw_min) if sig.signed else False)
                    flags[at_limit] |= FLAG["SATURATED"]
                sink.add(src.role, unit_of_role(src.role), t, v, flags, self.name, texts.get(name))

        return decode

    def truth_channels(self) -> dict[str, TruthChannel]:
        """Every signal with a role, to one step of its DBC scaling."""
        out = {}
        sources = SIGNAL_MAP[self.stem]
        not_sent = set(getattr(self.cfg, "not_sent", ())) | set(getattr(self.cfg, "not_recorded", ()))
        for codec in message_codecs(self.stem):
            for name, sig in codec.signals.items():
                src = sources.get(name)
                if src is not None and src.role is not None and src.trace is not None and src.role not in not_sent:
                    ends = sorted((sig.raw_min * sig.scale + sig.offset, sig.raw_max * sig.scale + sig.offset))
                    out[src.role] = TruthChannel(src.trace, src.factor, src.hold, float(sig.scale),
                                                 (float(ends[0]), float(ends[1])))
        return out

    def error_budget(self) -> dict[str, tuple[ChannelErrors | None, LinkErrors, float]]:
        """Every role: the errors the setup declares for it (None: ideal), and the bus link."""
        out: dict[str, tuple[ChannelErrors | None, LinkErrors, float]] = {
            role: (None, self.cfg.link, 0.0) for role in self.truth_channels()}
        for role, err in self.cfg.errors.items():
            out[role] = (err, self.cfg.link, 0.0)
        return out

    def saturation(self) -> dict[str, ChannelErrors]:
        """Every role with declared errors."""
        return dict(self.cfg.errors)


class VehicleCan(_DbcDevice):
    """The vehicle CAN tap: ECU signals (setup section ``[vehicle_can]``, ``vehicle.dbc``)."""

    section = "vehicle_can"
    stem = "vehicle"


class DynoCan(_DbcDevice):
    """The chassis dyno's CAN broadcast (setup section ``[dyno]``, ``dyno.dbc``)."""

    section = "dyno"
    stem = "dyno"
