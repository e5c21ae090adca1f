"""Engine: the fuel of one engine start (``engine.start_fuel``), from the campaign's starts.

An engine start burns a fuel mass ``m`` beyond the firing engine's map (cranking, the first firing cycles'
enrichment), as a pulse of some duration ``D`` (the plant's: flat over ``start_fuel_duration_s``, 0.5 s by default).
The vehicle CAN's fuel signal is a point sample of the flow at its frame rate (20 Hz, period ``dt_f``). Summed by
the rectangle rule (each sample weighted by ``dt_f``), point samples at a phase uniform to the pulse are unbiased
for any shape: each frame position's mean reading is the pulse's mean over a frame period, so the weighted sum's
mean is the pulse's area ``m`` (a sensor's low-pass or linear interpolation spreads the pulse but keeps its area:
the same mean). Per start the reading scatters with the phase:

- a flat pulse of ``D >= dt_f`` is seen by ``floor(D / dt_f)`` or one more frame, each worth ``m dt_f / D``: one
  start's error is at most ``m dt_f / D`` (a tenth of ``m`` at 0.5 s), its standard deviation
  ``m (dt_f / D) sqrt(f (1 - f))`` with ``f`` the fractional part of ``D / dt_f`` (zero when ``D`` is a whole
  number of frames);
- a pulse shorter than a frame (a one-step impulse, ``D = dt_p``) is seen by a frame with probability
  ``dt_p / dt_f`` and then reads ``m dt_f / dt_p``, or nothing: a standard deviation of ``m sqrt(dt_f / dt_p - 1)``,
  twice ``m`` at 100 Hz against 20 Hz.

So the estimate is a mean over the campaign's starts, whatever the pulse:

- starts: the rises of ``engine_on`` (else of engine speed above 300 rpm);
- per start, in a window ``[t - pre_s, t + post_s)`` that holds the pulse: the measured fuel mass (the fuel
  samples' sum times their median period) minus the mass the warm map predicts at the same samples (from the
  engine speed and torque, zero while the engine is off; times the cold-start factor ``engine.cold_fuel`` when it
  is used and the coolant is recorded), less ``post_s`` times the mean of (measured - map) over the reference
  ``[t + post_s, t + post_s + ref_s)`` that follows it: the map's own local error on the running engine, which
  a fitted map leaves near the starts (the run-up's speeds and loads, the coolant after a stop). Measured on the
  hifi truth's ideal bench, that error is +0.05 g/s after a start (+3 %), and without the reference a 2.5 s window
  read 0.69 +- 0.015 g for 0.6 g true. The correction is exact when the map's error is constant over
  ``[t, t + post_s + ref_s)`` (the engine is off before ``t``, both flows zero there) and the pulse ends within
  ``post_s``; its noise is ``post_s / sqrt(ref_s / dt_f)`` samples' worth, small beside the pulse's scatter;
- ``engine.start_fuel``: the mean of those excesses, ``m_g`` (g per start), with the standard error over starts
  (a one-column least-squares fit). ``data['use']`` is True only when at least ``min_starts`` starts were found
  and ``m_g``'s 95 % interval lies above zero (as for ``engine.cold_fuel``); otherwise the fit is flagged.

A start whose window or reference holds another start, or a gap in the fuel signal (fewer than 80 % of the
expected samples in either), is left out. Reads only the Recording and the public specs (no truth).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import IdentificationError, InsufficientDataError
from benchtwin.identification._fit import FitResult, linear_fit
from benchtwin.identification._signals import time_ordered
from benchtwin.identification._state_changes import state_changes
from benchtwin.identification._windows import at_times, ordered_by_blocks, reads_by_block
from benchtwin.identification.engine_cold import COOLANT_ROLE, cold_factor
from benchtwin.identification.fuel_map import fuel_map_gps, map_pmf
from benchtwin.recording import Channel, Flag, LazyChannel, Recording

__all__ = ["START_KEY", "fit_start_fuel", "identify_start_fuel", "start_excess", "start_times"]

START_KEY = "engine.start_fuel"

#: engine speed above which an engine without ``engine_on`` counts as running
RUNNING_RPM = 300.0


def start_times(rec: Recording) -> np.ndarray:
    """Times of the engine's starts: rises of ``engine_on`` (0 -> 1), else of engine speed above 300 rpm.

    Raises
    ------
    IdentificationError
        When neither channel is recorded.
    """
    if "engine_on" in rec:
        sc = state_changes(_above(rec["engine_on"], 0.5), of=(rec["engine_on"], ("above", 0.5)))
    elif "engine_speed_rpm" in rec:
        sc = state_changes(_above(rec["engine_speed_rpm"], RUNNING_RPM),
                           of=(rec["engine_speed_rpm"], ("above", RUNNING_RPM)))
    else:
        raise IdentificationError(f"{START_KEY}: neither engine_on nor engine_speed_rpm recorded")
    return np.asarray(sc.t_new, float)[(np.asarray(sc.old) == 0) & (np.asarray(sc.new) == 1)]


def _above(ch: Channel, level: float) -> Channel:
    """``ch.with_values(ch.values > level)`` (1.0 above, else 0.0), read a block at a time when ``ch`` is: a lazy
    channel is never loaded whole for it."""
    def block(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t, v, f = ch.block(a, b)
        return t, (np.asarray(v, float) > level).astype(np.float64), f

    if not reads_by_block(ch):
        return ch.with_values(np.asarray(ch.values, float) > level)
    return LazyChannel(ch.name, ch.unit, ch.source, len(ch), lambda: block(0, len(ch)), ch.value_texts,
                       block_loader=block)


#: samples of the fuel channel read at a time (a lazy channel read by blocks)
FUEL_BLOCK = 1 << 20


def _near(ch: Channel, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Timestamps, values and flags of the samples of ``ch`` (in time order) with ``lo[k] <= t < hi[k]`` for some
    ``k``; a time-ordered lazy channel read by blocks is read ``FUEL_BLOCK`` samples at a time, never whole."""
    if not (reads_by_block(ch) and ordered_by_blocks(ch)):
        ts, vs, fl = time_ordered(ch)
        near = np.zeros(ts.size, bool)
        for i, j in zip(np.searchsorted(ts, lo), np.searchsorted(ts, hi), strict=True):
            near[i:j] = True
        return ts[near], vs[near], fl[near]
    # the intervals merged into disjoint ones in time order: a sample is near when it lies in the one before it
    order = np.argsort(lo, kind="stable")
    m_lo: list[float] = []
    m_hi: list[float] = []
    for a, b in zip(lo[order], hi[order], strict=True):
        if not a < b:
            continue
        if m_lo and a <= m_hi[-1]:
            m_hi[-1] = max(m_hi[-1], float(b))
        else:
            m_lo.append(float(a))
            m_hi.append(float(b))
    los, his = np.array(m_lo), np.array(m_hi)
    parts = []
    for a in range(0, len(ch), FUEL_BLOCK):
        t, v, f = ch.block(a, a + FUEL_BLOCK)
        k = np.searchsorted(los, t, side="right") - 1
        keep = (k >= 0) & (t < his[np.maximum(k, 0)]) if los.size else np.zeros(t.shape, bool)
        parts.append((t[keep], v[keep], f[keep]))
    dtypes = (np.float64, np.float64, np.uint16)
    t, v, f = (np.concatenate([p[i] for p in parts]) if parts else np.zeros(0, dtypes[i]) for i in range(3))
    return t, v, f


def start_excess(t_fuel: np.ndarray, fuel_gps: np.ndarray, predicted_gps: np.ndarray, starts: np.ndarray, *,
                 pre_s: float = 0.5, post_s: float = 1.0, ref_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Measured fuel mass less the predicted one (g) in a window around each start (rectangle rule), less the
    map's local error over the window's running part.

    Parameters
    ----------
    t_fuel, fuel_gps:
        The fuel signal's sample times (increasing) and values (g/s).
    predicted_gps:
        The model's flow at the same times (g/s; zero while the engine is off).
    starts:
        Start times (s).
    pre_s, post_s:
        The window ``[t - pre_s, t + post_s)`` around each start (it must hold the start's pulse).
    ref_s:
        The reference ``[t + post_s, t + post_s + ref_s)``: ``post_s`` times its mean of measured - predicted is
        taken off (0: no reference, the window's sum only).

    Returns
    -------
    excess, kept
        Per kept start the excess (g), and the kept starts' times. A start is left out when its window or reference
        holds another start, fewer than 80 % of the samples the median period expects, or a non-finite value.

    Raises
    ------
    ValueError
        When a duration is negative or ``post_s`` is not positive.
    """
    if pre_s < 0 or post_s <= 0 or ref_s < 0:
        raise ValueError(f"{START_KEY}: window durations pre_s={pre_s}, post_s={post_s}, ref_s={ref_s} (need "
                         "pre_s >= 0, post_s > 0, ref_s >= 0)")
    t = np.asarray(t_fuel, float)
    d = np.asarray(fuel_gps, float) - np.asarray(predicted_gps, float)
    s = np.sort(np.asarray(starts, float))
    if t.size < 2 or s.size == 0:
        return np.zeros(0), np.zeros(0)
    dt = float(np.median(np.diff(t)))
    span = pre_s + post_s + ref_s
    a = np.searchsorted(t, s - pre_s, side="left")
    b = np.searchsorted(t, s + post_s, side="left")
    c = np.searchsorted(t, s + post_s + ref_s, side="left")
    csum = np.concatenate([[0.0], np.cumsum(np.where(np.isfinite(d), d, 0.0))])
    cbad = np.concatenate([[0], np.cumsum(~np.isfinite(d))])
    gap_prev = np.diff(s, prepend=-np.inf)
    gap_next = np.diff(s, append=np.inf)
    alone = (gap_prev > span) & (gap_next > span)
    ok = alone & ((b - a) >= 0.8 * (pre_s + post_s) / dt) & ((cbad[c] - cbad[a]) == 0)
    excess = (csum[b] - csum[a]) * dt
    if ref_s > 0:
        n_ref = c - b
        ok &= n_ref >= max(1.0, 0.8 * ref_s / dt)
        excess = excess - post_s * (csum[c] - csum[b]) / np.maximum(n_ref, 1)
    return excess[ok], s[ok]


def fit_start_fuel(excess_g: np.ndarray, *, min_starts: int = 20, segments: list[str] | None = None) -> FitResult:
    """``engine.start_fuel``: the mean excess per start, its standard error over starts and the use flag.

    Parameters
    ----------
    excess_g:
        Per start, the measured fuel less the map's around the start (:func:`start_excess`).
    min_starts:
        Fewer starts flag the fit ("too few starts"): one start's reading scatters with the frames' phase to the
        start's pulse (a pulse shorter than a frame is seen or missed whole), so the mean needs many.

    Returns
    -------
    FitResult
        Parameter ``m_g`` (g per start); data ``use`` (True only with enough starts and ``m_g``'s 95 % interval
        above zero), ``n_starts``, ``excess_g``.

    Raises
    ------
    InsufficientDataError
        When fewer than 3 finite excesses are given.
    """
    x = np.asarray(excess_g, float)
    x = x[np.isfinite(x)]
    if x.size < 3:
        raise InsufficientDataError(f"{START_KEY}: {x.size} engine start(s) with a whole fuel window; need 3")
    fit = linear_fit(np.ones((x.size, 1)), x, ["m_g"], units=["g"], segments=segments or [], what=START_KEY)
    lo = fit.params["m_g"].ci95[0]
    use = bool(x.size >= min_starts and math.isfinite(lo) and lo > 0)
    fit.data.update(use=np.array([use]), n_starts=np.array([x.size]), excess_g=x)
    if x.size < min_starts:
        fit.flag(f"too few starts: {x.size} engine start(s) (need {min_starts}: one start's 20 Hz reading scatters "
                 "with the frames' phase to the start's fuel pulse); the start fuel is not used")
    elif not use:
        fit.flag(f"not significant: m = {fit.value('m_g'):.3f} g per start, its 95 % interval reaches zero or below; "
                 "the start fuel is not used")
    return fit


def _predictor(rec: Recording, specs: VehicleSpecs, bsfc_data: dict,
               cold: tuple[float, float] | None) -> Callable[[np.ndarray], np.ndarray]:
    """The warm map's (x the cold factor's) fuel flow at given times, zero while the engine is off."""
    m = map_pmf(bsfc_data, specs.fuel_lhv_j_per_kg)
    if m is None:
        raise IdentificationError(f"{START_KEY}: the BSFC map cannot be read")
    speed, torque = rec["engine_speed_rpm"], rec["engine_torque_nm"]
    on_ch: Channel | None = None
    if "engine_on" in rec:  # a Recording has no get()
        on_ch = rec["engine_on"]
    cool: Channel | None = rec[COOLANT_ROLE] if cold is not None and COOLANT_ROLE in rec else None

    def predict(t: np.ndarray) -> np.ndarray:
        n = at_times(speed, t)[0]  # a channel read by blocks: around the times only
        tq = at_times(torque, t)[0]
        on = (at_times(on_ch, t, hold=True)[0] > 0.5) if on_ch is not None else (n > RUNNING_RPM)
        on &= np.isfinite(n) & np.isfinite(tq)
        out = np.zeros(t.size)
        if on.any():
            out[on] = fuel_map_gps(*m, specs.engine_displacement_m3, specs.engine_strokes, specs.fuel_lhv_j_per_kg,
                                   n[on], tq[on])
            if cool is not None and cold is not None:
                c = at_times(cool, t[on])[0]
                out[on] *= np.where(np.isfinite(c), cold_factor(cold[0], cold[1], c), 1.0)
        return out

    return predict


def identify_start_fuel(rec: Recording, specs: VehicleSpecs, bsfc_data: dict, *,
                        cold: tuple[float, float] | None = None, pre_s: float = 0.5, post_s: float = 1.0,
                        ref_s: float = 1.0, min_starts: int = 20) -> FitResult:
    """``engine.start_fuel`` from a Recording (see the module).

    Parameters
    ----------
    rec:
        The Recording: ``fuel_mass_flow_gps``, ``engine_speed_rpm``, ``engine_torque_nm`` (``engine_on`` and the
        coolant used when present).
    specs:
        Displacement, strokes, the fuel's lower heating value.
    bsfc_data:
        The warm map (``engine.bsfc``'s data).
    cold:
        ``(k per K, T_warm degC)`` of the cold-start factor when it is used, else None.
    pre_s, post_s, ref_s, min_starts:
        As :func:`start_excess` and :func:`fit_start_fuel`.

    Raises
    ------
    IdentificationError
        When channels are missing, the map cannot be read or fewer than 3 starts have a whole window.
    """
    need = ["fuel_mass_flow_gps", "engine_speed_rpm", "engine_torque_nm"]
    missing = [c for c in need if c not in rec]
    if missing:
        raise IdentificationError(f"{START_KEY}: missing channel(s) {', '.join(missing)}")
    kept = rec.loaded()
    try:
        starts = start_times(rec)
        predict = _predictor(rec, specs, bsfc_data, cold)
        # only the samples near a start are read and predicted (the map is read there only)
        t_n, vs, fl = _near(rec["fuel_mass_flow_gps"], starts - pre_s - 1.0, starts + post_s + ref_s + 1.0)
        v_n = np.where(((fl & int(Flag.bad())) == 0) & np.isfinite(vs), vs, np.nan)
        excess, _t = start_excess(t_n, v_n, predict(t_n), starts, pre_s=pre_s, post_s=post_s, ref_s=ref_s)
    finally:
        rec.drop([c for c in [*need, "engine_on", COOLANT_ROLE] if c in rec and c not in kept])
    return fit_start_fuel(excess, min_starts=min_starts)
