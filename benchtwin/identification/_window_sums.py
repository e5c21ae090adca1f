"""Means of a channel's own samples over time windows, as running sums over the windows' samples laid end to end.

:meth:`~benchtwin.identification.steady.SteadyWindows.raw_average` sums each channel's good samples inside every
steady window. :func:`running_sums` does it for a run of windows and carries the sums on from where the previous
run stopped, so windows averaged group by group (:func:`window_groups`, one read of the channel per group) give the
very numbers of one pass over the whole channel.
"""

from __future__ import annotations

import numpy as np

from benchtwin.identification._signals import BAD_FLAGS, Shift, to_ref, to_source
from benchtwin.identification._sum_kernels import window_sums

__all__ = ["GROUP_S", "cut_windows", "running_sums", "window_groups"]


#: longest span of a group of steady windows averaged from one read of a channel (a channel at 500 Hz: 150 k samples)
GROUP_S = 300.0


def window_groups(starts: np.ndarray, ends: np.ndarray, span_s: float = GROUP_S) -> list[tuple[int, int]]:
    """Runs ``[i, j)`` of consecutive windows (in their order) each spanning at most ``span_s`` from its earliest
    start to its latest end (a longer window is a group of its own)."""
    out: list[tuple[int, int]] = []
    i = 0
    while i < starts.size:
        lo, hi, j = starts[i], ends[i], i + 1
        while j < starts.size and max(hi, ends[j]) - min(lo, starts[j]) <= span_s:
            lo, hi, j = min(lo, starts[j]), max(hi, ends[j]), j + 1
        out.append((i, j))
        i = j
    return out


def cut_windows(starts: np.ndarray, ends: np.ndarray, span_s: float = GROUP_S
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The windows ``[start, end)`` cut into pieces of at most ``span_s`` each (a window no longer stays whole), in
    order: ``(piece starts, piece ends, index of each window's first piece)``.

    A window's pieces hold its samples one after the other, split at the cut times (each sample in exactly one
    piece: the same edge search on both sides of a cut), so running sums over the pieces laid end to end are the
    very numbers of those over the windows (:func:`running_sums` adds the samples in the same order): a steady hold
    of half an hour is read in pieces, not at once."""
    starts = np.asarray(starts, dtype=float)
    ends = np.asarray(ends, dtype=float)
    # pieces per window: 1 when it fits (or is empty or not finite), else as many as cover it
    with np.errstate(invalid="ignore"):
        span = ends - starts
        count = np.where(np.isfinite(span) & (span > span_s), np.ceil(span / span_s), 1.0).astype(np.int64)
    first = np.concatenate(([0], np.cumsum(count)[:-1])).astype(np.int64)
    k = np.arange(int(count.sum())) - np.repeat(first, count)  # piece number within its window
    w = np.repeat(np.arange(starts.size), count)
    ps = np.where(k == 0, starts[w], starts[w] + k * span_s)
    last = k == count[w] - 1
    pe = np.where(last, ends[w], starts[w] + (k + 1) * span_s)
    return ps, pe, first


def running_sums(ts: np.ndarray, vals: np.ndarray, fl: np.ndarray, pair: tuple[np.ndarray, np.ndarray] | None,
                 shift: Shift, starts: np.ndarray, ends: np.ndarray, c0: float, n0: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Running sums of the good samples (or of the products with ``pair``'s) of the windows ``[start, end)`` (grid
    clock) laid one after the other, and of their counts, at each window's first sample and after the last one,
    continuing from ``c0`` and ``n0`` (so a run of windows done in groups gives the very numbers of one pass)."""
    # source samples inside each window [start, end) on the grid's clock, found on the shifted timestamps
    # near the window edges only (shifting the whole channel would cost a pass over every sample)
    lo = _edges(ts, shift, starts)
    hi = _edges(ts, shift, ends)
    if _kernel_fits(vals, fl, pair):  # one pass free of the GIL: the same terms in the same order (_sum_kernels)
        v2, f2 = pair if pair is not None else (vals, fl)
        return window_sums(vals, fl, v2, f2, pair is not None, int(BAD_FLAGS), lo.astype(np.int64),
                           np.maximum(hi, lo).astype(np.int64), float(c0), int(n0))
    # the samples of all windows, one after the other (windows may overlap: their samples then repeat)
    cnt_all = np.maximum(hi - lo, 0)
    off = np.concatenate(([0], np.cumsum(cnt_all)))
    sel = np.repeat(lo - off[:-1], cnt_all) + np.arange(off[-1])
    v = vals[sel]
    good = ((fl[sel] & BAD_FLAGS) == 0) & np.isfinite(v)
    if pair is not None:
        v2 = pair[0][sel]
        good &= ((pair[1][sel] & BAD_FLAGS) == 0) & np.isfinite(v2)
        v = v * v2
    cs = np.cumsum(np.concatenate(([c0], np.where(good, v, 0.0))))  # sequential: c0 + x0, (c0 + x0) + x1, ...
    cn = np.concatenate(([n0], n0 + np.cumsum(good)))
    return cs[off], cn[off]


def _kernel_fits(vals: np.ndarray, fl: np.ndarray, pair: tuple[np.ndarray, np.ndarray] | None) -> bool:
    """Whether :func:`~benchtwin.identification._sum_kernels.window_sums` takes these arrays (float64 values, uint16
    flags, one dimension): others keep the NumPy expression."""
    arrays = [(vals, fl)] if pair is None else [(vals, fl), pair]
    return all(v.dtype == np.float64 and f.dtype == np.uint16 and v.ndim == 1 and f.ndim == 1 for v, f in arrays)


def _edges(ts: np.ndarray, shift: Shift, times: np.ndarray) -> np.ndarray:
    """``np.searchsorted(to_ref(ts, shift), times, side="left")`` without shifting every sample of ``ts``: the
    search runs on ``ts`` and is corrected near each hit, where the shifted ``ts`` may round across ``times``."""
    if not shift:
        return np.searchsorted(ts, times, side="left")
    i = np.searchsorted(ts, to_source(times, shift), side="left")
    n = ts.size
    # a step back while the sample before still lies at or after the time, a step on while the sample lies before it
    while True:
        back = (i > 0) & (to_ref(ts[np.maximum(i - 1, 0)], shift) >= times)
        if not back.any():
            break
        i = np.where(back, i - 1, i)
    while True:
        on = (i < n) & (to_ref(ts[np.minimum(i, n - 1)], shift) < times)
        if not on.any():
            break
        i = np.where(on, i + 1, i)
    return i
