"""Register map of the 16-bit analogue input module that reads the SPA100 brake pressure transducers.

The module is a Modbus TCP device (unit id from the setup file). Five SPA100 transducers
(0-100 bar -> 0-5 V, linear) are wired to its inputs, in this order::

    channel 0  front-left caliper        channel 3  rear-right caliper
    channel 1  front-right caliper       channel 4  master cylinder
    channel 2  rear-left caliper

Input registers (function code 4), updated by the module at its update rate:

======  ===========================================================================================
reg     content
======  ===========================================================================================
0..4    raw ADC counts of channels 0..4, uint16, 0 = 0 V, 65535 = 10 V (input range 0-10 V, 16 bit)
5..9    pressure of channels 0..4 in 0.01 bar (uint16), the module's own scaling
        ``p = counts * 10 V / 65535 * full_scale_bar / full_scale_v``; 65535 = overload
10      status: bit n set = channel n at the top of the ADC range (clipped), bit 8+n = below zero
        (clipped low: a negative offset or a broken wire)
11      update counter, +1 per module update, wraps at 65536
12, 13  module uptime in ms, uint32 big-word first (high word in 12): the module's own clock
======  ===========================================================================================

Holding registers (function code 3), the scaling configuration: 100..104 full-scale pressure of each
channel in bar (default 100), 105..109 sensor output at full scale in mV (default 5000). A read outside
0..13 (input) or 100..109 (holding) answers Modbus exception code 2 (illegal data address).

The acquisition polls input registers 0..13 in one request (function code 4, count 14) and
converts the raw counts itself (the scaled registers are a cross-check), so the resolution is that
of the 16-bit converter: 10 V / 65535 per count = 0.0031 bar for a 0-5 V / 0-100 bar sensor.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "ADC_FULL_SCALE_V",
    "CHANNELS",
    "HOLDING_FIRST",
    "INPUT_COUNT",
    "REG_COUNTER",
    "REG_PRESSURE",
    "REG_RAW",
    "REG_STATUS",
    "REG_UPTIME_HI",
    "REG_UPTIME_LO",
    "counts_to_volts",
    "holding_defaults",
    "volts_to_counts",
]

#: trace channel suffix and Recording role of each module input, in register order
CHANNELS: tuple[tuple[str, str], ...] = (
    ("brake_pressure_fl_pa", "brake_pressure_fl_bar"),
    ("brake_pressure_fr_pa", "brake_pressure_fr_bar"),
    ("brake_pressure_rl_pa", "brake_pressure_rl_bar"),
    ("brake_pressure_rr_pa", "brake_pressure_rr_bar"),
    ("master_cylinder_pa", "master_cylinder_bar"),
)
REG_RAW = 0
REG_PRESSURE = 5
REG_STATUS = 10
REG_COUNTER = 11
REG_UPTIME_HI = 12
REG_UPTIME_LO = 13
#: input registers 0..13
INPUT_COUNT = 14
HOLDING_FIRST = 100
#: ADC input range, volts (0..10 V over 0..65535)
ADC_FULL_SCALE_V = 10.0
_ADC_MAX = 65535


def volts_to_counts(volts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quantise input voltages with the 16-bit converter.

    Returns
    -------
    counts, high, low
        uint16 counts and masks of inputs clipped at the top and at zero.
    """
    c = np.rint(np.asarray(volts, dtype=np.float64) / ADC_FULL_SCALE_V * _ADC_MAX)
    high = c >= _ADC_MAX
    low = c < 0
    return np.clip(c, 0, _ADC_MAX).astype(np.uint16), high, low


def counts_to_volts(counts: np.ndarray) -> np.ndarray:
    """Inverse of :func:`volts_to_counts` (no clipping information)."""
    return np.asarray(counts, dtype=np.float64) * (ADC_FULL_SCALE_V / _ADC_MAX)


def holding_defaults(full_scale_bar: float = 100.0, full_scale_v: float = 5.0) -> dict[int, int]:
    """Holding register address -> default value (the scaling configuration)."""
    out = {HOLDING_FIRST + i: round(full_scale_bar) for i in range(len(CHANNELS))}
    out.update({HOLDING_FIRST + 5 + i: round(full_scale_v * 1000) for i in range(len(CHANNELS))})
    return out
