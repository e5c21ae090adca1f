"""Isabellenhuette IVT-S current/voltage shunt: measurement model, result frames and command channel.

Result frames (6 bytes, big-endian; see ``benchtwin/wire/dbc/ivt_s.dbc``)::

    byte 0      mux: 0x00 I, 0x01 U1, 0x02 U2, 0x03 U3, 0x04 T, 0x05 W, 0x06 As, 0x07 Wh
    byte 1      low nibble: cyclic message counter; high nibble: status
                (bit4 OCS, bit5 result out of range / channel error, bit6 measurement error, bit7 system error)
    bytes 2..5  signed int32: mA, mV, mV, mV, 0.1 degC, W, As, Wh

e.g. I = -12345 mA with counter 5 is ``00 05 FF FF CF C7``.

Measurement: the shunt's own 16-bit converter over +-range (LSB 30.5 mA at 1000 A, 18.3 mV at
600 V), then the integer result units. Out of range: the value is clipped at the range and the
status bit 5 is set. With ``ocs_threshold_a`` set, the over-current detection bit (4) is set on the
current result while |I| exceeds it (an event, not an error: the acquisition counts it).
Power W = I * U1; charge As and energy Wh are integrated from I and I*U1.
U2 and U3 are not wired at the paper's places and read 0 V.

Commands (:class:`IvtDevice`, used by the live half; answers have byte 0 = command + 0x80,
0xFF for an unknown command): 0x20+n configure result n (byte 1 bits 0-1: 0 off, 1 triggered,
2 cyclic; bytes 2-3 cycle time ms, big-endian), 0x30 reset errors, 0x31 trigger (byte 2 bit mask
of results), 0x34 set mode (byte 1 bit 0: 1 run, 0 stop).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import TYPE_CHECKING

import numba
import numpy as np

from benchtwin.config.setup import IVT_PLACES, ChannelErrors, FaultSpec, IvtConfig, LinkErrors, SetupConfig
from benchtwin.errors import FrameError
from benchtwin.roles import unit_of_role
from benchtwin.sensors.base import Device, FrameDecoder, TriggerSpec, TruthChannel
from benchtwin.sensors.blocks import Block
from benchtwin.sensors.imperfections import (
    DeviceClock,
    frame_faults,
    in_spans,
    measure,
    silent_ticks,
    span_frame_faults,
    with_stuck,
)
from benchtwin.trace import Trace
from benchtwin.wire.codec import MessageCodec
from benchtwin.wire.dbc import build_ivt, ivt_node_name
from benchtwin.wire.frames import FRAME_DTYPE
from benchtwin.wire.merge import merge_frames
from benchtwin.wire.quality import FLAG, DecodeSink, FrameStream, counter_flags, mark_after, split_bad

if TYPE_CHECKING:
    from cantools.database.can import Database

__all__ = [
    "CMD_CONFIGURE",
    "CMD_RESET_ERRORS",
    "CMD_SET_MODE",
    "CMD_TRIGGER",
    "MODE_CYCLIC",
    "MODE_OFF",
    "MODE_TRIGGERED",
    "RESULT_NAMES",
    "STATUS_OCS",
    "STATUS_OUT_OF_RANGE",
    "IvtAnswer",
    "IvtDevice",
    "IvtSamples",
    "IvtShunt",
    "encode_ivt",
    "ivt_samples",
    "result_codecs",
]

RESULT_NAMES: tuple[str, ...] = ("I", "U1", "U2", "U3", "T", "W", "As", "Wh")
CMD_CONFIGURE = 0x20
CMD_RESET_ERRORS = 0x30
CMD_TRIGGER = 0x31
CMD_SET_MODE = 0x34
MODE_OFF, MODE_TRIGGERED, MODE_CYCLIC = 0, 1, 2
#: status nibble bits (byte 1 bits 4..7)
STATUS_OCS, STATUS_OUT_OF_RANGE, STATUS_MEAS_ERROR, STATUS_SYS_ERROR = 0x1, 0x2, 0x4, 0x8
#: delay between a trigger command and the triggered results
TRIGGER_RESPONSE_S = 0.0002
#: spacing of the timestamps of the results of one cycle (0: stamped with the measurement time; the
#: frames follow each other in mux order)
RESULT_SPACING_S = 0.0


@cache
def result_codecs(result_base_id: int = 0x521, name: str = "IVT") -> tuple[MessageCodec, ...]:
    """The compiled codecs of the eight result messages of a shunt (mux order), from its DBC messages.

    Parameters
    ----------
    result_base_id:
        Identifier of the current result.
    name:
        Node name of the shunt (signal-name prefix).
    """
    db = build_ivt(name, result_base_id)
    return tuple(MessageCodec(db.get_message_by_frame_id(result_base_id + k)) for k in range(len(RESULT_NAMES)))


@numba.njit(cache=True, nogil=True)
def _status_flags(flags: np.ndarray, status: np.ndarray, range_flag: int, error_flag: int
                  ) -> int:  # pragma: no cover - numba
    """OR ``range_flag`` into ``flags`` where the status has the out-of-range bit, ``error_flag`` where it has the
    measurement or system error bit (in place); return the count of frames with the over-current bit."""
    n_ocs = 0
    for i in range(status.size):
        st = status[i]
        if st & STATUS_OUT_OF_RANGE:
            flags[i] |= range_flag
        if st & (STATUS_MEAS_ERROR | STATUS_SYS_ERROR):
            flags[i] |= error_flag
        if st & STATUS_OCS:
            n_ocs += 1
    return n_ocs


def _status_flags_numpy(flags: np.ndarray, status: np.ndarray, range_flag: int, error_flag: int) -> int:
    """The numpy reference of :func:`_status_flags` (what the result decoder did before it)."""
    flags[(status & STATUS_OUT_OF_RANGE) != 0] |= range_flag
    flags[(status & (STATUS_MEAS_ERROR | STATUS_SYS_ERROR)) != 0] |= error_flag
    return int(np.count_nonzero(status & STATUS_OCS))


def _signal(codec: MessageCodec, suffix: str) -> str:
    """The name of a result message's signal by role (``MuxID``, ``Status``, ``Counter`` or ``""`` for the value)."""
    value = next(n for n in codec.signals if not n.endswith(("_MuxID", "_Counter", "_Status")))
    return value if not suffix else f"{value}_{suffix}"


@dataclass
class IvtSamples:
    """The shunt's results at its sample times, before framing (what the live half can page through).

    ``values[k]`` and ``status[k]`` are the int32 result and status nibble of result ``k``
    (0 I .. 7 Wh) at ``t_device``.
    """

    t_device: np.ndarray
    t_plant: np.ndarray
    values: np.ndarray
    status: np.ndarray


def _adc(x: np.ndarray, full_range: float, bits: int) -> tuple[np.ndarray, np.ndarray]:
    lsb = 2.0 * full_range / 2**bits
    over = np.abs(x) > full_range
    return np.rint(np.clip(x, -full_range, full_range) / lsb) * lsb, over


def ivt_samples(trace: Trace, place: str, cfg: IvtConfig, rng: np.random.Generator, t_device: np.ndarray,
                faults: Sequence[FaultSpec] = (), blk: Block | None = None) -> IvtSamples:
    """All eight results of the shunt at device times ``t_device``.

    Parameters
    ----------
    trace:
        The truth.
    place:
        One of :data:`~benchtwin.config.setup.IVT_PLACES`.
    cfg:
        The shunt's setup.
    rng:
        The device's generator.
    t_device:
        Sample times on the shunt's clock.
    faults:
        Injected faults of this shunt: ``stuck`` on its current or voltage role, ``ivt_error`` (the status
        nibble of every result over the span).
    blk:
        The block of plant time being encoded (carries the filters and the charge and energy integrals);
        None: ``trace`` is the whole run.
    """
    blk = Block.whole(trace, rng) if blk is None else blk
    ch_i, ch_u, role_i, role_u = IVT_PLACES[place]
    clock = DeviceClock.of(cfg.link)
    t = clock.to_plant(t_device)
    i_true, u_true = trace[ch_i], trace[ch_u]
    i_m = measure(trace.time_s, i_true, t, with_stuck(cfg.current_errors, faults, role_i), rng,
                  latency_s=cfg.link.latency_s, blk=blk, key="i")
    u_m = measure(trace.time_s, u_true, t, with_stuck(cfg.voltage_errors, faults, role_u), rng,
                  latency_s=cfg.link.latency_s, blk=blk, key="u")
    i_q, i_over = _adc(i_m, cfg.current_range_a, cfg.adc_bits)
    u_q, u_over = _adc(u_m, cfg.voltage_range_v, cfg.adc_bits)
    # charge and energy integrate the measured signals on the trace grid (the shunt integrates internally)
    dt = np.diff(trace.time_s, prepend=trace.time_s[0])
    i_g = np.clip(i_true * (1 + cfg.current_errors.gain_error_frac) + cfg.current_errors.offset,
                  -cfg.current_range_a, cfg.current_range_a)
    u_g = np.clip(u_true * (1 + cfg.voltage_errors.gain_error_frac) + cfg.voltage_errors.offset,
                  -cfg.voltage_range_v, cfg.voltage_range_v)
    p_g = i_g * u_g
    q = blk.accumulated("charge", np.concatenate([[0.0], 0.5 * (i_g[1:] + i_g[:-1]) * dt[1:]]))
    e = blk.accumulated("energy", np.concatenate([[0.0], 0.5 * (p_g[1:] + p_g[:-1]) * dt[1:]])) / 3600.0
    ts = t - cfg.link.latency_s
    n = t.shape[0]
    values = np.zeros((8, n), dtype=np.int64)
    status = np.zeros((8, n), dtype=np.int64)
    values[0] = np.rint(i_q * 1000.0)
    values[1] = np.rint(u_q * 1000.0)
    values[4] = np.rint(cfg.temperature_degc * 10.0)
    values[5] = np.rint(i_q * u_q)
    values[6] = np.trunc(np.interp(ts, trace.time_s, q))
    values[7] = np.trunc(np.interp(ts, trace.time_s, e))
    status[0] = np.where(i_over, STATUS_OUT_OF_RANGE, 0)
    if cfg.ocs_threshold_a is not None:
        status[0] |= np.where(np.abs(i_m) > cfg.ocs_threshold_a, STATUS_OCS, 0)
    status[1] = np.where(u_over, STATUS_OUT_OF_RANGE, 0)
    status[5] = np.where(i_over | u_over, STATUS_OUT_OF_RANGE, 0)
    for f in faults:  # the shunt in an error state: its status nibble on every result over the span
        if f.kind == "ivt_error":
            status[:, in_spans(t, [f], "ivt_error")] |= f.status
    values = np.clip(values, -(2**31), 2**31 - 1)
    return IvtSamples(np.asarray(t_device, dtype=np.float64), t, values, status)


def encode_ivt(trace: Trace, place: str, cfg: IvtConfig, rng: np.random.Generator,
               faults: Sequence[FaultSpec] = (), blk: Block | None = None) -> np.ndarray:
    """All frames the shunt (and, in triggered mode, the bench's trigger commands) put on the bus.

    ``faults``: the shunt's injected faults (``silent`` spans send nothing, frame faults over spans,
    ``stuck`` and ``ivt_error`` in :func:`ivt_samples`). ``blk``: the block of plant time to encode (its
    window, generator and carried state; ``trace`` and ``rng`` are then unused); None: the whole ``trace``.

    Returns
    -------
    numpy.ndarray
        FRAME_DTYPE array sorted by timestamp.
    """
    blk = Block.whole(trace, rng) if blk is None else blk
    trace, rng = blk.trace, blk.rng
    clock = DeviceClock.of(cfg.link)
    t0, t1 = blk.start_s, blk.end_s
    enabled = [RESULT_NAMES.index(r) for r in cfg.results]
    parts = []
    if cfg.mode == "cyclic":
        t_dev = clock.ticks(t0, t1, cfg.cycle_ms / 1000.0)
    else:
        # the bench triggers every trigger_period on its own (plant) clock; the shunt answers on its clock
        t_cmd = np.arange(np.ceil(t0 * 1000.0 / cfg.trigger_period_ms), np.ceil(t1 * 1000.0 / cfg.trigger_period_ms)
                          ) * cfg.trigger_period_ms / 1000.0
        if blk.final:  # the run ends before the answer to its last trigger
            t_cmd = t_cmd[t_cmd < t1 - TRIGGER_RESPONSE_S - RESULT_SPACING_S * 8]
        t_dev = clock.to_device(t_cmd + TRIGGER_RESPONSE_S)
        mask = sum(1 << k for k in enabled)
        for cid, payload, dt in ((cfg.command_id, [CMD_TRIGGER, 0, mask, 0, 0, 0, 0, 0], 0.0),
                                 (cfg.response_id, [CMD_TRIGGER | 0x80, 0, mask, 0, 0, 0, 0, 0], TRIGGER_RESPONSE_S)):
            fr = np.zeros(t_cmd.shape[0], dtype=FRAME_DTYPE)
            fr["timestamp"] = t_cmd + dt if cid == cfg.command_id else clock.to_device(t_cmd + dt)
            fr["arbitration_id"] = cid
            fr["dlc"] = 8
            fr["data"] = np.array(payload, dtype=np.uint8)
            parts.append(fr)
    t_dev = silent_ticks(t_dev, clock, faults)
    s = ivt_samples(trace, place, cfg, rng, t_dev, faults, blk)
    n = s.t_device.shape[0]
    counter = blk.counter("results", n) & 0xF
    # the results of one measurement follow each other in mux order: build them interleaved
    # packed with the codec compiled from the shunt's DBC messages (the layout's one source of truth)
    codecs = result_codecs(cfg.result_base_id, ivt_node_name(place))
    res = np.zeros((n, len(enabled)), dtype=FRAME_DTYPE)
    for j, k in enumerate(enabled):
        codec = codecs[k]
        res["timestamp"][:, j] = s.t_device + RESULT_SPACING_S * k
        res["arbitration_id"][:, j] = cfg.result_base_id + k
        res["dlc"][:, j] = codec.length
        res["data"][:, j] = codec.pack({_signal(codec, "MuxID"): k, _signal(codec, "Counter"): counter,
                                        _signal(codec, "Status"): s.status[k], _signal(codec, ""): s.values[k]}, n)
    parts.insert(0, res.reshape(-1))
    frames = merge_frames(parts)
    frames = frame_faults(frames, frames["arbitration_id"].astype(np.int64), cfg.link, rng)
    return span_frame_faults(frames, frames["arbitration_id"].astype(np.int64), faults, rng, clock)


@dataclass
class IvtAnswer:
    """What the shunt does after a command: the answer frame's data and the results to send now."""

    data: bytes
    triggered: list[int] = field(default_factory=list)


@dataclass
class IvtDevice:
    """The shunt's command state machine (configure, trigger, run/stop, reset errors).

    The live half wires :meth:`handle_command` to frames received on ``command_id`` and sends the
    answer on ``response_id``; :meth:`cyclic_due` tells which results are due at a device time and
    :meth:`result_frame` builds a result frame with the running counter of that result.
    """

    cfg: IvtConfig
    running: bool = True
    modes: list[int] = field(default_factory=list)
    cycles_ms: list[int] = field(default_factory=list)
    counters: list[int] = field(default_factory=lambda: [0] * 8)
    latched_status: int = 0

    def __post_init__(self) -> None:
        enabled = {RESULT_NAMES.index(r) for r in self.cfg.results}
        mode = MODE_CYCLIC if self.cfg.mode == "cyclic" else MODE_TRIGGERED
        if not self.modes:
            self.modes = [mode if k in enabled else MODE_OFF for k in range(8)]
        if not self.cycles_ms:
            self.cycles_ms = [self.cfg.cycle_ms] * 8

    def handle_command(self, data: bytes) -> IvtAnswer:
        """Apply one command frame and return the answer.

        Raises
        ------
        FrameError
            If the frame is empty (no command byte).
        """
        if len(data) == 0:
            raise FrameError("IVT-S command frame without data", code=None)
        cmd = data[0]
        body = bytes(data[1:8]).ljust(7, b"\x00")
        if CMD_CONFIGURE <= cmd < CMD_CONFIGURE + 8:
            ch = cmd - CMD_CONFIGURE
            self.modes[ch] = body[0] & 0x3 if (body[0] & 0x3) != 3 else MODE_OFF
            cycle = int.from_bytes(body[1:3], "big")
            if cycle > 0:
                self.cycles_ms[ch] = cycle
            return IvtAnswer(bytes([cmd | 0x80]) + body)
        if cmd == CMD_RESET_ERRORS:
            self.latched_status = 0
            return IvtAnswer(bytes([cmd | 0x80]) + body)
        if cmd == CMD_TRIGGER:
            mask = body[1]
            chans = [k for k in range(8) if mask >> k & 1 and self.modes[k] == MODE_TRIGGERED] if self.running else []
            return IvtAnswer(bytes([cmd | 0x80]) + body, chans)
        if cmd == CMD_SET_MODE:
            self.running = bool(body[0] & 1)
            return IvtAnswer(bytes([cmd | 0x80]) + body)
        return IvtAnswer(bytes([0xFF, cmd]) + body[1:])

    def cyclic_due(self, t_prev_ms: float, t_now_ms: float) -> list[int]:
        """Results in cyclic mode whose cycle boundary falls in ``(t_prev_ms, t_now_ms]`` (device ms)."""
        if not self.running:
            return []
        return [k for k in range(8) if self.modes[k] == MODE_CYCLIC
                and np.floor(t_now_ms / self.cycles_ms[k]) > np.floor(t_prev_ms / self.cycles_ms[k])]

    def result_frame(self, k: int, value: int, status: int = 0) -> tuple[int, bytes]:
        """Arbitration id and 6 data bytes of result ``k`` with the next counter value."""
        c = self.counters[k]
        self.counters[k] = (c + 1) & 0xF
        st = (status | self.latched_status) & 0xF
        codec = result_codecs(self.cfg.result_base_id)[k]
        data = codec.pack({_signal(codec, "MuxID"): k, _signal(codec, "Counter"): c, _signal(codec, "Status"): st,
                           _signal(codec, ""): value}, 1)[0, :codec.length].tobytes()
        return self.cfg.result_base_id + k, data

    def unpack_result(self, k: int, data: bytes) -> tuple[int, int]:
        """Status nibble and int32 value of a result frame of result ``k`` (the inverse of :meth:`result_frame`)."""
        codec = result_codecs(self.cfg.result_base_id)[k]
        words = np.frombuffer(bytes(data).ljust(8, b"\0")[:8], dtype="<u8")
        raw = codec.unpack_words(words, [_signal(codec, "Status"), _signal(codec, "")])
        return int(raw[_signal(codec, "Status")][0]), int(raw[_signal(codec, "")][0])


# ---------------------------------------------------------------------------------------------- the device


def _result_channels(place: str) -> list[tuple[str, str, float]]:
    """(role or name, unit, scale of the integer result) of the eight results of the shunt at ``place``."""
    _, _, role_i, role_u = IVT_PLACES[place]
    prefix = role_i[: -len("_current_a")]
    return [(role_i, "A", 1e-3), (role_u, "V", 1e-3), (f"ivt_{place}_u2_v", "V", 1e-3),
            (f"ivt_{place}_u3_v", "V", 1e-3), (f"ivt_{place}_temp_degc", "degC", 0.1),
            (f"{prefix}_power_w", "W", 1.0), (f"ivt_{place}_charge_as", "As", 1.0),
            (f"ivt_{place}_energy_wh", "Wh", 1.0)]


class IvtShunt(Device):
    """An IVT-S shunt at one place of the HV or LV system (setup section ``[ivt.<place>]``)."""

    section = "ivt"
    wire = "can"
    counters = True

    def __init__(self, name: str, cfg: IvtConfig, setup: SetupConfig, place: str) -> None:
        super().__init__(name, cfg, setup)
        self.place = place

    @classmethod
    def from_setup(cls, setup: SetupConfig) -> list[Device]:
        """One device per configured place."""
        return [cls(f"ivt_{place}", cfg, setup, place) for place, cfg in setup.ivt.items()]

    def encode(self, blk: Block) -> np.ndarray:
        """Result frames (and the bench's trigger commands in triggered mode) over one block."""
        return encode_ivt(blk.trace, self.place, self.cfg, blk.rng, self.setup.faults_of(self.name), blk)

    def database(self) -> Database:
        """The shunt's result, command and answer messages on its own identifiers."""
        c = self.cfg
        return build_ivt(ivt_node_name(self.place), c.result_base_id, c.command_id, c.response_id,
                         c.cycle_ms if c.mode == "cyclic" else None)

    def frame_decoders(self) -> dict[int, FrameDecoder]:
        """The eight results, the command channel and its answers."""
        c = self.cfg
        codecs = result_codecs(c.result_base_id, ivt_node_name(self.place))
        channels = _result_channels(self.place)
        out = {c.result_base_id + k: FrameDecoder(codecs[k].length, self._result_decoder(k, codecs[k], channels[k]))
               for k in range(len(RESULT_NAMES))}
        out[c.command_id] = FrameDecoder(0, lambda s, sink: sink.count("ivt_commands", self.name, s.t.shape[0]))
        out[c.response_id] = FrameDecoder(0, self._decode_answers)
        return out

    def _result_decoder(self, k: int, codec: MessageCodec, channel: tuple[str, str, float]):
        name, unit, scale = channel

        names = tuple(_signal(codec, role) for role in ("MuxID", "Counter", "Status", ""))  # unpacked in one pass
        range_flag, error_flag = FLAG["OUT_OF_RANGE"] | FLAG["SATURATED"], FLAG["STATUS_ERROR"]

        def decode(s: FrameStream, sink: DecodeSink) -> None:
            raw = codec.unpack_words(s.words, names)
            mux_bad = raw[names[0]] != k
            corrupt = mux_bad & (s.dlc == codec.length)
            if corrupt.any():  # a full-length frame whose mux byte is not this identifier's result
                sink.fault("corrupt_payload", self.name, s.t[corrupt])
            good, proto, nbad = split_bad(s.dlc, codec.length, mux_bad)
            sink.protocol_error(s.where, nbad)
            counter, status, value = (raw[n][good] if nbad else raw[n] for n in names[1:])
            flags = proto | counter_flags(counter, 4)
            n_ocs = _status_flags(flags, status, range_flag, error_flag)
            if n_ocs:  # over-current detection is an event of the circuit, not a measurement error
                sink.count("ivt_ocs_frames", self.name, n_ocs)
            t = s.t[good]
            mark_after(flags, t, s.drops, FLAG["TRANSPORT_DROP"] | FLAG["LOST_FRAME"])
            sink.add(name, unit_of_role(name) or unit, t, value * scale, flags, self.name)

        return decode

    def _decode_answers(self, s: FrameStream, sink: DecodeSink) -> None:
        sink.count("ivt_answers", self.name, s.t.shape[0])
        unk = int(np.sum((s.words & np.uint64(0xFF)) == 0xFF))
        if unk:
            sink.protocol_error(f"{s.where} unknown-command answers", unk)

    def truth_channels(self) -> dict[str, TruthChannel]:
        """Current and voltage: the shunt's converter step over +-range plus the 1 mA / 1 mV step of the result."""
        ch_i, ch_u, role_i, role_u = IVT_PLACES[self.place]
        c = self.cfg
        return {role_i: TruthChannel(ch_i, 1.0, False, 2 * c.current_range_a / 2**c.adc_bits + 0.001),
                role_u: TruthChannel(ch_u, 1.0, False, 2 * c.voltage_range_v / 2**c.adc_bits + 0.001)}

    def error_budget(self) -> dict[str, tuple[ChannelErrors | None, LinkErrors, float]]:
        """The current and voltage errors of the shunt."""
        _, _, role_i, role_u = IVT_PLACES[self.place]
        return {role_i: (self.cfg.current_errors, self.cfg.link, 0.0),
                role_u: (self.cfg.voltage_errors, self.cfg.link, 0.0)}

    def saturation(self) -> dict[str, ChannelErrors]:
        """Current and voltage."""
        _, _, role_i, role_u = IVT_PLACES[self.place]
        return {role_i: self.cfg.current_errors, role_u: self.cfg.voltage_errors}

    def command_device(self) -> IvtDevice:
        """The shunt's command state machine."""
        return IvtDevice(self.cfg)

    def triggers(self) -> list[TriggerSpec]:
        """In triggered mode, the bench triggers the enabled results every ``trigger_period_ms``."""
        c = self.cfg
        if c.mode != "triggered":
            return []
        return [TriggerSpec(c.bus, c.command_id, sum(1 << RESULT_NAMES.index(r) for r in c.results),
                            c.trigger_period_ms / 1000.0)]
