"""The CAN layouts of the bench as DBC files (built with cantools, shipped in ``benchtwin/wire/dbc/``).

Four layouts, one file each:

``vehicle.dbc`` (vehicle CAN, 500 kbit/s)
    What the car's ECUs put on the bus (read through the OBD/gateway tap): engine speed, torque and
    state, motor speed and torque, fuel mass flow, gears, lock-up and K0 state, pedals, vehicle speed,
    displayed SOC and hybrid mode. Resolutions and cycle times as on production buses (10 ms for the
    drive-train torque messages, 20 ms for transmission, pedals and speed, 50 ms fuel, 100 ms for the
    hybrid status). Some messages are Motorola (big-endian), some Intel, as on real cars.
``dyno.dbc`` (dyno CAN, 500 kbit/s, 100 Hz)
    The chassis dyno's automation system broadcasts roller speed, set speed (``0xFFFF`` = no speed
    set point: road-load mode) and the front and rear roller forces. This is the dyno signal source of
    the bench: a separate bus with its own logger clock, so the acquisition can detect the clock
    offset between the car and the dyno.
``ivt_s.dbc`` (instrument CAN)
    One Isabellenhuette IVT-S with the factory identifiers (results 0x521..0x528, commands 0x411,
    answers 0x511): mux byte, 4-bit counter and status nibble, big-endian int32 in mA/mV/0.1 degC/
    W/As/Wh. Each shunt of a setup gets its own identifiers; ``benchtwin.sensors.bus_database`` renames
    and moves the messages per shunt.
``ad_module.dbc`` (instrument CAN)
    The AD module digitising the telemetry output of the propeller-shaft torque: 12-bit two's
    complement over +-10 V (LSB 20 V / 4096), a 4-bit counter and a clip bit.

The CANopen thermo module is described by its EDS (``thermo_module.eds``); :func:`build_thermo_pdos`
gives its TPDOs as DBC messages derived from the EDS mapping, so the per-bus DBC written next to the logs
decodes every frame of the bus.

Run ``python -m benchtwin.wire.dbc`` to regenerate the shipped files from the definitions below.
"""

from __future__ import annotations

import functools
from collections import OrderedDict
from pathlib import Path
from typing import Any

import cantools
from cantools.database.can import Database, Message, Node, Signal
from cantools.database.conversion import BaseConversion

from benchtwin.errors import ConfigError
from benchtwin.wire.canopen_pdo import pdo_layout

__all__ = [
    "AD_TORQUE_LSB_V",
    "DBC_DIR",
    "IVT_RESULTS",
    "build_ad_module",
    "build_dyno",
    "build_ivt",
    "build_thermo_pdos",
    "build_vehicle",
    "ivt_node_name",
    "load_dbc",
    "write_shipped",
]

DBC_DIR = Path(__file__).resolve().parent / "dbc"

#: IVT-S results in mux order: (short name, DBC unit, DBC scale of the int32): I in mA, U in mV, T in 0.1 degC
IVT_RESULTS: tuple[tuple[str, str, float], ...] = (
    ("I", "mA", 1.0), ("U1", "mV", 1.0), ("U2", "mV", 1.0), ("U3", "mV", 1.0), ("T", "degC", 0.1), ("W", "W", 1.0),
    ("As", "As", 1.0), ("Wh", "Wh", 1.0),
)

#: telemetry AD module: 12 bits over +-10 V
AD_TORQUE_LSB_V = 20.0 / 4096.0


def _sig(name: str, start: int, length: int, *, big: bool = False, signed: bool = False, scale: float = 1.0,
         offset: float = 0.0, unit: str = "", minimum: float | None = None, maximum: float | None = None,
         comment: str = "", choices: dict[int, str] | None = None, receivers: list[str] | None = None) -> Signal:
    conv = BaseConversion.factory(scale=scale, offset=offset,
                                  choices=OrderedDict(sorted(choices.items())) if choices else None)
    return Signal(name, start, length, "big_endian" if big else "little_endian", signed, conversion=conv,
                  minimum=minimum, maximum=maximum, unit=unit or None, comment=comment or None,
                  receivers=receivers or ["BENCH"])


def _msg(frame_id: int, name: str, length: int, signals: list[Signal], cycle_ms: int | None, sender: str,
         comment: str = "") -> Message:
    return Message(frame_id, name, length, signals, cycle_time=cycle_ms, senders=[sender], comment=comment or None,
                   strict=True)


#: value table of the gear signals
GEAR_TEXTS: dict[int, str] = {0: "Neutral", 1: "1st", 2: "2nd", 3: "3rd", **{g: f"{g}th" for g in range(4, 10)}}


def build_vehicle() -> Database:
    """The vehicle CAN layout (see the module docstring)."""
    msgs = [
        _msg(0x0A0, "ENG_Status", 8, [
            _sig("EngSpeed", 7, 16, big=True, scale=0.25, unit="rpm", minimum=0, maximum=16383.75,
                 comment="crankshaft speed"),
            _sig("EngTorque", 23, 16, big=True, signed=True, scale=0.1, unit="Nm", minimum=-3276.8, maximum=3276.7,
                 comment="engine brake torque"),
            _sig("EngOn", 39, 1, big=True, choices={0: "off", 1: "firing"}),
            _sig("EngCounter", 59, 4, big=True, comment="alive counter"),
        ], 10, "ECM", "engine status"),
        _msg(0x0B0, "EM_Status", 8, [
            _sig("EmSpeed", 0, 16, signed=True, scale=0.5, unit="rpm", minimum=-16384, maximum=16383.5),
            _sig("EmTorque", 16, 16, signed=True, scale=0.1, unit="Nm", minimum=-3276.8, maximum=3276.7),
            _sig("EmCounter", 56, 4, comment="alive counter"),
        ], 10, "HPCU", "electric motor status"),
        _msg(0x0C0, "ENG_Fuel", 8, [
            _sig("FuelMassFlow", 0, 16, scale=0.001, unit="g/s", minimum=0, maximum=65.535),
        ], 50, "ECM", "fuel mass flow"),
        _msg(0x0D0, "TCU_Status", 8, [
            _sig("GearTarget", 0, 4, minimum=0, maximum=9, comment="0 neutral", choices=GEAR_TEXTS),
            _sig("GearActual", 4, 4, minimum=0, maximum=9, comment="0 neutral", choices=GEAR_TEXTS),
            _sig("LockupClosed", 8, 1, choices={0: "open", 1: "closed"}),
            _sig("K0Closed", 9, 1, choices={0: "open", 1: "closed"}),
        ], 20, "TCU", "transmission status"),
        _msg(0x0E0, "PEDALS", 8, [
            _sig("AccelPedal", 0, 8, scale=0.4, unit="%", minimum=0, maximum=100),
            _sig("BrakePedal", 8, 8, scale=0.4, unit="%", minimum=0, maximum=100),
        ], 20, "VCU", "pedal positions"),
        _msg(0x1A0, "VEH_Speed", 8, [
            _sig("VehicleSpeed", 7, 16, big=True, scale=0.01, unit="km/h", minimum=0, maximum=655.35),
        ], 20, "ABS", "vehicle speed"),
        _msg(0x3A0, "HYB_Status", 8, [
            _sig("DisplayedSOC", 0, 8, scale=0.5, unit="%", minimum=0, maximum=100),
            _sig("HybridMode", 8, 3, choices={0: "Hybrid", 1: "Electric", 2: "E-Save", 3: "Charge"}),
        ], 100, "VCU", "hybrid status"),
    ]
    nodes = [Node(n) for n in ("ECM", "HPCU", "TCU", "VCU", "ABS", "BENCH")]
    return Database(msgs, nodes, version="benchtwin-vehicle-1")


def build_dyno() -> Database:
    """The chassis dyno CAN layout (100 Hz)."""
    msgs = [
        _msg(0x700, "DYNO_Speed", 8, [
            _sig("RollerSpeed", 0, 16, signed=True, scale=0.01, unit="km/h", minimum=-327.68, maximum=327.67),
            _sig("SetSpeed", 16, 16, scale=0.01, unit="km/h", minimum=0, maximum=655.34,
                 comment="0xFFFF: no speed set point (road-load mode)"),
            _sig("DynoCounter", 56, 4),
        ], 10, "DYNO", "roller speed and set point"),
        _msg(0x701, "DYNO_Force", 8, [
            _sig("ForceFront", 0, 32, signed=True, scale=0.1, unit="N", comment="front roller tractive force"),
            _sig("ForceRear", 32, 32, signed=True, scale=0.1, unit="N", comment="rear roller tractive force"),
        ], 10, "DYNO", "roller forces"),
    ]
    return Database(msgs, [Node("DYNO"), Node("BENCH")], version="benchtwin-dyno-1")


def build_ivt(name: str = "IVT", result_base_id: int = 0x521, command_id: int = 0x411,
              response_id: int = 0x511, cycle_ms: int = 20) -> Database:
    """One IVT-S: eight result messages, the command message and its answer.

    Parameters
    ----------
    name:
        Prefix of the message names and the sender node (``IVT_Battery``).
    result_base_id:
        Identifier of the current result; U1..Wh follow at +1..+7.
    command_id, response_id:
        Identifiers of the command channel.
    cycle_ms:
        Cycle time written to the DBC (GenMsgCycleTime).
    """
    msgs = []
    for mux, (res, unit, scale) in enumerate(IVT_RESULTS):
        msgs.append(_msg(result_base_id + mux, f"{name}_Result_{res}", 6, [
            _sig(f"{name}_{res}_MuxID", 7, 8, big=True, comment=f"mux byte, always 0x{mux:02X}"),
            _sig(f"{name}_{res}_Status", 15, 4, big=True,
                 comment="bit0 OCS, bit1 out of range / channel error, bit2 measurement error, bit3 system error"),
            _sig(f"{name}_{res}_Counter", 11, 4, big=True, comment="cyclic message counter"),
            _sig(f"{name}_{res}", 23, 32, big=True, signed=True, scale=scale, unit=unit),
        ], cycle_ms, name, f"IVT-S result {res}"))
    msgs.append(_msg(command_id, f"{name}_Msg_Command", 8, [
        _sig(f"{name}_Cmd", 7, 8, big=True, comment="0x2n configure channel n, 0x30 reset errors, 0x31 trigger, "
                                                     "0x34 set run/stop mode"),
        _sig(f"{name}_CmdArg1", 15, 8, big=True),
        _sig(f"{name}_CmdArg2", 23, 16, big=True),
        _sig(f"{name}_CmdArg3", 39, 32, big=True),
    ], None, "BENCH", "commands to the sensor"))
    msgs.append(_msg(response_id, f"{name}_Msg_Response", 8, [
        _sig(f"{name}_Resp", 7, 8, big=True, comment="command + 0x80; 0xFF unknown command"),
        _sig(f"{name}_RespArg1", 15, 8, big=True),
        _sig(f"{name}_RespArg2", 23, 16, big=True),
        _sig(f"{name}_RespArg3", 39, 32, big=True),
    ], None, name, "answers of the sensor"))
    return Database(msgs, [Node(name), Node("BENCH")], version="benchtwin-ivt-s-1")


def build_ad_module(name: str = "AD_Torque", frame_id: int = 0x310, cycle_ms: int = 2,
                    k_tot_nm_per_v: float | None = None) -> Database:
    """The AD module frame carrying the telemetry output voltage (12-bit, +-10 V).

    The shipped ``ad_module.dbc`` is generic: ``<name>_Vout`` in volts. With ``k_tot_nm_per_v`` (the
    setup's K_TOT, eq. 12) the same bits are ``<name>_ShaftTorque`` in Nm (scale K_TOT * 20 V / 4096):
    the per-setup DBC written beside the logs decodes the shaft torque directly.
    """
    if k_tot_nm_per_v is None:
        value = _sig(f"{name}_Vout", 0, 12, signed=True, scale=AD_TORQUE_LSB_V, unit="V", minimum=-10.0,
                     maximum=10.0, comment="telemetry output voltage; torque = K_TOT * Vout")
    else:
        k = float(k_tot_nm_per_v)
        value = _sig(f"{name}_ShaftTorque", 0, 12, signed=True, scale=k * AD_TORQUE_LSB_V, unit="Nm",
                     minimum=-10.0 * k, maximum=10.0 * k,
                     comment=f"propeller-shaft torque = K_TOT * Vout with this setup's K_TOT = {k:.6g} Nm/V "
                             f"(Vout = raw * 20 V / 4096)")
    msgs = [_msg(frame_id, name, 3, [
        value,
        _sig(f"{name}_Counter", 12, 4),
        _sig(f"{name}_Clip", 16, 1, choices={0: "ok", 1: "clipped"}),
    ], cycle_ms, "ADMM", "AD MiniModule, propeller-shaft torque telemetry")]
    return Database(msgs, [Node("ADMM"), Node("BENCH")], version="benchtwin-ad-1")


_SHIPPED: dict[str, Any] = {
    "vehicle": build_vehicle,
    "dyno": build_dyno,
    "ivt_s": build_ivt,
    "ad_module": build_ad_module,
}


def write_shipped(directory: Path = DBC_DIR) -> list[Path]:
    """Write the shipped DBC files from the definitions; return their paths."""
    directory.mkdir(parents=True, exist_ok=True)
    out = []
    for stem, build in _SHIPPED.items():
        path = directory / f"{stem}.dbc"
        cantools.database.dump_file(build(), str(path))
        out.append(path)
    return out


@functools.cache
def load_dbc(stem: str) -> Database:
    """Load a shipped DBC (``vehicle``, ``dyno``, ``ivt_s``, ``ad_module``) with cantools.

    Raises
    ------
    ConfigError
        If no such file is shipped.
    """
    path = DBC_DIR / f"{stem}.dbc"
    if not path.exists():
        raise ConfigError(f"no shipped DBC {stem!r} (have: {', '.join(sorted(_SHIPPED))})")
    return cantools.database.load_file(str(path))


def ivt_node_name(place: str) -> str:
    """DBC node/message prefix of the shunt at ``place`` (``battery`` -> ``IVT_Battery``)."""
    return "IVT_" + "".join(w.capitalize() for w in place.split("_"))


#: CANopen NMT states as the heartbeat carries them
NMT_STATE_TEXTS: dict[int, str] = {0: "Boot-up", 4: "Stopped", 5: "Operational", 127: "Pre-operational"}


def build_thermo_pdos(node_id: int, places: list[str] | tuple[str, ...] = ()) -> Database:
    """The thermo module's TPDOs as DBC messages, derived from its EDS mapping (for CAN tools).

    The EDS stays the description of the node; this view lets ``cantools decode`` or a CAN tool
    read the temperatures from a bus log. Inputs are named after ``places`` (in input order).
    """
    layout = pdo_layout(node_id)
    msgs = []
    for tp in layout.tpdos:
        sigs = []
        for (index, sub), dt, off in zip(tp.entries, tp.dtypes, tp.offsets):
            if index == 0x9130:
                name = places[sub - 1] if sub <= len(places) else f"AI_Input_{sub}"
                comment = f"0x9130 sub {sub}; 0x7FFF above range, -0x8000 below range or open"
            elif index == 0x2100:
                name, comment = "Cold_Junction", "0x2100 cold-junction temperature"
            else:
                name, comment = f"Obj_{index:04X}_{sub}", ""
            bits = 8 * int(dt[1:])
            sigs.append(_sig(f"Thermo_{name}", 8 * off, bits, signed=dt.startswith("i"),
                             scale=layout.scale((index, sub)), unit="degC", comment=comment))
        msgs.append(_msg(tp.cob_id, f"THERMO_TPDO{tp.number}", tp.length, sigs, tp.event_ms or None, "THMM",
                         f"CANopen TPDO{tp.number} of node {node_id} (from thermo_module.eds)"))
    msgs.append(_msg(0x700 + node_id, "THERMO_NMT_ErrorControl", 1, [
        _sig("Thermo_NMT_State", 0, 7, choices=NMT_STATE_TEXTS,
             comment="0 boot-up message, else the heartbeat's state"),
        _sig("Thermo_NMT_Toggle", 7, 1),
    ], None, "THMM", f"CANopen boot-up and heartbeat of node {node_id} (period: object 0x1017)"))
    return Database(msgs, [Node("THMM"), Node("BENCH")], version="benchtwin-thermo-pdo-1")


if __name__ == "__main__":  # pragma: no cover
    for p in write_shipped():
        print(p)
