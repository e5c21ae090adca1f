"""Why a gear has no transmission model of its own on a bench whose telemetry clipped: the clip guard's flags per gear.

The telemetry's AD module sets its clip bit when the shaft torque leaves the gain's range (K_TEL 8000: +-273 Nm on
the paper's shaft, Table 2); the chain turns it into ``Flag.SATURATED`` and every method leaves flagged samples out,
the steady windows of eq. 13-17 among them. A gear whose ramp-ups climb past the range keeps only its steps below
it: too few steady points for eq. 14 (``InsufficientDataError``), or none, and the converter method then reads that
gear through a borrowed model (:mod:`~benchtwin.identification.torque_converter_borrowed`). :func:`clip_causes`
traces it from the Recording alone: per gear, the shaft-torque samples flagged ``SATURATED`` in the tests the
transmission method searches (ramp-ups and constant drives), with the gear engaged and the lock-up closed (the
states eq. 14's points need), and the range they clipped at, read from the data (the largest ``|value|`` of those
samples: the rail). Identification does not read the setup: the range is what the data show.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from benchtwin.identification._fit import IdentificationResult
from benchtwin.identification.keys import FitKey
from benchtwin.recording import Flag, Recording
from benchtwin.segments import inside_any

__all__ = ["CLIP_KINDS", "ClipCause", "clip_causes", "clipped_by_gear"]

#: the tests the transmission method searches for its steady points (``transmission_points``' default kinds)
CLIP_KINDS = ("ramp_up", "constant_drive")
#: samples of the shaft torque read at a time
_BLOCK = 1 << 20


@dataclass(frozen=True)
class ClipCause:
    """A gear's eq. 14 missing because the telemetry clipped in its tests.

    Attributes
    ----------
    gear:
        The gear.
    clipped_samples:
        Shaft-torque samples flagged ``SATURATED`` in the searched tests with the gear engaged and the lock-up
        closed (excluded from every fit).
    clipped_s, engaged_s:
        Their time (s, at the channel's median sample spacing), and the time the gear was engaged with the lock-up
        closed in those tests (s, on the gear channel's samples).
    range_nm:
        The range the shaft torque clipped at: the largest ``|value|`` of the clipped samples (Nm).
    fit_error:
        What the gear's drive fit said (its error, or that it had no steady point at all).
    """

    gear: int
    clipped_samples: int
    clipped_s: float
    engaged_s: float
    range_nm: float
    fit_error: str

    def reason(self) -> str:
        """The cause in words."""
        return (f"gear {self.gear} clipped: K_TEL range +-{self.range_nm:.0f} Nm exceeded in gear {self.gear} "
                f"({self.clipped_samples} shaft-torque samples, {self.clipped_s:.1f} s of its {self.engaged_s:.1f} s "
                f"with the lock-up closed in the ramp-ups and drives, flagged SATURATED and excluded), so no "
                f"transmission model of its own: {self.fit_error}")


def clipped_by_gear(rec: Recording, *, role: str = "shaft_torque_nm", kinds: Sequence[str] = CLIP_KINDS
                    ) -> dict[int, ClipCause]:
    """Per gear, the clipped shaft-torque samples in the searched tests (``fit_error`` left empty).

    Parameters
    ----------
    rec:
        The Recording (``gear_actual`` and ``role`` needed; ``lockup_closed`` used when present).
    role:
        The torque channel whose ``SATURATED`` samples count.
    kinds:
        The tests searched; a Recording without a segment of these kinds is searched whole.

    Returns
    -------
    dict
        Gear -> :class:`ClipCause` for the gears with at least one clipped sample.
    """
    if role not in rec or "gear_actual" not in rec:
        return {}
    kept = rec.loaded()
    try:
        segs = [s for s in rec.segments if s.kind in kinds]
        ch = rec[role]
        ts, vs = [], []
        step = float("nan")
        for a in range(0, len(ch), _BLOCK):
            t, v, f = ch.block(a, a + _BLOCK)
            if a == 0 and t.size > 1:
                step = float(np.median(np.diff(t)))
            sat = (f & int(Flag.SATURATED)) != 0
            if segs:
                sat &= inside_any(segs, t)
            ts.append(t[sat])
            vs.append(np.abs(v[sat]))
        t_sat, v_sat = np.concatenate(ts), np.concatenate(vs)
        if t_sat.size == 0:
            return {}
        gch = rec["gear_actual"]
        closed = rec["lockup_closed"] if "lockup_closed" in rec else None  # noqa: SIM401 (no Recording.get)
        gear = np.round(gch.at(t_sat, hold=True))
        engaged = closed.at(t_sat, hold=True) > 0.5 if closed is not None else np.ones(t_sat.shape, dtype=bool)
        # the time each gear was engaged with the lock-up closed in the searched tests, on the gear channel's samples
        tg = gch.timestamps
        dt = np.diff(tg, append=tg[-1])
        g_all = np.round(gch.values)
        on = inside_any(segs, tg) if segs else np.ones(tg.shape, dtype=bool)
        if closed is not None:
            on &= closed.at(tg, hold=True) > 0.5
        out = {}
        for k in sorted({int(x) for x in gear[np.isfinite(gear) & engaged] if x >= 1}):
            m = engaged & (gear == k)
            out[k] = ClipCause(k, int(m.sum()), float(m.sum() * step) if np.isfinite(step) else float("nan"),
                               float(dt[on & (g_all == k)].sum()), float(v_sat[m].max()), "")
        return out
    finally:
        rec.drop([n for n in (role, "gear_actual", "lockup_closed") if n in rec and n not in kept])


def clip_causes(rec: Recording, result: IdentificationResult, gears: Iterable[int], *,
                role: str = "shaft_torque_nm") -> dict[int, ClipCause]:
    """The gears among ``gears`` without a drive transmission fit of their own whose tests the telemetry clipped.

    A gear counts when its drive fit ``transmission.gear<k>`` is missing from ``result.fits`` (its error, or no
    steady point at all) and :func:`clipped_by_gear` finds clipped samples with it engaged and the lock-up closed:
    the clip guard's exclusion is what left eq. 14 without points there.

    Parameters
    ----------
    rec:
        The Recording the transmission was identified on.
    result:
        The identification result holding the transmission fits and errors.
    gears:
        The gears to explain (e.g. the converter's gears left on a borrowed, uncalibrated model).
    role:
        The torque channel (see :func:`clipped_by_gear`).
    """
    wanted = [int(k) for k in gears if str(FitKey.transmission(int(k))) not in result.fits]
    if not wanted:
        return {}
    found = clipped_by_gear(rec, role=role)
    out = {}
    for k in wanted:
        if k in found:
            err = result.errors.get(str(FitKey.transmission(k)), "no steady point with the lock-up closed")
            c = found[k]
            out[k] = ClipCause(k, c.clipped_samples, c.clipped_s, c.engaged_s, c.range_nm, err)
    return out
