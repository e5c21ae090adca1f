"""Eq. 30's samples kept only where the fit uses them: the common grid walked a block at a time.

:func:`~benchtwin.identification.battery.battery_samples` puts V, I and the displayed SOC on a grid over the whole
Recording (10 Hz: about 0.8 MB per array per paper campaign, six arrays and the SOC refinement's three more) and
the fit then keeps the constant drives' samples. :func:`used_samples` walks the same grid
(:class:`~benchtwin.identification._resample_blocks.StrictGrid`) a block at a time and keeps only the usable
points, with the charge counted from the current over every grid point (``refine_soc``'s ``Q``, the same running
sum carried from block to block) and the runs of consecutive usable points (``refine_soc``'s blocks): the same
numbers as the whole grid's, bit for bit.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from benchtwin.identification._resample_blocks import GRID_BLOCK, StrictGrid
from benchtwin.identification._signals import segment_mask
from benchtwin.recording import Recording
from benchtwin.segments import touched

__all__ = ["UsedSamples", "used_samples"]

NAMES = ("battery_voltage_v", "battery_current_a", "displayed_soc_pct")
#: grid points per block walked
BLOCK = GRID_BLOCK


@dataclass
class UsedSamples:
    """The usable grid points of eq. 30's samples.

    Attributes
    ----------
    t, v, i, soc:
        Time, pack voltage, current and displayed SOC at the usable points.
    q:
        The charge counted from the current over the whole grid (Ah, positive charging), at the usable points.
    runs:
        ``(a, b)`` index ranges (into the usable points) of runs of consecutive grid points.
    segs:
        Names of the segments searched that hold a grid point.
    n_bad:
        Grid points inside those segments left out as bad.
    """

    t: np.ndarray
    v: np.ndarray
    i: np.ndarray
    soc: np.ndarray
    q: np.ndarray
    runs: list[tuple[int, int]]
    segs: list[str]
    n_bad: int


def used_samples(rec: Recording, rate: float, kinds: tuple[str, ...] | None, block: int | None = None
                 ) -> UsedSamples | None:
    """Eq. 30's usable samples on the common grid at ``rate`` Hz, walked ``block`` points at a time; None when
    segments of ``kinds`` exist but no grid point falls in one (every sample is used then: the caller's whole path).

    Parameters
    ----------
    rec:
        The Recording (V, I and displayed SOC present).
    rate:
        The grid's rate, Hz.
    kinds:
        Segment kinds whose points are usable; None: every point.
    block:
        Grid points per block (default :data:`BLOCK`).
    """
    block = block or BLOCK
    grid = StrictGrid(rec, NAMES, rate)
    searched = [s for s in rec.segments if s.kind in kinds] if kinds else []
    hit = [False] * len(searched)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "v", "i", "soc", "q", "k")}
    n_bad = 0
    i_prev = t_prev = q_prev = 0.0
    for a in range(0, grid.size, block):
        t, d, bad = grid.block(a, min(a + block, grid.size))
        mask = segment_mask(rec, t, kinds) if kinds else None
        if mask is None:
            mask = np.ones(t.shape, dtype=bool)
        elif searched:
            hit = [h or x for h, x in zip(hit, touched(searched, t), strict=True)]
        # refine_soc's charge: dq[k] = -0.5 (I[k] + I[k-1]) (t[k] - t[k-1]) / 3600 (dq[0] = 0), Q its running sum
        cur = np.nan_to_num(d["battery_current_a"])
        if a == 0:
            dq = np.r_[0.0, -0.5 * (cur[1:] + cur[:-1]) * np.diff(t)] / 3600.0
            q = np.cumsum(dq)
        else:
            dq = -0.5 * (cur + np.r_[i_prev, cur[:-1]]) * np.diff(t, prepend=t_prev) / 3600.0
            q = np.cumsum(np.r_[q_prev, dq])[1:]  # the same additions, in the same order, as one running sum
        i_prev, t_prev, q_prev = float(cur[-1]), float(t[-1]), float(q[-1])
        use = mask & ~bad
        n_bad += int((mask & bad).sum())
        parts["t"].append(t[use])
        parts["v"].append(d["battery_voltage_v"][use])
        parts["i"].append(d["battery_current_a"][use])
        parts["soc"].append(d["displayed_soc_pct"][use])
        parts["q"].append(q[use])
        parts["k"].append(np.flatnonzero(use) + a)
    if searched and not any(hit):
        return None
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in parts.items()}
    k = cat["k"].astype(np.int64)
    cuts = np.r_[0, np.flatnonzero(np.diff(k) != 1) + 1, k.size] if k.size else np.zeros(1, dtype=np.int64)
    runs = [(int(x), int(y)) for x, y in itertools.pairwise(cuts)]
    segs = [s.name for s, h in zip(searched, hit, strict=True) if h]
    return UsedSamples(cat["t"], cat["v"], cat["i"], cat["soc"], cat["q"], runs, segs, n_bad)
