"""The socketcand transport: our endpoint on 127.0.0.1 and a client that notices a closed connection.

Split by job: :mod:`.socketcand_protocol` (the ASCII messages), :mod:`.socketcand_server` (the endpoint,
the device side's bus and the :class:`~benchtwin.chain.transports.base.Transport`), :mod:`.socketcand_client`
(the acquisition's bus). This module is the name the transport registry and users import.
"""

from benchtwin.chain.transports.socketcand_client import SocketcandClientBus
from benchtwin.chain.transports.socketcand_protocol import format_frames, format_message, parse_send
from benchtwin.chain.transports.socketcand_server import SocketcandDeviceBus, SocketcandServer, SocketcandTransport

__all__ = ["SocketcandClientBus", "SocketcandDeviceBus", "SocketcandServer", "SocketcandTransport", "format_frames",
           "format_message", "parse_send"]
