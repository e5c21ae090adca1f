"""The thermo module as a CANopen device (canopen LocalNode) and its acquisition (canopen RemoteNode).

Both sides are built from one EDS (the device and the master mirror each other over one object
dictionary). The device (:class:`ThermoNode`) takes a :class:`~benchtwin.wire.frames.ProcessImage`:
at each row's time (the scheduler calls :meth:`ThermoNode.update`) it writes the values into the
LocalNode's SDO data store (so an SDO upload returns the current value) and into every enabled TPDO
that maps one of them, and transmits those TPDOs. The acquisition (:class:`ThermoAcquisition`) is a
RemoteNode that records every TPDO it receives (arrival time, raw values) and can SDO-read.

A process-image column that no enabled TPDO maps is still served by SDO.

The device is an NMT slave (CiA 301): it sends its boot-up message, produces the heartbeat of object
0x1017 (an SDO write of 0x1017 changes it), and follows NMT commands: TPDOs only in OPERATIONAL, no
SDO answers in STOPPED, a reset restores the EDS configuration and boots again. With ``autostart``
(the default, as a module configured for NMT self-start) it goes OPERATIONAL after booting. SDO writes
to the TPDO communication (0x1800+) and mapping (0x1A00+) objects take effect at the next update, or
are refused with the CiA 301 abort code: a COB-ID change of a valid PDO 0x06090030, a mapping change
of a valid PDO (or of an entry while sub-index 0 is not 0) 0x06010000 (as CANopenNode does), an object
that does not exist 0x06020000, one that cannot be mapped 0x06040041, a mapping longer than 8 bytes
0x06040042.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import canopen
import numpy as np

from benchtwin.chain.live.scheduler import Stream
from benchtwin.errors import CanopenError, ConfigError, TransportTimeoutError
from benchtwin.wire.frames import ProcessImage

__all__ = ["ABORT_CANNOT_MAP", "ABORT_INVALID_VALUE", "ABORT_MAP_LENGTH", "ABORT_NOT_IN_OD", "ABORT_UNSUPPORTED_ACCESS",
           "PdoLog", "ThermoAcquisition", "ThermoNode"]

log = logging.getLogger(__name__)

EdsLike = str | Path | canopen.ObjectDictionary

#: CiA 301 SDO abort codes the node answers to PDO configuration writes
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_NOT_IN_OD = 0x06020000
ABORT_CANNOT_MAP = 0x06040041
ABORT_MAP_LENGTH = 0x06040042
ABORT_INVALID_VALUE = 0x06090030
_INVALID = 0x80000000  #: COB-ID bit 31: PDO does not exist / is not valid
_STOPPED, _OPERATIONAL = 4, 5


class _StampedNetwork(canopen.Network):
    """A canopen network whose frames carry :attr:`stamp` (the time they are due on the bus) when set."""

    stamp: float | None = None

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        msg = can.Message(is_extended_id=can_id > 0x7FF, arbitration_id=can_id, data=data, is_remote_frame=remote,
                          timestamp=self.stamp if self.stamp is not None else time.time())
        with self.send_lock:
            self.bus.send(msg)
        self.check()


def _attach(bus: can.BusABC, notifier: can.Notifier | None) -> tuple[canopen.Network, can.Notifier, bool]:
    network = _StampedNetwork(bus)
    own = notifier is None
    if notifier is None:
        notifier = can.Notifier(bus, [], timeout=0.2)
    for listener in network.listeners:
        notifier.add_listener(listener)
    network.notifier = notifier
    return network, notifier, own


def _od_var(od: Any, index: int, sub: int) -> Any:
    obj = od[index]
    if isinstance(obj, canopen.objectdictionary.ODVariable):
        if sub:
            raise KeyError(sub)
        return obj
    return obj[sub]


def _enabled_tpdos(pdo_maps: Any) -> list[Any]:
    out = []
    for m in pdo_maps.map.values():
        if m.enabled and len(m.map):
            out.append(m)
    return out


class ThermoNode:
    """The emulated CANopen thermo module.

    Parameters
    ----------
    image:
        Values over time; its ``entries`` must exist in the EDS.
    eds:
        EDS file (or a canopen ObjectDictionary) of the module.
    bus:
        Device-side python-can bus the node lives on.
    notifier:
        A python-can notifier already reading ``bus`` (shared with other listeners); one is made
        otherwise.
    autostart:
        Go OPERATIONAL after booting (NMT self-start); otherwise wait in PRE-OPERATIONAL for a master's
        start command.
    """

    def __init__(self, image: ProcessImage, eds: EdsLike, bus: can.BusABC,
                 notifier: can.Notifier | None = None, *, autostart: bool = True) -> None:
        if not 1 <= image.node_id <= 127:
            raise ConfigError(f"canopen node {image.node!r}: node id {image.node_id} outside 1..127")
        self.image = image
        self.network, self._notifier, self._own_notifier = _attach(bus, notifier)
        try:
            self.node = canopen.LocalNode(image.node_id, eds if isinstance(eds, canopen.ObjectDictionary) else str(eds))
        except (OSError, ValueError, KeyError) as exc:
            raise ConfigError(f"canopen node {image.node!r}: cannot load EDS {eds}: {exc}") from exc
        # NMT commands and SDO requests pass the node's state machine first (subscribed by add_node)
        self._nmt_on_command, self._sdo_on_request = self.node.nmt.on_command, self.node.sdo.on_request
        self.node.nmt.on_command = self._on_nmt
        self.node.sdo.on_request = self._on_sdo
        self.network.add_node(self.node)
        od = self.node.object_dictionary
        self._vars = []
        for index, sub in image.entries:
            try:
                self._vars.append(_od_var(od, index, sub))
            except KeyError:
                raise ConfigError(f"canopen node {image.node!r}: entry 0x{index:04X}:{sub} is not in the EDS") from None
        self._col = {e: k for k, e in enumerate(image.entries)}
        self._n_tpdo = sum(1 for i in range(512) if 0x1800 + i in od and 0x1A00 + i in od)
        # per valid TPDO: (COB-ID, [(variable, column or None)])
        self._tpdos: list[tuple[int, list[tuple[Any, int | None]]]] = self._compile()
        self.node.add_write_callback(self._on_write)
        self.pdos_sent = 0
        self.pdos_held = 0  #: TPDOs not sent because the node was not OPERATIONAL
        self.updates = 0
        self.autostart = autostart
        self.boot()

    # ------------------------------------------------------------------ NMT
    @property
    def nmt_state(self) -> str:
        """The NMT state (``OPERATIONAL``, ``PRE-OPERATIONAL``, ``STOPPED``, ``INITIALISING``)."""
        return str(self.node.nmt.state)

    def boot(self) -> None:
        """Boot: send the boot-up message, enter PRE-OPERATIONAL (heartbeat from 0x1017), then OPERATIONAL
        with ``autostart``."""
        self.node.nmt.state = "INITIALISING"  # sends the boot-up message
        self.node.nmt.state = "PRE-OPERATIONAL"  # starts the heartbeat of 0x1017
        if self.autostart:
            self.node.nmt.state = "OPERATIONAL"

    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        if len(data) < 2:
            return  # not an NMT command
        self._nmt_on_command(can_id, data, timestamp)
        if data[1] in (0, self.node.id) and data[0] in (0x81, 0x82):  # reset node / reset communication
            self._restore_defaults(communication_only=data[0] == 0x82)
            self.boot()

    def _on_sdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        if self.node.nmt._state == _STOPPED:
            return  # STOPPED: only NMT and heartbeat
        self._sdo_on_request(can_id, data, timestamp)

    def _restore_defaults(self, communication_only: bool) -> None:
        for index in list(self.node.data_store):
            if not communication_only or 0x1000 <= index <= 0x1FFF:
                del self.node.data_store[index]
        self._tpdos = self._compile()

    # ------------------------------------------------------------------ PDO configuration by SDO
    def _read(self, index: int, sub: int, override: dict[tuple[int, int], int] | None = None) -> int:
        if override and (index, sub) in override:
            return override[(index, sub)]
        var = _od_var(self.node.object_dictionary, index, sub)
        return int(var.decode_raw(self.node.get_data(index, sub)))

    def _entry(self, value: int) -> Any:
        """The mapped variable of a mapping entry (index << 16 | sub << 8 | bits), or an SDO abort."""
        index, sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        try:
            var = _od_var(self.node.object_dictionary, index, sub)
        except KeyError:
            raise canopen.SdoAbortedError(ABORT_NOT_IN_OD) from None
        if not var.pdo_mappable or len(var) != bits:
            raise canopen.SdoAbortedError(ABORT_CANNOT_MAP)
        return var

    def _compile(self, override: dict[tuple[int, int], int] | None = None) -> list[tuple[int, list[Any]]]:
        out = []
        for n in range(self._n_tpdo):
            cob = self._read(0x1800 + n, 1, override)
            count = self._read(0x1A00 + n, 0, override)
            if cob & _INVALID or count == 0:
                continue
            pairs = []
            for k in range(1, count + 1):
                var = self._entry(self._read(0x1A00 + n, k, override))
                pairs.append((var, self._col.get((var.index, var.subindex))))
            out.append((cob & 0x7FF, pairs))
        return out

    def _on_write(self, index: int, subindex: int, od: Any, data: bytes, **_: Any) -> None:
        n = index - 0x1800 if 0x1800 <= index < 0x1800 + self._n_tpdo else index - 0x1A00
        if not (0 <= n < self._n_tpdo and index in (0x1800 + n, 0x1A00 + n)):
            return
        value = int(od.decode_raw(data))
        cob = self._read(0x1800 + n, 1)
        valid = not cob & _INVALID
        if index == 0x1800 + n:
            if subindex == 1 and valid and not value & _INVALID and (value & 0x1FFFFFFF) != (cob & 0x1FFFFFFF):
                raise canopen.SdoAbortedError(ABORT_INVALID_VALUE)  # change the COB-ID of a valid PDO
            if subindex == 1 and value & 0x60000000:
                raise canopen.SdoAbortedError(ABORT_INVALID_VALUE)  # RTR / 29-bit ids: not supported
        else:
            if valid:
                raise canopen.SdoAbortedError(ABORT_UNSUPPORTED_ACCESS)  # disable the PDO first
            if subindex > 0:
                if self._read(0x1A00 + n, 0) != 0:
                    raise canopen.SdoAbortedError(ABORT_UNSUPPORTED_ACCESS)  # set sub-index 0 to 0 first
                self._entry(value)
            else:
                if value > 8 or sum(len(self._entry(self._read(0x1A00 + n, k))) for k in range(1, value + 1)) > 64:
                    raise canopen.SdoAbortedError(ABORT_MAP_LENGTH)
        self._tpdos = self._compile({(index, subindex): value})

    @property
    def cob_ids(self) -> list[int]:
        """COB-IDs of the valid TPDOs."""
        return [cob for cob, _ in self._tpdos]

    def update(self, row: int, stamp: float | None = None) -> int:
        """Take process-image row ``row``: SDO store and TPDOs; transmit the TPDOs; return how many.

        ``stamp`` (Unix seconds) is the time the PDOs are due on the bus (default: now).
        """
        values = self.image.values[row].tolist()
        for var, v in zip(self._vars, values):
            self.node.set_data(var.index, var.subindex, var.encode_raw(int(v)))
        self.updates += 1
        tpdos = self._tpdos
        if self.node.nmt._state != _OPERATIONAL:
            self.pdos_held += len(tpdos)
            return 0
        sent = 0
        self.network.stamp = stamp
        try:
            for cob, pairs in tpdos:
                data = b"".join(var.encode_raw(int(values[k])) if k is not None else
                                self.node.get_data(var.index, var.subindex) for var, k in pairs)
                self.network.send_message(cob, data)
                sent += 1
        finally:
            self.network.stamp = None
        self.pdos_sent += sent
        return sent

    def stream(self, name: str | None = None, clock: Callable[[np.ndarray], np.ndarray] | None = None) -> Stream:
        """A scheduler stream applying each process-image row at its time.

        ``clock`` maps plant times to the Unix times they are due (the scheduler's ``to_unix``), used
        to stamp the PDOs; without it they are stamped when sent.
        """
        times = self.image.times

        def deliver(i0: int, i1: int) -> int:
            stamps = clock(times[i0:i1]).tolist() if clock is not None else [None] * (i1 - i0)
            for r, st in zip(range(i0, i1), stamps):
                self.update(r, st)
            return i1 - i0

        return Stream(name or f"canopen:{self.image.node}", self.image.times, deliver, kind="canopen")

    def close(self) -> None:
        """Stop the heartbeat and detach from the bus (stops the notifier if this node made it)."""
        self.node.nmt.stop_heartbeat()
        for listener in self.network.listeners:
            self._notifier.remove_listener(listener)
        if self._own_notifier:
            self._notifier.stop()


@dataclass
class PdoLog:
    """TPDOs one acquisition received: arrival times and raw values per mapped entry."""

    entries: list[tuple[int, int]]
    times: list[float] = field(default_factory=list)
    values: list[list[int | None]] = field(default_factory=list)
    cob_ids: list[int] = field(default_factory=list)

    def as_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(times, values with NaN where a PDO did not carry an entry, cob ids)."""
        t = np.asarray(self.times, dtype=np.float64)
        v = np.array([[np.nan if x is None else float(x) for x in row] for row in self.values],
                     dtype=np.float64).reshape(len(self.times), len(self.entries))
        return t, v, np.asarray(self.cob_ids, dtype=np.uint32)


class ThermoAcquisition:
    """The acquisition side of the thermo module: a canopen RemoteNode that logs TPDOs and SDO-reads.

    Parameters
    ----------
    node_id:
        Node id of the module.
    eds:
        The module's EDS (the same file the device uses).
    bus:
        Acquisition-side python-can bus.
    entries:
        Object-dictionary entries to log (default: every entry the enabled TPDOs map).
    notifier:
        A notifier already reading ``bus``; one is made otherwise.
    """

    def __init__(self, node_id: int, eds: EdsLike, bus: can.BusABC, entries: Sequence[tuple[int, int]] | None = None,
                 notifier: can.Notifier | None = None, sdo_timeout_s: float = 1.0) -> None:
        self.network, self._notifier, self._own_notifier = _attach(bus, notifier)
        try:
            self.node = canopen.RemoteNode(node_id, eds if isinstance(eds, canopen.ObjectDictionary) else str(eds))
        except (OSError, ValueError, KeyError) as exc:
            raise ConfigError(f"canopen node {node_id}: cannot load EDS {eds}: {exc}") from exc
        self.node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
        self.network.add_node(self.node)
        self.node.tpdo.read(from_od=True)
        maps = _enabled_tpdos(self.node.tpdo)
        if entries is None:
            entries = [(v.index, v.subindex) for m in maps for v in m.map]
        self.log = PdoLog(list(entries))
        self._lock = threading.Lock()
        col = {e: k for k, e in enumerate(self.log.entries)}
        for m in maps:
            pairs = [(v, col[(v.index, v.subindex)]) for v in m.map if (v.index, v.subindex) in col]
            if pairs:
                m.add_callback(self._make_callback(pairs))

    def _make_callback(self, pairs: list[tuple[Any, int]]) -> Any:
        n = len(self.log.entries)

        def on_pdo(pdo_map: Any) -> None:
            row: list[int | None] = [None] * n
            for var, k in pairs:
                row[k] = int(var.raw)
            with self._lock:
                self.log.times.append(float(pdo_map.timestamp) if pdo_map.timestamp else time.time())
                self.log.values.append(row)
                self.log.cob_ids.append(int(pdo_map.cob_id))

        return on_pdo

    def wait_for_pdos(self, n: int, timeout: float) -> bool:
        """Block until ``n`` PDOs were received or ``timeout`` passed."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if len(self.log.times) >= n:
                return True
            time.sleep(0.005)
        return len(self.log.times) >= n

    def sdo_read(self, index: int, subindex: int = 0) -> int:
        """Read one entry by SDO upload (raw integer).

        Raises
        ------
        CanopenError
            The device aborted the transfer (``code`` = SDO abort code).
        TransportTimeoutError
            The device did not answer.
        """
        try:
            _od_var(self.node.object_dictionary, index, subindex)
            obj = self.node.sdo[index]
            var = obj if isinstance(obj, canopen.sdo.base.SdoVariable) else obj[subindex]
            return int(var.raw)
        except canopen.SdoAbortedError as exc:
            raise CanopenError(f"SDO read 0x{index:04X}:{subindex} aborted: {exc}", code=exc.code) from exc
        except canopen.SdoCommunicationError as exc:
            raise TransportTimeoutError(f"SDO read 0x{index:04X}:{subindex}: {exc}") from exc
        except KeyError:
            raise CanopenError(f"SDO read: 0x{index:04X}:{subindex} is not in the EDS", code=0x06020000) from None

    def close(self) -> None:
        """Detach from the bus."""
        for listener in self.network.listeners:
            self._notifier.remove_listener(listener)
        if self._own_notifier:
            self._notifier.stop()
