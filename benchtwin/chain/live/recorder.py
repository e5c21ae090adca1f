"""The live acquisition: record CAN buses, poll Modbus, receive PDOs; hand everything to the decoder.

:class:`LiveRecorder` connects to the transports of a running ``benchtwin serve`` (or a real bench):

- every CAN bus through python-can (socketcand through :class:`~benchtwin.chain.transports.socketcand.
  SocketcandClientBus`, which notices a dropped connection), each received frame logged raw and
  flushed incrementally to a spool file (``<spool>/<bus>.frames``: FRAME_DTYPE records appended as
  they come, so a crash or a drop loses nothing already received);
- every Modbus device with a pymodbus client polling at the setup's rate (status per poll: 0 ok, the
  exception code, or -1 timeout/no connection), spooled to ``<spool>/<device>.polls``;
- the CANopen thermo module with a canopen RemoteNode (TPDOs received, SDO reads possible);
- transport events (a drop, a reconnect, the end) with their times, appended to ``<spool>/events.jsonl``.

The spool survives the recorder being killed at any moment (``kill -9``, a power cut of the process):
the frames are appended as fixed-size FRAME_DTYPE records and handed to the operating system at
least every ``flush_s`` (0.2 s by default; the guaranteed bound is **1 s** of wall time, see
:data:`SPOOL_FLUSH_BOUND_S`), the polls likewise; a partial last record (a write cut by the kill) is
detected by its length and dropped. ``spool.json`` (acquisition clock: start time and speed-up, the
buses, the poll layouts) and, when the bench gives them, ``setup.json`` and ``segments.json`` are in the
spool from the start, written atomically (temporary file + rename). ``benchtwin acquire SPOOL_DIR
--out REC.mf4`` turns such a folder into a Recording (:func:`benchtwin.chain.live.bench.read_spool`).

Times are on the acquisition's clock: ``(wall - start) * speedup`` seconds, i.e. plant seconds
when the server plays at the same speed-up. On stop (duration, end of stream, Ctrl-C, or every CAN
connection dropped) :meth:`LiveRecorder.stop` returns a :class:`LiveCapture` with the same raw
arrays batch delivery writes to logs, which the batch decoder turns into the Recording.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from benchtwin.chain.live.canopen_node import EdsLike, PdoLog, ThermoAcquisition
from benchtwin.chain.live.spool import SPOOL_FLUSH_BOUND_S, poll_dtype, read_frame_spool, read_poll_spool, write_atomic
from benchtwin.chain.transports.socketcand import SocketcandClientBus
from benchtwin.errors import ConfigError, DataError, TransportError
from benchtwin.wire.frames import FRAME_DTYPE, FrameTable, PollLog, TransportEvent

__all__ = ["SPOOL_FLUSH_BOUND_S", "IvtTriggerSpec", "LiveCapture", "LiveRecorder", "ModbusPollSpec",
           "open_acquisition_bus", "read_frame_spool", "read_poll_spool", "write_atomic"]

log = logging.getLogger(__name__)

def open_acquisition_bus(transport: str, bus: str, *, host: str = "127.0.0.1", port: int = 29536,
                         channel: str | None = None, connect_timeout: float = 10.0) -> can.BusABC:
    """Open an acquisition-side python-can bus on a served bus.

    Parameters
    ----------
    transport:
        ``socketcand`` (our drop-aware client), ``socketcan`` (``channel`` = interface, e.g. vcan0)
        or ``virtual`` (``channel`` = the virtual channel name; same process only).
    connect_timeout:
        socketcand: seconds to keep trying while the server starts.
    """
    try:
        if transport == "socketcand":
            return SocketcandClientBus(channel or bus, host=host, port=port, connect_timeout=connect_timeout)
        if transport == "socketcan":
            return can.Bus(interface="socketcan", channel=channel or bus)
        if transport == "virtual":
            return can.Bus(interface="virtual", channel=channel or bus)
    except (can.CanError, OSError) as exc:
        raise TransportError(f"cannot connect to bus {bus!r} over {transport} ({host}:{port}): {exc}") from exc
    raise ConfigError(f"unknown transport {transport!r}; choose socketcand, socketcan or virtual")


@dataclass(frozen=True)
class ModbusPollSpec:
    """One Modbus device to poll."""

    device: str
    host: str = "127.0.0.1"
    port: int = 5020
    unit_id: int = 1
    function_code: int = 4
    first_register: int = 0
    count: int = 14
    poll_hz: float = 100.0
    timeout_s: float = 0.5


@dataclass(frozen=True)
class IvtTriggerSpec:
    """An IVT-S in triggered mode: the acquisition sends ``0x31 00 mask`` on its command id every period."""

    bus: str
    command_id: int
    mask: int = 0xFF
    period_s: float = 0.02


@dataclass
class LiveCapture:
    """Everything one live acquisition received, as raw arrays (the decoder's input).

    Attributes
    ----------
    can:
        Bus name -> frames received, timestamps on the acquisition clock.
    polls:
        Modbus device -> poll log.
    pdos:
        CANopen node -> TPDOs received through the RemoteNode.
    events:
        Drops, reconnects and the end, with their times.
    start_wall:
        Wall-clock time (Unix seconds) of acquisition time 0.
    speedup:
        Acquisition seconds per wall second.
    stats:
        Counters (frames per bus, polls, errors).
    """

    can: dict[str, FrameTable] = field(default_factory=dict)
    polls: dict[str, PollLog] = field(default_factory=dict)
    pdos: dict[str, PdoLog] = field(default_factory=dict)
    events: list[TransportEvent] = field(default_factory=list)
    start_wall: float = 0.0
    speedup: float = 1.0
    stats: dict[str, Any] = field(default_factory=dict)


class _FrameSpooler(can.Listener):
    """Keeps received frames and appends them to a spool file every ``flush_s``."""

    def __init__(self, recorder: LiveRecorder, bus: str, path: Path) -> None:
        self.recorder, self.bus, self.path = recorder, bus, path
        # appended by the notifier thread, drained by the flusher: a deque needs no lock for that
        self._rows: deque[tuple[float, int, bool, int, bytes]] = deque()
        self._lock = threading.Lock()
        self._fh = path.open("ab")
        self.parts: list[np.ndarray] = []
        self.n = 0
        self.errors = 0
        self.dropped = False
        self.last_rx = 0.0

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self.errors += 1
            return
        self._rows.append((msg.timestamp, msg.arbitration_id, msg.is_extended_id, msg.dlc, bytes(msg.data)))
        self.last_rx = time.monotonic()

    def on_error(self, exc: Exception) -> None:
        if self.dropped:
            return
        self.dropped = True
        self.recorder._event(self.bus, "drop", f"{type(exc).__name__}: {exc}")
        log.warning("bus %s: connection closed (%s); what was received is kept", self.bus, exc)

    def flush(self) -> None:
        with self._lock:
            pop = self._rows.popleft
            rows = [pop() for _ in range(len(self._rows))]
            if not rows:
                return
            out = np.zeros(len(rows), dtype=FRAME_DTYPE)
            ts, ids, ext, dlc, data = zip(*rows)
            out["timestamp"] = self.recorder.acq_time(np.asarray(ts, dtype=np.float64))
            out["arbitration_id"] = ids
            out["is_extended"] = ext
            out["dlc"] = np.minimum(np.asarray(dlc), 8)
            raw = b"".join(d[:8].ljust(8, b"\0") for d in data)
            out["data"] = np.frombuffer(raw, dtype=np.uint8).reshape(-1, 8)
            out.tofile(self._fh)
            self._fh.flush()
            self.parts.append(out)
            self.n += len(out)

    def close(self) -> None:
        self.flush()
        with contextlib.suppress(OSError):
            self._fh.close()


class _Poller:
    """Polls one Modbus device at its rate in a thread, spooling every answer, timeout or exception."""

    def __init__(self, recorder: LiveRecorder, spec: ModbusPollSpec, path: Path) -> None:
        self.recorder, self.spec, self.path = recorder, spec, path
        self.dtype = poll_dtype(spec.count)
        self._fh = path.open("ab")
        self._stop = threading.Event()
        self._flushed_at = time.monotonic()
        self.rows: list[np.ndarray] = []
        self.counts = {"ok": 0, "timeout": 0, "exception": 0}
        self._thread = threading.Thread(target=self._run, name=f"modbus-poll-{spec.device}", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _client(self) -> Any:
        from pymodbus.client import ModbusTcpClient

        return ModbusTcpClient(self.spec.host, port=self.spec.port, timeout=self.spec.timeout_s, retries=0)

    def _run(self) -> None:
        from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

        if logging.getLogger().level > logging.DEBUG:
            logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # our own events say it once

        spec = self.spec
        client = self._client()
        connected = client.connect()
        was_down = not connected
        if not connected:
            self.recorder._event(spec.device, "drop", f"cannot connect to {spec.host}:{spec.port}")
        period = 1.0 / (spec.poll_hz * self.recorder.speedup)
        read = client.read_input_registers if spec.function_code == 4 else client.read_holding_registers
        next_t = time.perf_counter()
        while not self._stop.is_set():
            status, values = -1, None
            try:
                if not client.connected and not client.connect():
                    raise ConnectionError("not connected")
                r = read(spec.first_register, count=spec.count, device_id=spec.unit_id)
                if r.isError():
                    status = int(getattr(r, "exception_code", 4) or 4)
                    self.counts["exception"] += 1
                else:
                    status, values = 0, r.registers
                    self.counts["ok"] += 1
                if was_down:
                    was_down = False
                    self.recorder._event(spec.device, "reconnect", "")
            except ModbusIOException:
                # no answer in time: a timeout, logged in the poll log only (not a transport drop); reconnect
                # so that a late answer cannot be taken for the next poll's
                self.counts["timeout"] += 1
                client.close()
            except (ConnectionException, ModbusException, ConnectionError, OSError) as exc:
                self.counts["timeout"] += 1  # the connection is gone: a transport drop until it is back
                if not was_down:
                    was_down = True
                    self.recorder._event(spec.device, "drop", str(exc))
                client.close()
            rec = np.zeros(1, dtype=self.dtype)
            rec["time"] = self.recorder.acq_time(time.time())
            rec["status"] = status
            if values is not None and len(values) == spec.count:
                rec["values"][0] = values
            rec.tofile(self._fh)
            if time.monotonic() - self._flushed_at >= self.recorder.flush_s:
                self._fh.flush()  # to the operating system: a kill of the recorder keeps it
                self._flushed_at = time.monotonic()
            self.rows.append(rec)
            next_t += period
            delay = next_t - time.perf_counter()
            if delay > 0:
                self._stop.wait(delay)
            else:
                next_t = time.perf_counter()  # behind: do not burst to catch up
        client.close()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        with contextlib.suppress(OSError):
            self._fh.flush()
            self._fh.close()

    def poll_log(self) -> PollLog:
        rec = np.concatenate(self.rows) if self.rows else np.zeros(0, dtype=self.dtype)
        s = self.spec
        return PollLog(s.device, s.unit_id, s.function_code, s.first_register, rec["time"],
                       rec["values"].reshape(len(rec), s.count), rec["status"])


class LiveRecorder:
    """Record a served bench live.

    Parameters
    ----------
    buses:
        Bus name -> an open acquisition-side python-can bus (see :func:`open_acquisition_bus`).
    spool_dir:
        Where the incremental logs go (created).
    modbus:
        Devices to poll.
    canopen:
        Node name -> (node id, EDS, bus name) to receive with a RemoteNode.
    triggers:
        IVT-S to trigger periodically (plant-time period; sent every ``period_s / speedup`` wall seconds).
    speedup:
        The server's speed-up (acquisition seconds per wall second).
    flush_s:
        Spool flush period, wall seconds (at most :data:`SPOOL_FLUSH_BOUND_S`).
    context:
        Files written into the spool at once (name -> text), e.g. ``setup.json`` and ``segments.json``, so
        that a killed recorder's spool can be decoded alone.
    """

    def __init__(self, buses: Mapping[str, can.BusABC], spool_dir: str | Path, *,
                 modbus: list[ModbusPollSpec] | None = None,
                 canopen: Mapping[str, tuple[int, EdsLike, str]] | None = None,
                 triggers: list[IvtTriggerSpec] | None = None, speedup: float = 1.0, flush_s: float = 0.2,
                 context: Mapping[str, str] | None = None) -> None:
        if not speedup > 0:
            raise ConfigError(f"speed-up must be > 0, got {speedup}")
        if not 0 < flush_s <= SPOOL_FLUSH_BOUND_S:
            raise ConfigError(f"spool flush period must be in (0, {SPOOL_FLUSH_BOUND_S}] s, got {flush_s}")
        self.buses = dict(buses)
        self.spool = Path(spool_dir)
        self.spool.mkdir(parents=True, exist_ok=True)
        for name, text in (context or {}).items():
            write_atomic(self.spool / name, text)
        self._events_fh = (self.spool / "events.jsonl").open("a", encoding="utf-8")
        self.speedup = float(speedup)
        self.flush_s = flush_s
        self.start_wall = time.time()
        self.events: list[TransportEvent] = []
        self._ev_lock = threading.Lock()
        self.spoolers = {b: _FrameSpooler(self, b, self.spool / f"{b}.frames") for b in self.buses}
        self.notifiers: dict[str, can.Notifier] = {}
        self.pollers = [_Poller(self, s, self.spool / f"{s.device}.polls") for s in (modbus or [])]
        self.canopen_spec = dict(canopen or {})
        for name, (_, _, bus) in self.canopen_spec.items():
            if bus not in self.buses:
                raise ConfigError(f"CANopen node {name!r} is on bus {bus!r}, which is not recorded")
        self.triggers = list(triggers or [])
        for t in self.triggers:
            if t.bus not in self.buses:
                raise ConfigError(f"IVT-S trigger on bus {t.bus!r}, which is not recorded")
        self.triggers_sent = 0
        self._trigger_threads: list[threading.Thread] = []
        self.thermo: dict[str, ThermoAcquisition] = {}
        self._stop = threading.Event()
        self._flusher: threading.Thread | None = None
        self._started = False

    def acq_time(self, wall: float | np.ndarray) -> float | np.ndarray:
        """Acquisition-clock seconds of a wall-clock (Unix) time."""
        return (wall - self.start_wall) * self.speedup

    def _event(self, source: str, kind: str, detail: str) -> None:
        t = float(self.acq_time(time.time()))
        with self._ev_lock:
            if kind == "reconnect":
                for ev in reversed(self.events):
                    if ev.source == source and ev.kind == "drop" and not np.isfinite(ev.end_s):
                        ev.end_s = t
                        break
            self.events.append(TransportEvent(t, source, kind, t if kind != "drop" else float("inf"), detail))
            with contextlib.suppress(OSError, ValueError):
                line = json.dumps({"time_s": t, "source": source, "kind": kind, "detail": detail})
                self._events_fh.write(line + "\n")
                self._events_fh.flush()

    def _write_manifest(self) -> None:
        write_atomic(self.spool / "spool.json", json.dumps({
            "format": "benchtwin spool 1", "start_unix_s": self.start_wall, "speedup": self.speedup,
            "flush_s": self.flush_s, "buses": list(self.buses),
            "polls": [{"device": p.spec.device, "unit_id": p.spec.unit_id, "function_code": p.spec.function_code,
                       "first_register": p.spec.first_register, "count": p.spec.count} for p in self.pollers],
            "canopen": list(self.canopen_spec)}, indent=1))

    def start(self) -> LiveRecorder:
        """Start receiving (acquisition time 0 is now)."""
        self.start_wall = time.time()
        self._write_manifest()
        for bus, b in self.buses.items():
            self.notifiers[bus] = can.Notifier(b, [self.spoolers[bus]], timeout=0.1)
        for name, (node_id, eds, bus) in self.canopen_spec.items():
            self.thermo[name] = ThermoAcquisition(node_id, eds, self.buses[bus], notifier=self.notifiers[bus])
        for p in self.pollers:
            p.start()
        for spec in self.triggers:
            th = threading.Thread(target=self._trigger_loop, args=(spec,), name="ivt-trigger", daemon=True)
            th.start()
            self._trigger_threads.append(th)
        self._flusher = threading.Thread(target=self._flush_loop, name="spool-flush", daemon=True)
        self._flusher.start()
        self._started = True
        return self

    def _trigger_loop(self, spec: IvtTriggerSpec) -> None:
        bus = self.buses[spec.bus]
        msg = can.Message(arbitration_id=spec.command_id, is_extended_id=False, data=[0x31, 0x00, spec.mask & 0xFF])
        period = spec.period_s / self.speedup
        next_t = time.perf_counter()
        while not self._stop.is_set():
            try:
                bus.send(msg)
                self.triggers_sent += 1
            except (can.CanError, OSError) as exc:
                log.warning("IVT-S trigger on %s failed: %s", spec.bus, exc)
                if self.spoolers[spec.bus].dropped:
                    return
            next_t += period
            self._stop.wait(max(0.0, next_t - time.perf_counter()))

    def _flush_loop(self) -> None:
        while not self._stop.wait(self.flush_s):
            for s in self.spoolers.values():
                try:
                    s.flush()
                except Exception as exc:  # a failing flush must not end the recording
                    log.error("spool flush of %s failed: %s", s.bus, exc)

    @property
    def all_can_dropped(self) -> bool:
        """True when every CAN bus lost its connection."""
        return bool(self.spoolers) and all(s.dropped for s in self.spoolers.values())

    def frames_received(self) -> int:
        """CAN frames received so far (flushed or not)."""
        return sum(s.n + len(s._rows) for s in self.spoolers.values())

    def wait(self, duration_s: float | None = None, idle_s: float | None = None) -> str:
        """Block until the duration (acquisition seconds) passed, the stream went idle, or every bus dropped.

        Returns the reason: ``duration``, ``idle``, ``dropped`` or ``interrupted`` (Ctrl-C).
        """
        end = None if duration_s is None else self.start_wall + duration_s / self.speedup
        try:
            while True:
                time.sleep(0.02)
                now = time.time()
                if end is not None and now >= end:
                    return "duration"
                if self.all_can_dropped:
                    return "dropped"
                if idle_s is not None and self.spoolers:
                    last = max(s.last_rx for s in self.spoolers.values())
                    if last > 0 and time.monotonic() - last > idle_s:
                        return "idle"
        except KeyboardInterrupt:
            return "interrupted"

    def stop(self, reason: str = "stop") -> LiveCapture:
        """Stop everything, flush the spools, and return what was received."""
        if not self._started:
            raise DataError("recorder was not started")
        self._stop.set()
        for th in self._trigger_threads:
            th.join(timeout=2.0)
        for p in self.pollers:
            p.stop()
        for n in self.notifiers.values():
            with contextlib.suppress(Exception):
                n.stop(timeout=1.0)
        if self._flusher is not None:
            self._flusher.join(timeout=2.0)
        for s in self.spoolers.values():
            s.close()
        self._event("*", "end", reason)
        with contextlib.suppress(OSError):
            self._events_fh.close()
        cap = LiveCapture(start_wall=self.start_wall, speedup=self.speedup, events=list(self.events))
        for bus, s in self.spoolers.items():
            frames = np.concatenate(s.parts) if s.parts else np.zeros(0, dtype=FRAME_DTYPE)
            cap.can[bus] = FrameTable(bus, frames)
        for p in self.pollers:
            cap.polls[p.spec.device] = p.poll_log()
        for name, acq in self.thermo.items():
            t = self.acq_time(np.asarray(acq.log.times, dtype=np.float64))
            cap.pdos[name] = PdoLog(list(acq.log.entries), [float(x) for x in np.atleast_1d(t)],
                                    list(acq.log.values), list(acq.log.cob_ids))
            with contextlib.suppress(Exception):
                acq.close()
        cap.stats = {
            "frames": {b: s.n for b, s in self.spoolers.items()},
            "error_frames": {b: s.errors for b, s in self.spoolers.items()},
            "polls": {p.spec.device: dict(p.counts) for p in self.pollers},
            "pdos": {n: len(a.log.times) for n, a in self.thermo.items()},
            "ivt_triggers_sent": self.triggers_sent,
            "reason": reason,
        }
        for b in self.buses.values():
            with contextlib.suppress(Exception):
                b.shutdown()
        return cap
