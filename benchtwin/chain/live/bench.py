"""A bench setup file turned into a live session (device side) and a live recorder (acquisition side).

The setup says which buses exist (and their bit rates), which IVT-S sit on which bus with which
identifiers, where the pressure module serves Modbus (unit id, port, poll rate) and where the thermo
module lives (bus, node id); the shipped wire formats say the rest (the thermo module's EDS, the
Modbus register map). Both ``benchtwin serve`` and ``benchtwin record`` start from here, so the two
sides of a live run agree by construction.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from benchtwin.chain.frames import DeviceOutputs
from benchtwin.chain.live.recorder import (
    IvtTriggerSpec,
    LiveCapture,
    LiveRecorder,
    ModbusPollSpec,
    open_acquisition_bus,
)
from benchtwin.chain.live.session import LiveSession
from benchtwin.config.setup import SetupConfig
from benchtwin.errors import ConfigError, DataError
from benchtwin.segments import Segment

__all__ = ["capture_to_input", "embedded_recorder", "recorder_from_setup", "save_capture", "session_from_setup"]


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
    from benchtwin.chain.canopen_pdo import EDS_PATH
    from benchtwin.chain.modbus_map import holding_defaults
    from benchtwin.sensors.ivt import IvtDevice

    ivt: dict[str, dict[str, IvtDevice]] = {}
    for place, cfg in setup.ivt.items():
        ivt.setdefault(cfg.bus, {})[f"ivt_{place}"] = IvtDevice(cfg)
    holding = {}
    faults: dict[str, dict[str, Any]] = {}
    port = 0
    if setup.pressure is not None:
        p = setup.pressure
        holding[p.device] = holding_defaults(p.full_scale_bar, p.full_scale_v)
        faults[p.device] = {"exception_prob": p.exception_prob, "exception_code": p.exception_code,
                            "timeout_prob": p.timeout_prob, "seed": seed}
        port = p.port
    if modbus_port is not None:
        port = modbus_port
    canopen_bus = {"thermo": setup.thermo.bus} if setup.thermo is not None else {}
    return LiveSession(outputs, transport=transport, speedup=speedup, can_port=can_port, modbus_port=port,
                       eds=EDS_PATH, canopen_bus=canopen_bus, ivt=ivt, holding=holding, modbus_faults=faults,
                       bitrates={b: c.bitrate for b, c in setup.buses.items()}, channel_map=channel_map,
                       start_s=start_s, end_s=end_s, scheduler_options=scheduler_options,
                       realtime_priority=realtime_priority)


def recorder_from_setup(setup: SetupConfig, spool_dir: str | Path, *, transport: str = "socketcand",
                        host: str = "127.0.0.1", port: int = 29536, modbus_host: str | None = None,
                        modbus_port: int | None = None, speedup: float = 1.0, buses: list[str] | None = None,
                        channel_map: Mapping[str, str] | None = None, modbus: bool = True,
                        canopen: bool = True, connect_timeout: float = 10.0) -> LiveRecorder:
    """A :class:`LiveRecorder` connected to every bus, the pressure module and the thermo module of ``setup``.

    IVT-S configured in triggered mode are triggered at their ``trigger_period_ms`` (plant time).

    Raises
    ------
    TransportError
        A bus cannot be reached (nothing is left open).
    """
    from benchtwin.chain.canopen_pdo import EDS_PATH
    from benchtwin.chain.modbus_map import INPUT_COUNT
    from benchtwin.sensors.ivt import RESULT_NAMES

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
    polls = []
    if modbus and setup.pressure is not None:
        p = setup.pressure
        polls.append(ModbusPollSpec(p.device, modbus_host or host, modbus_port if modbus_port is not None else p.port,
                                    p.unit_id, 4, 0, INPUT_COUNT, p.poll_hz))
    nodes = {}
    if canopen and setup.thermo is not None and setup.thermo.bus in opened:
        nodes["thermo"] = (setup.thermo.node_id, EDS_PATH, setup.thermo.bus)
    triggers = [IvtTriggerSpec(cfg.bus, cfg.command_id, sum(1 << RESULT_NAMES.index(r) for r in cfg.results),
                               cfg.trigger_period_ms / 1000.0)
                for cfg in setup.ivt.values() if cfg.mode == "triggered" and cfg.bus in opened]
    return LiveRecorder(opened, spool_dir, modbus=polls, canopen=nodes, triggers=triggers, speedup=speedup)


def capture_to_input(capture: LiveCapture, segments: list[Segment] | None = None,
                     meta: Mapping[str, Any] | None = None) -> Any:
    """The decoder's input (:class:`benchtwin.chain.acquisition.AcquisitionInput`) from a live capture.

    The PDO frames are already in the thermo module's bus's frame table (they were recorded raw), so
    live and batch decode them the same way; the RemoteNode's own log goes into the metadata counts.
    """
    from benchtwin.chain.acquisition import AcquisitionInput

    m = {"acquisition": "live", "live_start_unix_s": capture.start_wall, "live_speedup": capture.speedup,
         "live_stats": capture.stats}
    m.update(meta or {})
    return AcquisitionInput(can=dict(capture.can), polls=dict(capture.polls), events=list(capture.events),
                            segments=list(segments or []), meta=m)


def embedded_recorder(session: LiveSession, setup: SetupConfig, spool_dir: str | Path) -> LiveRecorder:
    """A recorder in the serving process: one client per bus on the session's own transport (the embedded
    ``virtual`` bus works), the session's Modbus server, the thermo module's PDOs, IVT-S triggers."""
    from benchtwin.chain.canopen_pdo import EDS_PATH
    from benchtwin.chain.modbus_map import INPUT_COUNT
    from benchtwin.sensors.ivt import RESULT_NAMES

    if session.transport is None or session.scheduler is None:
        raise ConfigError("start the session before attaching a recorder")
    buses = {b: session.transport.open_client(b) for b in session.transport.bitrates}
    polls = []
    if setup.pressure is not None and session.modbus is not None:
        p = setup.pressure
        polls.append(ModbusPollSpec(p.device, "127.0.0.1", session.modbus.port, p.unit_id, 4, 0, INPUT_COUNT,
                                    p.poll_hz))
    nodes = {}
    if setup.thermo is not None and setup.thermo.bus in buses:
        nodes["thermo"] = (setup.thermo.node_id, EDS_PATH, setup.thermo.bus)
    triggers = [IvtTriggerSpec(cfg.bus, cfg.command_id, sum(1 << RESULT_NAMES.index(r) for r in cfg.results),
                               cfg.trigger_period_ms / 1000.0)
                for cfg in setup.ivt.values() if cfg.mode == "triggered" and cfg.bus in buses]
    return LiveRecorder(buses, spool_dir, modbus=polls, canopen=nodes, triggers=triggers, speedup=session.speedup)


def save_capture(capture: LiveCapture, setup: SetupConfig, out: str | Path, *, segments: list[Segment] | None = None,
                 meta: Mapping[str, Any] | None = None, spool_dir: str | Path | None = None) -> Any:
    """Decode a live capture into the Recording ``out`` (MF4) and write the raw logs next to it.

    Raw logs: ``<out stem>_raw/<bus>.mf4`` (MF4 bus logging), ``<device>.polls.npz`` and ``capture.json``
    (counters and transport events). Returns the Recording.

    Raises
    ------
    DataError
        Something cannot be written (the spool, if given, still holds everything received).
    """
    import json

    from benchtwin.chain.acquisition import acquire
    from benchtwin.chain.buslog import write_mf4, write_poll_log

    out = Path(out)
    raw_dir = out.with_name(out.stem + "_raw")
    try:
        raw_dir.mkdir(parents=True, exist_ok=True)
        for bus, table in capture.can.items():
            if len(table):
                write_mf4(table, raw_dir / f"{bus}.mf4")
        for dev, plog in capture.polls.items():
            write_poll_log(plog, raw_dir / f"{dev}.polls.npz")
        recording = acquire(capture_to_input(capture, segments, meta), setup)
        recording.save(out)
        (raw_dir / "capture.json").write_text(json.dumps(
            {"stats": capture.stats, "events": recording.meta.get("transport_events", [])}, indent=1,
            default=float))
    except OSError as exc:
        kept = f"; everything received is kept in {spool_dir}" if spool_dir is not None else ""
        raise DataError(f"cannot write {out} or its raw logs ({exc}){kept}") from exc
    return recording
