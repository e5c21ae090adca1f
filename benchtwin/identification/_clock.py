"""Clock maps between a Recording's sources: the time to add to each source's timestamps to put it on the reference
clock (a constant offset, or an offset plus a drift when the acquisition measured a significant one), from the
offsets and drifts the acquisition reports in ``rec.meta``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from benchtwin.recording import Recording

__all__ = ["ClockShift", "Shift", "source_shifts", "to_ref", "to_source"]


@dataclass(frozen=True)
class ClockShift:
    """An affine clock map: ``offset_s + rate * t`` seconds added to a source's timestamps ``t`` (a constant
    offset plus a drift; ``rate`` is the drift in s/s, ppm * 1e-6)."""

    offset_s: float
    rate: float

    def __bool__(self) -> bool:
        return bool(self.offset_s or self.rate)


#: seconds added to a source's timestamps: a constant, or an affine map (:class:`ClockShift`)
Shift = float | ClockShift


def to_ref(ts: np.ndarray | float, shift: Shift) -> np.ndarray | float:
    """A source's timestamps ``ts`` on the reference clock (``ts + shift``, or the affine map's ``ts + offset + rate
    ts``); a plain constant shift gives the bits of ``ts + shift``."""
    if isinstance(shift, ClockShift):
        return ts + (shift.offset_s + shift.rate * ts)
    return ts + shift


def to_source(t: np.ndarray | float, shift: Shift) -> np.ndarray | float:
    """Reference-clock times ``t`` on the source's clock (the inverse of :func:`to_ref`)."""
    if isinstance(shift, ClockShift):
        return (t - shift.offset_s) / (1.0 + shift.rate)
    return t - shift


def source_shifts(rec: Recording) -> dict[str, Shift]:
    """Time to add to each source's timestamps to put it on one reference clock.

    The acquisition keeps every source on its own clock and reports the offsets it detected in
    ``rec.meta["clock_offsets_s"]`` (``"a->b"``: time to add to ``a``'s timestamps to line them up
    with ``b``). The reference is the vehicle CAN's clock (else the first source by name); the
    acquisition host clock (``"acquisition"``) is taken as that reference, since the bus loggers
    stamp frames on it. An offset key names a source exactly or by a unique part of its name
    (``"pressure"`` for ``"brake_pressure"``). Sources not linked to the reference get no shift.

    A pair's drift (``meta["clock_drift_ppm"]``, with its standard error ``meta["clock_drift_se_ppm"]`` and the
    time its offset holds ``meta["clock_offset_time_s"]``) makes its offset ``offset + drift (t - t_ref)``, and the
    shift a :class:`ClockShift`, when the drift is significant: ``|drift| > sqrt(2) se``. Left out, a drift ``d``
    leaves an error ``d (t - t_ref)`` in the mapped times; applied, the estimate's ``(d_hat - d) (t - t_ref)``,
    of mean square ``se^2 (t - t_ref)^2``. Since ``d_hat^2 - se^2`` estimates ``d^2`` without bias, applying it is
    expected to do better when ``d_hat^2 - se^2 > se^2``. A drift without the other two keys (an older
    recording) is not applied. Shifts without an applied drift are plain floats.
    """
    meta = rec.meta if isinstance(rec.meta, dict) else {}
    offsets = meta.get("clock_offsets_s")
    sources = {c.source for c in rec.channels.values() if c.source}
    if not offsets or not isinstance(offsets, dict) or not sources:
        return {}

    def table(key: str) -> dict:
        val = meta.get(key)
        return val if isinstance(val, dict) else {}

    drifts, errors, times = table("clock_drift_ppm"), table("clock_drift_se_ppm"), table("clock_offset_time_s")

    def node(name: str) -> str:
        if name in sources:
            return name
        found = [s for s in sources if name and name in s]
        return found[0] if len(found) == 1 else name

    def number(x: object) -> bool:
        return isinstance(x, int | float) and bool(np.isfinite(x))

    edges = []  # (a, b, c, r): a's offset to b at a's time t is c + r t
    for key, val in offsets.items():
        if not isinstance(key, str) or "->" not in key or not number(val):
            continue
        a, b = key.split("->", 1)
        c, r = float(val), 0.0
        d, se, t_ref = drifts.get(key), errors.get(key), times.get(key)
        if number(d) and number(se) and number(t_ref) and abs(d) > np.sqrt(2.0) * se:
            r = float(d) * 1e-6
            c = float(val) - r * float(t_ref)
        edges.append((node(a), node(b), c, r))
    ref = "vehicle_can" if "vehicle_can" in sources else sorted(sources)[0]
    shift: dict[str, tuple[float, float]] = {ref: (0.0, 0.0), "acquisition": (0.0, 0.0)}
    changed = True
    while changed:
        changed = False
        for a, b, c, r in edges:
            if b in shift and a not in shift:
                shift[a], changed = (shift[b][0] + c, shift[b][1] + r), True
            elif a in shift and b not in shift:
                shift[b], changed = (shift[a][0] - c, shift[a][1] - r), True
    out: dict[str, Shift] = {}
    for k, (c, r) in shift.items():
        if k in sources and (c != 0.0 or r != 0.0):
            out[k] = ClockShift(c, r) if r != 0.0 else c
    return out
