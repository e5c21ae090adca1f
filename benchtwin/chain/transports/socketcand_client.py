"""A socketcand client for the acquisition side: python-can's bus interface, and a closed connection reported."""

from __future__ import annotations

import contextlib
import logging
import select
import socket
import time
from typing import Any

import can

__all__ = ["SocketcandClientBus"]

log = logging.getLogger(__name__)


class SocketcandClientBus(can.BusABC):
    """A socketcand client as a python-can bus that reports a closed connection.

    python-can's own ``socketcand`` interface returns nothing forever when the server goes away;
    an acquisition must notice a drop. This client does the same handshake (``< open CH >``,
    ``< rawmode >``), parses ``< frame >`` messages in bulk and raises
    :class:`can.CanOperationError` once the server closed the connection (after the frames that
    arrived before the close were returned).

    Parameters
    ----------
    channel:
        Bus name to open.
    host, port:
        The endpoint.
    connect_timeout:
        Seconds to keep trying to connect (the server may still be starting), and to wait for the
        greeting and each ``< ok >``.
    """

    def __init__(self, channel: str, host: str = "127.0.0.1", port: int = 29536, connect_timeout: float = 5.0,
                 **kwargs: Any) -> None:
        end = time.monotonic() + connect_timeout
        while True:  # the server may still be starting: retry until the timeout
            try:
                self._sock = socket.create_connection((host, int(port)), timeout=max(0.1, end - time.monotonic()))
                break
            except ConnectionRefusedError:
                if time.monotonic() >= end:
                    raise
                time.sleep(0.1)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._buf = bytearray()
        self._pending: list[can.Message] = []
        self._closed_by_peer = False
        self._reported = False
        self.channel_info = f"socketcand client {host}:{port} bus {channel}"
        try:
            self._expect("hi")
            self._sock.sendall(f"< open {channel} >".encode("ascii"))
            self._expect("ok")
            self._sock.sendall(b"< rawmode >")
            self._expect("ok")
        except (OSError, can.CanError):
            self._sock.close()
            raise
        self._sock.settimeout(None)
        self._sock.setblocking(False)
        super().__init__(channel=channel, **kwargs)
        self.channel = channel

    def _expect(self, word: str) -> None:
        while b">" not in self._buf:
            data = self._sock.recv(4096)
            if not data:
                raise can.CanOperationError("socketcand server closed the connection during the handshake")
            self._buf += data
        end = self._buf.index(b">")
        text = bytes(self._buf[:end + 1]).decode("ascii", "replace")
        del self._buf[:end + 1]
        if text.strip("<> ").split(" ", 1)[0] != word:
            raise can.CanInitializationError(f"socketcand server answered {text!r}, expected '< {word} >'")

    def _parse(self) -> None:
        buf = self._buf
        cut = buf.rfind(b">")
        if cut < 0:
            return
        chunk = bytes(buf[:cut + 1]).decode("ascii", "replace")
        del buf[:cut + 1]
        for part in chunk.split(">"):
            body = part.strip().lstrip("<").strip()
            if not body:
                continue
            fields = body.split(" ")
            if fields[0] != "frame" or len(fields) < 3:
                log.debug("socketcand client: ignoring %r", body)
                continue
            try:
                id_text = fields[1]
                data = bytes.fromhex("".join(fields[3:]))
                self._pending.append(can.Message(timestamp=float(fields[2]), arbitration_id=int(id_text, 16),
                                                 is_extended_id=len(id_text) > 3, dlc=len(data), data=data,
                                                 is_rx=True, channel=self.channel, check=False))
            except ValueError:
                log.warning("socketcand client: malformed frame %r", body)
        self._pending.reverse()  # pop() from the end returns the oldest

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._pending:
            return self._pending.pop(), False
        if self._closed_by_peer:
            if not self._reported:
                self._reported = True
                raise can.CanOperationError("socketcand server closed the connection")
            time.sleep(timeout if timeout is not None else 0.1)  # closed: behave as a silent bus
            return None, False
        ready, _, _ = select.select([self._sock], [], [], timeout)
        if not ready:
            return None, False
        try:
            data = self._sock.recv(262144)
        except BlockingIOError:
            return None, False
        except OSError as exc:
            self._closed_by_peer = self._reported = True
            raise can.CanOperationError(f"socketcand connection failed: {exc}") from exc
        if not data:
            self._closed_by_peer = True
            self._parse()
            if self._pending:
                return self._pending.pop(), False
            self._reported = True
            raise can.CanOperationError("socketcand server closed the connection")
        self._buf += data
        self._parse()
        return (self._pending.pop(), False) if self._pending else (None, False)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send ``msg`` as ``< send ID DLC B0 .. >``."""
        idt = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
        text = f"< send {idt} {msg.dlc:X} {' '.join(f'{b:02X}' for b in msg.data[:msg.dlc])} >"
        try:
            self._sock.setblocking(True)
            self._sock.sendall(text.encode("ascii"))
        except OSError as exc:
            raise can.CanOperationError(f"socketcand send failed: {exc}") from exc
        finally:
            self._sock.setblocking(False)

    def shutdown(self) -> None:
        """Close the connection."""
        super().shutdown()
        with contextlib.suppress(OSError):
            self._sock.close()
