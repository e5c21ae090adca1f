"""Channels stuck at one value over a whole Recording: a stuck sensor or a wrong signal mapping (a method reading one
is skipped, :func:`benchtwin.identification.run.identify_all`)."""

from __future__ import annotations

import numpy as np

from benchtwin.identification._signals import STATE_ROLES
from benchtwin.recording import Channel, Recording
from benchtwin.roles import unit_of_role

__all__ = ["STUCK_BLOCK", "STUCK_HEAD", "STUCK_MIN_SAMPLES", "stuck_channels"]

#: fewest samples over which a continuous channel that never changes is taken for a stuck sensor
STUCK_MIN_SAMPLES = 100
#: samples looked at first (a channel that changes among them is not stuck)
STUCK_HEAD = 4096


def stuck_channels(recording: Recording) -> dict[str, float]:
    """Continuous channels (torques, speeds, currents, voltages; not states) that hold one value over the whole
    Recording: a stuck sensor or a wrong signal mapping, never a measurement of a vehicle that was driven.

    Returns
    -------
    dict
        Channel name -> the value it is stuck at (channels with fewer than :data:`STUCK_MIN_SAMPLES` finite
        samples are not judged).
    """
    out: dict[str, float] = {}
    kept = recording.loaded()
    for name, ch in recording.channels.items():
        if name in STATE_ROLES or unit_of_role(name) == "" or len(ch) < STUCK_MIN_SAMPLES:
            continue
        head = ch.block(0, STUCK_HEAD)[1]
        head = head[np.isfinite(head)]
        # two different readings among the first ones settle it without a pass over the whole channel
        if not (head.size and bool(np.any(head != head[0]))):
            value = _stuck_value(ch, STUCK_BLOCK)
            if value is not None:
                out[name] = value
        if name not in kept:
            recording.drop([name])  # a lazy Recording: one channel in memory at a time
    return out


#: samples of a channel read at a time by :func:`stuck_channels` (a lazy channel read by blocks is never whole)
STUCK_BLOCK = 1 << 20


def _stuck_value(ch: Channel, block: int) -> float | None:
    """The value every finite sample of ``ch`` holds when there are at least :data:`STUCK_MIN_SAMPLES` of them and it
    is not zero, else None (read ``block`` samples at a time: a channel that changes is left at its first change)."""
    first: float | None = None
    n = 0
    for a in range(0, len(ch), block):
        v = ch.block(a, a + block)[1]
        v = v[np.isfinite(v)]
        if v.size and first is None:
            first = float(v[0])
        if bool(np.any(v != first)):  # False on an empty block
            return None
        n += int(v.size)
    if first is None or n < STUCK_MIN_SAMPLES or first == 0.0:
        return None
    return first
