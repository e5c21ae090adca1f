"""The rounding draws of the type B propagation (:mod:`benchtwin.identification.uncertainty`): level-wise rounding
errors added to a Recording's channels, one Monte Carlo draw at a time (:func:`dithered`).

A component's draws are made in turn from one generator (:func:`drawn`: each draw's grid phase and level errors per
role) and can then be added in any order, on any thread (:func:`dithered_with`): the numbers of a draw do not depend
on where it runs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numba
import numpy as np

from benchtwin.identification._windows import reads_by_block, share_time_index
from benchtwin.recording import Channel, Flag, LazyChannel, Recording

if TYPE_CHECKING:
    from benchtwin.identification.uncertainty import Component

__all__ = ["BIN_STEPS", "ROUNDING_BLOCK", "dithered", "dithered_with", "drawn"]

#: width of the level intervals sharing one rounding error, in steps: a reading whose noise flickers it by
#: one step about a steady level keeps one error (its rounding is not dithered by that flicker)
BIN_STEPS = 2.0
#: samples read at a time by the rounding's pass over a channel read by blocks (its lowest and highest level)
ROUNDING_BLOCK = 1 << 16


@numba.njit(cache=True, nogil=True)
def _add_level_errors(values: np.ndarray, scaled: np.ndarray, phase: float, errors: np.ndarray,
                      positions: np.ndarray) -> np.ndarray:
    """``values`` plus, at each good sample (``positions``, or all), the error of its level ``floor(scaled + phase)``.

    One pass without temporaries, free of the GIL; the same operations as the NumPy expression
    ``values[good] + errors[np.floor(scaled + phase).astype(int)]``, so the same numbers.
    """
    if positions.size == 0:
        out = np.empty_like(values)
        for i in range(values.size):
            out[i] = values[i] + errors[math.floor(scaled[i] + phase)]
        return out
    out = values.copy()
    for j in range(positions.size):
        k = positions[j]
        out[k] = values[k] + errors[math.floor(scaled[j] + phase)]
    return out


class _Rounding:
    """What every draw of :func:`dithered` over one role shares: its good samples and their scaled levels.

    The scaling ``(v - lo) / (BIN_STEPS q)`` does not depend on the draw, only the grid phase added to it does,
    so the draws of one component compute it once (the same floating-point operations as a draw on its own,
    hence the same errors). The largest level index of a draw is that of the largest reading (``floor`` of a
    monotone expression), so the number of errors drawn is known without a maximum over the indices.

    A lazy channel that reads blocks from its store (:func:`reads_by_block`, the chunk files ``validate --out``
    identifies from) is not held: one pass by blocks finds ``lo`` and the top level (a minimum and a maximum, the
    same numbers block by block), and each draw is a lazy channel that adds the draw's errors to every block it
    reads (:meth:`moved_lazily`): the same per-sample operations, so the same values, and a re-run that reads
    windows of it never holds it whole.
    """

    def __init__(self, ch: Any, q: float) -> None:
        self.q = q
        #: whether the draws move blocks as they are read (the channel is never held whole)
        self.by_block = reads_by_block(ch)
        if self.by_block:
            self._scan_blocks(ch)
            return
        v = ch.values
        # the good samples only: a flagged sample (clipped, lost, out of range) is excluded by every method, so
        # its value must not move the grid of the others' rounding errors
        fin = ch.good
        self.usable = bool(fin.any()) and q > 0
        if not self.usable:
            return
        all_good = bool(fin.all())
        #: the good samples' indices (none: every sample is good)
        self.positions = np.empty(0, dtype=np.int64) if all_good else np.flatnonzero(fin).astype(np.int64)
        vf = v if all_good else v[fin]
        self.lo = float(vf.min())
        self.scaled = (vf - self.lo) / (BIN_STEPS * q)
        self.top = float(self.scaled.max())

    def _scan_blocks(self, ch: Any) -> None:
        """``lo`` (lowest good reading) and ``top`` (highest scaled level) of a channel read by blocks."""
        lo, hi = math.inf, -math.inf
        for a in range(0, len(ch), ROUNDING_BLOCK):
            _ts, v, f = ch.block(a, a + ROUNDING_BLOCK)
            vf = v[_good(v, f)]
            if vf.size:
                lo, hi = min(lo, float(vf.min())), max(hi, float(vf.max()))
        self.usable = math.isfinite(lo) and self.q > 0
        if self.usable:
            self.lo = lo
            # the maximum of (v - lo) / (2 q) over the samples is that of the largest v: floating-point subtraction
            # and division by a positive number are monotone, so this is the whole pass's maximum bit for bit
            self.top = float((np.float64(hi) - lo) / (BIN_STEPS * self.q))

    def _draw(self, rng: np.random.Generator) -> tuple[float, np.ndarray]:
        """One draw's grid phase and level errors (in this order from ``rng``)."""
        phase = rng.uniform(0.0, 1.0)
        n_levels = math.floor(self.top + phase) + 1
        return phase, rng.uniform(-0.5 * self.q, 0.5 * self.q, n_levels)

    def moved(self, ch: Any, drawn: tuple[float, np.ndarray]) -> Channel:
        """The channel with one draw (:meth:`_draw`: grid phase, level errors) of level-wise rounding errors added
        (see :func:`dithered`): in memory, or a lazy channel moving each block it reads for a channel read by blocks."""
        if self.by_block:
            return self._moved_lazily(ch, *drawn)
        phase, errors = drawn
        return ch.with_values(_add_level_errors(ch.values, self.scaled, phase, errors, self.positions))

    def _moved_lazily(self, ch: Any, phase: float, errors: np.ndarray) -> LazyChannel:
        """One draw as a lazy channel that adds the draw's errors to each block it reads (a channel read by blocks)."""
        scale = BIN_STEPS * self.q
        lo = self.lo

        def read(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            ts, v, f = ch.block(a, b)
            good = _good(v, f)
            if good.all():
                return ts, _add_level_errors(v, (v - lo) / scale, phase, errors, np.empty(0, dtype=np.int64)), f
            positions = np.flatnonzero(good).astype(np.int64)
            return ts, _add_level_errors(v, (v[good] - lo) / scale, phase, errors, positions), f

        out = LazyChannel(ch.name, ch.unit, ch.source, len(ch), lambda: read(0, len(ch)), ch.value_texts,
                          block_loader=read)
        share_time_index(out, ch)  # the same timestamps: the re-run finds spans without indexing them again
        return out


def _good(values: np.ndarray, flags: np.ndarray) -> np.ndarray:
    """:attr:`Channel.good` of a block: free of :meth:`Flag.bad` flags and finite."""
    return ((flags & int(Flag.bad())) == 0) & np.isfinite(values)


def dithered(recording: Recording, comp: Component, rng: np.random.Generator,
             shared: dict[str, _Rounding] | None = None) -> Recording:
    """One Monte Carlo draw of the rounding errors of the component's roles (GUM Supplement 1, JCGM 101).

    A reading rounded to a step ``q`` is off by an error uniform in ``+-q/2`` (JCGM 100 F.2.2.1) that is a
    function of the level: a steady point holds one error, a point at another level another. Each draw
    gives every interval of width ``BIN_STEPS q`` of the reading (on a grid of random phase) an independent
    error ``U(-q/2, q/2)`` and adds to each sample the error of its interval: a steady point moves as a
    whole (also when its noise flickers it by a step), points at other levels move independently, and a
    channel whose noise spreads it over many steps averages its errors out, as the rounding does.

    ``shared`` (role -> work shared by the draws, filled on first use) lets several draws of one component
    skip what they have in common; the draws are the same with or without it. A channel read by blocks from its
    store stays so: its draw is a lazy channel moving each block it reads (the same numbers, see :class:`_Rounding`).
    """
    shared = {} if shared is None else shared
    return dithered_with(recording, comp, shared, drawn(recording, comp, rng, shared))


def drawn(recording: Recording, comp: Component, rng: np.random.Generator,
          shared: dict[str, _Rounding]) -> dict[str, tuple[float, np.ndarray]]:
    """One draw's grid phase and level errors per role of ``comp`` whose rounding is usable, taken from ``rng`` role
    by role in the component's order (``shared`` filled on first use): what :func:`dithered` adds.

    Parameters
    ----------
    recording:
        The Recording.
    comp:
        The resolution component.
    rng:
        The generator the draw is taken from.
    shared:
        Role -> the rounding shared by the component's draws (:class:`_Rounding`, filled here on first use).
    """
    out = {}
    for role, q in zip(comp.roles, comp.steps, strict=True):
        r = shared.get(role)
        if r is None:
            r = shared[role] = _Rounding(recording.channels[role], q)
        if r.usable:
            out[role] = r._draw(rng)
    return out


def dithered_with(recording: Recording, comp: Component, shared: dict[str, _Rounding],
                  draw: Mapping[str, tuple[float, np.ndarray]]) -> Recording:
    """The Recording with the draw ``draw`` (:func:`drawn`, with the same ``shared``) added to its roles' channels.

    Parameters
    ----------
    recording:
        The Recording.
    comp:
        The resolution component drawn.
    shared:
        Role -> the rounding shared by the component's draws (filled by :func:`drawn`).
    draw:
        Role -> grid phase and level errors of the draw.
    """
    channels = dict(recording.channels)
    for role, d in draw.items():
        channels[role] = shared[role].moved(recording.channels[role], d)
    return Recording(channels=channels, segments=recording.segments, meta=recording.meta,
                     start_time=recording.start_time)
