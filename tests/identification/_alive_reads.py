"""Block reads of lazy channels, tracked: the most bytes of them alive at once (the bounded-read tests' probe)."""

from __future__ import annotations

import weakref

import numpy as np


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
