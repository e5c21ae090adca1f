"""Steady windows whose edges move with the noise: the transmission plan's selection term.

The identification averages each steady window; where a window is found is decided on the noisy readings
(the steadiness thresholds on the shaft torque, the speeds and the CAN torques). Where the signals still
settle when a hold begins (a hybrid ramp-up's engine and motor sharing the torque at a low speed: gears 1-2
of the paper campaign), the noise moves the first sample that meets the thresholds by a few grid steps from
seed to seed, and the window's mean moves with it: over 20 seeds on the paper bench the gear-1 point at 54 Nm
scattered 4.5 times what the noise inside a fixed window gives (its start fell at 151.0, 151.2 or 151.3 s),
so the planned standard errors of gear 1 were 1.6-2.8 times too small.

The term is computed from the setup alone, as the brakes' poll faults are (:mod:`.plan_brakes`): the readings
the window search reads are drawn as the bench records them (the truth with the sensor's gain and offset,
white noise, the step of the converter or the wire), the identification's own window search runs on each
draw, and the noise-free estimate is taken at the windows found (window means of the noise-free readings).
The planned variance is the law of total variance over the draws: the noise term at the planned windows plus
the variance of the noise-free estimates over the draws.

Where a hold begins is decided to a grid step (0.1 s) by the edge of the pedal step before it, so the draws
must see that edge when the bench does: a reading lags the plant's truth (the sensor's filter, discretised
at the plant step, its latency, the link), by about 15 ms for the paper bench's shaft torque, and without
that lag every drawn window began one grid step early and the edges moved with other odds (the gear-1
points' windows at 151.0/151.2 s against the bench's 151.0/151.2/151.3 s). The lag of each drawn channel is
measured on the plan's one bench run (:func:`reading_lag`: the shift of the truth that best matches the
recorded readings where the truth changes fast) and the drawn readings are the truth shifted by it. Where the
plan has the sensor's own noise-free response (:func:`~benchtwin.studies.plan_noise.sensor_response`: its filter at
the plant step, the device clock's offset and drift, the latency), the readings are drawn around that instead: a
delay is a filter only where the truth changes smoothly, and one delay for a whole campaign misses the clock's
drift (25 ppm on the paper bench: 0.25 s at 10,000 s). The noise-free estimate at the windows found reads that
response too, not the truth sampled at the readings' timestamps: those are on the device's clock, so that truth
leads the readings by the clock's offset from the plant (and the sensor's lag), whatever offset the
identification maps. On the paper campaign the telemetry clock is 0.125 s ahead by the hybrid gear-1 ramp-up
(about 5,000 s; a transmission family run maps the 0.02 s it measured on its first run of tests, too short for a
drift), so the window means of the truth moved less with a window's start than the readings' do, and gear 1's C0
was planned 1.8 times too small (eta_m 1.4, gear 2's C0 1.6).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import BenchtwinError
from benchtwin.identification.keys import FitKey
from benchtwin.identification.transmission import (
    TransmissionPoints,
    direction_points,
    efficiency_design,
    transmission_points,
)
from benchtwin.recording import Channel, Recording
from benchtwin.studies.plan_noise import ChannelNoise

__all__ = ["SEARCHED", "WINDOW_DRAWS", "noisy_readings", "reading_lag", "reading_lag_line", "sensed_recording",
           "window_draws"]

#: draws of the noise deciding the windows: the selection variance over K draws is known to about
#: sqrt(2 / (K - 1)) (26 % at 30, 13 % on the standard error); one draw is one window search over the steady
#: tests (~0.1 s per 1,000 s of tests)
WINDOW_DRAWS = 30
#: the channels the transmission's window search reads (identification/transmission.py) that may be noisy
SEARCHED: tuple[str, ...] = ("vehicle_speed_kmh", "em_speed_rpm", "em_torque_nm", "engine_torque_nm",
                             "shaft_torque_nm", "engine_speed_rpm")


#: lags tried by :func:`reading_lag` (s): 0-50 ms in 0.5 ms steps
_LAGS = np.arange(0.0, 0.0505, 0.0005)


def reading_lag(truth: Channel, recorded: Channel, cn: ChannelNoise, lags: np.ndarray | None = None,
                span: tuple[float, float] | None = None) -> float:
    """How far the bench's readings of a channel lag its truth (s), from one recorded run.

    The lag minimising the mean squared difference between the recorded readings and the truth shifted by
    it (with the declared gain and offset), over the readings where the truth moves faster than 10 steps of
    the channel (or 10 noise sigmas) a second; 0 when the two do not share timestamps or nothing moves.
    ``lags``: the lags tried (default 0-50 ms in 0.5 ms steps); ``span``: only readings in ``[start, end)``.
    """
    t, x = truth.timestamps, truth.values
    if recorded.timestamps.shape != t.shape or not np.array_equal(recorded.timestamps, t) or t.size < 3:
        return 0.0
    fast = np.abs(np.gradient(x, t)) > 10.0 * max(cn.q, cn.sigma, 1e-12)
    fast &= recorded.good & np.isfinite(recorded.values)
    if span is not None:
        fast &= (t >= span[0]) & (t < span[1])
    if fast.sum() < 10:
        return 0.0
    y = recorded.values[fast]
    grid = _LAGS if lags is None else lags
    err = [np.mean((y - (1.0 + cn.gain) * np.interp(t[fast] - lag, t, x) - cn.offset) ** 2) for lag in grid]
    return float(grid[int(np.argmin(err))])


def reading_lag_line(truth: Channel, recorded: Channel, cn: ChannelNoise, chunk_s: float = 1000.0
                     ) -> tuple[float, float]:
    """The lag of the bench's readings as a line in time, ``lag(t) = a + b t`` (s, s/s): ``(a, b)``.

    A device clock that drifts against the recorder's (the paper bench's telemetry: 25 ppm, uncorrected) makes
    the lag grow over a long campaign: 19 ms at the start of the paper campaign, 0.26 s at 10,000 s. The lag of
    each ``chunk_s`` of the run (:func:`reading_lag` over 0-0.5 s in 1 ms steps, chunks with at least 100 fast
    readings) is fitted with a line; a single chunk gives a constant lag, none ``(0, 0)``.
    """
    t = truth.timestamps
    if t.size < 3 or recorded.timestamps.shape != t.shape or not np.array_equal(recorded.timestamps, t):
        return 0.0, 0.0
    fast = np.abs(np.gradient(truth.values, t)) > 10.0 * max(cn.q, cn.sigma, 1e-12)
    grid = np.arange(0.0, 0.5005, 0.001)
    mid, lag = [], []
    for a in np.arange(float(t[0]), float(t[-1]), chunk_s):
        sel = fast & (t >= a) & (t < a + chunk_s)
        if sel.sum() >= 100:
            mid.append(float(np.mean(t[sel])))
            lag.append(reading_lag(truth, recorded, cn, grid, (a, a + chunk_s)))
    if not lag:
        return 0.0, 0.0
    if len(lag) == 1:
        return lag[0], 0.0
    b, a = np.polyfit(mid, lag, 1)
    return float(a), float(b)


def noisy_readings(rec: Recording, noise: Mapping[str, ChannelNoise], names: tuple[str, ...],
                   rng: np.random.Generator, lags: Mapping[str, float] | None = None,
                   sensed: Mapping[str, Channel] | None = None) -> Recording:
    """``rec`` with the channels ``names`` drawn as the bench records them (others shared, not copied).

    Each reading is ``q rint(((1 + gain) y + offset + n) / q)`` with ``y`` the noise-free value (``sensed[name]``,
    the sensor's own response, where given; else the truth ``lags[name]`` seconds earlier) and
    ``n ~ N(0, sigma^2)`` (no rounding when ``q`` is 0).
    """
    out = Recording(segments=list(rec.segments), meta=dict(rec.meta))
    for name, ch in rec.channels.items():
        cn = noise.get(name)
        if name not in names or cn is None:
            out.add(ch)
            continue
        lag = (lags or {}).get(name, 0.0)
        if sensed and name in sensed:
            y = sensed[name].values
        else:
            y = np.interp(ch.timestamps - lag, ch.timestamps, ch.values) if lag else ch.values
        v = (1.0 + cn.gain) * y + cn.offset + rng.normal(0.0, cn.sigma, ch.values.shape)
        if cn.q > 0:
            v = cn.q * np.rint(v / cn.q)
        out.add(Channel(name, ch.unit, ch.timestamps, v, ch.flags, ch.source, ch.value_texts))
    return out


def sensed_recording(rec: Recording, sensed: Mapping[str, Channel]) -> Recording:
    """``rec`` with the channels found in ``sensed`` taking its values (the noise-free value each reading measures).

    The truth Recording holds each channel's truth at the reading's own timestamp, as if the device's clock
    were the plant's, so it leads the bench's readings (filtered, stamped on the device's clock) by that
    clock's offset from the plant and the sensor's lag; window means of it then differ from what the bench
    averages wherever a window's edge sits on a transient. Channels of ``rec`` not in ``sensed`` are shared,
    not copied.
    """
    if not sensed:
        return rec
    out = Recording(segments=list(rec.segments), meta=dict(rec.meta))
    for name, ch in rec.channels.items():
        s = sensed.get(name)
        if s is not None and s.values.shape == ch.values.shape:
            out.add(Channel(name, ch.unit, ch.timestamps, s.values, ch.flags, ch.source))
        else:
            out.add(ch)
    return out


def window_draws(rec: Recording, specs: VehicleSpecs, noise: Mapping[str, ChannelNoise], *,
                 recorded: Mapping[str, Channel] | None = None, draws: int = WINDOW_DRAWS,
                 seed: int = 0, sensed: Mapping[str, Channel] | None = None,
                 keep: list[TransmissionPoints] | None = None) -> dict[str, np.ndarray]:
    """The noise-free ``(eta_m, C0)`` of every transmission fit at the windows each draw of the noise gives.

    Parameters
    ----------
    rec:
        The noise-free Recording of the plan (:func:`~benchtwin.studies.plan_noise.truth_recording`).
    specs:
        Public specs (ratios, final drive, wheel radius).
    noise:
        Role -> the random error of its readings.
    recorded:
        The searched channels as the plan's bench run recorded them (role -> Channel), for their lag
        (:func:`reading_lag`); without them the draws take the truth unshifted.
    sensed:
        Role -> the noise-free value of each of its readings (:func:`~benchtwin.studies.plan_noise.
        sensor_response`: filter, clock, latency); a channel found here is drawn around it, not around the
        lagged truth, and the noise-free estimate at the windows found reads it too
        (:func:`sensed_recording`).
    draws, seed:
        Number of draws and the seed of their generator (the same plan gives the same numbers).
    keep:
        When given, the points each draw's search found on its noisy readings (their noisy values) are appended
        to it (the drag model's draws, :mod:`.plan_drag`). A searched channel without random error (the CAN
        torques and speeds) is read there as the plan's bench run recorded it (``recorded``: the CAN signal's
        scaling, step and the ECU's gain and offset, the same on every seed), not as its truth.

    Returns
    -------
    dict
        Fit key (``transmission.gear<g>[_coast]``) -> array ``[k, 2]`` of ``(eta_m, C0)``, one row per draw
        whose windows give the fit at least 3 points; empty when no searched channel is noisy.
    """
    names = tuple(n for n in SEARCHED if n in rec and n in noise)
    if not names or draws < 2:
        return {}
    ratios = np.asarray(specs.gear_ratios, dtype=float)
    lags = {n: reading_lag(rec[n], recorded[n], noise[n]) for n in names
            if recorded and n in recorded and not (sensed and n in sensed)}
    rng = np.random.default_rng(seed)
    read = sensed_recording(rec, {n: sensed[n] for n in names if n in sensed} if sensed else {})
    # the channels free of random error as the bench reads them (the same on every seed): 45.3 Nm of CAN input
    # torque where the truth is 41.5 (the ECU's 2 % and 3 Nm); the noise-free estimates below keep the truth
    base = sensed_recording(rec, {n: ch for n, ch in (recorded or {}).items()
                                  if n in SEARCHED and n not in noise and n in rec})
    out: dict[str, list[tuple[float, float]]] = {}
    for _ in range(draws):
        try:
            found = transmission_points(noisy_readings(base, noise, names, rng, lags, sensed), specs)
            pts = transmission_points(read, specs, steady=found.windows)
        except BenchtwinError:
            continue
        if keep is not None:
            keep.append(found)
        for g in range(1, ratios.size + 1):
            for direction in ("drive", "coast"):
                _m, dom, c, eta = direction_points(pts, g, direction, ratios[g - 1])
                c, eta = c[dom], eta[dom]
                if c.size < 3:
                    continue
                A, w = efficiency_design(c)
                sw = np.sqrt(w)
                x = np.linalg.lstsq(A * sw[:, None], eta * sw, rcond=None)[0]
                out.setdefault(str(FitKey.transmission(g, direction)), []).append((float(x[0]), float(x[1] / x[0])))
    return {k: np.asarray(v, dtype=float) for k, v in out.items()}
