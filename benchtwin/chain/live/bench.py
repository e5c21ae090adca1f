"""A bench setup file turned into a live session (device side) and a live recorder (acquisition side).

The setup says which buses exist (and their bit rates), which IVT-S sit on which bus with which
identifiers, where the pressure module serves Modbus (unit id, port, poll rate) and where the thermo
module lives (bus, node id); the shipped wire formats say the rest (the thermo module's EDS, the
Modbus register map). Both ``benchtwin serve`` and ``benchtwin record`` start from here, so the two
sides of a live run agree by construction.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from benchtwin.chain.acquisition import AcquisitionInput, acquire
from benchtwin.chain.batch import write_logs
from benchtwin.chain.live.recorder import (
    IvtTriggerSpec,
    LiveCapture,
    LiveRecorder,
    ModbusPollSpec,
    open_acquisition_bus,
    read_frame_spool,
    read_poll_spool,
)
from benchtwin.chain.live.session import LiveSession
from benchtwin.config.setup import SetupConfig
from benchtwin.errors import ConfigError, DataError
from benchtwin.segments import Segment, load_segments, segments_to_json
from benchtwin.sensors import devices
from benchtwin.wire.frames import DeviceOutputs, TransportEvent

__all__ = ["capture_to_input", "embedded_recorder", "is_spool", "read_spool", "recorder_from_setup", "save_capture",
           "session_from_setup"]


def session_from_setup(outputs: DeviceOutputs, setup: SetupConfig, *, transport: str = "virtual",
                       speedup: float = 1.0, can_port: int = 0, modbus_port: int | None = None,
                       channel_map: Mapping[str, str] | None = None, start_s: float | None = None,
                       end_s: float | None = None, scheduler_options: Mapping[str, Any] | None = None,
                       seed: int | None = 0, realtime_priority: int | None = None) -> LiveSession:
    """A :class:`LiveSession` serving ``outputs`` as the bench of ``setup`` describes.

    The pressure module answers with the setup's poll faults (exception and no-answer probabilities)
    drawn from ``seed``.

    Parameters
    ----------
    modbus_port:
        Port of the pressure module; default: the setup's (``pressure.port``); 0 picks a free one.
    """
    devs = devices(setup)
    ivt: dict[str, dict[str, Any]] = {}
    holding: dict[str, dict[int, int]] = {}
    faults: dict[str, dict[str, Any]] = {}
    port = 0
    canopen_bus: dict[str, str] = {}
    eds = None
    for d in devs:
        commands = d.command_device()
        if commands is not None:
            ivt.setdefault(d.bus, {})[d.name] = commands
        ep = d.modbus_endpoint(seed)
        if ep is not None:
            holding[ep.device] = ep.holding
            faults[ep.device] = ep.faults
            port = port or ep.port  # one Modbus TCP server serves every device (by unit id)
        node = d.canopen_endpoint()
        if node is not None:
            canopen_bus[node.name] = node.bus
            eds = node.eds
    if modbus_port is not None:
        port = modbus_port
    return LiveSession(outputs, transport=transport, speedup=speedup, can_port=can_port, modbus_port=port,
                       eds=eds, canopen_bus=canopen_bus, ivt=ivt, holding=holding, modbus_faults=faults,
                       bitrates={b: c.bitrate for b, c in setup.buses.items()}, channel_map=channel_map,
                       start_s=start_s, end_s=end_s, scheduler_options=scheduler_options,
                       realtime_priority=realtime_priority)


def _acquisition_side(setup: SetupConfig, buses: Mapping[str, Any], *, modbus_host: str,
                      modbus_port: int | None, modbus: bool = True, canopen: bool = True
                      ) -> tuple[list[ModbusPollSpec], dict[str, tuple[int, Path, str]], list[IvtTriggerSpec]]:
    """What the acquisition polls, which CANopen nodes it listens to and which triggers it sends."""
    polls, nodes, triggers = [], {}, []
    for d in devices(setup):
        ep = d.modbus_endpoint(None) if modbus else None
        if ep is not None:
            polls.append(ModbusPollSpec(ep.device, modbus_host, modbus_port if modbus_port is not None else ep.port,
                                        ep.unit_id, ep.function_code, ep.first_register, ep.count, ep.poll_hz))
        node = d.canopen_endpoint() if canopen else None
        if node is not None and node.bus in buses:
            nodes[node.name] = (node.node_id, node.eds, node.bus)
        triggers += [IvtTriggerSpec(t.bus, t.command_id, t.mask, t.period_s) for t in d.triggers() if t.bus in buses]
    return polls, nodes, triggers


def recorder_from_setup(setup: SetupConfig, spool_dir: str | Path, *, transport: str = "socketcand",
                        host: str = "127.0.0.1", port: int = 29536, modbus_host: str | None = None,
                        modbus_port: int | None = None, speedup: float = 1.0, buses: list[str] | None = None,
                        channel_map: Mapping[str, str] | None = None, modbus: bool = True,
                        canopen: bool = True, connect_timeout: float = 10.0,
                        segments: list[Segment] | None = None) -> LiveRecorder:
    """A :class:`LiveRecorder` connected to every bus, the pressure module and the thermo module of ``setup``.

    IVT-S configured in triggered mode are triggered at their ``trigger_period_ms`` (plant time).

    Raises
    ------
    TransportError
        A bus cannot be reached (nothing is left open).
    """
    names = list(buses) if buses is not None else list(setup.buses)
    opened = {}
    try:
        for b in names:
            opened[b] = open_acquisition_bus(transport, b, host=host, port=port,
                                             channel=(channel_map or {}).get(b), connect_timeout=connect_timeout)
    except BaseException:
        for bus in opened.values():
            bus.shutdown()
        raise
    polls, nodes, triggers = _acquisition_side(setup, opened, modbus_host=modbus_host or host,
                                               modbus_port=modbus_port, modbus=modbus, canopen=canopen)
    return LiveRecorder(opened, spool_dir, modbus=polls, canopen=nodes, triggers=triggers, speedup=speedup,
                        context=_spool_context(setup, segments))


def _spool_context(setup: SetupConfig, segments: list[Segment] | None) -> dict[str, str]:
    """The files a spool holds from the start so that it decodes alone: the setup and the segment table."""
    out = {"setup.json": setup.model_dump_json(indent=1)}
    if segments:
        out["segments.json"] = segments_to_json(segments)
    return out


def capture_to_input(capture: LiveCapture, segments: list[Segment] | None = None,
                     meta: Mapping[str, Any] | None = None) -> AcquisitionInput:
    """The decoder's input from a live capture.

    The PDO frames are already in the thermo module's bus's frame table (they were recorded raw), so
    live and batch decode them the same way; the RemoteNode's own log goes into the metadata counts.
    """
    m = {"acquisition": "live", "live_start_unix_s": capture.start_wall, "live_speedup": capture.speedup,
         "live_stats": capture.stats}
    m.update(meta or {})
    return AcquisitionInput(can=dict(capture.can), polls=dict(capture.polls), events=list(capture.events),
                            segments=list(segments or []), meta=m,
                            start_time=datetime.fromtimestamp(capture.start_wall, UTC))


def embedded_recorder(session: LiveSession, setup: SetupConfig, spool_dir: str | Path,
                      segments: list[Segment] | None = None) -> LiveRecorder:
    """A recorder in the serving process: one client per bus on the session's own transport (the embedded
    ``virtual`` bus works), the session's Modbus server, the thermo module's PDOs, IVT-S triggers."""
    if session.transport is None or session.scheduler is None:
        raise ConfigError("start the session before attaching a recorder")
    buses = {b: session.transport.open_client(b) for b in session.transport.bitrates}
    modbus_port = session.modbus.port if session.modbus is not None else None
    polls, nodes, triggers = _acquisition_side(setup, buses, modbus_host="127.0.0.1", modbus_port=modbus_port,
                                               modbus=session.modbus is not None)
    return LiveRecorder(buses, spool_dir, modbus=polls, canopen=nodes, triggers=triggers, speedup=session.speedup,
                        context=_spool_context(setup, segments))


def is_spool(directory: str | Path) -> bool:
    """True when ``directory`` is a live recorder's spool (``spool.json`` or ``<bus>.frames`` files)."""
    d = Path(directory)
    return d.is_dir() and ((d / "spool.json").exists() or any(d.glob("*.frames")))


def read_spool(directory: str | Path, setup: SetupConfig | None = None) -> tuple[AcquisitionInput, SetupConfig]:
    """The decoder's input from a recorder's spool, e.g. after the recorder was killed.

    Every whole record of ``<bus>.frames`` and ``<device>.polls`` is kept (a partial last record, cut by
    the kill, is dropped); the transport events come from ``events.jsonl``; the setup from ``setup.json``
    unless given; the segment table from ``segments.json`` if present. ``meta["recovered_spool"]`` says
    what was recovered and where each bus's data ends.

    Raises
    ------
    DataError
        The folder is not a spool, or no setup is given or found.
    """
    import json

    from benchtwin.config._base import validate_data

    d = Path(directory)
    if not is_spool(d):
        raise DataError(f"{d}: not a recorder spool (no spool.json or *.frames)")
    if setup is None:
        sp = d / "setup.json"
        if not sp.exists():
            raise DataError(f"{d}: the spool has no setup.json; pass the setup used for the recording")
        setup = validate_data(SetupConfig, json.loads(sp.read_text(encoding="utf-8")), str(sp))
    manifest: dict[str, Any] = {}
    if (d / "spool.json").exists():
        try:
            manifest = json.loads((d / "spool.json").read_text(encoding="utf-8"))
        except ValueError as exc:
            raise DataError(f"{d / 'spool.json'}: not readable ({exc})") from exc
    received = AcquisitionInput()
    for p in sorted(d.glob("*.frames")):
        bitrate = setup.buses[p.stem].bitrate if p.stem in setup.buses else 500_000
        received.can[p.stem] = read_frame_spool(p, p.stem, bitrate)
    specs = {s["device"]: s for s in manifest.get("polls", [])}
    if not specs:  # a spool without its manifest: the poll layouts of the setup
        polls, _, _ = _acquisition_side(setup, {}, modbus_host="127.0.0.1", modbus_port=None, canopen=False)
        specs = {s.device: {"unit_id": s.unit_id, "function_code": s.function_code,
                            "first_register": s.first_register, "count": s.count} for s in polls}
    for p in sorted(d.glob("*.polls")):
        dev = p.name[:-len(".polls")]
        sp = specs.get(dev)
        if sp is not None:
            received.polls[dev] = read_poll_spool(p, dev, int(sp["unit_id"]), int(sp["function_code"]),
                                                  int(sp["first_register"]), int(sp["count"]))
    if (d / "events.jsonl").exists():
        for line in (d / "events.jsonl").read_text(encoding="utf-8").splitlines():
            try:
                e = json.loads(line)
                t, src, kind = float(e["time_s"]), str(e["source"]), str(e["kind"])
            except (ValueError, KeyError, TypeError):
                continue  # the last line, cut by the kill
            if kind == "reconnect":
                for ev in reversed(received.events):
                    if ev.source == src and ev.kind == "drop" and ev.end_s == float("inf"):
                        ev.end_s = t
                        break
            received.events.append(TransportEvent(t, src, kind, float("inf") if kind == "drop" else t,
                                                  str(e.get("detail", ""))))
    if (d / "segments.json").exists():
        received.segments = load_segments(d / "segments.json")
    ended = any(e.kind == "end" for e in received.events)
    ends = {b: float(t.frames["timestamp"][-1]) if len(t) else None for b, t in received.can.items()}
    received.meta = {"acquisition": "live", "live_start_unix_s": manifest.get("start_unix_s"),
                     "live_speedup": manifest.get("speedup"),
                     "recovered_spool": {"folder": str(d), "recorder_stopped_cleanly": ended,
                                         "frames": {b: len(t) for b, t in received.can.items()},
                                         "polls": {k: len(v) for k, v in received.polls.items()},
                                         "last_frame_s": ends},
                     "stop_reason": "end" if ended else "recorder killed: recovered from its spool"}
    return received, setup


def save_capture(capture: LiveCapture, setup: SetupConfig, out: str | Path, *, segments: list[Segment] | None = None,
                 meta: Mapping[str, Any] | None = None, spool_dir: str | Path | None = None) -> Any:
    """Decode a live capture into the Recording ``out`` (MF4) and write the raw logs next to it.

    Raw logs in ``<out stem>_raw/``, as batch writes them (:func:`benchtwin.chain.batch.write_logs`), so
    the folder decodes on its own (``benchtwin acquire <out stem>_raw``, ``cantools decode``, asammdf):
    ``<bus>.mf4`` (MF4 bus logging), ``<device>.polls.npz``, ``<bus>.dbc`` for every bus, the thermo
    module's EDS, ``setup.json``, ``segments.json``, ``meta.json``, plus ``capture.json`` (counters and
    transport events). The logs and the Recording start at the acquisition start (wall clock, UTC).
    Returns the Recording.

    Raises
    ------
    DataError
        Something cannot be written (the spool, if given, still holds everything received).
    """
    import json

    out = Path(out)
    raw_dir = out.with_name(out.stem + "_raw")
    try:
        received = capture_to_input(capture, segments, meta)
        write_logs(received, setup, raw_dir)
        recording = acquire(received, setup)
        recording.save(out)
        (raw_dir / "capture.json").write_text(json.dumps(
            {"stats": capture.stats, "events": recording.meta.get("transport_events", [])}, indent=1,
            default=float))
    except OSError as exc:
        kept = f"; everything received is kept in {spool_dir}" if spool_dir is not None else ""
        raise DataError(f"cannot write {out} or its raw logs ({exc}){kept}") from exc
    return recording
