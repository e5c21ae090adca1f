"""The gearbox's actuation delay: how long after the target gear changes the actual gear follows.

The shift lines (:mod:`.shifts`) are fitted where ``gear_target`` changes; the gearbox engages the new gear
later (the plant's ``shift_delay_s``, one gear at a time). A model that drives the gear from the lines must
engage it late by that delay too, or every upshift comes early: over the WLTC held out of the paper campaign
(high-fidelity truth) the 158 shifts at 0.35 s each put 7 s of firing engine into the next gear up at a lower
speed and the predicted fuel 1 % low (docs/fidelity.md).

The delay is the time from a change of ``gear_target`` (``a -> b``, one gear, both forward) to the next change of
``gear_actual`` when that change is the same ``a -> b`` (so the gearbox was in ``a`` when the target changed) and
the target did not change in between (in a gearbox that shifts one gear at a time, a second step's lag from its
target change is not the delay, so those pairs are left out). Change times are midpoints between the last old and the
first new sample on a periodic channel (as in :func:`~benchtwin.identification.shifts.find_shift_events`). The
estimate is the median of the pairs' delays (robust to a pair cut by a flagged sample), its standard error
``1.2533 s / sqrt(n)`` (the median's asymptotic one for normal scatter).
"""

from __future__ import annotations

import numpy as np

from benchtwin.identification._fit import FitResult, ParameterEstimate
from benchtwin.identification._state_changes import state_changes
from benchtwin.recording import Recording

__all__ = ["SHIFT_DELAY_KEY", "identify_shift_delay", "shift_delay_pairs"]

#: the fit's name in an identification result
SHIFT_DELAY_KEY = "shifts.actuation"


def _times(rec: Recording, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ch = state_changes(rec[name])
    t = 0.5 * (ch.t_new + ch.t_old) if ch.periodic else ch.t_new
    return np.asarray(t, float), np.asarray(ch.old, int), np.asarray(ch.new, int)


def shift_delay_pairs(rec: Recording, *, max_delay_s: float = 2.0) -> np.ndarray:
    """Delays (s) from each one-gear target change to the actual gear's matching change.

    Parameters
    ----------
    rec:
        Recording with ``gear_target`` and ``gear_actual``.
    max_delay_s:
        A pair further apart than this is no actuation (e.g. a held gear released later): left out.

    Returns
    -------
    numpy.ndarray
        One delay per matched pair, in target-change order.
    """
    tt, to, tn = _times(rec, "gear_target")
    ta, ao, an = _times(rec, "gear_actual")
    out: list[float] = []
    for i in range(tt.size):
        if abs(int(tn[i]) - int(to[i])) != 1 or min(int(to[i]), int(tn[i])) < 1:
            continue
        j = int(np.searchsorted(ta, tt[i], side="left"))
        if j >= ta.size or ao[j] != to[i] or an[j] != tn[i]:
            continue
        if i + 1 < tt.size and tt[i + 1] <= ta[j]:  # the target moved on before the gearbox followed
            continue
        d = float(ta[j] - tt[i])
        if 0.0 <= d <= max_delay_s:
            out.append(d)
    return np.asarray(out, float)


def identify_shift_delay(rec: Recording, *, min_pairs: int = 5) -> FitResult:
    """The actuation delay ``delay_s`` from target to actual gear (see the module's text).

    Parameters
    ----------
    rec:
        Recording with ``gear_target`` and ``gear_actual``.
    min_pairs:
        Fewer matched pairs than this: a flagged result (``delay_s`` NaN).

    Returns
    -------
    FitResult
        ``delay_s`` (s); ``data["delays_s"]`` holds the pairs' delays.
    """
    d = shift_delay_pairs(rec)
    n = int(d.size)
    if n >= min_pairs:
        med = float(np.median(d))
        se = float(1.2533 * np.std(d, ddof=1) / np.sqrt(n))
    else:
        med = se = float("nan")
    est = ParameterEstimate("delay_s", med, se, (med - 1.96 * se, med + 1.96 * se), float("nan"), n, "s", [])
    fit = FitResult({"delay_s": est}, float("nan"), float("nan"), float("nan"), n, data={"delays_s": d})
    if n < min_pairs:
        fit.flag(f"{SHIFT_DELAY_KEY}: {n} target-to-actual gear change pair(s), need {min_pairs}")
    return fit
