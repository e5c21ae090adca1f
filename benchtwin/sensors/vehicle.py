"""Vehicle CAN (ECU signals) and the chassis dyno's CAN broadcast, encoded from the DBC files.

Every message of ``vehicle.dbc`` and ``dyno.dbc`` is sent at its DBC cycle time on the sender's
clock; each signal is the trace channel converted to the signal's unit (:data:`SIGNAL_MAP`), with
the per-role errors of the setup file, scaled and packed by the vectorised codec. Counters count
up per frame. A NaN dyno set speed (road-load mode) is sent as the raw maximum 0xFFFF.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from benchtwin.chain.codec import MessageCodec
from benchtwin.chain.dbc import load_dbc
from benchtwin.chain.frames import FRAME_DTYPE
from benchtwin.chain.merge import merge_frames
from benchtwin.config.setup import ChannelErrors, DynoConfig, VehicleCanConfig
from benchtwin.sensors.imperfections import DeviceClock, frame_faults, measure
from benchtwin.trace import Trace

__all__ = ["SIGNAL_MAP", "SignalSource", "encode_can_device", "message_codecs"]

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


def message_codecs(stem: str) -> list[MessageCodec]:
    """Compiled codecs of every message of a shipped DBC."""
    return [MessageCodec(m) for m in load_dbc(stem).messages]


def encode_can_device(trace: Trace, stem: str, cfg: VehicleCanConfig | DynoConfig, rng: np.random.Generator
                      ) -> np.ndarray:
    """All frames of the vehicle CAN (``stem='vehicle'``) or the dyno (``'dyno'``), time-sorted."""
    clock = DeviceClock.of(cfg.link)
    t0, t1 = float(trace.time_s[0]), float(trace.time_s[-1]) + 1e-9
    parts = []
    sources = SIGNAL_MAP[stem]
    ideal = ChannelErrors()
    for codec in message_codecs(stem):
        period = (codec.message.cycle_time or 100) / 1000.0
        phase = (zlib.crc32(codec.name.encode()) % 97) * 1e-4 % period  # senders are not in phase
        t_dev = clock.ticks(t0, t1, period, phase)
        t = clock.to_plant(t_dev)
        n = t.shape[0]
        raw = {}
        for name in codec.signals:
            src = sources[name]
            if src.trace is None:
                raw[name] = np.arange(n, dtype=np.int64)
                continue
            errors = cfg.errors.get(src.role or "", ideal)
            x = measure(trace.time_s, trace[src.trace] * src.factor, t, errors, rng, latency_s=cfg.link.latency_s,
                        hold=src.hold)
            raw[name], _ = codec.to_raw(name, x)
        fr = np.zeros(n, dtype=FRAME_DTYPE)
        fr["timestamp"] = t_dev
        fr["arbitration_id"] = codec.frame_id
        fr["dlc"] = codec.length
        fr["data"] = codec.pack(raw, n)
        parts.append(fr)
    frames = merge_frames(parts)
    return frame_faults(frames, frames["arbitration_id"].astype(np.int64), cfg.link, rng)
