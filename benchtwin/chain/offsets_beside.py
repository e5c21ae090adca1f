"""The clock offsets found on a thread while the acquisition's other whole-recording passes run.

:func:`~benchtwin.chain.alignment.clock_offsets` reads the timestamps and values of the few channels its pairs use
(:data:`PAIR_CHANNELS`); the passes that run after the CAN channels are decoded (the poll logs' decoding, the
saturation flags, fault detection) add channels and change flags only. So once the CAN channels are final, the
offsets can be found beside those passes (a second core; the reads and numpy's kernels run without the GIL) from a
Recording holding the pair channels as they are then. :meth:`OffsetsBeside.result` gives that result when the pair
channels are still the same ones (the same channel objects, no pair channel added) when the passes are done, and
otherwise finds the offsets again in line on the finished view: either way what :func:`clock_offsets` gives on it.
"""

from __future__ import annotations

import threading
from typing import Any

from benchtwin.chain.alignment import clock_offsets
from benchtwin.chain.blocks import ChannelBlocks
from benchtwin.recording import Recording

__all__ = ["PAIR_CHANNELS", "OffsetsBeside"]

#: every channel :func:`~benchtwin.chain.alignment.clock_offsets` may read (its pairs', forces' and parts')
PAIR_CHANNELS = ("vehicle_speed_kmh", "dyno_speed_kmh", "dyno_force_front_n", "dyno_force_rear_n", "em_torque_nm",
                 "em_speed_rpm", "hpcu_power_w", "battery_power_w", "engine_torque_nm", "engine_speed_rpm",
                 "shaft_torque_nm")


class OffsetsBeside:
    """:func:`clock_offsets` of ``view``'s pair channels as they are now, found on a thread.

    Parameters
    ----------
    view:
        The Recording being finished (its channels' timestamps and values final for :data:`PAIR_CHANNELS`).
    """

    def __init__(self, view: ChannelBlocks) -> None:
        self._pairs = {n: view.rec.channels[n] for n in PAIR_CHANNELS if n in view.rec.channels}
        snap = Recording()
        for ch in self._pairs.values():
            snap.add(ch)
        self._view = ChannelBlocks(snap, view.store, view.size)
        self._detail: dict[str, dict[str, float]] = {}
        self._out: tuple[dict[str, float], dict[str, float]] | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="clock-offsets", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            self._out = clock_offsets(self._view, self._detail)
        except BaseException as exc:  # handed to result()
            self._error = exc

    def join(self) -> None:
        """Wait for the thread (an acquisition given up: before its files go)."""
        self._thread.join()

    def result(self, view: ChannelBlocks, detail: dict[str, Any]) -> tuple[dict[str, float], dict[str, float]]:
        """``clock_offsets(view, detail)`` of the finished ``view``: the thread's when its pair channels are the
        ones it read, else found again here."""
        self.join()
        now = {n: view.rec.channels[n] for n in PAIR_CHANNELS if n in view.rec.channels}
        if now.keys() != self._pairs.keys() or any(now[n] is not self._pairs[n] for n in now):
            return clock_offsets(view, detail)
        if self._error is not None:
            raise self._error
        assert self._out is not None
        detail.update(self._detail)
        return self._out
