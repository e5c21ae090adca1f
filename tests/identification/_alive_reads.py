"""Block reads of lazy channels, tracked: the most bytes of them alive at once (the bounded-read tests' probe)."""

from __future__ import annotations

import weakref

import numpy as np

from benchtwin.recording import Channel, LazyChannel


class AliveReads:
    """Block reads of a Recording's lazy channels: the most bytes of them alive at once."""

    def __init__(self) -> None:
        self.alive = 0
        self.most = 0

    def track(self, arrays: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
        """Count ``arrays`` as alive until each is garbage; return them unchanged."""
        for a in arrays:
            self.alive += a.nbytes
            weakref.finalize(a, self._gone, a.nbytes)
        self.most = max(self.most, self.alive)
        return arrays

    def _gone(self, n: int) -> None:
        self.alive -= n


def tracked_lazy(ch: Channel, reads: AliveReads) -> LazyChannel:
    """``ch`` as a lazy channel whose whole read fails and whose block reads are copies tracked by ``reads``."""
    def whole() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise AssertionError(f"{ch.name} read whole")

    def part(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return reads.track((ch.timestamps[a:b].copy(), ch.values[a:b].copy(), ch.flags[a:b].copy()))

    return LazyChannel(ch.name, ch.unit, ch.source, len(ch), whole, ch.value_texts, block_loader=part)
