"""Planned spread of the brake-blending statistics (``brakes.blending``), by draws of the whole method.

The blending statistics (:func:`~benchtwin.identification.brakes.identify_brake_blending`: the mean regenerative,
hydraulic and front shares of the braking torque, the 95th percentile of the regenerative torque) are means over
the braking samples of the deceleration tests, and which samples count is decided on the noisy readings: a sample
is left out where a reading is flagged, where the braking torque or the deceleration is below a threshold, or where
the torques change fast (a smoothed derivative of the noisy pressures). The bench's pressure module flags a
reading ``SATURATED`` where the converter clips at 0 V, and with the transducers' offset (0.1 bar) and noise
(0.05 bar) on the paper bench that is about one reading in 40 of every unbraked caliper, so the samples of
regenerative braking alone (no hydraulic pressure) come and go with the seed: over 6 seeds the fit kept 734-831
braking samples and its regenerative share moved by 0.04. That is a selection, not a linear function of the
noise, so the plan does not linearise it: each draw of the brakes plan (:mod:`.plan_brakes`: the poll faults and
the pressures' noise drawn on the sensor's noise-free response) is given the converter's clipping
(:func:`clipped_readings`), the gains are fitted on the draw's readings as the bench fits them, and the
identification's own blending runs on it; the planned standard error is the standard deviation over the draws.
The bootstrap standard errors the identification reports hold the seed's samples fixed, so they say nothing of
this selection.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import BenchtwinError
from benchtwin.identification.brakes import identify_brake_blending
from benchtwin.recording import Channel, Flag, Recording
from benchtwin.studies.plan_fits import PlannedParameter
from benchtwin.studies.plan_noise import ChannelNoise
from benchtwin.studies.plan_windows import noisy_readings

__all__ = ["BLENDING_KEY", "blending_rows", "blending_values", "clipped_readings"]

BLENDING_KEY = "brakes.blending"
#: the pressure module's converter clips at 0 V, i.e. 0 bar (:mod:`benchtwin.sensors.pressure`)
PRESSURE_LOW_BAR = 0.0

_UNITS = {"regen_torque_p95_nm": "Nm"}


def clipped_readings(rec: Recording, noise: Mapping[str, ChannelNoise], names: Sequence[str],
                     rng: np.random.Generator, low: float = PRESSURE_LOW_BAR) -> Recording:
    """``rec`` with the pressure channels ``names`` drawn with their noise, clipped and flagged at the converter.

    Each reading is drawn as :func:`~benchtwin.studies.plan_windows.noisy_readings` does; one below ``low`` (the
    converter's 0 V) reads ``low`` and is flagged ``SATURATED`` as the bench flags it; the ``SATURATED`` flags of
    ``rec`` on these channels (its own run's clipping) are cleared first. Other channels are shared.
    """
    names = tuple(n for n in names if n in rec)
    out = noisy_readings(rec, noise, names, rng)
    sat = np.uint16(Flag.SATURATED)
    for n in names:
        ch = out[n]
        under = ch.values < low
        fl = np.where(under, ch.flags | sat, ch.flags & ~sat).astype(np.uint16)
        out.add(Channel(n, ch.unit, ch.timestamps, np.where(under, low, ch.values), fl, ch.source))
    return out


def blending_values(rec: Recording, specs: VehicleSpecs, gains: Sequence[float]) -> dict[str, float] | None:
    """The blending statistics of ``rec`` with the gains ``(m_f, m_r, c_f, c_r)``; None when the method fails."""
    if not all(math.isfinite(g) for g in gains):
        return None
    try:
        fit = identify_brake_blending(rec, specs, list(gains))
    except BenchtwinError:
        return None
    return {k: float(p.value) for k, p in fit.params.items()}


def blending_rows(base: Mapping[str, float] | None, drawn: Sequence[Mapping[str, float] | None], why_not: str = ""
                  ) -> list[PlannedParameter]:
    """One row per blending statistic: the noise-free value, the standard deviation over the drawn values.

    Parameters
    ----------
    base:
        The statistics on the noise-free readings (None: the method fails there).
    drawn:
        The statistics of each draw (None where the method failed on it).
    why_not:
        The reason when nothing could be drawn (no deceleration test, no noisy pressure).
    """
    test = "add [[tests]] kind = \"deceleration\" (brake steps in gear, e.g. decel_mps2 = 1.0)"
    if base is None:
        return [PlannedParameter(f"{BLENDING_KEY}.*", "-", math.nan, math.nan, False,
                                 why_not or "no braking sample in gear on the noise-free readings", test)]
    ok = [d for d in drawn if d is not None]
    out = []
    for k, v0 in base.items():
        v = np.array([d[k] for d in ok if k in d], dtype=float)
        v = v[np.isfinite(v)]
        if v.size < 2:
            out.append(PlannedParameter(f"{BLENDING_KEY}.{k}", _UNITS.get(k, "-"), v0, math.nan, True,
                                        why_not or f"the blending fails on {len(drawn) - len(ok)} of {len(drawn)} "
                                        "draws", "", 0))
            continue
        why = (f"std over {v.size} draws of the pressures' noise, the converter's clipping at 0 bar and the poll "
               "faults through the identification's blending (its gains fitted on each draw)"
               + (f"; fails on {len(drawn) - len(ok)} draws" if len(ok) < len(drawn) else ""))
        out.append(PlannedParameter(f"{BLENDING_KEY}.{k}", _UNITS.get(k, "-"), v0, float(np.std(v, ddof=1)), True,
                                    why, "", 0))
    return out
