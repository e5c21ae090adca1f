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

Faults injected on purpose (the setup's ``[[faults]]``, :class:`~benchtwin.config.setup.FaultSpec`) over a
span of plant time: :func:`span_frame_faults` (random and burst loss, duplicates, reorders, corrupted
payloads, wrong DLC, applied after the link's own faults), :func:`silent_ticks` (a device that sends
nothing, its counters do not advance), :func:`with_stuck` (a frozen channel), :func:`faulty_clock` (a
clock that drifts or steps), :func:`disconnect` (a transport drop span) and :func:`truncate_log` (a log
that ends early). Kinds that change what a device measures or reports (IVT-S status, Modbus restart and
slow answers, telemetry clip, thermocouple open circuit) are injected in the device's own module.

Random draws come from one :class:`numpy.random.Generator` per device and block of plant time
(:func:`benchtwin.sensors.blocks.block_rng`, split from the campaign seed by the device's name and the
block index), so adding a device does not change the draws of the others and cutting the Trace into
chunks does not change any draw.
"""

from __future__ import annotations

import functools
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from benchtwin.config.setup import ChannelErrors, FaultSpec, LinkErrors, StuckInterval
from benchtwin.errors import DataError
from benchtwin.wire.frames import FRAME_DTYPE

__all__ = ["SPAN_FRAME_FAULTS", "DeviceClock", "FaultyClock", "device_rng", "disconnect", "draw_as_measured",
           "faulty_clock", "frame_faults", "frames_faulted", "hold_sample", "in_spans", "lti_filter", "measure",
           "sample", "silent_ticks", "span_frame_faults", "truncate_log", "with_stuck"]


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
            rng: np.random.Generator, *, latency_s: float = 0.0, hold: bool = False, blk: Any = None,
            key: str = "") -> np.ndarray:
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
    blk, key:
        The block of plant time being encoded (:class:`~benchtwin.sensors.blocks.Block`) and the channel's
        key in the device's carried state: the filter runs on from the previous block and a stuck output
        stays at the reading it froze at. None: the whole signal at once, from steady state.
    """
    x = np.asarray(x_true, dtype=np.float64)
    if blk is not None:
        x = blk.filtered(key, x, errors)
    elif errors.bandwidth_hz > 0 and len(t_trace) > 1:
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
    frozen = blk.state.setdefault("stuck", {}) if blk is not None else {}
    for k, iv in enumerate(errors.stuck):  # the output freezes at its first reading in the interval
        inside = np.flatnonzero((ts >= iv.start_s) & (ts < iv.end_s))
        if inside.size:
            y[inside] = frozen.setdefault((key, k), y[inside[0]])
    return y


def draw_as_measured(errors: ChannelErrors, rng: np.random.Generator, n: int) -> None:
    """Take the draws :func:`measure` takes for ``n`` readings (its noise only) without measuring: a reading left out
    keeps the generator where the others expect it."""
    if errors.noise_std > 0:
        rng.normal(0.0, errors.noise_std, (n,))


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
    from benchtwin.wire.merge import copy_frames, insert_frames, void_view

    n = len(frames)
    out = frames
    if link.reorder_prob > 0:
        out = copy_frames(frames)
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


# ---------------------------------------------------------------------------------------------- injected faults


def in_spans(t_plant: np.ndarray, faults: Sequence[FaultSpec], kind: str) -> np.ndarray:
    """Mask of the plant times inside any fault of ``kind``."""
    t = np.asarray(t_plant, dtype=np.float64)
    m = np.zeros(t.shape, dtype=bool)
    for f in faults:
        if f.kind == kind:
            m |= (t >= f.start_s) & (t < f.end_s)
    return m


def silent_ticks(t_dev: np.ndarray, clock: DeviceClock, faults: Sequence[FaultSpec]) -> np.ndarray:
    """The device ticks outside its ``silent`` spans: a device that stops sending does not count either."""
    if not any(f.kind == "silent" for f in faults):
        return t_dev
    return t_dev[~in_spans(clock.to_plant(t_dev), faults, "silent")]


def with_stuck(errors: ChannelErrors, faults: Sequence[FaultSpec], channel: str) -> ChannelErrors:
    """The channel's errors with the ``stuck`` faults on ``channel`` added as stuck intervals."""
    extra = [StuckInterval(start_s=f.start_s, end_s=f.end_s) for f in faults
             if f.kind == "stuck" and f.channel == channel]
    return errors if not extra else errors.model_copy(update={"stuck": [*errors.stuck, *extra]})


#: the injected faults that act on a device's frames over a span (:func:`span_frame_faults`)
SPAN_FRAME_FAULTS = ("frame_loss", "frame_loss_burst", "duplicate", "reorder", "corrupt_payload", "wrong_dlc")


def frames_faulted(link: LinkErrors, faults: Sequence[FaultSpec]) -> bool:
    """Whether :func:`frame_faults` or :func:`span_frame_faults` act on (and draw over) a device's frames."""
    return (link.drop_prob > 0 or link.duplicate_prob > 0 or link.reorder_prob > 0
            or any(f.kind in SPAN_FRAME_FAULTS for f in faults))


def span_frame_faults(frames: np.ndarray, stream: np.ndarray, faults: Sequence[FaultSpec], rng: np.random.Generator,
                      clock: DeviceClock | None = None) -> np.ndarray:
    """Apply the frame faults injected over spans to a device's (or a bus's) frames, time-sorted.

    ``frame_loss`` drops each frame of the span with ``prob``; ``frame_loss_burst`` drops them all;
    ``duplicate`` sends a frame twice (+50 us); ``reorder`` swaps a frame's data with the next frame of
    its stream; ``corrupt_payload`` replaces the data bytes by random ones; ``wrong_dlc`` sends a frame
    with another data length. Frame times are device times; ``clock`` maps them to plant time.
    """
    todo = [f for f in faults if f.kind in SPAN_FRAME_FAULTS]
    if not todo or len(frames) == 0:
        return frames
    from benchtwin.wire.merge import copy_frames, insert_frames, mask_frames

    out = copy_frames(frames)
    t = out["timestamp"] if clock is None else clock.to_plant(out["timestamp"])
    drop = np.zeros(len(out), dtype=bool)
    dups = []
    for f in todo:
        inside = np.flatnonzero((t >= f.start_s) & (t < f.end_s))
        hit = inside if f.kind == "frame_loss_burst" else inside[rng.random(inside.size) < f.prob]
        if f.kind in ("frame_loss", "frame_loss_burst"):
            drop[hit] = True
        elif f.kind == "duplicate":
            d = out[hit].copy()
            d["timestamp"] += 50e-6
            dups.append(d)
        elif f.kind == "reorder":
            order = inside
            st = stream[order]
            for i in hit:  # swap with the next frame of the same stream inside the span
                k = int(np.searchsorted(order, i))
                nxt = np.flatnonzero(st[k + 1:] == stream[i])
                if nxt.size:
                    j = order[k + 1 + nxt[0]]
                    out["data"][[i, j]] = out["data"][[j, i]]
        elif f.kind == "corrupt_payload":
            noise = rng.integers(1, 256, size=(hit.size, 8), dtype=np.uint8)  # every byte changes
            out["data"][hit] ^= noise
        else:  # wrong_dlc
            shift = rng.integers(1, 9, size=hit.size)
            out["dlc"][hit] = (out["dlc"][hit].astype(np.int64) + shift) % 9
    res = mask_frames(out, ~drop)
    for d in dups:
        res = insert_frames(res, d)
    return res


@dataclass(frozen=True)
class FaultyClock(DeviceClock):
    """A device clock with injected ``clock_drift`` (extra rate over a span) and ``clock_step`` (a forward jump).

    ``t_dev = (1 + drift) t + offset + sum(step_i [t >= s_i]) + sum(ppm_i 1e-6 clip(t - s_i, 0, d_i))``.
    """

    faults: tuple[FaultSpec, ...] = ()

    def _extra(self, t: np.ndarray) -> np.ndarray:
        out = np.zeros(t.shape)
        for f in self.faults:
            if f.kind == "clock_step":
                out += np.where(t >= f.start_s, f.offset_s, 0.0)
            elif f.kind == "clock_drift":
                out += f.drift_ppm * 1e-6 * np.clip(t - f.start_s, 0.0, float(f.duration_s))
        return out

    def to_device(self, t_plant: np.ndarray) -> np.ndarray:
        """Plant time -> device time."""
        t = np.asarray(t_plant, dtype=np.float64)
        return super().to_device(t) + self._extra(t)

    def _grid(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        base = super().to_plant(np.array([np.min(d), np.max(d)])) if d.size else np.zeros(2)
        lo, hi = float(base[0]) - 20.0, float(base[1]) + 20.0
        pts = [lo, hi]
        for f in self.faults:
            pts += [f.start_s - 1e-9, f.start_s, f.end_s]
        g = np.unique(np.clip(np.asarray(pts), lo, hi))
        return g, self.to_device(g)

    def to_plant(self, t_dev: np.ndarray) -> np.ndarray:
        """Device time -> plant time (a device time inside a forward step maps to the step)."""
        d = np.asarray(t_dev, dtype=np.float64)
        g, gd = self._grid(d)
        return np.interp(d, gd, g)

    def ticks(self, start_plant: float, end_plant: float, period_s: float, phase_s: float = 0.0) -> np.ndarray:
        """Device ticks in the plant span, without the device times a forward step skipped."""
        d0, d1 = self.to_device(np.array([start_plant, end_plant]))
        k0 = np.ceil((d0 - phase_s) / period_s - 1e-9)
        k1 = np.ceil((d1 - phase_s) / period_s - 1e-9)
        t = np.arange(k0, k1) * period_s + phase_s
        keep = np.ones(t.shape, dtype=bool)
        for f in self.faults:
            if f.kind == "clock_step":
                a, b = self.to_device(np.array([f.start_s - 1e-9, f.start_s]))
                keep &= ~((t > a) & (t < b))
        return t[keep]


def faulty_clock(link: LinkErrors, faults: Sequence[FaultSpec]) -> DeviceClock:
    """The device's clock with its injected clock faults (a plain :class:`DeviceClock` without)."""
    mine = tuple(f for f in faults if f.kind in ("clock_drift", "clock_step"))
    if not mine:
        return DeviceClock.of(link)
    return FaultyClock(link.clock_offset_s, link.clock_drift_ppm, mine)


def disconnect(frames: np.ndarray, faults: Sequence[FaultSpec]) -> tuple[np.ndarray, list[tuple[float, float]]]:
    """Remove a bus's frames over its ``transport_disconnect`` spans; return them and the spans."""
    spans = [(f.start_s, f.end_s) for f in faults if f.kind == "transport_disconnect"]
    if not spans or len(frames) == 0:
        return frames, spans
    from benchtwin.wire.merge import mask_frames

    t = frames["timestamp"]
    drop = np.zeros(len(frames), dtype=bool)
    for a, b in spans:
        drop |= (t >= a) & (t < b)
    return mask_frames(frames, ~drop), spans


def truncate_log(frames: np.ndarray, faults: Sequence[FaultSpec]) -> np.ndarray:
    """A bus log cut at the earliest ``log_truncation`` of the bus: nothing after it is written."""
    cuts = [f.start_s for f in faults if f.kind == "log_truncation"]
    if not cuts or len(frames) == 0:
        return frames
    from benchtwin.wire.merge import mask_frames

    return mask_frames(frames, frames["timestamp"] < min(cuts))
