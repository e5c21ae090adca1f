"""CAN transports behind one small base, chosen by name from a lazy registry.

A transport carries the emulated devices' CAN buses to an acquisition: the device side gets a
python-can bus per named bus (``powertrain``, ``vehicle``, ``instrument``), the acquisition side
opens python-can buses of its own (in the same process, or in another one for the network
transports). Backends are named here as strings and imported only when chosen, so a backend whose
optional dependency or kernel feature is missing breaks only itself::

    virtual     python-can in-process virtual bus (the embedded default)
    socketcand  our endpoint speaking the socketcand ASCII protocol on 127.0.0.1
    socketcan   kernel SocketCAN interfaces (vcan0 ...), only where AF_CAN exists

python-can's ``udp_multicast`` is deliberately not offered: its traffic leaves the machine.
"""

from __future__ import annotations

import importlib

from benchtwin.chain.transports.base import Transport, frames_to_messages, message_to_frame
from benchtwin.errors import ConfigError, TransportError

__all__ = ["TRANSPORTS", "Transport", "available_transports", "frames_to_messages", "get_transport",
           "message_to_frame"]

#: name -> "module:Class", imported on first use
TRANSPORTS: dict[str, str] = {
    "virtual": "benchtwin.chain.transports.virtual:VirtualTransport",
    "socketcand": "benchtwin.chain.transports.socketcand:SocketcandTransport",
    "socketcan": "benchtwin.chain.transports.socketcan:SocketcanTransport",
}


def get_transport(name: str) -> type[Transport]:
    """The transport class registered under ``name``.

    Raises
    ------
    ConfigError
        Unknown name.
    TransportError
        The backend cannot be imported here (missing optional dependency).
    """
    try:
        target = TRANSPORTS[name]
    except KeyError:
        raise ConfigError(f"unknown transport {name!r}; choose one of {', '.join(TRANSPORTS)}") from None
    module_name, _, class_name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise TransportError(f"transport {name!r} is unavailable: {exc}") from exc
    return getattr(module, class_name)


def available_transports() -> dict[str, str | None]:
    """Every registered transport with ``None`` when usable here, else the reason it is not."""
    out: dict[str, str | None] = {}
    for name in TRANSPORTS:
        try:
            out[name] = get_transport(name).unavailable_reason()
        except TransportError as exc:
            out[name] = str(exc)
    return out
