"""A channel's samples inside a few disjoint time spans, read a span's part at a time (never the channel whole).

The paper fits' battery hold fit (:func:`~benchtwin.validation.paper_r2.battery_hold_fit`) takes the samples of
the constant-speed holds: a long campaign (the paper campaign repeated) has many holds, far apart. Sliced into
memory, the holds' samples of every pack channel grow with the campaign; :func:`spans_view` gives the same samples as
a lazy channel whose blocks are read from the source channel's blocks, so what is read at a time is bounded by a
block of the fit's grid, not by the campaign.
"""

from __future__ import annotations

import bisect
import itertools

import numpy as np

from benchtwin.identification._windows import ordered_by_blocks, reads_by_block, window_of
from benchtwin.recording import Channel, LazyChannel

__all__ = ["span_ranges", "spans_view"]


def span_ranges(ch: Channel, spans: list[tuple[float, float]]) -> list[tuple[int, int]] | None:
    """Index ranges ``[i0, i1)`` of the samples with ``start <= t < end`` of each span, found by reads around the
    spans' ends; None when ``ch`` does not read by blocks, is not in time order, or the spans (taken in order) are
    not disjoint (the caller's whole path then).

    Parameters
    ----------
    ch:
        The source channel.
    spans:
        ``(start_s, end_s)`` spans, sorted by start.
    """
    if not reads_by_block(ch) or not ordered_by_blocks(ch):
        return None
    if any(b > c for (_a, b), (c, _d) in itertools.pairwise(spans)) or spans != sorted(spans):
        return None
    out = []
    for a, b in spans:
        i0, i1 = _first_at_or_after(ch, a), _first_at_or_after(ch, b)
        out.append((i0, max(i0, i1)))
    return out


def _first_at_or_after(ch: Channel, t: float) -> int:
    """The index of the first sample at or after ``t`` (``len(ch)`` when none) of a time-ordered channel read by
    blocks: read around ``t`` only (from the last sample strictly before it)."""
    k0, ts, _v, _f = window_of(ch, float(np.nextafter(t, -np.inf)), t)
    k = int(np.searchsorted(ts, t, side="left"))
    return k0 + k if k < ts.size else len(ch)  # the window ends at the first sample at or after t, if any


def spans_view(ch: Channel, ranges: list[tuple[int, int]]) -> LazyChannel:
    """The samples ``ranges`` of ``ch`` (:func:`span_ranges`) one after the other, as a lazy channel read by blocks:
    each block read takes the source's samples of the ranges it covers (a read of it whole takes them all)."""
    ranges = [(a, b) for a, b in ranges if b > a]
    starts = [0, *itertools.accumulate(b - a for a, b in ranges)]
    n = starts[-1]

    def part(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pieces = []
        k = max(bisect.bisect_right(starts, a) - 1, 0)
        while k < len(ranges) and starts[k] < b:
            lo, hi = max(a, starts[k]), min(b, starts[k + 1])
            if hi > lo:
                off = ranges[k][0] - starts[k]
                pieces.append(ch.block(lo + off, hi + off))
            k += 1
        if len(pieces) == 1:
            return pieces[0]
        if not pieces:
            t, v, f = ch.block(0, 0)
            return t, v, f
        return tuple(np.concatenate([p[j] for p in pieces]) for j in range(3))  # type: ignore[return-value]

    return LazyChannel(ch.name, ch.unit, ch.source, n, lambda: part(0, n), ch.value_texts, block_loader=part)
