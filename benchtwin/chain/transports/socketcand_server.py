"""Our endpoint speaking the socketcand ASCII protocol on 127.0.0.1, and its transport (the device side).

Any socketcand client (python-can's ``socketcand`` interface, ``python -m can.logger -i socketcand``,
the real socketcand tools) connects from another process::

    server: < hi >                       client: < open powertrain >
    server: < ok >                       client: < rawmode >
    server: < ok >
    server: < frame 521 1700000000.000123 0005FFFFCFC7 >     (every frame on the opened bus)
    client: < send 411 4 20 2 0 14 >                          (a frame onto the bus)

The server runs one thread with a selector. Frames are written to the clients' sockets directly
from the sending thread (no hop through a queue, so pacing is what the scheduler did); what a socket
does not take at once waits in the client's backlog, which the server thread flushes. A client whose
backlog exceeds ``max_backlog_bytes`` is disconnected and counted as dropped (never silently: the
frames it missed are counted in :meth:`SocketcandServer.stats`). Frames a client sends reach the
device side (:class:`SocketcandDeviceBus`) and every other client on that bus, as on a real bus.

After ``< rawmode >`` is answered the server holds the client's frames back for ``arm_delay_s``
(they wait in its backlog, none is lost): python-can's client reads the ``< ok >`` with one
``recv`` and would fail if frames arrived glued to it.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import selectors
import socket
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import can
import numpy as np

from benchtwin.chain.transports.base import Transport
from benchtwin.chain.transports.socketcand_protocol import format_frames, format_message, parse_send
from benchtwin.errors import ConfigError, TransportError

__all__ = ["SocketcandDeviceBus", "SocketcandServer", "SocketcandTransport"]

log = logging.getLogger(__name__)

#: at most this much of a malformed command goes into the log
_LOGGED_CHARS = 80


@dataclass(eq=False)
class _Client:
    sock: socket.socket
    peer: str
    state: str = "greeted"  # greeted -> open -> raw
    channel: str = ""
    inbuf: bytearray = field(default_factory=bytearray)
    outbuf: bytearray = field(default_factory=bytearray)
    lock: threading.Lock = field(default_factory=threading.Lock)
    armed_at: float = 0.0
    writing: bool = False
    alive: bool = True
    bytes_out: int = 0
    malformed: int = 0


class SocketcandServer:
    """A socketcand-protocol hub on a loopback address serving several named buses.

    Parameters
    ----------
    channels:
        Bus names a client may ``open``.
    host, port:
        Listening address (loopback only; port 0 picks a free port, see :attr:`address`).
    arm_delay_s:
        Hold-back after answering ``< rawmode >`` (see the module docstring).
    max_backlog_bytes:
        A client further behind than this is disconnected (its loss is counted).
    """

    def __init__(self, channels: Iterable[str], host: str = "127.0.0.1", port: int = 0, *,
                 arm_delay_s: float = 0.05, max_backlog_bytes: int = 256 * 1024 * 1024) -> None:
        self.channels = list(channels)
        if host not in ("127.0.0.1", "::1"):
            raise ConfigError(f"socketcand endpoint: host {host!r} is not loopback; it binds 127.0.0.1 only")
        self.arm_delay_s = float(arm_delay_s)
        self.max_backlog_bytes = int(max_backlog_bytes)
        self.inbound: dict[str, queue.SimpleQueue[can.Message]] = {c: queue.SimpleQueue() for c in self.channels}
        self._clients: list[_Client] = []
        self._clients_lock = threading.Lock()
        self._sel = selectors.DefaultSelector()
        self._listen = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
        self._listen.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._listen.bind((host, port))
        except OSError as exc:
            self._listen.close()
            raise TransportError(f"socketcand endpoint: cannot bind {host}:{port}: {exc}") from exc
        self._listen.listen(16)
        self._listen.setblocking(False)
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.counters = {"clients_accepted": 0, "clients_dropped": 0, "frames_dropped_bytes": 0,
                         "malformed_commands": 0, "frames_from_clients": 0, "raw_clients_left": 0}
        self._raw_clients_seen = 0
        self._raw_event = threading.Condition()

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the server listens on."""
        host, port = self._listen.getsockname()[:2]
        return host, port

    # ------------------------------------------------------------------ life cycle
    def start(self) -> SocketcandServer:
        """Start serving in a background thread."""
        self._sel.register(self._listen, selectors.EVENT_READ, None)
        self._sel.register(self._wake_r, selectors.EVENT_READ, None)
        self._thread = threading.Thread(target=self._run, name="socketcand-endpoint", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Flush what the clients' sockets take within a second, then close everything."""
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline and any(c.outbuf and c.alive for c in self._clients):
            time.sleep(0.005)
        self._stop.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        with self._clients_lock:
            for c in self._clients:
                self._close_client(c, unregister=False)
            self._clients.clear()
        for s in (self._listen, self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                s.close()
        self._sel.close()

    def wait_for_clients(self, n: int, timeout: float) -> bool:
        """Block until ``n`` clients have entered raw mode (since start) or ``timeout`` passes."""
        end = time.monotonic() + timeout
        with self._raw_event:
            while self._raw_clients_seen < n:
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._raw_event.wait(left)
        # let the arm delay pass so the first frames go out at once
        time.sleep(self.arm_delay_s)
        return True

    def raw_clients(self, channel: str | None = None) -> int:
        """Clients currently in raw mode (on ``channel``, or on any)."""
        return sum(1 for c in self._clients if c.alive and c.state == "raw"
                   and (channel is None or c.channel == channel))

    def stats(self) -> dict[str, Any]:
        """Counters: clients accepted/dropped, bytes dropped with dropped clients, malformed commands."""
        out = dict(self.counters)
        out["clients_connected"] = sum(1 for c in self._clients if c.alive)
        out["backlog_bytes"] = sum(len(c.outbuf) for c in self._clients if c.alive)
        return out

    # ------------------------------------------------------------------ sending (any thread)
    def broadcast(self, channel: str, payload: bytes, exclude: _Client | None = None) -> None:
        """Write ``payload`` (whole ``< frame >`` messages) to every raw-mode client on ``channel``."""
        if not payload:
            return
        now = time.monotonic()
        need_wake = False
        for c in self._clients:
            if c is exclude or not c.alive or c.state != "raw" or c.channel != channel:
                continue
            with c.lock:
                if c.outbuf or now < c.armed_at:
                    c.outbuf += payload
                else:
                    try:
                        n = c.sock.send(payload)
                    except BlockingIOError:
                        n = 0
                    except OSError:
                        c.alive = False
                        need_wake = True
                        continue
                    c.bytes_out += n
                    if n < len(payload):
                        c.outbuf += payload[n:]
                if c.outbuf and not c.writing:
                    need_wake = True
                if len(c.outbuf) > self.max_backlog_bytes:
                    log.error("socketcand endpoint: client %s is %d bytes behind; disconnecting it", c.peer,
                              len(c.outbuf))
                    self.counters["frames_dropped_bytes"] += len(c.outbuf)
                    self.counters["clients_dropped"] += 1
                    c.outbuf.clear()
                    c.alive = False
                    need_wake = True
        if need_wake:
            self._wake()

    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")

    # ------------------------------------------------------------------ server thread
    def _run(self) -> None:
        while not self._stop.is_set():
            timeout = 0.1
            now = time.monotonic()
            for c in list(self._clients):
                if not c.alive:
                    self._drop(c)
                    continue
                if c.outbuf and not c.writing:
                    if now >= c.armed_at:
                        self._want_write(c, True)
                    else:
                        timeout = min(timeout, c.armed_at - now)
            try:
                events = self._sel.select(timeout)
            except OSError:
                break
            for key, mask in events:
                if key.fileobj is self._listen:
                    self._accept()
                elif key.fileobj is self._wake_r:
                    try:
                        while self._wake_r.recv(4096):
                            pass
                    except OSError:
                        pass
                else:
                    client: _Client = key.data
                    if mask & selectors.EVENT_READ:
                        try:
                            self._read(client)
                        except Exception:  # one client's garbage never stops the endpoint for the others
                            log.exception("socketcand endpoint: closing client %s after an error", client.peer)
                            self.counters["malformed_commands"] += 1
                            self._close_client(client)
                            continue
                    if mask & selectors.EVENT_WRITE and client.alive:
                        self._flush(client)

    def _accept(self) -> None:
        try:
            sock, peer = self._listen.accept()
        except OSError:
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        c = _Client(sock=sock, peer=f"{peer[0]}:{peer[1]}")
        with self._clients_lock:
            self._clients.append(c)
        self.counters["clients_accepted"] += 1
        self._sel.register(sock, selectors.EVENT_READ, c)
        self._reply(c, "< hi >")
        log.info("socketcand endpoint: client %s connected", c.peer)

    def _reply(self, c: _Client, text: str) -> None:
        with c.lock:
            try:
                c.sock.sendall(text.encode("ascii", "replace"))
            except OSError:
                c.alive = False

    def _want_write(self, c: _Client, on: bool) -> None:
        if c.writing == on or not c.alive:
            return
        c.writing = on
        try:
            self._sel.modify(c.sock, selectors.EVENT_READ | (selectors.EVENT_WRITE if on else 0), c)
        except (KeyError, ValueError, OSError):
            c.alive = False

    def _flush(self, c: _Client) -> None:
        with c.lock:
            if c.outbuf and time.monotonic() >= c.armed_at:
                try:
                    n = c.sock.send(c.outbuf)
                except BlockingIOError:
                    n = 0
                except OSError:
                    c.alive = False
                    return
                c.bytes_out += n
                del c.outbuf[:n]
            empty = not c.outbuf
        if empty:
            self._want_write(c, False)

    def _read(self, c: _Client) -> None:
        try:
            data = c.sock.recv(65536)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            c.alive = False
            self._drop(c)
            return
        c.inbuf += data
        while True:
            start = c.inbuf.find(b"<")
            if start < 0:
                if c.inbuf.strip():
                    self._malformed(c, bytes(c.inbuf))
                c.inbuf.clear()
                return
            if start and c.inbuf[:start].strip():
                self._malformed(c, bytes(c.inbuf[:start]))  # text outside < >
            end = c.inbuf.find(b">", start)
            if end < 0:
                if start:
                    del c.inbuf[:start]
                if len(c.inbuf) > 4096:
                    self._malformed(c, bytes(c.inbuf[:80]))
                    c.inbuf.clear()
                return
            body = bytes(c.inbuf[start + 1:end]).decode("ascii", "replace").strip()
            del c.inbuf[:end + 1]
            self._command(c, body)
            if not c.alive:  # refused and closed: the rest of its input is not read
                return

    def _malformed(self, c: _Client, what: bytes | str) -> None:
        c.malformed += 1
        self.counters["malformed_commands"] += 1
        shown = what[:_LOGGED_CHARS]  # a client's 64 KiB of garbage must not flood the log
        more = f" ... ({len(what)} bytes)" if len(what) > _LOGGED_CHARS else ""
        log.warning("socketcand endpoint: malformed command from %s: %r%s", c.peer, shown, more)

    def _command(self, c: _Client, body: str) -> None:
        word = body.split(" ", 1)[0]
        if c.state == "raw" and word == "send":
            now = time.time()
            try:
                msg = parse_send(body, now)
            except ValueError:
                self._malformed(c, body)
                return
            msg.channel = c.channel
            self.counters["frames_from_clients"] += 1
            self.inbound[c.channel].put(msg)
            self.broadcast(c.channel, format_message(msg, now), exclude=c)
        elif word == "open":
            name = body[4:].strip()
            if c.state != "greeted":
                self._refuse(c, body, "< error bus already open >")
            elif name not in self.inbound:
                self._refuse(c, body, f"< error no such bus {name}; buses: {','.join(self.channels)} >")
            else:
                c.channel = name
                c.state = "open"
                self._reply(c, "< ok >")
        elif word == "rawmode":
            if c.state != "open":
                self._refuse(c, body, "< error open a bus first >")
                return
            c.armed_at = time.monotonic() + self.arm_delay_s
            c.state = "raw"
            self._reply(c, "< ok >")
            with self._raw_event:
                self._raw_clients_seen += 1
                self._raw_event.notify_all()
        elif word == "echo":
            self._reply(c, "< echo >")
        elif c.state == "raw":
            # in raw mode an error text would be parsed as an error frame by some clients: count it only
            self._malformed(c, body)
        else:
            self._refuse(c, body, f"< error unsupported command {word} >")

    def _refuse(self, c: _Client, body: str, answer: str) -> None:
        """A malformed command: the client gets ``< error ... >`` and is closed; every other client goes on.

        (In raw mode a malformed ``send`` is only counted: an error text in the frame stream would be
        parsed as a frame by some clients.)
        """
        self._malformed(c, body)
        self._reply(c, answer)
        c.alive = False
        self._drop(c)

    def _close_client(self, c: _Client, unregister: bool = True) -> None:
        if unregister:
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._sel.unregister(c.sock)
        with contextlib.suppress(OSError):
            c.sock.close()

    def _drop(self, c: _Client) -> None:
        with self._clients_lock:
            if c not in self._clients:
                return
            self._clients.remove(c)
        if c.state == "raw":  # a receiving client went away (closed, killed or disconnected for lagging)
            self.counters["raw_clients_left"] += 1
        if c.outbuf:
            self.counters["frames_dropped_bytes"] += len(c.outbuf)
            self.counters["clients_dropped"] += 1
        self._close_client(c)
        log.info("socketcand endpoint: client %s left", c.peer)


class SocketcandDeviceBus(can.BusABC):
    """The device side of one bus of a :class:`SocketcandServer`, as a python-can bus.

    ``send`` puts a frame on the bus (every raw-mode client gets it); ``recv`` returns the frames
    clients sent (``< send ... >``).
    """

    def __init__(self, server: SocketcandServer, channel: str, **kwargs: Any) -> None:
        self._server = server
        self.channel_info = f"socketcand endpoint {server.address[0]}:{server.address[1]} bus {channel}"
        super().__init__(channel=channel, **kwargs)
        self.channel = channel

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Broadcast ``msg`` to the bus's clients (timestamp: the message's, or now if it has none)."""
        self._server.broadcast(self.channel, format_message(msg, msg.timestamp or time.time()))

    def send_frames(self, frames: np.ndarray, timestamp: float | np.ndarray | None = None) -> None:
        """Broadcast rows of a frame table in one write per client."""
        self._server.broadcast(self.channel, format_frames(frames, time.time() if timestamp is None else timestamp))

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            return self._server.inbound[self.channel].get(timeout=timeout), False
        except queue.Empty:
            return None, False


class SocketcandTransport(Transport):
    """Buses served by our socketcand-protocol endpoint on 127.0.0.1 (reachable from other processes)."""

    name: ClassVar[str] = "socketcand"
    cross_process: ClassVar[bool] = True

    def __init__(self, *args: Any, arm_delay_s: float = 0.05, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.arm_delay_s = arm_delay_s
        self.server: SocketcandServer | None = None

    def _start_backend(self) -> None:
        self.server = SocketcandServer(self.bitrates, self.host, self.port, arm_delay_s=self.arm_delay_s).start()
        self.port = self.server.address[1]

    def _close_backend(self) -> None:
        if self.server is not None:
            self.server.close()
            self.server = None

    def _open_device_bus(self, bus: str) -> can.BusABC:
        if self.server is None:
            raise TransportError("socketcand endpoint is not running")
        return SocketcandDeviceBus(self.server, bus)

    def client_kwargs(self, bus: str) -> dict[str, Any]:
        return {"interface": "socketcand", "host": self.host, "port": self.port, "channel": bus}

    def endpoints(self) -> list[str]:
        return [f"{bus}: socketcand tcp://{self.host}:{self.port} channel {bus} "
                f"(python -m can.logger -i socketcand -c {bus} --bus-kwargs host={self.host} port={self.port})"
                for bus in self.bitrates]

    def send_frames(self, bus: str, frames: np.ndarray, timestamp: float | np.ndarray | None = None) -> int:
        dev = self.device_bus(bus)
        dev.send_frames(frames, timestamp)  # type: ignore[attr-defined]
        return len(frames)

    def stats(self) -> dict[str, Any]:
        return self.server.stats() if self.server is not None else {}
