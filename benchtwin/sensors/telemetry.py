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

from dataclasses import dataclass

import numpy as np

from benchtwin.chain.codec import MessageCodec
from benchtwin.chain.dbc import AD_TORQUE_LSB_V, build_ad_module
from benchtwin.chain.frames import FRAME_DTYPE
from benchtwin.config.setup import K_TEL_STEPS, ShaftConfig, TelemetryConfig
from benchtwin.errors import ConfigError
from benchtwin.sensors.imperfections import DeviceClock, frame_faults, measure
from benchtwin.trace import Trace

__all__ = [
    "AD_BITS",
    "Table2Row",
    "bridge_voltage",
    "encode_telemetry",
    "k_tel_for",
    "k_tot",
    "pack_ad_frames",
    "table2",
    "torque_from_code",
    "unpack_ad_frames",
    "unpack_ad_words",
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
        rows.append(Table2Row(k, max(kt * 2 * vout_max_v / 2**AD_BITS, resolution_floor_nm), kt, kt * vout_max_v))
    return rows


def pack_ad_frames(code: np.ndarray, counter: np.ndarray, clip: np.ndarray) -> np.ndarray:
    """AD module payload (see ``ad_module.dbc``): 12-bit code, 4-bit counter, clip bit -> (n, 8) bytes."""
    c = np.asarray(code, dtype=np.int64) & 0xFFF
    word = c | ((np.asarray(counter, dtype=np.int64) & 0xF) << 12) | (np.asarray(clip, dtype=np.int64) & 1) << 16
    out = np.zeros((c.shape[0], 8), dtype=np.uint8)
    out[:, 0] = word & 0xFF
    out[:, 1] = (word >> 8) & 0xFF
    out[:, 2] = (word >> 16) & 0xFF
    return out


def unpack_ad_frames(data: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`pack_ad_frames`: signed code, counter, clip (int64)."""
    d = np.asarray(data, dtype=np.int64)
    word = d[:, 0] | (d[:, 1] << 8) | (d[:, 2] << 16)
    code = word & 0xFFF
    code = np.where(code > _CODE_MAX, code - 4096, code)
    return code, (word >> 12) & 0xF, (word >> 16) & 1


def unpack_ad_words(words_le: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`unpack_ad_frames` from the data as little-endian 64-bit words."""
    word = (np.asarray(words_le, dtype=np.uint64) & np.uint64(0xFFFFFF)).astype(np.int64)
    code = word & 0xFFF
    code = np.where(code > _CODE_MAX, code - 4096, code)
    return code, (word >> 12) & 0xF, (word >> 16) & 1


def torque_from_code(code: np.ndarray, cfg: TelemetryConfig) -> np.ndarray:
    """The acquisition's conversion back: T = K_TOT * code * LSB (eq. 12)."""
    return k_tot(cfg.shaft, cfg.k_tel) * np.asarray(code, dtype=np.float64) * AD_TORQUE_LSB_V


def encode_telemetry(trace: Trace, cfg: TelemetryConfig, rng: np.random.Generator) -> np.ndarray:
    """AD module frames of the propeller-shaft torque (FRAME_DTYPE, time-sorted)."""
    clock = DeviceClock.of(cfg.link)
    t_dev = clock.ticks(float(trace.time_s[0]), float(trace.time_s[-1]) + 1e-9, 1.0 / cfg.rate_hz)
    t = clock.to_plant(t_dev)
    torque = measure(trace.time_s, trace["shaft_torque_nm"], t, cfg.errors, rng, latency_s=cfg.link.latency_s)
    vout = cfg.k_tel * bridge_voltage(torque, cfg.shaft)
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
    codec = MessageCodec(build_ad_module("AD_Torque", cfg.can_id).messages[0])
    frames["data"] = codec.pack({"AD_Torque_Vout": code, "AD_Torque_Counter": np.arange(n), "AD_Torque_Clip": clip}, n)
    return frame_faults(frames, np.zeros(n, np.int64), cfg.link, rng)
