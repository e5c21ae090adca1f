"""Encoding in blocks of plant time, so a Trace can be encoded chunk by chunk with the same bytes as at once.

A device encodes the campaign one :class:`Block` of plant time at a time (:data:`BLOCK_S`, fixed block edges
at multiples of it). What it draws comes from :func:`block_rng`: a generator keyed by the campaign seed, the
stream's name (the device) and the block index, so no draw depends on where a caller cut the Trace. What runs
on from one block to the next is carried in the block's ``state`` (one dict per device, kept by the
:class:`~benchtwin.sensors.ChunkEncoder`):

- LTI filter states (``lfilter`` ``zi``) and the filtered samples the next block's window still needs
  (:meth:`Block.filtered`);
- running integrals, e.g. the IVT-S charge and energy (:meth:`Block.accumulated`);
- cyclic counters and update counters (:meth:`Block.counter`);
- the reading a stuck output froze at (``measure``).

The block's ``trace`` is a window of the Trace: from ``tail_s`` before the block (what a latency reaches
back to) to the first sample at or after its end (what an interpolation just before the end needs). Tick
times come from the plant span ``[start_s, end_s)`` mapped to the device clock, so the blocks' ticks put end
to end are the ticks of the whole span.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from benchtwin.config.setup import ChannelErrors
from benchtwin.sensors.imperfections import _discrete_filter
from benchtwin.trace import Trace

__all__ = ["BLOCK_S", "Block", "block_rng", "step_of"]

#: length of one block of plant time, seconds (the unit of the keyed random draws)
BLOCK_S = 60.0


def block_rng(seed: int | None, stream: str, block: int) -> np.random.Generator:
    """The generator of one random stream (a device, a bus, a poll log) over one block of plant time.

    Parameters
    ----------
    seed:
        Campaign seed.
    stream:
        Name of the stream (the device's name, ``faults:<bus>``, ``modbus_poll``, ``thermo_pdo``).
    block:
        Block index (``floor(t / BLOCK_S)``; negative before time 0).
    """
    key = (zlib.crc32(stream.encode()), int(block) & 0xFFFFFFFF, 1 if block < 0 else 0)
    return np.random.default_rng(np.random.SeedSequence(0 if seed is None else int(seed), spawn_key=key))


def step_of(time_s: np.ndarray) -> float:
    """The plant step a filter is discretised at: the median spacing, rounded to 1 ns (the same for any chunk)."""
    if time_s.shape[0] < 2:
        return float("nan")
    return round(float(np.median(np.diff(time_s))), 9)


@dataclass
class Block:
    """One block of plant time a device encodes.

    Attributes
    ----------
    trace:
        The window of the Trace (see the module docstring).
    start_s, end_s:
        The block's plant span ``[start_s, end_s)``.
    index:
        Block index (the key of its random draws).
    final:
        The last block of the run (the run's end trims what needs time after it).
    rng:
        The device's generator for this block.
    state:
        The device's carried state (the same dict every block).
    first:
        Index of the window's first sample in the whole Trace.
    dt_s:
        The plant step filters are discretised at.
    """

    trace: Trace
    start_s: float
    end_s: float
    index: int
    final: bool
    rng: np.random.Generator
    state: dict[str, Any] = field(default_factory=dict)
    first: int = 0
    dt_s: float = float("nan")

    @classmethod
    def whole(cls, trace: Trace, rng: np.random.Generator) -> Block:
        """The whole Trace as one block drawing from ``rng`` (fresh state): a device run at once."""
        t = trace.time_s
        return cls(trace, float(t[0]), float(t[-1]) + 1e-9, 0, True, rng, {}, 0, step_of(t))

    def filtered(self, key: str, x: np.ndarray, errors: ChannelErrors) -> np.ndarray:
        """``x`` (on the window) through the channel's LTI model, the filter running on from the last block.

        The filter starts from steady state at the run's first sample; every sample is filtered once, in
        order, so the output does not depend on the blocks. ``bandwidth_hz <= 0`` returns ``x``.
        """
        if errors.bandwidth_hz <= 0 or x.size == 0 or not np.isfinite(self.dt_s):
            return x
        from scipy.signal import lfilter, lfilter_zi

        b, a = _discrete_filter(float(errors.bandwidth_hz), int(errors.filter_order), float(errors.damping),
                                float(self.dt_s))
        finite = np.isfinite(x)
        xf = x if finite.all() else np.where(finite, x, 0.0)
        carried = self.state.setdefault("lti", {}).get(key)
        if carried is None:
            done, zi, kept = 0, lfilter_zi(b, a) * xf[0], np.zeros(0)
        else:
            nxt, zi, kept_first, kept = carried
            done = nxt - self.first
            kept = kept[self.first - kept_first:]
        new, zf = lfilter(b, a, xf[done:], zi=zi) if done < x.size else (np.zeros(0), zi)
        y = np.concatenate([kept[:done], new])
        if not finite.all():
            y[~finite] = np.nan
        self.state["lti"][key] = (self.first + x.size, zf, self.first, y)
        return y

    def accumulated(self, key: str, increment: np.ndarray) -> np.ndarray:
        """Running sum on the window: ``s[k] = s[k-1] + increment[k]``, 0 at the run's first sample."""
        carried = self.state.setdefault("sum", {}).get(key)
        if carried is None:
            done, kept = 1, np.zeros(1)
        else:
            nxt, kept_first, kept = carried
            done = nxt - self.first
            kept = kept[self.first - kept_first:]
        new = np.cumsum(np.concatenate([kept[done - 1:done], increment[done:]]))[1:]
        y = np.concatenate([kept[:done], new])
        self.state["sum"][key] = (self.first + increment.size, self.first, y)
        return y

    def counter(self, key: str, n: int) -> np.ndarray:
        """The next ``n`` values of a running count (a frame or update counter), from 0 at the run's start."""
        c = self.state.setdefault("count", {})
        start = c.get(key, 0)
        c[key] = start + n
        return np.arange(start, start + n, dtype=np.int64)
