"""Planned standard errors of the gearbox drag model (``transmission.drag``), by draws of the whole fit.

The drag fit (:mod:`~benchtwin.identification.transmission_drag`) takes every gear's steady points with their
oil temperature, and finds the oil and speed coefficients ``k_T``, ``k_w`` by a Nelder-Mead search of the
profile sum of squares, then ``eta_m`` and ``C0`` per gear and direction at them; it drops the speed term when
``k_w`` is not three standard errors from zero, and ``T_ref`` is the points' median oil temperature. The
search's tolerances (``xatol`` 1e-8 on ``k_T``), the dropped term and the median are not linear in the noise,
so the plan does not linearise the fit: each draw of the transmission plan's window search
(:func:`~benchtwin.studies.plan_windows.window_draws`: the searched channels drawn with their noise, the
identification's own window search and points on them) is given oil readings drawn with the thermocouple's
noise (:func:`~benchtwin.studies.plan_windows.noisy_readings`, its own generator, so the window draws do not
change), and the identification's own grouping and drag fit
(:func:`~benchtwin.identification.transmission.identify_transmission` with those points) runs on it. The
planned standard error of each drag parameter is its standard deviation over the draws (known to about
``1 / sqrt(2 (K - 1))``); a parameter the same on every draw (``k_w`` when the speed term is dropped on every
draw) is planned 0.

The 30 window draws of the transmission plan are too few here: on the paper campaign their own scatter put
gear 3 coast's ``eta_m`` at 5.5e-6 where 400 draws give 8.1e-6 (and 200 seeds 8.0e-6), gear 5's at 2.0e-5
against 2.3e-5 / 2.5e-5. The drag's spread is also heavy-tailed: now and then one 2 s window of a hold fails the
slope test on the shaft torque's noise and the hold gives two overlapping points (gear 6's first electric hold:
7 of 400 draws, 2 of 200 seeds of the bench), which moves ``T_ref`` (a median) and gear 6's ``eta_m``, ``C0``
by several times their usual spread. So the drag draws its own windows beyond the transmission plan's
(:data:`DRAG_DRAWS` in all, :func:`~benchtwin.studies.plan_windows.window_draws` with its own seed: the other
rows do not move).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import BenchtwinError
from benchtwin.identification.transmission import OIL_ROLE, TransmissionPoints, identify_transmission
from benchtwin.identification.transmission_drag import DRAG_KEY
from benchtwin.recording import Channel, Recording
from benchtwin.studies.plan_fits import PlannedParameter
from benchtwin.studies.plan_noise import ChannelNoise
from benchtwin.studies.plan_windows import noisy_readings, window_draws

__all__ = ["DRAG_DRAWS", "plan_drag"]

_UNITS = {"k_T": "1/K", "k_w": "s/rad", "T_ref": "degC"}
#: draws of the drag fit (the transmission plan's window draws and more): its std over K draws is known to about
#: 1 / sqrt(2 (K - 1)), 6.5 % at 120; a split hold (about 1 draw in 60 on the paper campaign) then enters about twice
DRAG_DRAWS = 120


def plan_drag(rec: Recording, specs: VehicleSpecs, noise: Mapping[str, ChannelNoise], points: TransmissionPoints,
              drawn: Sequence[TransmissionPoints], *, seed: int = 1, draws: int = DRAG_DRAWS,
              recorded: Mapping[str, Channel] | None = None,
              sensed: Mapping[str, Channel] | None = None) -> list[PlannedParameter]:
    """The drag model's parameters: the noise-free fit's values, the spread of the fit over the drawn points.

    Parameters
    ----------
    rec:
        The noise-free Recording of the plan (the oil thermocouple's truth among its channels).
    specs:
        Public specs (ratios).
    noise:
        Role -> the random error of its readings (the oil thermocouple's, ``gearbox_oil_degc``).
    points:
        The transmission points on the noise-free readings (:func:`~benchtwin.identification.transmission.
        transmission_points`).
    drawn:
        The points each draw of the window search found on the noisy readings (their own noisy values).
    seed:
        Seed of the oil readings' generator and of the further window draws (the same plan gives the same numbers).
    draws:
        Draws of the drag fit in all: ``drawn`` and as many further window draws as it lacks (none when
        ``drawn`` has as many, or when no searched channel is noisy).
    recorded, sensed:
        As :func:`~benchtwin.studies.plan_windows.window_draws` takes them, for the further draws.

    Returns
    -------
    list of PlannedParameter
        One row per parameter of the noise-free fit (``transmission.drag.k_T``, ``k_w``, ``T_ref``,
        ``eta_m_<group>``, ``C0_<group>``); a single ``transmission.drag.*`` row, not identifiable, with the reason
        when the campaign gives no drag fit; none when the Recording logs no oil temperature (no fit is made).
    """
    if points.oil_degc is None or not np.isfinite(points.oil_degc).any():
        return []
    test = "log the gearbox oil (role gearbox_oil_degc) over ramp-ups in every gear spanning 15 K or more"
    try:
        base = identify_transmission(rec, specs, points=points)
    except BenchtwinError as exc:
        return [PlannedParameter(f"{DRAG_KEY}.*", "-", math.nan, math.nan, False, f"no drag fit: {exc}", test)]
    fit0 = base.fits.get(DRAG_KEY)
    if fit0 is None:
        why = base.errors.get(DRAG_KEY, "no drag fit")
        return [PlannedParameter(f"{DRAG_KEY}.*", "-", math.nan, math.nan, False, why, test)]
    rng = np.random.default_rng(seed)
    more: list[TransmissionPoints] = []
    if draws > len(drawn):
        window_draws(rec, specs, noise, recorded=recorded, sensed=sensed, draws=draws - len(drawn),
                     seed=seed + 1000, keep=more)
    drawn = [*drawn, *more]
    vals: dict[str, list[float]] = {k: [] for k in fit0.params}
    n_lost = 0
    for found in drawn:
        oil = found.oil_degc
        if OIL_ROLE in noise and found.windows is not None:
            read = noisy_readings(rec, noise, (OIL_ROLE,), rng)
            oil = found.windows.raw_average(read, OIL_ROLE)
        try:
            fit = identify_transmission(rec, specs, points=replace(found, oil_degc=oil)).fits.get(DRAG_KEY)
        except BenchtwinError:
            fit = None
        if fit is None or any(k not in fit.params for k in vals):
            n_lost += 1
            continue
        for k in vals:
            vals[k].append(fit.params[k].value)
    out = []
    n = fit0.n_points
    speed = "the speed term dropped" if fit0.value("k_w") == 0.0 else "with the speed term"
    for k, p in fit0.params.items():
        v = np.asarray(vals[k], dtype=float)
        v = v[np.isfinite(v)]
        if v.size < 2:
            out.append(PlannedParameter(f"{DRAG_KEY}.{k}", p.unit, p.value, math.nan, True,
                                        f"the drag fit fails on {n_lost} of {len(drawn)} draws", "", n))
            continue
        why = (f"std of the drag fit over {v.size} draws of the noise (window search and points, oil readings), "
               f"{n} points, {speed} on the noise-free points"
               + (f"; the fit fails on {n_lost} of {len(drawn)} draws" if n_lost else ""))
        out.append(PlannedParameter(f"{DRAG_KEY}.{k}", _UNITS.get(k, p.unit), p.value,
                                    float(np.std(v, ddof=1)), True, why, "", n))
    return out
