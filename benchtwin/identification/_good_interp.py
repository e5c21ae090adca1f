"""A channel's good samples interpolated at times, read around those times only (a channel read by blocks).

``np.interp(t, ts[ok], vs[ok])`` with ``ok`` the finite, unflagged samples needs the whole channel in memory; a
lazy channel of the acquisition's chunk files would be loaded whole (the pack temperature of ``battery.rc``: a
campaign's worth of samples per type B re-run). :func:`interp_good` reads the channel in parts of at most
:data:`~benchtwin.identification._windows.READ_SPAN_S` of the times, each part widened until a good sample at or
before its first time and one after its last (or the channel's end) are in it: every time then falls between the
same two good samples as on the whole channel, and ``np.interp`` uses only those two, so the numbers are the same
bit for bit.
"""

from __future__ import annotations

import numpy as np

from benchtwin.identification._windows import MARGIN_S, ordered_by_blocks, read_parts, reads_by_block, window_of
from benchtwin.recording import Channel

__all__ = ["count_good", "interp_good"]

#: samples read per block when counting good samples of a channel read by blocks
COUNT_BLOCK = 1 << 12


def _good(vs: np.ndarray, fl: np.ndarray) -> np.ndarray:
    return np.isfinite(vs) & (fl == 0)


def count_good(ch: Channel, at_least: int) -> int:
    """The number of finite, unflagged samples of ``ch``, capped at ``at_least`` (a channel read by blocks is read
    block by block, stopping there)."""
    if not reads_by_block(ch):
        return min(int(_good(ch.values, ch.flags).sum()), at_least)
    n = 0
    for a in range(0, len(ch), COUNT_BLOCK):
        _, vs, fl = ch.block(a, a + COUNT_BLOCK)
        n += int(_good(vs, fl).sum())
        if n >= at_least:
            break
    return min(n, at_least)


def interp_good(ch: Channel, t: np.ndarray) -> np.ndarray:
    """``np.interp(t, ch.timestamps[ok], ch.values[ok])``, ``ok`` the finite samples with zero flags.

    Parameters
    ----------
    ch:
        The channel (at least one good sample). A time-ordered channel read by blocks is read around parts of the
        times only; any other channel is read whole, as ``np.interp`` would.
    t:
        The times (the channel's clock).

    Raises
    ------
    ValueError
        The channel has no good sample (as ``np.interp`` on empty samples).
    """
    t = np.asarray(t, dtype=np.float64)
    if (t.size == 0 or not reads_by_block(ch) or not ordered_by_blocks(ch) or not np.all(np.isfinite(t))
            or np.any(np.diff(t) < 0)):
        ok = _good(ch.values, ch.flags)
        return np.interp(t, ch.timestamps[ok], ch.values[ok])
    n = len(ch)
    out = np.empty(t.shape)
    for i, j in read_parts(t):
        lo, hi = float(t[i]), float(t[j - 1])
        pad_lo = pad_hi = MARGIN_S
        while True:
            k0, ts, vs, fl = window_of(ch, lo - pad_lo, hi + pad_hi)
            ok = _good(vs, fl)
            tg = ts[ok]
            left = k0 == 0 or (tg.size > 0 and tg[0] <= lo)  # the good sample at or before lo, or the channel's start
            right = k0 + ts.size >= n or (tg.size > 0 and tg[-1] > hi)  # one after hi, or the channel's end
            if left and right:
                break
            if not left:
                pad_lo *= 2.0
            if not right:
                pad_hi *= 2.0
        if tg.size == 0:
            raise ValueError(f"channel {ch.name!r} has no good sample to interpolate")
        out[i:j] = np.interp(t[i:j], tg, vs[ok])
        del ts, vs, fl, ok, tg
    return out
