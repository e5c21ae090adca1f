"""A live run wired together: transports, Modbus server, CANopen node, IVT-S command channel, scheduler.

:class:`LiveSession` takes the :class:`~benchtwin.wire.frames.DeviceOutputs` of a run (the same
arrays batch delivery writes to logs) and serves them: every CAN bus on the chosen transport, every
Modbus device on one pymodbus TCP server, every CANopen node as a LocalNode on its bus, each IVT-S
answering its command channel; then :meth:`LiveSession.run` paces it all on one clock.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import can
import numpy as np

from benchtwin.chain.live.canopen_node import EdsLike, ThermoNode
from benchtwin.chain.live.ivt_commands import IvtCommandResponder
from benchtwin.chain.live.modbus_server import ModbusDeviceServer, RegisterStore
from benchtwin.chain.live.scheduler import (
    LiveScheduler,
    PacingReport,
    Stream,
    restore_policy,
    use_realtime_priority,
)
from benchtwin.chain.transports import Transport, get_transport
from benchtwin.errors import ConfigError
from benchtwin.sensors.ivt import IvtDevice
from benchtwin.wire.frames import DeviceOutputs, FrameTable

__all__ = ["LiveSession"]

log = logging.getLogger(__name__)


class LiveSession:
    """Serve a run's device outputs live.

    Parameters
    ----------
    outputs:
        What the instruments put on their wires.
    transport:
        Registry name of the CAN transport (``virtual``, ``socketcand``, ``socketcan``).
    speedup:
        Plant seconds per wall second.
    can_port:
        Port of the socketcand endpoint (0: a free one).
    modbus_port:
        Port of the Modbus TCP server (0: a free one).
    eds:
        EDS of the CANopen nodes (one file, or node name -> file).
    canopen_bus:
        Node name -> bus it lives on (default: ``instrument`` if present, else the first bus).
    ivt:
        Bus name -> {shunt name: its :class:`~benchtwin.sensors.ivt.IvtDevice`} (their command channels
        are answered and their results gated by their state).
    holding:
        Modbus device name -> static holding registers ``{address: value}`` (configuration block).
    modbus_faults:
        Modbus device name -> keyword arguments of :class:`RegisterStore` for poll faults
        (``exception_prob``, ``exception_code``, ``timeout_prob``, ``no_answer_s``, ``seed``).
    bitrates:
        Bus name -> bit rate for buses that carry no frames in ``outputs`` (e.g. a CANopen-only bus).
    start_s, end_s:
        Plant-time slice to play.
    scheduler_options:
        Passed to :class:`~benchtwin.chain.live.scheduler.LiveScheduler` (``batch_window_s``, ``spin_s``).
    realtime_priority:
        Run the session (the pacing loop and every server thread it starts) under ``SCHED_FIFO`` at this
        priority; see :func:`~benchtwin.chain.live.scheduler.use_realtime_priority`.
    """

    def __init__(self, outputs: DeviceOutputs, *, transport: str = "virtual", speedup: float = 1.0,
                 can_port: int = 0, modbus_port: int = 0, eds: EdsLike | Mapping[str, EdsLike] | None = None,
                 canopen_bus: Mapping[str, str] | None = None, ivt: Mapping[str, Mapping[str, IvtDevice]] | None = None,
                 holding: Mapping[str, Mapping[int, int]] | None = None,
                 modbus_faults: Mapping[str, Mapping[str, Any]] | None = None,
                 bitrates: Mapping[str, int] | None = None,
                 channel_map: Mapping[str, str] | None = None, start_s: float | None = None,
                 end_s: float | None = None, scheduler_options: Mapping[str, Any] | None = None,
                 realtime_priority: int | None = None) -> None:
        self.outputs = outputs
        self.speedup = speedup
        self.start_s, self.end_s = start_s, end_s
        self.scheduler_options = dict(scheduler_options or {})
        self.realtime_priority = realtime_priority
        self._previous_policy: Any = None
        #: True when the session runs under the real-time policy it asked for
        self.realtime_active = False
        buses: dict[str, int] = {name: t.bitrate for name, t in outputs.can.items()}
        buses.update({b: r for b, r in (bitrates or {}).items() if b not in buses})
        default_bus = "instrument" if "instrument" in buses else (next(iter(buses)) if buses else "instrument")
        self.canopen_bus = {n: (canopen_bus or {}).get(n, default_bus) for n in outputs.canopen}
        for b in self.canopen_bus.values():
            buses.setdefault(b, 500_000)
        self.ivt = {b: dict(d) for b, d in (ivt or {}).items()}
        for b in self.ivt:
            if b not in buses:
                raise ConfigError(f"IVT-S configured on bus {b!r}, which carries nothing (buses: {', '.join(buses)})")
        if outputs.canopen and eds is None:
            raise ConfigError("the run has CANopen nodes but no EDS was given")
        self.eds = eds
        self.holding = {k: dict(v) for k, v in (holding or {}).items()}
        self.modbus_faults = {k: dict(v) for k, v in (modbus_faults or {}).items()}
        self.transport: Transport | None = (get_transport(transport)(buses, port=can_port, channel_map=channel_map)
                                            if buses else None)
        self.modbus: ModbusDeviceServer | None = None
        self.modbus_port = modbus_port
        self.nodes: dict[str, ThermoNode] = {}
        self.responders: dict[str, IvtCommandResponder] = {}
        self._notifiers: dict[str, can.Notifier] = {}
        self.scheduler: LiveScheduler | None = None
        self.stores: dict[str, RegisterStore] = {}

    def _eds_for(self, node: str) -> EdsLike:
        if isinstance(self.eds, Mapping):
            try:
                return self.eds[node]
            except KeyError:
                raise ConfigError(f"no EDS for CANopen node {node!r}") from None
        if self.eds is None:
            raise ConfigError(f"no EDS for CANopen node {node!r}")
        return self.eds if not isinstance(self.eds, str) else Path(self.eds)

    def start(self) -> LiveSession:
        """Start the transports and servers; build the schedule (once; later calls do nothing)."""
        if self.scheduler is not None:
            return self
        if self.realtime_priority is not None:  # before any thread starts: they inherit it
            self._previous_policy = use_realtime_priority(self.realtime_priority)
            self.realtime_active = self._previous_policy is not None
        try:
            self._start()
        except BaseException:
            self.close()
            raise
        return self

    def _start(self) -> None:
        streams: list[Stream] = []
        tr = self.transport
        if tr is not None:
            tr.start()
            for bus in tr.bitrates:
                listeners: list[Any] = []
                if bus in self.ivt:
                    resp = IvtCommandResponder(self.ivt[bus], tr.device_bus(bus))
                    self.responders[bus] = resp
                    listeners.append(resp)
                if listeners or bus in self.canopen_bus.values():
                    self._notifiers[bus] = can.Notifier(tr.device_bus(bus), listeners, timeout=0.2)
            for name, image in self.outputs.canopen.items():
                bus = self.canopen_bus[name]
                node = ThermoNode(image, self._eds_for(name), tr.device_bus(bus), notifier=self._notifiers[bus])
                self.nodes[name] = node
                streams.append(node.stream(f"canopen:{name}", clock=self._to_unix))
            for bus, table in self.outputs.can.items():
                streams.append(self._can_stream(tr, bus, table))
        if self.outputs.modbus:
            for name, snap in self.outputs.modbus.items():
                store = RegisterStore.for_snapshots(snap, holding=self.holding.get(name),
                                                    **self.modbus_faults.get(name, {}))
                self.stores[name] = store
                streams.append(store.stream(snap, f"modbus:{name}"))
            self.modbus = ModbusDeviceServer(self.stores.values(), port=self.modbus_port).start()
        self.scheduler = LiveScheduler(streams, speedup=self.speedup, start_s=self.start_s, end_s=self.end_s,
                                       **self.scheduler_options)

    def _to_unix(self, t_plant: np.ndarray) -> np.ndarray:
        if self.scheduler is None:
            return np.full(np.shape(t_plant), time.time())
        return self.scheduler.to_unix(t_plant)

    def _can_stream(self, tr: Transport, bus: str, table: FrameTable) -> Stream:
        frames = table.frames
        gate = self.responders.get(bus)

        def deliver(i0: int, i1: int) -> int:
            part = frames[i0:i1]
            if gate is not None:
                part = gate.gate(part)
            if len(part):
                # stamped with the time each frame is due on the emulated bus (as a hardware-timestamping
                # interface would), not with when this thread got to it: pacing jitter stays in the report
                tr.send_frames(bus, part, self.scheduler.to_unix(part["timestamp"]))
            return i1 - i0

        return Stream(f"can:{bus}", frames["timestamp"], deliver, kind="can", frames=frames, bitrate=table.bitrate)

    def endpoints(self) -> list[str]:
        """Where each bus, Modbus device and CANopen node can be reached."""
        out: list[str] = []
        if self.transport is not None:
            out += [f"can:{line}" for line in self.transport.endpoints()]
        if self.modbus is not None:
            out += self.modbus.endpoints()
        for name, node in self.nodes.items():
            out.append(f"canopen:{name}: node {node.image.node_id} on bus {self.canopen_bus[name]}, TPDO COB-IDs "
                       + ", ".join(f"0x{c:03X}" for c in node.cob_ids))
        for bus, resp in self.responders.items():
            out += [f"ivt:{name}: bus {bus}, commands on 0x{d.cfg.command_id:03X}, answers on "
                    f"0x{d.cfg.response_id:03X}" for name, d in resp.devices.items()]
        return out

    def wait_for_clients(self, n: int, timeout: float) -> bool:
        """For network transports: wait until ``n`` CAN clients are connected (raw mode)."""
        srv = getattr(self.transport, "server", None)
        if srv is None or n <= 0:
            return True
        return bool(srv.wait_for_clients(n, timeout))

    def run(self, progress: Callable[[float], None] | None = None) -> PacingReport:
        """Play the run; return the pacing report."""
        if self.scheduler is None:
            self.start()
        scheduler = self.scheduler
        if scheduler is None:
            raise ConfigError("live session did not start")
        pinned = _pin_to_one_cpu() if self.transport is not None and self.transport.per_cpu_queues else None
        try:
            return scheduler.run(progress=progress)
        finally:
            if pinned is not None:
                with contextlib.suppress(OSError):
                    os.sched_setaffinity(0, pinned)

    def stop(self) -> None:
        """Stop a running :meth:`run` (from another thread or a signal handler)."""
        if self.scheduler is not None:
            self.scheduler.stop()

    def stats(self) -> dict[str, Any]:
        """Transport counters, Modbus reads, IVT-S command counters, PDOs sent."""
        out: dict[str, Any] = {}
        if self.transport is not None:
            out["transport"] = {"name": self.transport.name, **self.transport.stats()}
        out["modbus_reads"] = {n: s.reads for n, s in self.stores.items()}
        out["modbus_faults"] = {n: dict(s.faults) for n, s in self.stores.items()}
        out["ivt_commands"] = {b: dict(r.counters) for b, r in self.responders.items()}
        out["pdos_sent"] = {n: node.pdos_sent for n, node in self.nodes.items()}
        return out

    def close(self) -> None:
        """Stop everything (idempotent)."""
        for node in self.nodes.values():
            with contextlib.suppress(Exception):
                node.close()
        for n in self._notifiers.values():
            with contextlib.suppress(Exception):
                n.stop(timeout=1.0)
        self._notifiers.clear()
        if self.modbus is not None:
            self.modbus.close()
            self.modbus = None
        if self.transport is not None:
            self.transport.close()
        restore_policy(self._previous_policy)
        self._previous_policy = None

    def __enter__(self) -> LiveSession:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


def _pin_to_one_cpu() -> set[int] | None:
    """Keep the calling (pacing) thread on one CPU while it sends on kernel SocketCAN; return the previous set.

    vcan hands each frame to the receive backlog of the CPU the sender runs on, so a pacing thread that moves
    between CPUs can have a frame overtake the one sent before it (seen in the vcan guest on a loaded host: two
    instrument frames swapped); on one CPU the backlog keeps the order the scheduler sent. None: not pinned
    (one CPU only, or no affinity call on this platform).
    """
    try:
        allowed = os.sched_getaffinity(0)
        if len(allowed) < 2:
            return None
        os.sched_setaffinity(0, {min(allowed)})
    except (AttributeError, OSError) as exc:
        log.debug("pacing thread not pinned to one CPU: %s", exc)
        return None
    return set(allowed)
