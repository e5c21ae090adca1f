"""Gear-shift thresholds: speed-vs-pedal lines for every gear pair, up and down (paper, Figure 21).

The model (docs/models.md): for each pair ``(g, g+1)`` the gearbox asks for an upshift when
``v >= u0 + u1 * pedal`` and for a downshift from ``g+1`` to ``g`` when ``v <= d0 + d1 * pedal``
(v in km/h, pedal in %). The *target* gear on the CAN changes at once when a threshold is crossed;
the actual gear follows after the actuation delay, so events are taken where ``gear_target``
changes (never ``gear_actual``, whose speed would be late by the delay times the acceleration).

Only events inside segments where the automatic schedule chooses the gear (accelerations,
decelerations, ramp-downs, cycles) are used when the Recording has a segment table: in ramp-up and
constant-drive tests the gear is held by the test, so their target-gear changes are no thresholds.
The event time on a periodically sampled target-gear channel is the midpoint between the last sample
with the old gear and the first with the new one (the change happened somewhere in between; the
midpoint is unbiased); on an event-driven channel it is the sample's own time.

At each event the vehicle speed and pedal at the event time are recorded;
per pair and direction, ``v = c0 + c1 pedal`` is fitted by least squares. A pair with too few
events or too little pedal spread gets a *flagged* result without a line (``c0``, ``c1`` NaN) that
reports the mean speed and pedal of its events instead (e.g. the downshift speed at zero pedal when
every downshift of a cycle happened while coasting).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from benchtwin.errors import MissingChannelError
from benchtwin.identification._fit import FitResult, ParameterEstimate, linear_fit
from benchtwin.identification._state_changes import state_changes
from benchtwin.identification._windows import at_times
from benchtwin.identification.keys import FitKey
from benchtwin.identification.shift_delay import SHIFT_DELAY_KEY, identify_shift_delay
from benchtwin.recording import Recording
from benchtwin.segments import inside_any, touched

__all__ = ["find_shift_events", "identify_shift_thresholds", "shift_fits"]


#: segment kinds in which the gearbox's own schedule chooses the gear
SCHEDULE_SEGMENT_KINDS: tuple[str, ...] = ("acceleration", "deceleration", "ramp_down", "cycle")


def find_shift_events(rec: Recording, *, segment_kinds: tuple[str, ...] | None = SCHEDULE_SEGMENT_KINDS,
                      lookback_s: float = 0.5, pedal_tol_pct: float = 1.0) -> dict[str, np.ndarray]:
    """Target-gear change events.

    Parameters
    ----------
    rec:
        The Recording.
    segment_kinds:
        When the Recording has segments of these kinds, only events inside them are returned;
        ``None`` or a Recording without such segments: every event.
    lookback_s, pedal_tol_pct:
        An event is a *speed crossing* when the pedal moved by at most ``pedal_tol_pct`` over the
        ``lookback_s`` before it and the speed moved in the shift's direction (rising for an
        upshift, falling for a downshift). A shift caused by a pedal step (kick-down, tip-out) puts
        the point off the line, so only speed crossings are used for the lines.

    Returns
    -------
    dict
        ``t`` (s), ``from_gear``, ``to_gear``, ``speed_kmh`` and ``pedal_pct`` at each change of
        ``gear_target`` (speed and pedal interpolated at the change's timestamp on their own clocks),
        ``good`` (False where speed or pedal is flagged bad or missing there) and ``crossing``
        (True for speed crossings, see above).

    Raises
    ------
    MissingChannelError
        ``gear_target``, ``vehicle_speed_kmh`` or ``pedal_pct`` is absent.
    """
    for n in ("gear_target", "vehicle_speed_kmh", "pedal_pct"):
        if n not in rec:
            raise MissingChannelError(f"shift-threshold identification needs channel {n!r}")
    ch = state_changes(rec["gear_target"])  # read by blocks: only the changes are kept
    g_old, g_new = ch.old, ch.new
    t_ev = ch.t_new
    if ch.periodic:
        t_ev = 0.5 * (ch.t_new + ch.t_old)
    if segment_kinds and rec.segments:
        segs = [sg for sg in rec.segments if sg.kind in segment_kinds]
        if segs:
            inside = inside_any(segs, t_ev)
            g_old, g_new, t_ev = g_old[inside], g_new[inside], t_ev[inside]
    sp, pd = rec["vehicle_speed_kmh"], rec["pedal_pct"]
    # read around the events only when the channels are read by blocks (see _windows.at_times)
    v, v_flags = at_times(sp, t_ev)
    p, p_flags = at_times(pd, t_ev)
    from benchtwin.recording import Flag

    good = np.isfinite(v) & np.isfinite(p) & ((v_flags & int(Flag.bad())) == 0) \
        & ((p_flags & int(Flag.bad())) == 0)
    v_before = at_times(sp, t_ev - lookback_s)[0]
    p_before = at_times(pd, t_ev - lookback_s)[0]
    up = g_new > g_old
    dv = v - v_before
    steady_pedal = np.abs(p - p_before) <= pedal_tol_pct
    crossing = np.where(up, dv > 0, dv < 0) & steady_pedal & np.isfinite(dv)
    return {"t": t_ev, "from_gear": g_old, "to_gear": g_new, "speed_kmh": v, "pedal_pct": p, "good": good,
            "crossing": crossing}


def _est(name: str, x: np.ndarray, unit: str, segs: list[str]) -> ParameterEstimate:
    n = int(x.size)
    m = float(np.mean(x)) if n else float("nan")
    se = float(np.std(x, ddof=1) / np.sqrt(n)) if n > 1 else float("nan")
    return ParameterEstimate(name, m, se, (m - 1.96 * se, m + 1.96 * se), float("nan"), n, unit, segs)


def _flagged(name: str, v: np.ndarray, p: np.ndarray, reason: str, segs: list[str]) -> FitResult:
    """A pair without a confident line: no c0/c1, only the mean speed and pedal of its events."""
    n = int(v.size)
    nan = float("nan")
    params = {
        "c0_kmh": ParameterEstimate("c0_kmh", nan, nan, (nan, nan), nan, n, "km/h", segs),
        "c1_kmh_per_pct": ParameterEstimate("c1_kmh_per_pct", nan, nan, (nan, nan), nan, n, "km/h/%", segs),
        "mean_speed_kmh": _est("mean_speed_kmh", v, "km/h", segs),
        "mean_pedal_pct": _est("mean_pedal_pct", p, "%", segs),
    }
    fit = FitResult(params, nan, nan, nan, n, segments=segs, data={"pedal": p, "speed": v})
    fit.flag(f"{name}: {reason}")
    return fit


def identify_shift_thresholds(
    rec: Recording,
    *,
    n_gears: int | None = None,
    min_events: int = 3,
    min_pedal_spread_pct: float = 10.0,
    segment_kinds: tuple[str, ...] | None = SCHEDULE_SEGMENT_KINDS,
) -> dict[str, FitResult]:
    """Fit the shift lines of every gear pair and direction.

    Parameters
    ----------
    rec:
        Recording with ``gear_target``, ``vehicle_speed_kmh`` and ``pedal_pct``.
    n_gears:
        Number of forward gears; every pair ``1-2 ... (n-1)-n`` gets a result (flagged when it has
        no events). Default: the highest target gear seen.
    min_events:
        Fewer events than this: flagged.
    min_pedal_spread_pct:
        Pedal range (max - min) of a pair's events below this: flagged (slope not identifiable).
    segment_kinds:
        See :func:`find_shift_events`.

    Returns
    -------
    dict
        ``up_1_2``, ``down_2_1``, ... -> :class:`FitResult` with ``c0_kmh`` and ``c1_kmh_per_pct``
        (``v = c0 + c1 pedal``; NaN in a flagged result, which has ``mean_speed_kmh`` and
        ``mean_pedal_pct`` instead); ``data`` holds ``pedal`` and ``speed`` of the events. Events that
        skip a gear (3 -> 5) or involve neutral are not used; events whose speed or pedal is flagged,
        and events that are no speed crossing (pedal steps), are counted in the pair's ``n_excluded``.
    """
    ev = find_shift_events(rec, segment_kinds=segment_kinds)
    seen = int(max(ev["from_gear"].max(initial=0), ev["to_gear"].max(initial=0)))
    n_gears = n_gears or seen
    adjacent = (np.abs(ev["to_gear"] - ev["from_gear"]) == 1) & (np.minimum(ev["from_gear"], ev["to_gear"]) >= 1)
    out: dict[str, FitResult] = {}
    for g in range(1, max(n_gears, 1)):
        for direction, a, b in (("up", g, g + 1), ("down", g + 1, g)):
            name = FitKey.shift(a, direction).local
            m = adjacent & (ev["from_gear"] == a) & (ev["to_gear"] == b)
            n_bad = int((m & ~(ev["good"] & ev["crossing"])).sum())
            m &= ev["good"] & ev["crossing"]
            v, p = ev["speed_kmh"][m], ev["pedal_pct"][m]
            hits = touched(rec.segments, ev["t"][m])
            segs = sorted({s.name for s, hit in zip(rec.segments, hits, strict=True) if hit})
            spread = float(p.max() - p.min()) if p.size else 0.0
            if v.size < min_events:
                fit = _flagged(name, v, p, f"{v.size} target-gear change event(s), need {min_events}", segs)
            elif spread < min_pedal_spread_pct:
                fit = _flagged(name, v, p, f"pedal spread {spread:.1f} % < {min_pedal_spread_pct:g} %: "
                               "slope not identifiable", segs)
            else:
                fit = linear_fit(np.column_stack([np.ones_like(p), p]), v, ["c0_kmh", "c1_kmh_per_pct"],
                                 units=["km/h", "km/h/%"], segments=segs, min_points=min_events,
                                 what=f"shift line {name}")
                fit.data.update({"pedal": p, "speed": v})
            fit.n_excluded += n_bad
            out[name] = fit
    return out


def shift_fits(rec: Recording, **opts: Any) -> dict[str, FitResult]:
    """The ``shifts`` method: :func:`identify_shift_thresholds` (``opts``) and, when ``gear_actual`` was recorded,
    the actuation delay from target to actual gear under ``actuation``
    (:func:`~benchtwin.identification.shift_delay.identify_shift_delay`)."""
    out = identify_shift_thresholds(rec, **opts)
    if "gear_actual" in rec:
        out[SHIFT_DELAY_KEY.partition(".")[2]] = identify_shift_delay(rec)
    return out
