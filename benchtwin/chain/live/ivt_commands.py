"""The IVT-S command channel, live: the emulated shunt answers commands and changes what it sends.

Commands arrive on the sensor's command id (0x411 by default), answers leave on its response id
(0x511): byte 0 of the answer is the command + 0x80 and the remaining bytes echo the command's
arguments; an unknown command is answered with byte 0 = 0xFF and byte 1 = the command byte. The
commands (byte 0):

- ``0x20 + n`` configure result channel n (0 I, 1 U1, 2 U2, 3 U3, 4 T, 5 W, 6 As, 7 Wh): byte 1
  bits 0-1 = trigger mode (0 off, 1 triggered, 2 cyclic), bytes 2-3 = cycle time in ms, big-endian.
  Accepted in stop mode only (as on the sensor); in run mode the answer is 0xFF.
- ``0x30`` reset errors, ``0x31`` trigger (byte 2 = bit mask of the channels to send now),
  ``0x34`` set mode (byte 1 bit 0: 1 run, 0 stop).

The encoded result frames of a run are cyclic frames at the configured cycle. The responder turns
the sensor's state into a gate on them (:meth:`IvtCommandResponder.gate`): in stop mode or for a
channel set to off nothing passes; a triggered channel sends nothing cyclically but answers a
trigger with its newest result; a cyclic channel with a longer cycle time than encoded passes only
every frame that keeps that cycle. The IVT-S device model of the sensors package owns the physics of
the values; this module owns only the command protocol on a live bus.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import can
import numpy as np

from benchtwin.errors import ConfigError

__all__ = ["MODE_CYCLIC", "MODE_OFF", "MODE_TRIGGERED", "IvtCommandResponder", "IvtIds"]

log = logging.getLogger(__name__)

MODE_OFF, MODE_TRIGGERED, MODE_CYCLIC = 0, 1, 2
CMD_CONFIGURE, CMD_RESET, CMD_TRIGGER, CMD_SET_MODE = 0x20, 0x30, 0x31, 0x34
ANSWER_UNKNOWN = 0xFF


@dataclass(frozen=True)
class IvtIds:
    """The CAN identifiers of one IVT-S."""

    name: str = "ivt"
    command_id: int = 0x411
    response_id: int = 0x511
    result_base_id: int = 0x521

    @property
    def result_ids(self) -> list[int]:
        """Ids of the eight results (I, U1, U2, U3, T, W, As, Wh)."""
        return [self.result_base_id + k for k in range(8)]


@dataclass
class _State:
    running: bool = True
    modes: list[int] = field(default_factory=lambda: [MODE_CYCLIC] * 8)
    cycle_ms: list[int] = field(default_factory=lambda: [0] * 8)  # 0: as encoded
    last_sent_t: list[float] = field(default_factory=lambda: [-np.inf] * 8)
    latest: list[bytes | None] = field(default_factory=lambda: [None] * 8)
    latest_dlc: list[int] = field(default_factory=lambda: [6] * 8)


class IvtCommandResponder:
    """Answers the command channels of one or more IVT-S on one bus and gates their result frames.

    Parameters
    ----------
    sensors:
        Identifiers of each IVT-S on the bus.
    bus:
        The device-side bus (answers and triggered results are sent on it).
    """

    def __init__(self, sensors: Sequence[IvtIds], bus: can.BusABC) -> None:
        self.sensors = list(sensors)
        cmd_ids = [s.command_id for s in self.sensors]
        if len(set(cmd_ids)) != len(cmd_ids):
            raise ConfigError("two IVT-S share a command id on one bus")
        self.bus = bus
        self._by_cmd = {s.command_id: k for k, s in enumerate(self.sensors)}
        self._result_owner: dict[int, tuple[int, int]] = {}
        for k, s in enumerate(self.sensors):
            for ch, rid in enumerate(s.result_ids):
                self._result_owner[rid] = (k, ch)
        self.states = [_State() for _ in self.sensors]
        self._lock = threading.Lock()
        self._result_ids = np.array(sorted(self._result_owner), dtype=np.uint32)
        self.counters = {"commands": 0, "unknown": 0, "malformed": 0, "triggers": 0, "suppressed": 0,
                         "triggered_sent": 0}

    # ------------------------------------------------------------------ command side (listener)
    def __call__(self, msg: can.Message) -> None:
        """python-can listener entry: handle ``msg`` if it is a command to one of the sensors."""
        self.on_message_received(msg)

    def on_message_received(self, msg: can.Message) -> None:
        """Handle one frame seen on the bus (ignores everything that is not a command)."""
        k = self._by_cmd.get(msg.arbitration_id)
        if k is None or msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
            return
        try:
            self._handle(k, bytes(msg.data[:msg.dlc]))
        except Exception as exc:  # a failing handler never stops the bus
            log.error("IVT-S %s: command %s failed: %s", self.sensors[k].name, bytes(msg.data).hex(), exc)

    def _answer(self, k: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=self.sensors[k].response_id, is_extended_id=False,
                                  data=data.ljust(8, b"\0")[:8]))

    def _handle(self, k: int, data: bytes) -> None:
        st = self.states[k]
        if not data:
            self.counters["malformed"] += 1
            return
        cmd = data[0]
        self.counters["commands"] += 1
        with self._lock:
            if CMD_CONFIGURE <= cmd <= CMD_CONFIGURE + 7:
                ch = cmd - CMD_CONFIGURE
                if st.running or len(data) < 4 or (data[1] & 0x3) == 3:
                    self.counters["unknown"] += 1
                    self._answer(k, bytes([ANSWER_UNKNOWN, cmd]))
                    return
                st.modes[ch] = data[1] & 0x3
                st.cycle_ms[ch] = int.from_bytes(data[2:4], "big")
                self._answer(k, bytes([cmd + 0x80]) + data[1:])
            elif cmd == CMD_RESET:
                self._answer(k, bytes([cmd + 0x80]) + data[1:])
            elif cmd == CMD_SET_MODE and len(data) >= 2:
                st.running = bool(data[1] & 1)
                self._answer(k, bytes([cmd + 0x80]) + data[1:])
            elif cmd == CMD_TRIGGER and len(data) >= 3:
                self._answer(k, bytes([cmd + 0x80]) + data[1:])
                self.counters["triggers"] += 1
                if st.running:
                    for ch in range(8):
                        if data[2] >> ch & 1 and st.modes[ch] == MODE_TRIGGERED and st.latest[ch] is not None:
                            self.bus.send(can.Message(arbitration_id=self.sensors[k].result_ids[ch],
                                                      is_extended_id=False, dlc=st.latest_dlc[ch],
                                                      data=st.latest[ch][:st.latest_dlc[ch]]))
                            self.counters["triggered_sent"] += 1
            else:
                self.counters["unknown"] += 1
                self._answer(k, bytes([ANSWER_UNKNOWN, cmd]))

    # ------------------------------------------------------------------ result side (scheduler)
    def gate(self, frames: np.ndarray) -> np.ndarray:
        """The subset of ``frames`` (FRAME_DTYPE rows, in time order) the sensors' state lets out now.

        Every result frame updates the sensor's newest value (what a trigger returns) whether it
        passes or not.
        """
        ids = frames["arbitration_id"]
        mine = np.isin(ids, self._result_ids) & ~frames["is_extended"]
        if not mine.any():
            return frames
        keep = np.ones(len(frames), dtype=bool)
        with self._lock:
            for i in np.flatnonzero(mine).tolist():
                k, ch = self._result_owner[int(ids[i])]
                st = self.states[k]
                row = frames[i]
                st.latest[ch] = row["data"].tobytes()
                st.latest_dlc[ch] = int(row["dlc"])
                if not st.running or st.modes[ch] != MODE_CYCLIC:
                    keep[i] = False
                    continue
                t = float(row["timestamp"])
                if st.cycle_ms[ch] and t - st.last_sent_t[ch] < st.cycle_ms[ch] * 1e-3 - 1e-6:
                    keep[i] = False
                    continue
                st.last_sent_t[ch] = t
        self.counters["suppressed"] += int(len(frames) - keep.sum())
        return frames if keep.all() else frames[keep]
