"""The acquisition's whole-recording passes read each channel a block of samples at a time.

:class:`ChannelBlocks` gives the channels of a Recording being finished block by block: from the
:class:`~benchtwin.chain.channel_store.ChannelStore`'s files when the channel is there (plain reads of the block's
samples; the flags written back when a pass changed them), otherwise as slices of the channel's arrays in memory
(changed in place). What a pass holds is then one block of one channel (at most :data:`BLOCK_SAMPLES` samples,
18 bytes each) whatever the length of the recording: the 500 Hz shaft torque of a ten-fold paper campaign
(52 M samples, 0.9 GB) is read in 50 blocks of 18 MB. The passes give the same flags and numbers for any block
size (the tests compare blocks of a few samples with one block per channel).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from benchtwin.chain.channel_store import ChannelStore
from benchtwin.recording import Recording

__all__ = ["BLOCK_SAMPLES", "ChannelBlocks"]

#: samples per block of the whole-recording passes (timestamps, values, flags: 18 MB)
BLOCK_SAMPLES = 1 << 20


class ChannelBlocks:
    """Block-wise access to the channels of ``rec``, through ``store``'s files for the channels it holds on disk.

    Parameters
    ----------
    rec:
        The Recording being finished (names, sources and lengths; the arrays of channels not in the store).
    store:
        The acquisition's store, or None (every channel in memory).
    size:
        Samples per block (>= 1).
    """

    def __init__(self, rec: Recording, store: ChannelStore | None = None, size: int = BLOCK_SAMPLES) -> None:
        if int(size) < 1:
            raise ValueError(f"ChannelBlocks: the block size must be at least one sample, got {size}")
        self.rec = rec
        self.store = store if store is not None and store.on_disk else None
        self.size = int(size)

    def _stored(self, name: str) -> bool:
        return self.store is not None and self.store.holds(name)

    def length(self, name: str) -> int:
        """Samples of channel ``name`` (without reading it)."""
        return self.store.length(name) if self._stored(name) else len(self.rec.channels[name])

    def blocks(self, name: str, *, write: bool = False, start: int = 0, columns: str = "tvf"
               ) -> Iterator[tuple[int, Any, Any, Any]]:
        """``(first index, timestamps, values, flags)`` of each block of ``name`` from sample ``start`` on.

        With ``write``, what the loop's body changed in the block's flags (in place) is kept: written back to the
        store's file before the next block is read (in memory the flags are a view and change in place anyway).
        The arrays must not be kept past the loop's step: they are the store's buffers or views. ``columns``: the
        arrays given (``"t"``, ``"v"``, ``"f"``; the flags with ``write``), None in the others' places (not read).
        """
        if write and "f" not in columns:
            raise ValueError("ChannelBlocks.blocks: writing the flags back needs them read (columns with 'f')")
        n = self.length(name)
        if not self._stored(name):
            ch = self.rec.channels[name]
            arrays = tuple(x if c in columns else None for x, c in zip((ch.timestamps, ch.values, ch.flags), "tvf"))
            for a in range(start, n, self.size):
                b = min(a + self.size, n)
                yield (a, *(x[a:b] if x is not None else None for x in arrays))
            return
        assert self.store is not None
        for a in range(start, n, self.size):
            b = min(a + self.size, n)
            t, v, f = self.store.read_block(name, a, b, columns)
            yield a, t, v, f
            if write:
                self.store.write_flags(name, a, f)

    def read(self, name: str, start: int, stop: int, columns: str = "tvf") -> tuple[Any, Any, Any]:
        """Timestamps, values and flags of samples ``start:stop`` of ``name`` (``0 <= start <= stop <= length``):
        read from the store's files, or views of the arrays in memory (not to be changed); ``columns``: the arrays
        given, None in the others' places."""
        n = self.length(name)
        if not 0 <= start <= stop <= n:
            raise IndexError(f"channel {name!r} has {n} samples, no samples {start}:{stop}")
        if not self._stored(name):
            ch = self.rec.channels[name]
            return tuple(x[start:stop] if c in columns else None  # type: ignore[return-value]
                         for x, c in zip((ch.timestamps, ch.values, ch.flags), "tvf"))
        assert self.store is not None
        return self.store.read_block(name, start, stop, columns)

    def sample(self, name: str, index: int) -> float:
        """The timestamp of sample ``index`` of ``name`` (negative counts from the end)."""
        n = self.length(name)
        k = index + n if index < 0 else index
        if not 0 <= k < n:
            raise IndexError(f"channel {name!r} has {n} samples, no sample {index}")
        if not self._stored(name):
            return float(self.rec.channels[name].timestamps[k])
        assert self.store is not None
        return float(self.store.read_block(name, k, k + 1, "t")[0][0])

    def count_at_or_before(self, name: str, time_s: float) -> int:
        """How many samples of ``name`` are at or before ``time_s`` (``searchsorted(t, time_s, "right")`` of the
        whole, time-ordered channel), one block at a time."""
        k = 0
        for _a, t, _v, _f in self.blocks(name, columns="t"):
            j = int(np.searchsorted(t, time_s, side="right"))
            k += j
            if j < t.shape[0]:
                break
        return k
