"""The changes of a state channel (e.g. ``gear_target``) read block by block: what the shift method once found on the
whole channel (its good samples' changes and whether they are periodic), holding one block at a time.

Of a campaign's target gear only the changes are kept (a few thousand), and whether the good samples come
periodically: the median of their time steps, found exactly by a radix selection over the blocks (16 bits a pass),
then the share of steps within 10 % of it. Inside the type B re-runs' store
(:func:`~benchtwin.identification._reuse.reusing`) the result for a channel a re-run does not move is worked out once
and handed out again (keyed by the channel object).
"""

from __future__ import annotations

from collections.abc import Hashable, Iterator
from dataclasses import dataclass

import numpy as np

from benchtwin.identification._reuse import reused
from benchtwin.recording import Channel, Flag

__all__ = ["StateChanges", "good_step_median", "state_changes"]

BLOCK = 1 << 16


@dataclass
class StateChanges:
    """Where the rounded good values of a state channel change."""

    #: time of the first good sample with the new state, and of the last with the old one
    t_new: np.ndarray
    t_old: np.ndarray
    #: the old and the new state
    old: np.ndarray
    new: np.ndarray
    #: whether the good samples come periodically (>= 10 of them, > 80 % of the steps within 10 % of their median)
    periodic: bool


def _good_blocks(ch: Channel, block: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """The good samples' timestamps and rounded values, block by block."""
    bad = int(Flag.bad())
    for a in range(0, len(ch), block):
        t, v, f = ch.block(a, min(a + block, len(ch)))
        ok = ((f & bad) == 0) & np.isfinite(v)
        yield t[ok], np.rint(v[ok]).astype(int)


def _steps(ch: Channel, block: int) -> Iterator[np.ndarray]:
    """The good samples' time steps, block by block (the step across a block edge included)."""
    last = None
    for t, _g in _good_blocks(ch, block):
        if not t.size:
            continue
        yield np.diff(t) if last is None else np.diff(np.concatenate([[last], t]))
        last = t[-1]


def _keys(x: np.ndarray) -> np.ndarray:
    b = np.ascontiguousarray(x, dtype=np.float64).view(np.uint64)
    return np.where((b >> np.uint64(63)).astype(bool), ~b, b | np.uint64(1 << 63))


def _ranked(ch: Channel, block: int, ranks: list[int]) -> list[float]:
    """The time steps of these sorted positions, exactly (four passes of 16 bits)."""
    prefix, left = [0] * len(ranks), list(ranks)
    for shift in (48, 32, 16, 0):
        counts = [np.zeros(1 << 16, np.int64) for _ in ranks]
        for d in _steps(ch, block):
            k = _keys(d)
            for r in range(len(ranks)):
                kk = k if shift == 48 else k[(k >> np.uint64(shift + 16)) == np.uint64(prefix[r])]
                counts[r] += np.bincount(((kk >> np.uint64(shift)) & np.uint64(0xFFFF)).astype(np.intp),
                                         minlength=1 << 16)
        for r in range(len(ranks)):
            cum = np.cumsum(counts[r])
            digit = int(np.searchsorted(cum, left[r], side="right"))
            left[r] -= int(cum[digit - 1]) if digit else 0
            prefix[r] = (prefix[r] << 16) | digit
    out = []
    for p in prefix:
        bits = p & ~(1 << 63) if p >> 63 else ~p & 0xFFFFFFFFFFFFFFFF
        out.append(float(np.array([bits], dtype=np.uint64).view(np.float64)[0]))
    return out


def good_step_median(ch: Channel, n: int, block: int = BLOCK) -> float:
    """``np.median`` of the ``n`` (> 0) time steps between the good samples of ``ch``, read by blocks."""
    a, b = _ranked(ch, block, [(n - 1) // 2, n // 2])
    return a if a == b else float(np.mean(np.array([a, b])))


def state_changes(ch: Channel, block: int = BLOCK, *, of: tuple[Channel, Hashable] | None = None) -> StateChanges:
    """The changes of the rounded good values of ``ch`` and whether its good samples are periodic, read ``block``
    samples at a time (:meth:`~benchtwin.recording.Channel.block`): the whole channel's numbers, bit for bit.

    ``of``: for a ``ch`` derived from another channel (e.g. its values above a level), that channel and what else
    ``ch`` depends on (e.g. the level). Inside :func:`~benchtwin.identification._reuse.reusing` the result is computed
    once per channel object (``ch``, or the channel ``of`` names, with that key) and handed out again (copies): the
    type B re-runs that do not move the channel find the nominal run's.
    """
    src, key = (ch, None) if of is None else of
    def compute() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
        r = _changes(ch, block)
        return r.t_new, r.t_old, r.old, r.new, r.periodic

    return StateChanges(*reused("state_changes", (src,), (block, key), compute))  # type: ignore[arg-type]


def _changes(ch: Channel, block: int) -> StateChanges:
    """:func:`state_changes` computed."""
    t_new, t_old, old, new = [], [], [], []
    n_good = 0
    last: tuple[float, int] | None = None
    for t, g in _good_blocks(ch, block):
        if not t.size:
            continue
        n_good += t.size
        if last is not None:
            t, g = np.concatenate([[last[0]], t]), np.concatenate([[last[1]], g])
        k = np.flatnonzero(np.diff(g) != 0) + 1
        t_new.append(t[k])
        t_old.append(t[k - 1])
        old.append(g[k - 1])
        new.append(g[k])
        last = (float(t[-1]), int(g[-1]))
    periodic = False
    if n_good >= 10:
        n = n_good - 1
        med = good_step_median(ch, n, block)
        if med > 0:
            within = sum(int(np.count_nonzero(np.abs(d - med) <= 0.1 * med)) for d in _steps(ch, block))
            periodic = float(np.float64(within) / n) > 0.8

    def cat(parts: list[np.ndarray], dtype: type) -> np.ndarray:
        return np.concatenate(parts) if parts else np.zeros(0, dtype)

    return StateChanges(cat(t_new, float), cat(t_old, float), cat(old, int), cat(new, int), periodic)
