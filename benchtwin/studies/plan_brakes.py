"""Planned brake gains: the sensor noise through each window's mean, and the windows the poll faults leave.

The gains ``T = m p + c`` per axle are fitted on the steady neutral-braking windows
(:func:`~benchtwin.identification.brakes.brake_gain_windows`). Two things move the estimates from seed to
seed on a bench whose pressure module is polled over Modbus:

1. the transducers' noise, through each window's mean pressure (the regressor: errors in variables,
   ``s_i^2 = m^2 var(p_i)``), propagated by the fit's sandwich covariance, as every other planned fit;
2. which windows the fit gets. A failed poll (timeout or exception answer, at the rates the setup declares)
   flags a reading, and the steady-state detection cannot use a window over it: a steady hold is split in two
   pieces, or loses a piece shorter than the shortest window, at a place that changes with the seed. The rows
   of the fit and their spans change, and where the truth is not exactly ``m p + c`` over a window (the roller
   force still settling after a pressure step, the speed controller's ripple) the estimate moves with them.

The second term is computed from the setup alone by drawing the poll faults anew on the noise-free
Recording (:func:`redraw_poll_faults`: the declared per-poll probabilities, the client's timeout wait with
its skipped polls) and running the identification's own window selection and fit on each draw. The
planned variance is the law of total variance over the draws: the mean of the noise term at each draw's
windows plus the variance of the noise-free estimates over the draws.

The noise moves the windows too, as it moves the transmission's (:mod:`.plan_windows`): where a hold ends is
decided by the first noisy pressure reading out of its tolerance while the next step begins, and a noisy
reading below 0 bar on an unbraked caliper is clipped and flagged by the bench's converter. On 4 seeds of
the paper campaign the bench's 14-15 windows ended up to 0.45 s apart with the seed, and holds were split at
places that changed with the seed, beside the poll faults'. So each draw reads the pressures drawn with
their noise (:func:`~benchtwin.studies.plan_blending.clipped_readings`) around the transducers' noise-free
response (:func:`~benchtwin.studies.plan_noise.sensor_response`: filter, clock, latency; the truth at the
readings' timestamps puts every window 0.2 s early against the bench's), with the channels free of random
error (the rollers' forces and speed) as the plan's bench run read them (the same on every seed); the
window search runs on those, and the noise-free estimate is taken at the windows found. The same draws give
the blending statistics' spread (:mod:`.plan_blending`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from benchtwin.config.vehicle import VehicleConfig
from benchtwin.errors import BenchtwinError
from benchtwin.identification.brakes import brake_gain_windows
from benchtwin.recording import Channel, Flag, Recording
from benchtwin.segments import Segment
from benchtwin.studies.plan_blending import blending_rows, blending_values, clipped_readings
from benchtwin.studies.plan_fits import PlannedParameter
from benchtwin.studies.plan_noise import (
    ChannelNoise,
    PollFaults,
    sample_variances,
    sandwich_covariance,
    window_mean_variance,
)
from benchtwin.studies.plan_windows import sensed_recording

__all__ = ["BRAKES_SEARCHED", "BRAKE_FAULT_DRAWS", "plan_brakes", "redraw_poll_faults"]

#: draws of the poll faults for the selection term: the std over K draws is known to about 1 / sqrt(2 (K - 1))
#: (8 % at 80), and one draw costs a steady-window search over the braking tests (~10 ms per 1,000 s of tests)
BRAKE_FAULT_DRAWS = 80

#: the channels the braking window search reads (:func:`~benchtwin.identification.brakes.brake_gain_windows`)
BRAKES_SEARCHED: tuple[str, ...] = ("brake_pressure_fl_bar", "brake_pressure_fr_bar", "brake_pressure_rl_bar",
                                    "brake_pressure_rr_bar", "dyno_force_front_n", "dyno_force_rear_n",
                                    "dyno_speed_kmh")

_POLL_FLAGS = int(Flag.TIMEOUT | Flag.PROTOCOL_ERROR)

_NAMES = [("brakes.front.m_f", "Nm/bar"), ("brakes.front.c_f", "Nm"), ("brakes.rear.m_r", "Nm/bar"),
          ("brakes.rear.c_r", "Nm"), ("brakes.distribution.k_f", "-")]
_K_R = "brakes.distribution.k_r"


def redraw_poll_faults(rec: Recording, roles: Sequence[str], faults: PollFaults, rng: np.random.Generator
                       ) -> Recording:
    """A copy of ``rec`` whose polled ``roles`` (read by one poll, on one time base) carry new poll faults.

    The faults of the bench's run are cleared; each reading then fails with the declared probabilities: an
    exception answer flags it ``PROTOCOL_ERROR``; a timeout flags it ``TIMEOUT`` and drops the readings of the
    polls that fall in the client's wait (``timeout_s x poll_hz - 1`` of them), as
    :func:`~benchtwin.sensors.pressure.poll_snapshots` does. Other channels are shared, not copied.
    """
    roles = [r for r in roles if r in rec]
    out = Recording(segments=list(rec.segments), meta=rec.meta)
    for name, ch in rec.channels.items():
        if name not in roles:
            out.add(ch)
    if not roles:
        return out
    ts = rec[roles[0]].timestamps
    n = ts.size
    u = rng.random(n)
    timeout = u < faults.timeout_prob
    exception = (u >= faults.timeout_prob) & (u < faults.prob)
    keep = np.ones(n, dtype=bool)
    skip = max(math.ceil(faults.timeout_s * faults.poll_hz - 1e-9) - 1, 0)
    busy_until = -1
    for i in np.flatnonzero(timeout):  # rare: a short loop
        if i <= busy_until:
            keep[i], timeout[i] = False, False  # inside an earlier wait
            continue
        keep[i + 1:i + 1 + skip] = False
        busy_until = i + skip
    for name in roles:
        ch = rec[name]
        if ch.timestamps.shape != ts.shape:
            raise ValueError(f"redraw_poll_faults: {name} is not on the time base of {roles[0]}")
        fl = ch.flags & ~np.uint16(_POLL_FLAGS)
        fl = np.where(timeout, fl | np.uint16(Flag.TIMEOUT), fl)
        fl = np.where(exception, fl | np.uint16(Flag.PROTOCOL_ERROR), fl).astype(np.uint16)
        out.add(Channel(name, ch.unit, ch.timestamps[keep], ch.values[keep], fl[keep], ch.source))
    return out


def _axle_fits(rec: Recording, r: float, noise: Mapping[str, ChannelNoise], found: Recording | None = None
               ) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Axle -> (pressures, estimate ``[m, c]``, noise covariance) on the windows of ``rec`` (empty when too few).

    With ``found`` (the same readings drawn with their noise) the windows are those the search finds on it, and
    the estimate the noise-free one of ``rec`` at them.
    """
    sw, front, rear = brake_gain_windows(rec if found is None else found)
    st = np.array([w.start_s for w in sw.windows])
    en = np.array([w.end_s for w in sw.windows])
    out = {}
    for axle, chans, force in (("front", front, "dyno_force_front_n"), ("rear", rear, "dyno_force_rear_n")):
        if not len(sw):
            continue
        p = np.mean([sw.raw_average(rec, c) for c in chans], axis=0)
        t = -sw.raw_average(rec, force) * r
        ok = np.isfinite(p) & np.isfinite(t)
        p, t = p[ok], t[ok]
        if p.size < 4 or float(np.ptp(p)) < 5.0:
            out[axle] = (p, np.full(2, np.nan), np.full((2, 2), np.nan))
            continue
        A = np.column_stack([p, np.ones_like(p)])
        x0 = np.linalg.lstsq(A, t, rcond=None)[0]
        var_p = np.zeros(p.size)
        for c in chans:
            sv = sample_variances(rec, noise, c)
            if sv is not None:
                var_p += window_mean_variance(rec, c, sv, st[ok], en[ok]) / len(chans) ** 2
        out[axle] = (p, x0, sandwich_covariance(A, None, x0[0] ** 2 * var_p))
    return out


def _k_f(fits: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]]) -> tuple[float, float]:
    """``k_f`` and its noise variance (the identification's delta method) from both axles' fits."""
    (_pf, xf, cf), (_pr, xr, cr) = fits["front"], fits["rear"]
    mf, mr = float(xf[0]), float(xr[0])
    tot = mf + mr
    return mf / tot, (mr / tot**2) ** 2 * float(cf[0, 0]) + (mf / tot**2) ** 2 * float(cr[0, 0])


def plan_brakes(rec: Recording, vehicle: VehicleConfig, noise: Mapping[str, ChannelNoise],
                segments: list[Segment], faults: Mapping[str, PollFaults] | None = None, *,
                sensed: Mapping[str, Channel] | None = None, noisy_windows: bool = True, blending: bool = True,
                draws: int = BRAKE_FAULT_DRAWS, seed: int = 0) -> list[PlannedParameter]:
    """Brake gains ``T = m p + c`` per axle on the steady neutral-braking windows, and ``k_f``.

    Parameters
    ----------
    rec:
        The noise-free truth Recording (:func:`~benchtwin.studies.plan.planned_recording`).
    vehicle:
        ``wheel_radius_m``.
    noise:
        Role -> random error of its readings (:func:`~benchtwin.studies.plan_noise.noise_budget`).
    segments:
        The campaign's tests.
    faults:
        Role -> declared poll faults (:func:`~benchtwin.studies.plan_noise.poll_fault_model`); when the
        pressures' polls can fail, the variance from the windows they leave is added (module docstring).
    sensed:
        Role -> the noise-free value each reading measures (:func:`~benchtwin.studies.plan_noise.sensor_response`:
        filter, clock, latency); the draws read these instead of the truth for the channels found here.
    noisy_windows:
        Draw the noise of the searched channels (:data:`BRAKES_SEARCHED`) into the window search (default); False
        leaves the draws only the poll faults (the plan before the windows' edges were drawn).
    blending:
        Also plan the blending statistics (:mod:`.plan_blending`), by the same draws.
    draws, seed:
        Draws of the poll faults, and the seed of their generator (the plan is the same every run).

    Returns
    -------
    list of PlannedParameter
        ``m_f``, ``c_f``, ``m_r``, ``c_r``, ``k_f``, ``k_r`` and (``blending``) ``brakes.blending.*``'s statistics.
    """
    test = "add [[tests]] kind = \"neutral_braking\" with brake_steps_pct = [5.0, 10.0, 20.0, 30.0]"
    r = vehicle.specs.wheel_radius_m
    try:
        base = _axle_fits(rec, r, noise)
    except BenchtwinError as exc:
        return [PlannedParameter(n, u, float("nan"), float("nan"), False, f"no braking window: {exc}", test)
                for n, u in _NAMES]
    polled = sorted({k for k in (faults or {}) if k.startswith("brake_pressure_") or k == "master_cylinder_bar"}
                    & set(rec.channels))
    pf = (faults or {}).get(polled[0]) if polled else None
    pf = pf if pf is not None and pf.prob > 0 else None
    # the readings each reading measures (filter, clock, latency), and those the window search reads with noise
    read = sensed_recording(rec, {k: v for k, v in (sensed or {}).items() if k in BRAKES_SEARCHED})
    searched = tuple(n for n in BRAKES_SEARCHED if n in read and n in noise) if noisy_windows else ()
    # estimates and noise variances per draw of the poll faults: axle -> (estimates [K, 2], noise variances [K, 2])
    draw_x: dict[str, list[np.ndarray]] = {"front": [], "rear": []}
    draw_v: dict[str, list[np.ndarray]] = {"front": [], "rear": []}
    draw_k: list[tuple[float, float]] = []
    n_lost = 0
    blend0 = blending_values(read, vehicle.specs, _gains(base)) if blending else None
    blend_drawn: list[dict[str, float] | None] = []
    if pf is not None or searched:
        rng = np.random.default_rng(seed)
        for _ in range(draws):
            try:
                drawn = redraw_poll_faults(read, polled, pf, rng) if pf is not None else read
                noisy = clipped_readings(drawn, noise, searched, rng) if searched else None
                fits = _axle_fits(drawn, r, noise, noisy)
            except BenchtwinError:
                fits, noisy = {}, None
            if blend0 is not None and noisy is not None:
                try:  # the bench's own gains on the draw's readings, then its blending
                    blend_drawn.append(blending_values(noisy, vehicle.specs, _gains(_axle_fits(noisy, r, noise))))
                except BenchtwinError:
                    blend_drawn.append(None)
            good = {a: f for a, f in fits.items() if np.all(np.isfinite(f[1]))}
            if len(good) < 2:
                n_lost += 1
            for a, (_p, x, c) in good.items():
                draw_x[a].append(x)
                draw_v[a].append(np.diag(c))
            if len(good) == 2:
                draw_k.append(_k_f(good))
    out: list[PlannedParameter] = []
    for axle, names in (("front", _NAMES[:2]), ("rear", _NAMES[2:4])):
        p, x0, cov = base.get(axle, (np.array([]), np.full(2, np.nan), np.full((2, 2), np.nan)))
        spread = float(np.ptp(p)) if p.size else 0.0
        if not np.all(np.isfinite(x0)):
            why = (f"{p.size} steady neutral-braking windows (need 4)" if p.size < 4 else
                   f"{axle} pressure spans {spread:.3g} bar (need 5 bar)")
            out += [PlannedParameter(n, u, float("nan"), float("nan"), False, why, test, int(p.size))
                    for n, u in names]
            continue
        var = np.diag(cov).copy()
        why = f"{p.size} steady windows, {p.min():.1f}..{p.max():.1f} bar"
        if len(draw_x[axle]) >= 2:
            xs, vs = np.array(draw_x[axle]), np.array(draw_v[axle])
            var_sel = np.var(xs, axis=0, ddof=1)
            var = np.mean(vs, axis=0) + var_sel
            drew = " and ".join(([f"the noise of {len(searched)} searched channels"] if searched else [])
                                + (["the poll faults"] if pf is not None else []))
            why += ((f"; polls fail with p = {pf.prob:g} (timeouts {pf.timeout_prob:g})" if pf is not None else "")
                    + f": over {draws} draws of {drew} the windows found add {_share(var_sel[0], var[0])} of the "
                    f"gain's variance, {_share(var_sel[1], var[1])} of the intercept's"
                    + (f"; the fit fails on {n_lost} of the {draws} draws" if n_lost else ""))
        for j, (n, u) in enumerate(names):
            out.append(PlannedParameter(n, u, float(x0[j]), math.sqrt(max(float(var[j]), 0.0)), True, why, "",
                                        int(p.size)))
    if all(np.all(np.isfinite(base.get(a, (None, np.full(2, np.nan)))[1])) for a in ("front", "rear")):
        k0, var_k = _k_f(base)
        if len(draw_k) >= 2:
            ks = np.array(draw_k)
            var_k = float(np.mean(ks[:, 1]) + np.var(ks[:, 0], ddof=1))
        se_k = math.sqrt(max(var_k, 0.0))
        out.append(PlannedParameter(_NAMES[4][0], "-", k0, se_k, True, "from both gains", "", 0))
        # k_r = 1 - k_f as the identification reports it: the same standard error
        out.append(PlannedParameter(_K_R, "-", 1.0 - k0, se_k, True, "1 - k_f", "", 0))
    else:
        out += [PlannedParameter(n, "-", float("nan"), float("nan"), False, "needs both axle gains", test)
                for n in (_NAMES[4][0], _K_R)]
    if blending:
        out += blending_rows(blend0, blend_drawn, "" if searched else "no noisy pressure to draw")
    return out


def _gains(fits: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]]) -> tuple[float, float, float, float]:
    """``(m_f, m_r, c_f, c_r)`` of both axles' fits (NaN where an axle has none)."""
    nan = np.full(2, np.nan)
    xf, xr = fits.get("front", (None, nan))[1], fits.get("rear", (None, nan))[1]
    return float(xf[0]), float(xr[0]), float(xf[1]), float(xr[1])


def _share(part: float, total: float) -> str:
    return f"{part / total:.0%}" if total > 0 else "0 %"
