"""The noise model of planning: the random error of each recorded channel, and how it reaches a fit.

Each recorded channel's random error per reading comes from the setup's error budget
(:meth:`~benchtwin.sensors.base.Device.error_budget`): white noise ``sigma`` and quantisation ``q`` (the
wire's step or the sensor's own, the larger), as the variance of the quantised noisy reading at the
reading's own noise-free value (:func:`reading_variance`). A steady window's mean has the mean of its
readings' variances over its ``n`` good readings, divided by ``n``; a grid sample interpolated between
two readings at fraction ``a`` has ``(1-a)^2`` and ``a^2`` of theirs. A fit's covariance is the sandwich
of its weighted least squares (:func:`sandwich_covariance`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import special

from benchtwin.config.setup import ChannelErrors, SetupConfig
from benchtwin.recording import Channel, Recording
from benchtwin.sensors.imperfections import DeviceClock, hold_sample, lti_filter
from benchtwin.sensors.registry import devices
from benchtwin.trace import Trace

__all__ = [
    "ChannelNoise",
    "PollFaults",
    "grid_error_sampler",
    "grid_variance",
    "noise_budget",
    "poll_fault_model",
    "poll_faults",
    "product_mean_variance",
    "reading_variance",
    "sample_variances",
    "sandwich_covariance",
    "sensor_response",
    "truth_recording",
    "window_mean",
    "window_mean_variance",
]


def reading_variance(sigma: float, q: float, y: np.ndarray | float | None = None) -> np.ndarray | float:
    """Variance of the random part of a reading: white noise ``sigma`` quantised to steps ``q``.

    The reading is ``q rint((y + n) / q)`` with ``n ~ N(0, sigma^2)`` and ``y`` the sensor's noise-free
    output (truth with its gain and offset errors). With ``y`` given, the exact variance over ``n`` at
    each ``y``; without, its average over the position of ``y`` within a step. ``q = 0``: ``sigma^2``;
    ``sigma = 0``: 0 (the quantisation error of a fixed value is the same for every seed);
    ``sigma >= q``: ``sigma^2 + q^2/12`` (Sheppard's correction, exact to a few parts in a thousand there).
    """
    if y is None:
        pos = (np.arange(1024) + 0.5) / 1024.0 * q if q > 0 else np.zeros(1)
        return float(np.mean(reading_variance(sigma, q, pos)))
    y = np.asarray(y, dtype=float)
    if sigma <= 0.0:
        return np.zeros(y.shape)
    if q <= 0.0:
        return np.full(y.shape, float(sigma**2))
    if sigma >= q:
        return np.full(y.shape, float(sigma**2 + q**2 / 12.0))
    k = np.arange(-int(6 * sigma / q) - 2, int(6 * sigma / q) + 3)
    centre = np.rint(y / q)
    d = (y / q - centre)[..., None]  # position within the step, in steps
    # P(reading = (centre + k) q): the noise moves y into the step around (centre + k) q. The normal CDF at the
    # steps' edges k - 1/2 .. k_max + 1/2 once (each inner edge is the upper edge of one step and the lower of the
    # next; half-integers are exact, so the same numbers as two CDFs per step), as scipy.special.ndtr: what
    # stats.norm.cdf computes at loc 0, scale 1, without its argument checks (together 11 of the 40 s of the
    # transmission's plan on the paper campaign)
    edges = special.ndtr((np.append(k - 0.5, k[-1] + 0.5) - d) * q / sigma)
    p = edges[..., 1:] - edges[..., :-1]
    m1 = p @ (k * q)
    m2 = p @ (k * q) ** 2
    return np.clip(m2 - m1**2, 0.0, None)


@dataclass(frozen=True)
class ChannelNoise:
    """The random error of one role's readings: noise, quantisation, and the gain and offset before them."""

    sigma: float
    q: float
    gain: float = 0.0
    offset: float = 0.0

    def variances(self, truth_values: np.ndarray) -> np.ndarray:
        """Variance of each reading whose noise-free truth is ``truth_values``."""
        return np.asarray(reading_variance(self.sigma, self.q, (1.0 + self.gain) * truth_values + self.offset))


@dataclass(frozen=True)
class PollFaults:
    """The declared poll faults of a polled device: per-poll probabilities, the client's timeout, the poll rate.

    A timed-out poll is logged (flagged ``TIMEOUT``) after ``timeout_s`` and the polls that fall in that wait
    are skipped; an exception answer is one reading flagged ``PROTOCOL_ERROR``
    (:func:`~benchtwin.sensors.pressure.poll_snapshots`).
    """

    timeout_prob: float
    exception_prob: float
    timeout_s: float
    poll_hz: float

    @property
    def prob(self) -> float:
        """Probability that a poll fails."""
        return self.timeout_prob + self.exception_prob


def poll_fault_model(setup: SetupConfig) -> dict[str, PollFaults]:
    """Role -> the declared poll faults of the device that polls it (roles of devices whose polls can fail)."""
    out: dict[str, PollFaults] = {}
    for d in devices(setup):
        cfg = d.cfg
        pt = float(getattr(cfg, "timeout_prob", 0.0) or 0.0)
        pe = float(getattr(cfg, "exception_prob", 0.0) or 0.0)
        if pt + pe > 0:
            pf = PollFaults(pt, pe, float(getattr(cfg, "poll_timeout_s", 0.0)), float(getattr(cfg, "poll_hz", 0.0)))
            out.update(dict.fromkeys(d.truth_channels(), pf))
    return out


def poll_faults(setup: SetupConfig) -> dict[str, float]:
    """Role -> probability that a poll of it fails (timeout or exception answer), for polled devices.

    A failed poll flags a reading; the steady-state detection then splits a window at it, at random from seed
    to seed, so a fit's rows change with the seed: a spread the planned standard error does not hold.
    """
    out: dict[str, float] = {}
    for d in devices(setup):
        p = float(getattr(d.cfg, "timeout_prob", 0.0) or 0.0) + float(getattr(d.cfg, "exception_prob", 0.0) or 0.0)
        if p > 0:
            out.update(dict.fromkeys(d.truth_channels(), p))
    return out


def noise_budget(setup: SetupConfig) -> tuple[dict[str, Any], dict[str, ChannelNoise]]:
    """Role -> TruthChannel, and role -> the random error of its readings, from every device of the setup."""
    truth: dict[str, Any] = {}
    noise: dict[str, ChannelNoise] = {}
    for d in devices(setup):
        tcs = d.truth_channels()
        truth.update(tcs)
        for role, (err, _link, _extra) in d.error_budget().items():
            tc = tcs.get(role)
            res = tc.resolution if tc is not None else 0.0
            if isinstance(err, ChannelErrors) and err.noise_std > 0:
                noise[role] = ChannelNoise(err.noise_std, max(res, err.quantisation_step), err.gain_error_frac,
                                            err.offset)
    return truth, noise


def sample_variances(rec: Recording, noise: Mapping[str, ChannelNoise], name: str) -> np.ndarray | None:
    """Per-reading variance of channel ``name`` of the truth Recording (None: noise-free)."""
    if name not in rec or name not in noise:
        return None
    return noise[name].variances(rec[name].values)


def grid_variance(rec: Recording, noise: Mapping[str, ChannelNoise], name: str, t: np.ndarray) -> np.ndarray:
    """Variance of channel ``name`` linearly interpolated at times ``t`` (0 where it is noise-free).

    A grid sample between readings ``k`` and ``k+1`` at fraction ``a`` has ``(1-a)^2 v_k + a^2 v_{k+1}``.
    """
    sv = sample_variances(rec, noise, name)
    t = np.asarray(t, dtype=float)
    if sv is None or len(rec[name]) < 2:
        return np.zeros(t.shape)
    ts = rec[name].timestamps
    k = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, ts.size - 2)
    a = np.clip((t - ts[k]) / np.maximum(ts[k + 1] - ts[k], 1e-12), 0.0, 1.0)
    return (1.0 - a) ** 2 * sv[k] + a**2 * sv[k + 1]


def grid_error_sampler(rec: Recording, noise: Mapping[str, ChannelNoise], name: str, t: np.ndarray
                       ) -> Callable[[np.random.Generator], np.ndarray] | None:
    """Draws of the error of channel ``name`` interpolated at times ``t``, as a bench records it (None: noise-free).

    Each draw quantises the two readings around each time, ``q rint((y + n) / q)`` with ``y`` the reading's
    noise-free value (the channel's truth with the sensor's gain and offset) and ``n ~ N(0, sigma^2)``,
    interpolates them, and returns the difference from the interpolated noise-free values: the rounding's bias
    (the same every draw) with its noise.
    """
    if name not in rec or name not in noise or len(rec[name]) < 2:
        return None
    cn = noise[name]
    ch = rec[name]
    ts = ch.timestamps
    t = np.asarray(t, dtype=float)
    k = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, ts.size - 2)
    a = np.clip((t - ts[k]) / np.maximum(ts[k + 1] - ts[k], 1e-12), 0.0, 1.0)
    g0, g1 = ((1.0 + cn.gain) * y + cn.offset for y in (ch.values[k], ch.values[k + 1]))

    def draw(rng: np.random.Generator) -> np.ndarray:
        r0, r1 = (g + rng.normal(0.0, cn.sigma, g.shape) for g in (g0, g1))
        if cn.q > 0:
            r0, r1 = cn.q * np.rint(r0 / cn.q), cn.q * np.rint(r1 / cn.q)
        return (1.0 - a) * (r0 - g0) + a * (r1 - g1)

    return draw


def truth_recording(rec: Recording, trace: Trace, truth: Mapping[str, Any]) -> Recording:
    """The Recording with every channel that measures a Trace channel replaced by that truth.

    The timestamps, flags and segments stay those of the bench; channels without a truth stay as recorded.
    """
    out = Recording(segments=list(rec.segments), meta=dict(rec.meta))
    for name, ch in rec.channels.items():
        tc = truth.get(name)
        if tc is None or tc.trace not in trace:
            out.add(ch)
            continue
        x = trace[tc.trace] * tc.factor
        v = hold_sample(trace.time_s, x, ch.timestamps) if tc.hold else np.interp(ch.timestamps, trace.time_s, x)
        out.add(Channel(name, ch.unit, ch.timestamps, v, ch.flags, ch.source))
    return out


def sensor_response(rec: Recording, trace: Trace, setup: SetupConfig, names: Iterable[str]) -> dict[str, Channel]:
    """The noise-free value each reading of the named channels measures: the truth as the sensor sees it.

    A reading stamped ``t`` on the device's clock is the sensor's filtered truth (its declared bandwidth,
    order and damping, discretised at the plant step as the chain does) at the plant time
    ``clock.to_plant(t) - latency`` (:class:`~benchtwin.sensors.imperfections.DeviceClock`: the device's
    declared clock offset and drift), before its gain, offset, noise and quantisation. A pure delay of the
    truth is this only where the truth changes smoothly: at a pedal step the paper bench's shaft torque
    reads up to 17 Nm (13 ms delay) or 90 Nm (19 ms) away from it in the first 20 ms, and the delay grows
    with the clock's drift (25 ppm: 0.25 s at 10,000 s). This reproduces the noise-free chain's readings
    exactly (every quantised reading of the paper campaign's shaft torque at 0 and 5,500 s).

    Returns role -> Channel on the Recording's timestamps (flags kept); a role without a truth in the Trace,
    without declared errors or with a state (held) value is left out.
    """
    wanted = set(names)
    out: dict[str, Channel] = {}
    if len(trace.time_s) < 2:
        return out
    dt = float(np.median(np.diff(trace.time_s)))
    for d in devices(setup):
        tcs = d.truth_channels()
        for role, (err, link, _extra) in d.error_budget().items():
            tc = tcs.get(role)
            if role not in wanted or role not in rec or tc is None or tc.hold or tc.trace not in trace \
                    or not isinstance(err, ChannelErrors):
                continue
            x = np.asarray(trace[tc.trace], dtype=float) * tc.factor
            if err.bandwidth_hz > 0:
                x = lti_filter(x, dt, err.bandwidth_hz, err.filter_order, err.damping)
            ch = rec[role]
            tp = DeviceClock.of(link).to_plant(ch.timestamps) - link.latency_s
            out[role] = Channel(role, ch.unit, ch.timestamps, np.interp(tp, trace.time_s, x), ch.flags, ch.source)
    return out


def window_mean_variance(rec: Recording, name: str, var: np.ndarray, starts: np.ndarray, ends: np.ndarray
                          ) -> np.ndarray:
    """Variance of the mean of channel ``name``'s good readings inside each window ``[start, end)``."""
    ch = rec[name]
    order = np.argsort(ch.timestamps, kind="stable")
    ts = ch.timestamps[order]
    good = ch.good[order]
    cn = np.cumsum(np.concatenate(([0], good.astype(int))))
    cv = np.cumsum(np.concatenate(([0.0], np.where(good, var[order], 0.0))))
    lo = np.searchsorted(ts, starts, side="left")
    hi = np.searchsorted(ts, ends, side="left")
    n = np.maximum(cn[hi] - cn[lo], 1)
    return (cv[hi] - cv[lo]) / n**2


def sandwich_covariance(A: np.ndarray, w: np.ndarray | None, s2: np.ndarray) -> np.ndarray:
    """Covariance of weighted least squares with row weights ``w`` when row ``i`` has variance ``s2[i]``."""
    w = np.ones(A.shape[0]) if w is None else w
    Aw = A * w[:, None]
    B = np.linalg.inv(A.T @ Aw)
    return B @ (Aw.T @ (Aw * s2[:, None])) @ B


def window_mean(rec: Recording, name: str, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Mean of channel ``name``'s good readings inside each window ``[start, end)`` (NaN when none)."""
    ch = rec[name]
    order = np.argsort(ch.timestamps, kind="stable")
    ts, good = ch.timestamps[order], ch.good[order]
    cn = np.cumsum(np.concatenate(([0], good.astype(int))))
    cs = np.cumsum(np.concatenate(([0.0], np.where(good, ch.values[order], 0.0))))
    lo = np.searchsorted(ts, starts, side="left")
    hi = np.searchsorted(ts, ends, side="left")
    n = cn[hi] - cn[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (cs[hi] - cs[lo]) / np.maximum(n, 1), np.nan)


def product_mean_variance(rec: Recording, noise: Mapping[str, ChannelNoise], a: str, b: str, starts: np.ndarray,
                          ends: np.ndarray) -> np.ndarray:
    """Variance of a window's mean power ``a x b`` as the identification averages it.

    On shared timestamps the mean of the sample-by-sample product (each product's variance
    ``b^2 var_a + a^2 var_b + var_a var_b``); otherwise the product of the two means.
    """
    ca, cb = rec[a], rec[b]
    va = sample_variances(rec, noise, a)
    vb = sample_variances(rec, noise, b)
    va = np.zeros(len(ca)) if va is None else va
    vb = np.zeros(len(cb)) if vb is None else vb
    if ca.timestamps.shape == cb.timestamps.shape and np.array_equal(ca.timestamps, cb.timestamps):
        return window_mean_variance(rec, a, cb.values**2 * va + ca.values**2 * vb + va * vb, starts, ends)
    ma, mb = window_mean(rec, a, starts, ends), window_mean(rec, b, starts, ends)
    return (mb**2 * window_mean_variance(rec, a, va, starts, ends)
            + ma**2 * window_mean_variance(rec, b, vb, starts, ends))
