"""Propeller-shaft torque: strain gauge full bridge, telemetry gain, 12-bit AD module (paper eq. 1-12, Table 2).

Chain, for a shaft torque ``T``::

    tau_max = T R_e / I_p                               (8)  I_p = pi (R_e^4 - R_i^4) / 2
    eps     = (1 + nu) / E * tau_max                    (6)
    V_AB    = V_s K_SG eps                              (4, 7, 9)  full bridge, gauges at 45 deg
    V_out   = K_TEL V_AB, clipped at +-10 V             (10)
    code    = round(V_out / (20 V / 4096)), 12-bit two's complement -> AD module CAN frame
    T_out   = K_TOT V_out,  K_TOT = E I_p / (K_TEL V_s K_SG (1 + nu) R_e)     (12)

The resolution of the measured torque is ``max(K_TOT * 20 V / 4096, noise floor)``; with the
paper's shaft (steel, E 210 GPa, nu 0.3, K_SG 2.0, V_s 5 V, solid R_e ~20.5 mm) this is Table 2.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING

import numpy as np

from benchtwin.config.setup import K_TEL_STEPS, ChannelErrors, FaultSpec, LinkErrors, ShaftConfig, TelemetryConfig
from benchtwin.errors import ConfigError
from benchtwin.roles import unit_of_role
from benchtwin.sensors.base import Device, FrameDecoder, TruthChannel
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
from benchtwin.wire.dbc import AD_TORQUE_LSB_V, build_ad_module
from benchtwin.wire.frames import FRAME_DTYPE
from benchtwin.wire.quality import FLAG, DecodeSink, FrameStream, counter_flags, mark_after, split_bad

if TYPE_CHECKING:
    from cantools.database.can import Database

__all__ = [
    "AD_BITS",
    "ShaftTorqueTelemetry",
    "Table2Row",
    "ad_codec",
    "bridge_voltage",
    "decode_ad_frames",
    "encode_telemetry",
    "k_tel_for",
    "k_tot",
    "table2",
    "torque_from_code",
    "torque_step_nm",
]

AD_BITS = 12
_CODE_MIN, _CODE_MAX = -(2 ** (AD_BITS - 1)), 2 ** (AD_BITS - 1) - 1


def bridge_voltage(torque_nm: np.ndarray, shaft: ShaftConfig) -> np.ndarray:
    """Full-bridge output V_AB (volts) for a shaft torque (eq. 6-9)."""
    tau = np.asarray(torque_nm, dtype=np.float64) * shaft.outer_radius_m / shaft.polar_moment_m4
    eps = (1.0 + shaft.poisson) / shaft.youngs_modulus_pa * tau
    return shaft.supply_v * shaft.gauge_factor * eps


def k_tot(shaft: ShaftConfig, k_tel: float) -> float:
    """K_TOT in Nm/V (eq. 12)."""
    return (shaft.youngs_modulus_pa * shaft.polar_moment_m4
            / (k_tel * shaft.supply_v * shaft.gauge_factor * (1.0 + shaft.poisson) * shaft.outer_radius_m))


def torque_step_nm(shaft: ShaftConfig, k_tel: float) -> float:
    """One step of the 12-bit AD module (20 V / 4096) in shaft torque: ``K_TOT * LSB`` (Table 2 before its floor)."""
    return k_tot(shaft, k_tel) * AD_TORQUE_LSB_V


def k_tel_for(shaft: ShaftConfig, torque_max_nm: float, vout_max_v: float = 10.0) -> int:
    """The largest switch gain whose range still covers ``torque_max_nm`` (eq. 11 rounded down to a step).

    Raises
    ------
    ConfigError
        If even the smallest gain cannot cover the torque.
    """
    ideal = vout_max_v * shaft.youngs_modulus_pa * shaft.polar_moment_m4 / (
        shaft.supply_v * shaft.gauge_factor * (1.0 + shaft.poisson) * shaft.outer_radius_m * torque_max_nm)
    fits = [k for k in K_TEL_STEPS if k <= ideal]
    if not fits:
        raise ConfigError(f"no K_TEL step covers {torque_max_nm} Nm (eq. 11 gives {ideal:.0f})")
    return max(fits)


@dataclass(frozen=True)
class Table2Row:
    """One row of the paper's Table 2."""

    k_tel: int
    resolution_nm: float
    k_tot_nm_per_v: float
    range_nm: float


def table2(shaft: ShaftConfig, resolution_floor_nm: float = 0.3, vout_max_v: float = 10.0) -> list[Table2Row]:
    """Table 2 for a shaft: K_TOT, resolution (12-bit over +-10 V, floored) and range for every gain."""
    rows = []
    for k in K_TEL_STEPS:
        kt = k_tot(shaft, k)
        rows.append(Table2Row(k, max(torque_step_nm(shaft, k), resolution_floor_nm), kt, kt * vout_max_v))
    return rows


@cache
def ad_codec(can_id: int = 0x310) -> MessageCodec:
    """The compiled codec of the AD module's frame (``ad_module.dbc``) on identifier ``can_id``."""
    return MessageCodec(build_ad_module("AD_Torque", can_id).messages[0])


def decode_ad_frames(words_le: np.ndarray, can_id: int = 0x310) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signed converter code, counter and clip bit of AD module frames (data as little-endian 64-bit words)."""
    raw = ad_codec(can_id).unpack_words(words_le)
    return raw["AD_Torque_Vout"], raw["AD_Torque_Counter"], raw["AD_Torque_Clip"]


def torque_from_code(code: np.ndarray, cfg: TelemetryConfig) -> np.ndarray:
    """The acquisition's conversion back: T = K_TOT * code * LSB (eq. 12)."""
    return k_tot(cfg.shaft, cfg.k_tel) * np.asarray(code, dtype=np.float64) * AD_TORQUE_LSB_V


def encode_telemetry(trace: Trace, cfg: TelemetryConfig, rng: np.random.Generator,
                     faults: Sequence[FaultSpec] = (), blk: Block | None = None) -> np.ndarray:
    """AD module frames of the propeller-shaft torque (FRAME_DTYPE, time-sorted).

    ``faults``: injected faults; a ``clip`` holds the telemetry output at its rail over the span (the AD
    module sees its input at full scale and sets its clip bit). ``blk``: the block of plant time to encode
    (``trace`` and ``rng`` are then unused); None: the whole ``trace``.
    """
    blk = Block.whole(trace, rng) if blk is None else blk
    trace, rng = blk.trace, blk.rng
    clock = DeviceClock.of(cfg.link)
    t_dev = clock.ticks(blk.start_s, blk.end_s, 1.0 / cfg.rate_hz)
    t_dev = silent_ticks(t_dev, clock, faults)
    t = clock.to_plant(t_dev)
    torque = measure(trace.time_s, trace["shaft_torque_nm"], t, with_stuck(cfg.errors, faults, "shaft_torque_nm"),
                     rng, latency_s=cfg.link.latency_s, blk=blk, key="torque")
    vout = cfg.k_tel * bridge_voltage(torque, cfg.shaft)
    for f in faults:
        if f.kind == "clip":
            vout[in_spans(t, [f], "clip")] = cfg.vout_max_v if f.level == "high" else -cfg.vout_max_v
    clip = np.abs(vout) >= cfg.vout_max_v
    vout = np.clip(vout, -cfg.vout_max_v, cfg.vout_max_v)
    raw = np.rint(vout / AD_TORQUE_LSB_V)
    clip |= (raw > _CODE_MAX) | (raw < _CODE_MIN)
    code = np.clip(raw, _CODE_MIN, _CODE_MAX).astype(np.int64)
    n = t_dev.shape[0]
    frames = np.zeros(n, dtype=FRAME_DTYPE)
    frames["timestamp"] = t_dev
    frames["arbitration_id"] = cfg.can_id
    frames["dlc"] = 3
    frames["data"] = ad_codec(cfg.can_id).pack(
        {"AD_Torque_Vout": code, "AD_Torque_Counter": blk.counter("frames", n), "AD_Torque_Clip": clip}, n)
    frames = frame_faults(frames, np.zeros(n, np.int64), cfg.link, rng)
    return span_frame_faults(frames, np.zeros(len(frames), np.int64), faults, rng, clock)


class ShaftTorqueTelemetry(Device):
    """Strain-gauge bridge, telemetry and AD module of the propeller-shaft torque (setup section ``[telemetry]``)."""

    section = "telemetry"
    wire = "can"
    counters = True

    def encode(self, blk: Block) -> np.ndarray:
        """AD module frames over one block."""
        return encode_telemetry(blk.trace, self.cfg, blk.rng, self.setup.faults_of(self.name), blk)

    def database(self) -> Database:
        """The AD module's frame, its value scaled by this setup's K_TOT: ``AD_Torque_ShaftTorque`` in Nm."""
        return build_ad_module("AD_Torque", self.cfg.can_id, max(1, round(1000.0 / self.cfg.rate_hz)),
                               k_tot(self.cfg.shaft, self.cfg.k_tel))

    def frame_decoders(self) -> dict[int, FrameDecoder]:
        """The AD module's frame: code -> torque with eq. 12, clip bit -> SATURATED."""
        return {self.cfg.can_id: FrameDecoder(ad_codec(self.cfg.can_id).length, self._decode)}

    def _decode(self, s: FrameStream, sink: DecodeSink) -> None:
        good, proto, nbad = split_bad(s.dlc, ad_codec(self.cfg.can_id).length)
        sink.protocol_error(s.where, nbad)
        code, counter, clip = decode_ad_frames(s.words[good], self.cfg.can_id)
        flags = proto | counter_flags(counter, 4)
        flags[clip != 0] |= FLAG["SATURATED"]
        t = s.t[good]
        mark_after(flags, t, s.drops, FLAG["TRANSPORT_DROP"] | FLAG["LOST_FRAME"])
        sink.add("shaft_torque_nm", unit_of_role("shaft_torque_nm"), t, torque_from_code(code, self.cfg), flags,
                 self.name)

    def truth_channels(self) -> dict[str, TruthChannel]:
        """The shaft torque, to one converter step."""
        return {"shaft_torque_nm": TruthChannel("shaft_torque_nm", 1.0, False,
                                                torque_step_nm(self.cfg.shaft, self.cfg.k_tel))}

    def error_budget(self) -> dict[str, tuple[ChannelErrors | None, LinkErrors, float]]:
        """The torque errors plus the telemetry's resolution floor."""
        return {"shaft_torque_nm": (self.cfg.errors, self.cfg.link, self.cfg.resolution_floor_nm)}

    def saturation(self) -> dict[str, ChannelErrors]:
        """The shaft torque."""
        return {"shaft_torque_nm": self.cfg.errors}
