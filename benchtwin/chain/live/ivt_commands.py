"""The IVT-S command channel, live: the emulated shunt answers commands and changes what it sends.

Commands arrive on each shunt's command id (0x411 by default) and are handled by the shunt's own
state machine (:class:`benchtwin.sensors.ivt.IvtDevice`: configure result n with ``0x20+n``, reset
errors ``0x30``, trigger ``0x31``, run/stop ``0x34``; answer byte 0 = command + 0x80, 0xFF for an
unknown command); the answer leaves on the response id (0x511).

The encoded result frames of a run are cyclic frames at the configured cycle. This module turns the
shunt's live state into a gate on them (:meth:`IvtCommandResponder.gate`): in stop mode or for a
result set to off nothing passes; a triggered result sends nothing cyclically but answers a trigger
with its newest value (with the shunt's next counter); a cyclic result whose cycle time was set
longer than encoded passes only the frames that keep the new cycle (a shorter one cannot be made
from the encoded frames and passes everything).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Mapping

import can
import numpy as np

from benchtwin.errors import ConfigError, FrameError
from benchtwin.sensors.ivt import MODE_CYCLIC, IvtDevice

__all__ = ["IvtCommandResponder"]

log = logging.getLogger(__name__)


class IvtCommandResponder:
    """Answers the command channels of the IVT-S on one bus and gates their result frames.

    Parameters
    ----------
    devices:
        Shunt name -> its state machine (built from the setup's :class:`~benchtwin.config.setup.IvtConfig`).
    bus:
        The device-side bus (answers and triggered results are sent on it).
    """

    def __init__(self, devices: Mapping[str, IvtDevice], bus: can.BusABC) -> None:
        self.devices = dict(devices)
        cmd_ids = [d.cfg.command_id for d in self.devices.values()]
        if len(set(cmd_ids)) != len(cmd_ids):
            raise ConfigError("two IVT-S share a command id on one bus")
        self.bus = bus
        self._by_cmd = {d.cfg.command_id: name for name, d in self.devices.items()}
        self._owner: dict[int, tuple[str, int]] = {}
        for name, d in self.devices.items():
            for ch, rid in enumerate(d.cfg.result_ids):
                self._owner[rid] = (name, ch)
        self._result_ids = np.array(sorted(self._owner), dtype=np.uint32)
        self._latest: dict[tuple[str, int], bytes] = {}
        self._last_sent_t: dict[tuple[str, int], float] = {}
        self._lock = threading.Lock()
        self.counters = {"commands": 0, "unknown": 0, "malformed": 0, "triggers": 0, "suppressed": 0,
                         "triggered_sent": 0}

    # ------------------------------------------------------------------ command side (a python-can listener)
    def __call__(self, msg: can.Message) -> None:
        """python-can listener entry (see :meth:`on_message_received`)."""
        self.on_message_received(msg)

    def on_message_received(self, msg: can.Message) -> None:
        """Handle one frame seen on the bus; everything that is not a command is ignored."""
        name = self._by_cmd.get(msg.arbitration_id)
        if name is None or msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
            return
        try:
            self._handle(name, bytes(msg.data[:msg.dlc]))
        except FrameError as exc:
            self.counters["malformed"] += 1
            log.warning("IVT-S %s: %s", name, exc)
        except Exception as exc:  # a failing handler never stops the bus
            log.error("IVT-S %s: command %s failed: %s", name, bytes(msg.data).hex(), exc)

    def _handle(self, name: str, data: bytes) -> None:
        dev = self.devices[name]
        with self._lock:
            answer = dev.handle_command(data)
            self.counters["commands"] += 1
            if answer.data[0] == 0xFF:
                self.counters["unknown"] += 1
            self.bus.send(can.Message(arbitration_id=dev.cfg.response_id, is_extended_id=False,
                                      data=answer.data[:8]))
            if data[0] == 0x31:
                self.counters["triggers"] += 1
            for ch in answer.triggered:
                latest = self._latest.get((name, ch))
                if latest is None:
                    continue  # nothing measured yet
                status, value = dev.unpack_result(ch, latest)
                rid, payload = dev.result_frame(ch, value, status)
                self.bus.send(can.Message(arbitration_id=rid, is_extended_id=False, data=payload))
                self.counters["triggered_sent"] += 1

    # ------------------------------------------------------------------ result side (the scheduler)
    def gate(self, frames: np.ndarray) -> np.ndarray:
        """The rows of ``frames`` (FRAME_DTYPE, time order) the shunts' state lets out now.

        Every result frame updates the shunt's newest value (what a trigger returns), passed or not.
        """
        mine = np.isin(frames["arbitration_id"], self._result_ids) & ~frames["is_extended"]
        if not mine.any():
            return frames
        keep = np.ones(len(frames), dtype=bool)
        with self._lock:
            for i in np.flatnonzero(mine).tolist():
                row = frames[i]
                key = self._owner[int(row["arbitration_id"])]
                dev = self.devices[key[0]]
                ch = key[1]
                self._latest[key] = row["data"][:6].tobytes()
                if not dev.running or dev.modes[ch] != MODE_CYCLIC:
                    keep[i] = False
                    continue
                cycle_s = dev.cycles_ms[ch] * 1e-3
                t = float(row["timestamp"])
                if dev.cycles_ms[ch] > dev.cfg.cycle_ms and t - self._last_sent_t.get(key, -np.inf) < cycle_s - 1e-6:
                    keep[i] = False
                    continue
                self._last_sent_t[key] = t
        self.counters["suppressed"] += int(len(frames) - keep.sum())
        return frames if keep.all() else frames[keep]
