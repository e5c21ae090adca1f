""":func:`~benchtwin.identification._signals.strict_resample` on a Recording read by blocks: no channel read whole.

The methods that need a whole campaign on one grid (the torque converter's quasi-steady selection, the battery's
fit) resample every channel at a few hertz: the grid is small, the channels are not (the shaft torque at 500 Hz).
:func:`resample_strict` builds the very grid and the very numbers of ``strict_resample`` (``Recording.resample``'s
interpolation or hold, the bad samples next to each grid point, the gap mask with its strided typical step), reading
each channel around one block of grid points at a time (``_windows.window_of``). A Recording whose channels are in
memory, or not in time order, or not read by blocks, goes through ``strict_resample`` itself.

With ``shifts`` (:func:`~benchtwin.identification._signals.source_shifts`) the grid is the reference clock's and
each channel is sampled at the grid times on its own clock (a constant offset, or offset and drift), as ``gather``
aligns its channels; without them the channels' own timestamps are taken as one clock.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from benchtwin.identification._reuse import reused
from benchtwin.identification._signals import Shift, native_rate, strict_resample, to_ref, to_source
from benchtwin.identification._windows import (
    MARGIN_S,
    channel_bounds,
    ordered_by_blocks,
    reads_by_block,
    time_index,
    window_of,
)
from benchtwin.recording import Channel, Flag, Recording

__all__ = ["GRID_BLOCK", "StrictGrid", "grid_times", "rate_of", "resample_strict"]

#: grid points resampled at a time (at 10 Hz: 819 s, a 500 Hz channel's 410 k samples read around them)
GRID_BLOCK = 8192

#: timestamps read at a time for the typical step of the gap mask
_STEP_BLOCK = 1 << 16


def _typical_step(ch: Channel, s: Shift = 0.0) -> float:
    """``np.median(dt[:: max(1, dt.size // 20000)])`` of ``dt = np.diff(to_ref(ch.timestamps, s))`` (the steps on
    the reference clock, as ``strict_resample`` finds them on the shifted channel), read block by block (kept with the
    time index of a channel read by blocks, per shift: a property of its times, which the type B re-runs share)."""
    index = time_index(ch) if reads_by_block(ch) else None
    if index is not None and index.n == len(ch):
        step = index.typical_step if not s else index.shifted_steps.get(s)
        if step is not None:
            return step
    if index is not None and index.n == len(ch) and len(ch) > 1:
        # the strided timestamps kept with the index: a moved copy's new clock map (the converter's shaft clock per
        # draw) reads no block; the same steps, elementwise, and the same median
        if index.step_pairs is None:
            index.step_pairs = _step_pairs(ch)
        x, y = index.step_pairs
        step = float(np.median(to_ref(y, s) - to_ref(x, s) if s else y - x))
    else:
        step = _typical_step_of(ch, s)
    if index is not None:
        if s:
            index.shifted_steps[s] = step
        else:
            index.typical_step = step
    return step


def _typical_step_of(ch: Channel, s: Shift = 0.0) -> float:
    n = len(ch)
    stride = max(1, (n - 1) // 20000)
    picked = []
    for a in range(0, n - 1, _STEP_BLOCK):
        b = min(a + _STEP_BLOCK, n - 1)  # the diffs a .. b-1 need timestamps a .. b
        first = -(-a // stride) * stride  # the first strided diff index at or after a
        if first >= b:
            continue
        ts = ch.block(first, b + 1)[0]
        # on the reference clock (elementwise, as the shifted channel's); a copy: a view would keep the block's steps
        picked.append(np.diff(to_ref(ts, s) if s else ts)[::stride].copy())
    return float(np.median(np.concatenate(picked)))


def _step_pairs(ch: Channel) -> tuple[np.ndarray, np.ndarray]:
    """``(ts[j], ts[j + 1])`` at the strided steps ``j`` of :func:`_typical_step_of`, read block by block."""
    n = len(ch)
    stride = max(1, (n - 1) // 20000)
    xs, ys = [], []
    for a in range(0, n - 1, _STEP_BLOCK):
        b = min(a + _STEP_BLOCK, n - 1)
        first = -(-a // stride) * stride
        if first >= b:
            continue
        ts = ch.block(first, b + 1)[0]
        xs.append(ts[:-1][::stride].copy())
        ys.append(ts[1:][::stride].copy())
    return np.concatenate(xs), np.concatenate(ys)


def _shifted(rec: Recording, names: Sequence[str], shifts: Mapping[str, Shift]) -> Recording:
    """The channels ``names`` of ``rec`` with their timestamps on the reference clock (copies of the shifted ones)."""
    out = Recording()
    for n in names:
        c = rec[n]
        s = shifts.get(c.source, 0.0)
        out.add(Channel(c.name, c.unit, to_ref(c.timestamps, s) if s else c.timestamps, c.values, c.flags, c.source))
    return out


def resample_strict(rec: Recording, names: Sequence[str], rate_hz: float, *, hold: tuple[str, ...] = (),
                    shifts: Mapping[str, Shift] | None = None
                    ) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """``strict_resample(rec, names, rate_hz, hold=hold)``, reading lazy channels around blocks of grid points.

    Parameters
    ----------
    rec, names, rate_hz, hold:
        As for :func:`~benchtwin.identification._signals.strict_resample`.
    shifts:
        Source -> clock shift onto the reference clock (none: the timestamps as they are).

    Returns
    -------
    t, values, bad
        The same arrays as ``strict_resample``.
    """
    names = list(names)
    chans = [rec[n] for n in names]
    sh = [(shifts or {}).get(c.source, 0.0) for c in chans]
    if not all(reads_by_block(c) and len(c) >= 3 for c in chans) or not all(ordered_by_blocks(c) for c in chans):
        if any(sh):
            return strict_resample(_shifted(rec, names, shifts or {}), names, rate_hz, hold=hold)
        return strict_resample(rec, names, rate_hz, hold=hold)
    bounds = [channel_bounds(c) for c in chans]  # first and last timestamps (read from the ends)
    lo = max(float(to_ref(b[0], s)) for b, s in zip(bounds, sh, strict=True))
    hi = min(float(to_ref(b[1], s)) for b, s in zip(bounds, sh, strict=True))
    if not hi > lo:  # its error
        return strict_resample(_shifted(rec, names, shifts or {}) if any(sh) else rec, names, rate_hz, hold=hold)
    t = np.arange(lo, hi, 1.0 / rate_hz)
    out = {n: np.empty(t.shape) for n in names}
    bad = np.zeros(t.shape, dtype=bool)
    held = set(hold)
    for c, (first, last), s in zip(chans, bounds, sh, strict=True):
        step = None if c.name in held else _typical_step(c, s)
        for a in range(0, t.size, GRID_BLOCK):
            v, blk = _channel_block(c, first, last, s, step, t[a:a + GRID_BLOCK])
            out[c.name][a:a + GRID_BLOCK] = v
            bad[a:a + GRID_BLOCK] |= blk
    return t, out, bad


def _channel_block(c: Channel, first: float, last: float, s: Shift, step: float | None, tb: np.ndarray,
                   at_key: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One channel at the grid times ``tb`` (reference clock) and their bad mask, read around them.

    ``first``, ``last``: the channel's first and last timestamps (its own clock); ``s``: its clock shift; ``step``:
    its typical step on the reference clock (:func:`_typical_step` with ``s``; None: a held state, no gap mask).

    The samples around the block are read on the channel's own clock, then their timestamps put on the reference
    clock (``to_ref``) and the grid times ``tb`` looked up among them: the very numbers of ``strict_resample`` on the
    shifted channel (``_shifted``), which the whole path takes. (The grid times put on the channel's clock instead,
    ``to_source(tb)``, interpolate with other weights in the last bits: 1,213 of the quick campaign's 9,217 shaft
    torques differed by up to 5e-10 N m with the shaft clock's drift, so a Recording read by blocks and the same
    Recording in memory gave converter fits that differed in the last bits.)

    ``at_key`` (a channel read by blocks, whose time index the type B re-runs' moved copies share): everything the
    grid times depend on, under which the time-only part (:func:`_block_at`) is kept in the type B store; a draw that
    moves the channel's values then searches no timestamps (the same arrays: only the values are read again)."""
    if s:
        lo_src, hi_src = to_source(float(tb[0]), s), to_source(float(tb[-1]), s)
        _, ts, vs, fl = window_of(c, float(lo_src) - MARGIN_S, float(hi_src) + MARGIN_S)
        ts = to_ref(ts, s)  # elementwise: the shifted channel's timestamps, bit for bit
        first, last = float(to_ref(first, s)), float(to_ref(last, s))
    else:
        _, ts, vs, fl = window_of(c, float(tb[0]) - MARGIN_S, float(tb[-1]) + MARGIN_S)
    if at_key is None:
        k, early, late, nxt, gap = _block_at(ts, first, last, step, tb)
    else:  # a function of the timestamps (the time index's) and of the grid times only: shared by the re-runs
        k, early, late, nxt, gap = reused("strict_block_at", (time_index(c),), at_key,  # type: ignore[arg-type]
                                          lambda: _block_at(ts, first, last, step, tb))
    # Channel.at on the samples around the block (the same bracketing samples as on the whole channel)
    if step is None:
        v = vs[k].copy()
    else:
        v = np.interp(tb, ts, vs)
    v[early] = np.nan
    v[late] = np.nan
    bad_bits = int(Flag.bad())
    # Recording.resample: not finite, or flagged at the sample at or before
    blk = ~np.isfinite(v) | ((fl[k] & bad_bits) != 0)
    if step is not None:
        # strict_resample: the sample at or after flagged bad or not finite, and the gap mask
        blk |= ((fl[nxt] & bad_bits) != 0) | ~np.isfinite(vs[nxt])
        blk |= gap
    return v, blk


def _block_at(ts: np.ndarray, first: float, last: float, step: float | None, tb: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """What :func:`_channel_block` takes from the window's timestamps ``ts`` and the grid times ``tb`` alone (both on
    the reference clock, as ``first`` and ``last``): the sample at or before each grid time (clipped), the grid times
    before the channel's first value (``idx < 0`` for a hold, before ``first`` for an interpolation) and after its
    last, and for an interpolation the sample at or after each grid time (clipped) and the gap mask (None for a
    hold). A type B re-run moves values, never timestamps: the draws of one component get these from the store (a
    few arrays as long as the block, not the window's timestamps, which are read again with the values)."""
    # the sample at or before each grid time (one search, used by the hold, the flags and the gap mask)
    idx = np.searchsorted(ts, tb, side="right") - 1
    k = np.clip(idx, 0, ts.size - 1)
    early = idx < 0 if step is None else tb < first
    late = tb > last
    if step is None:
        return k, early, late, None, None
    nxt = np.clip(np.searchsorted(ts, tb, side="left"), 0, ts.size - 1)
    # gap_mask: the grid point inside a step longer than 3 typical steps
    inside = (idx >= 0) & (idx < ts.size - 1)
    gap = np.zeros(tb.shape, dtype=bool)
    gap[inside] = (np.diff(ts)[idx[inside]] > 3.0 * step) & (tb[inside] > ts[idx[inside]])
    return k, early, late, nxt, gap




def grid_times(lo: float, step: float, i0: int, i1: int) -> np.ndarray:
    """``np.arange(lo, hi, step)[i0:i1]`` without the rest of the grid: numpy's own fill, ``lo + i * delta`` with
    ``delta = (lo + step) - lo`` (the second point ``lo + step``)."""
    i = np.arange(i0, i1)
    out = lo + i * ((lo + step) - lo)
    out[i == 0] = lo
    out[i == 1] = lo + step
    return out


class StrictGrid:
    """:func:`resample_strict`'s grid read a block of grid points at a time: the very times, values and bad mask
    of its points ``i0 .. i1 - 1``, with no array as long as the grid.

    A Recording that :func:`resample_strict` resamples whole (channels in memory, not in time order or not read by
    blocks) is resampled whole once, and its blocks are slices of that.

    Parameters
    ----------
    rec, names, rate_hz, hold, shifts:
        As for :func:`resample_strict`.
    """

    def __init__(self, rec: Recording, names: Sequence[str], rate_hz: float, *, hold: tuple[str, ...] = (),
                 shifts: Mapping[str, Shift] | None = None) -> None:
        self.names = list(names)
        self._chans = [rec[n] for n in self.names]
        self._sh = [(shifts or {}).get(c.source, 0.0) for c in self._chans]
        self._whole: tuple[np.ndarray, dict[str, np.ndarray], np.ndarray] | None = None
        lazy = all(reads_by_block(c) and len(c) >= 3 for c in self._chans) \
            and all(ordered_by_blocks(c) for c in self._chans)
        if lazy:
            self._bounds = [channel_bounds(c) for c in self._chans]
            self.lo = max(float(to_ref(b[0], s)) for b, s in zip(self._bounds, self._sh, strict=True))
            hi = min(float(to_ref(b[1], s)) for b, s in zip(self._bounds, self._sh, strict=True))
            lazy = hi > self.lo
        if not lazy:  # resample_strict's own whole path (and its errors)
            self._whole = resample_strict(rec, self.names, rate_hz, hold=hold, shifts=shifts)
            self.size = int(self._whole[0].size)
            return
        self.step = 1.0 / rate_hz
        self.size = int(np.ceil((hi - self.lo) / self.step))  # np.arange's length
        held = set(hold)
        self._steps = [None if c.name in held else _typical_step(c, s)
                       for c, s in zip(self._chans, self._sh, strict=True)]

    def times(self, i0: int, i1: int) -> np.ndarray:
        """The times of grid points ``i0 .. i1 - 1`` (no channel read)."""
        return self._whole[0][i0:i1] if self._whole is not None else grid_times(self.lo, self.step, i0, i1)

    def block(self, i0: int, i1: int) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
        """Grid points ``i0 .. i1 - 1``: their times, each channel's values and the bad mask."""
        if self._whole is not None:
            t, d, bad = self._whole
            return t[i0:i1], {n: v[i0:i1] for n, v in d.items()}, bad[i0:i1]
        t = self.times(i0, i1)
        out, bad = {}, np.zeros(t.shape, dtype=bool)
        if t.size == 0:
            return t, {n: np.empty(0) for n in self.names}, bad
        for c, (first, last), s, step in zip(self._chans, self._bounds, self._sh, self._steps, strict=True):
            # the grid times are those of (lo, step, i0, i1) (grid_times): keyed by them and the channel object, a
            # channel a type B re-run does not move is read around the block once for all re-runs (see _reuse)
            key = (float(first), float(last), s, step, self.lo, self.step, i0, i1)
            out[c.name], blk = reused("strict_block", (c,), key,  # type: ignore[arg-type]
                                      lambda c=c, first=first, last=last, s=s, step=step, key=key:
                                      _channel_block(c, first, last, s, step, t, key))
            bad |= blk
        return t, out, bad


def _diff_bits(ch: Channel):  # type: ignore[no-untyped-def]
    """The channel's time steps block by block, as the bit patterns of the (non-negative) doubles: they sort alike."""
    n = len(ch)
    for a in range(0, n - 1, _STEP_BLOCK):
        ts = ch.block(a, min(a + _STEP_BLOCK, n - 1) + 1)[0]
        yield np.diff(ts).view(np.uint64)


def _ranked_steps(ch: Channel, ranks: tuple[int, ...]) -> list[float] | None:
    """The time steps of these ranks (ascending), exactly: a radix selection on 16 bits a pass, four passes over
    the channel for all the ranks together. None when a step is not finite."""
    prefix = [np.uint64(0)] * len(ranks)
    left = list(ranks)
    for shift in (48, 32, 16, 0):
        counts = [np.zeros(1 << 16, dtype=np.int64) for _ in ranks]
        for bits in _diff_bits(ch):
            if shift == 48 and not np.all(np.isfinite(bits.view(np.float64))):
                return None
            for r in range(len(ranks)):
                mine = bits if shift == 48 else bits[(bits >> np.uint64(shift + 16)) == prefix[r]]
                counts[r] += np.bincount(((mine >> np.uint64(shift)) & np.uint64(0xFFFF)).astype(np.int64),
                                         minlength=1 << 16)
        for r in range(len(ranks)):
            cum = np.cumsum(counts[r])
            digit = int(np.searchsorted(cum, left[r], side="right"))  # the bucket holding the rank
            left[r] -= int(cum[digit - 1]) if digit else 0
            prefix[r] = (prefix[r] << np.uint64(16)) | np.uint64(digit)
    return [float(np.array([p], dtype=np.uint64).view(np.float64)[0]) for p in prefix]


def rate_of(ch: Channel, *, max_hz: float = 200.0) -> float:
    """:func:`~benchtwin.identification._signals.native_rate` (the median time step, capped), found without reading
    a channel read by blocks whole (the same median: ``np.median`` of the steps, selected exactly)."""
    n = len(ch)
    if n < 3 or not reads_by_block(ch) or not ordered_by_blocks(ch):
        return native_rate(ch, max_hz=max_hz)
    index = time_index(ch)  # the median step is kept with it: the type B re-runs share it
    if index.median_step is None:
        m = n - 1
        steps = _ranked_steps(ch, (m // 2,) if m % 2 else (m // 2 - 1, m // 2))
        if steps is None:
            return native_rate(ch, max_hz=max_hz)
        index.median_step = float(np.median(np.array(steps)))  # one, or the mean of the two middle ones
    d = index.median_step
    return min(1.0 / d, max_hz) if d > 0 else 10.0
