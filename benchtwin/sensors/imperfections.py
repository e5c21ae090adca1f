"""Sensor imperfections shared by every device model: errors of the measured value, clocks, frame faults.

Measured value (:func:`measure`), in the unit the sensor measures::

    x_f   = LTI(bandwidth)(x_true)                python-control tf, c2d (ZOH) at the trace step,
                                                  applied with scipy.signal.lfilter from steady state
    x_s   = x_f(t_true - latency)                 sampled when the device samples (its own clock)
    x_m   = (1 + gain_error) x_s + offset + N(0, noise_std)
    x_q   = quantisation_step * round(x_m / step) (the wire's own resolution comes after, per device)
    x_q   = clipped to [saturation_min, saturation_max] if set (an output stage that saturates early)
    x_q   = frozen at its first reading over each stuck interval (noise included: a stuck-at output)

Clocks (:class:`DeviceClock`): a device clock reads ``t_dev = (1 + drift) * t_plant + offset``;
frames carry device time. Frame faults (:func:`frame_faults`): independent drops, duplicates
(+50 us) and reorders (swap with the next frame of the same stream).

All random draws come from one :class:`numpy.random.Generator` per device made by :func:`device_rng`
from the campaign seed, so adding a device does not change the draws of the others.
"""

from __future__ import annotations

import functools
import zlib
from dataclasses import dataclass

import numpy as np

from benchtwin.config.setup import ChannelErrors, LinkErrors
from benchtwin.errors import DataError
from benchtwin.wire.frames import FRAME_DTYPE

__all__ = ["DeviceClock", "device_rng", "frame_faults", "hold_sample", "lti_filter", "measure", "sample"]


def device_rng(seed: int | None, device: str) -> np.random.Generator:
    """The random generator of one device: the campaign seed split by the device's name."""
    ss = np.random.SeedSequence(0 if seed is None else int(seed), spawn_key=(zlib.crc32(device.encode()),))
    return np.random.default_rng(ss)


@dataclass(frozen=True)
class DeviceClock:
    """A device's clock: ``t_dev = (1 + drift_ppm * 1e-6) * t_plant + offset_s``."""

    offset_s: float = 0.0
    drift_ppm: float = 0.0

    @classmethod
    def of(cls, link: LinkErrors) -> DeviceClock:
        """The clock described by a device's link errors."""
        return cls(link.clock_offset_s, link.clock_drift_ppm)

    @property
    def rate(self) -> float:
        """Device seconds per plant second."""
        return 1.0 + self.drift_ppm * 1e-6

    def to_device(self, t_plant: np.ndarray) -> np.ndarray:
        """Plant time -> device time."""
        return np.asarray(t_plant, dtype=np.float64) * self.rate + self.offset_s

    def to_plant(self, t_dev: np.ndarray) -> np.ndarray:
        """Device time -> plant time."""
        return (np.asarray(t_dev, dtype=np.float64) - self.offset_s) / self.rate

    def ticks(self, start_plant: float, end_plant: float, period_s: float, phase_s: float = 0.0) -> np.ndarray:
        """Device times ``k * period + phase`` that fall inside the plant span ``[start, end)``."""
        if period_s <= 0:
            raise DataError(f"period must be positive, got {period_s}")
        d0, d1 = self.to_device(np.array([start_plant, end_plant]))
        k0 = np.ceil((d0 - phase_s) / period_s - 1e-9)
        k1 = np.ceil((d1 - phase_s) / period_s - 1e-9)
        return np.arange(k0, k1) * period_s + phase_s


@functools.lru_cache(maxsize=256)
def _discrete_filter(bandwidth_hz: float, order: int, damping: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    import control

    wc = 2.0 * np.pi * bandwidth_hz
    if order == 1:
        sys = control.tf([wc], [1.0, wc])
    else:
        sys = control.tf([wc * wc], [1.0, 2.0 * damping * wc, wc * wc])
    sysd = control.c2d(sys, dt, method="zoh")
    num = np.atleast_1d(np.squeeze(sysd.num[0][0])).astype(np.float64)
    den = np.atleast_1d(np.squeeze(sysd.den[0][0])).astype(np.float64)
    # polynomials in z -> in z^-1 for lfilter: right-align the numerator (keeps the ZOH delay)
    num = np.concatenate([np.zeros(den.size - num.size), num])
    return num / den[0], den / den[0]


def lti_filter(x: np.ndarray, dt: float, bandwidth_hz: float, order: int = 1, damping: float = 0.707) -> np.ndarray:
    """Low-pass ``x`` (uniform step ``dt``) with the sensor's LTI model, starting from steady state.

    The continuous model (python-control ``tf``: first order ``wc/(s+wc)`` or second order
    ``wc^2/(s^2+2 zeta wc s+wc^2)``) is discretised with ``c2d`` (zero-order hold) and applied
    with ``scipy.signal.lfilter``. ``bandwidth_hz <= 0`` returns ``x`` unchanged.
    """
    from scipy.signal import lfilter, lfilter_zi

    x = np.asarray(x, dtype=np.float64)
    if bandwidth_hz <= 0 or x.size == 0:
        return x
    b, a = _discrete_filter(float(bandwidth_hz), int(order), float(damping), float(dt))
    finite = np.isfinite(x)
    xf = np.where(finite, x, 0.0) if not finite.all() else x
    y, _ = lfilter(b, a, xf, zi=lfilter_zi(b, a) * xf[0])
    if not finite.all():
        y[~finite] = np.nan
    return y


def sample(t_src: np.ndarray, x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Linear interpolation of ``x(t_src)`` at ``t`` (held at the ends)."""
    return np.interp(t, t_src, x)


def hold_sample(t_src: np.ndarray, x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Zero-order hold of ``x(t_src)`` at ``t`` (for states: gears, flags)."""
    idx = np.clip(np.searchsorted(t_src, t, side="right") - 1, 0, len(t_src) - 1)
    return x[idx]


def measure(t_trace: np.ndarray, x_true: np.ndarray, t_sample: np.ndarray, errors: ChannelErrors,
            rng: np.random.Generator, *, latency_s: float = 0.0, hold: bool = False) -> np.ndarray:
    """The measured value at plant times ``t_sample`` (see the module docstring).

    Parameters
    ----------
    t_trace, x_true:
        The true signal on the trace's time base (uniform step expected for the bandwidth filter).
    t_sample:
        Plant times at which the device samples.
    errors:
        The channel's errors, in the unit of ``x_true``.
    rng:
        The device's generator.
    latency_s:
        Measurement age at sampling.
    hold:
        Zero-order hold instead of interpolation (discrete states).
    """
    x = np.asarray(x_true, dtype=np.float64)
    if errors.bandwidth_hz > 0 and len(t_trace) > 1:
        dt = float(np.median(np.diff(t_trace)))
        x = lti_filter(x, dt, errors.bandwidth_hz, errors.filter_order, errors.damping)
    ts = np.asarray(t_sample, dtype=np.float64) - latency_s
    y = hold_sample(t_trace, x, ts) if hold else sample(t_trace, x, ts)
    if errors.gain_error_frac:
        y = y * (1.0 + errors.gain_error_frac)
    if errors.offset:
        y = y + errors.offset
    if errors.noise_std > 0:
        y = y + rng.normal(0.0, errors.noise_std, y.shape)
    if errors.quantisation_step > 0:
        y = np.rint(y / errors.quantisation_step) * errors.quantisation_step
    if errors.saturation_min is not None or errors.saturation_max is not None:
        y = np.clip(y, errors.saturation_min, errors.saturation_max)
    for iv in errors.stuck:  # the output freezes at its first reading in the interval
        inside = np.flatnonzero((ts >= iv.start_s) & (ts < iv.end_s))
        if inside.size:
            y[inside] = y[inside[0]]
    return y


def frame_faults(frames: np.ndarray, stream: np.ndarray, link: LinkErrors, rng: np.random.Generator) -> np.ndarray:
    """Apply drops, duplicates and reorders to a device's frames (a FRAME_DTYPE array, time-sorted).

    Parameters
    ----------
    frames:
        The device's frames.
    stream:
        Stream key per frame (e.g. the identifier): reorders swap a frame with the next frame of the
        same stream, so a receiver sees the newer one first.
    link:
        Probabilities.
    rng:
        The device's generator.

    Returns
    -------
    numpy.ndarray
        A new frame array, sorted by timestamp.
    """
    if (link.drop_prob == 0 and link.duplicate_prob == 0 and link.reorder_prob == 0) or len(frames) == 0:
        return frames
    from benchtwin.wire.merge import insert_frames, void_view

    n = len(frames)
    out = frames
    if link.reorder_prob > 0:
        out = frames.copy()
        # frames of one stream in time order (stable sort on a small integer key is a radix sort)
        _, key = np.unique(stream, return_inverse=True)
        order = np.argsort(key.astype(np.uint16 if key.max() < 65536 else np.int64), kind="stable")
        s_sorted = key[order]
        swap = (rng.random(n) < link.reorder_prob)[:-1] & (s_sorted[:-1] == s_sorted[1:])
        swap[1:] &= ~swap[:-1]  # no chains
        i = order[:-1][swap]
        j = order[1:][swap]
        di, dj = out["data"][i].copy(), out["data"][j].copy()
        out["data"][i], out["data"][j] = dj, di
    dropped = np.flatnonzero(rng.random(n) < link.drop_prob) if link.drop_prob > 0 else np.zeros(0, np.int64)
    if link.duplicate_prob > 0:
        dup_idx = np.flatnonzero(rng.random(n) < link.duplicate_prob)
        dup_idx = np.setdiff1d(dup_idx, dropped, assume_unique=True)
        dup = out[dup_idx].copy()
        dup["timestamp"] += 50e-6
    res = np.delete(void_view(out), dropped).view(FRAME_DTYPE) if dropped.size else out
    if link.duplicate_prob > 0:
        res = insert_frames(res, dup)
    return res
