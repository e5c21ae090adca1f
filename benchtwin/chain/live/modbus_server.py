"""The pressure module's Modbus TCP server: pymodbus serving a register store the physics writes.

The store owns the data (:class:`RegisterStore`, one per Modbus device); the scheduler writes each
:class:`~benchtwin.wire.frames.RegisterSnapshots` row into it when its time comes; the pymodbus
server only reads it: the device's pymodbus ``SimDevice`` action copies the store into the register
block on every request. Registers outside the map answer exception code 2 (illegal data address),
the register kind the device does not have (input vs holding) too; writes are refused (read-only).

The server binds a loopback address only and runs its asyncio loop in a background thread.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import threading
import time
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from benchtwin.chain.live.scheduler import Stream
from benchtwin.errors import ConfigError, TransportError
from benchtwin.wire.frames import RegisterSnapshots

__all__ = ["ModbusDeviceServer", "RegisterStore", "free_port"]

log = logging.getLogger(__name__)

#: Modbus exception codes a server can answer (pymodbus ExcCodes: 1-8, 10, 11)
_EXCEPTION_CODES = frozenset({1, 2, 3, 4, 5, 6, 7, 8, 10, 11})


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that is free on ``host`` right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


class RegisterStore:
    """Current register values of one Modbus device (thread-safe; the physics writes, the server reads).

    Parameters
    ----------
    device:
        Device name.
    unit_id:
        Modbus device id.
    first_register:
        Address of the first register.
    n_registers:
        Number of registers in the map.
    kind:
        ``input`` (function code 4) or ``holding`` (function code 3).
    holding:
        Static holding registers ``{address: value}`` besides an ``input`` map (a configuration
        block, read-only here); their addresses must form one contiguous range.
    exception_prob, exception_code:
        Probability that a read of the live map answers Modbus exception ``exception_code``
        (a busy module: 6), as the setup file's poll faults.
    timeout_prob, no_answer_s:
        Probability that a read is answered only after ``no_answer_s`` (the poller times out first).
    seed:
        Seed of the fault draws.
    """

    def __init__(self, device: str, unit_id: int, first_register: int, n_registers: int, kind: str = "input",
                 holding: Mapping[int, int] | None = None, *, exception_prob: float = 0.0, exception_code: int = 6,
                 timeout_prob: float = 0.0, no_answer_s: float = 1.0, seed: int | None = 0) -> None:
        if kind not in ("input", "holding"):
            raise ConfigError(f"modbus device {device!r}: register kind must be 'input' or 'holding', got {kind!r}")
        if first_register < 0 or n_registers <= 0 or first_register + n_registers > 65536:
            raise ConfigError(f"modbus device {device!r}: registers {first_register}+{n_registers} outside 0..65535")
        if not 0 <= unit_id <= 247:
            raise ConfigError(f"modbus device {device!r}: unit id {unit_id} outside 0..247")
        self.holding = {int(a): int(v) & 0xFFFF for a, v in (holding or {}).items()}
        if self.holding:
            addrs = sorted(self.holding)
            if kind == "holding" or addrs != list(range(addrs[0], addrs[0] + len(addrs))) or addrs[-1] > 65535:
                raise ConfigError(f"modbus device {device!r}: static holding registers must be one contiguous range "
                                  "0..65535 beside an input map")
        if not (0 <= exception_prob < 1 and 0 <= timeout_prob < 1 and exception_code in _EXCEPTION_CODES):
            raise ConfigError(f"modbus device {device!r}: fault probabilities must be in [0, 1) and the "
                              f"exception code one of {sorted(_EXCEPTION_CODES)}, got {exception_code}")
        self.exception_prob, self.exception_code = float(exception_prob), int(exception_code)
        self.timeout_prob, self.no_answer_s = float(timeout_prob), float(no_answer_s)
        self._rng = np.random.default_rng(seed)
        self.faults = {"exceptions": 0, "no_answer": 0}
        self.device, self.unit_id, self.kind = device, int(unit_id), kind
        self.first_register, self.n_registers = int(first_register), int(n_registers)
        self._values = [0] * self.n_registers
        self._lock = threading.Lock()
        self.updates = 0
        self.reads = 0

    @classmethod
    def for_snapshots(cls, snap: RegisterSnapshots, holding: Mapping[int, int] | None = None,
                      **faults: Any) -> RegisterStore:
        """A store shaped like ``snap`` (plus static ``holding`` registers and poll ``faults``)."""
        return cls(snap.device, snap.unit_id, snap.first_register, snap.registers.shape[1], snap.kind, holding,
                   **faults)

    def draw_fault(self) -> str | None:
        """``"exception"``, ``"no_answer"`` or ``None`` for one request (from the fault probabilities)."""
        if not (self.exception_prob or self.timeout_prob):
            return None
        u = float(self._rng.random())
        if u < self.exception_prob:
            self.faults["exceptions"] += 1
            return "exception"
        if u < self.exception_prob + self.timeout_prob:
            self.faults["no_answer"] += 1
            return "no_answer"
        return None

    def write(self, row: np.ndarray | Iterable[int]) -> None:
        """Replace all register values (uint16 each)."""
        values = [int(v) & 0xFFFF for v in (row.tolist() if isinstance(row, np.ndarray) else row)]
        if len(values) != self.n_registers:
            raise ConfigError(f"modbus device {self.device!r}: {len(values)} values for {self.n_registers} registers")
        with self._lock:
            self._values = values
            self.updates += 1

    def read(self) -> list[int]:
        """A copy of the current register values."""
        with self._lock:
            self.reads += 1
            return list(self._values)

    def stream(self, snap: RegisterSnapshots, name: str | None = None) -> Stream:
        """A scheduler stream writing ``snap``'s rows into this store at their times."""
        regs = snap.registers

        def deliver(i0: int, i1: int) -> int:
            self.write(regs[i1 - 1])  # only the newest row of a batch is visible to a poll
            return i1 - i0

        return Stream(name or f"modbus:{snap.device}", snap.times, deliver, kind="modbus")


class ModbusDeviceServer:
    """One Modbus TCP server (pymodbus) serving one or more register stores by unit id.

    Parameters
    ----------
    stores:
        The devices; unit ids must be unique.
    host, port:
        Loopback address to bind; port 0 picks a free one (see :attr:`address`).
    """

    def __init__(self, stores: Iterable[RegisterStore], host: str = "127.0.0.1", port: int = 0) -> None:
        self.stores = {s.unit_id: s for s in stores}
        if not self.stores:
            raise ConfigError("modbus server: no devices to serve")
        if host not in ("127.0.0.1", "localhost"):
            raise ConfigError(f"modbus server: host {host!r} is not loopback; servers bind 127.0.0.1 only")
        self.host = "127.0.0.1"
        self.port = int(port) or free_port(self.host)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Any = None
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    @classmethod
    def from_snapshots(cls, snapshots: Mapping[str, RegisterSnapshots] | Iterable[RegisterSnapshots],
                       host: str = "127.0.0.1", port: int = 0) -> ModbusDeviceServer:
        """A server with one store per register-snapshot device."""
        snaps = list(snapshots.values()) if isinstance(snapshots, Mapping) else list(snapshots)
        return cls([RegisterStore.for_snapshots(s) for s in snaps], host, port)

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) of the server."""
        return self.host, self.port

    def _device(self, store: RegisterStore) -> Any:
        from pymodbus.constants import ExcCodes
        from pymodbus.simulator import DataType, SimData, SimDevice

        first, n = store.first_register, store.n_registers

        async def action(func_code: int, start_address: int, address: int, count: int,
                         current_registers: list[int], set_values: Any) -> Any:
            live = 4 if store.kind == "input" else 3
            if set_values is not None or func_code != live:
                return None  # writes are refused (read-only) before this; the static block is as built
            fault = store.draw_fault()
            if fault == "exception":
                return ExcCodes(store.exception_code)
            if fault == "no_answer":
                await asyncio.sleep(store.no_answer_s)
            current_registers[address - start_address: address - start_address + count] = \
                store.read()[address - first: address - first + count]
            return None

        regs = [SimData(first, values=[0] * n, datatype=DataType.REGISTERS, readonly=True)]
        invalid = [SimData(first, count=1, datatype=DataType.INVALID)]
        bits = [SimData(0, values=False, datatype=DataType.BITS, readonly=True)]
        if store.holding:
            addrs = sorted(store.holding)
            static = [SimData(addrs[0], values=[store.holding[a] for a in addrs], datatype=DataType.REGISTERS,
                              readonly=True)]
        else:
            static = invalid
        hr, ir = (regs, invalid) if store.kind == "holding" else (static, regs)
        return SimDevice(id=store.unit_id, simdata=(bits, bits, hr, ir), action=action)

    def start(self, timeout: float = 5.0) -> ModbusDeviceServer:
        """Start serving in a background thread; return once the port accepts connections."""
        from pymodbus.server import ModbusTcpServer

        if logging.getLogger().level > logging.DEBUG:
            # pymodbus logs every client that leaves mid-request with a frame dump; our stats say it once
            logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
        devices = [self._device(s) for s in self.stores.values()]
        ready = threading.Event()

        async def main() -> None:
            self._server = ModbusTcpServer(devices, address=(self.host, self.port))
            ready.set()
            await self._server.serve_forever()

        def run() -> None:
            self._loop = asyncio.new_event_loop()
            try:
                self._loop.run_until_complete(main())
            except BaseException as exc:
                self._error = exc
                ready.set()
            finally:
                pending = asyncio.all_tasks(self._loop)  # requests still waiting (a no-answer fault)
                for task in pending:
                    task.cancel()
                with contextlib.suppress(Exception):
                    self._loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
                self._loop.close()

        self._thread = threading.Thread(target=run, name="modbus-server", daemon=True)
        self._thread.start()
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self._error is not None:
                raise TransportError(f"modbus server on {self.host}:{self.port} failed: {self._error}")
            try:
                with socket.create_connection((self.host, self.port), timeout=0.2):
                    return self
            except OSError:
                time.sleep(0.02)
        raise TransportError(f"modbus server on {self.host}:{self.port} did not start within {timeout} s")

    def close(self) -> None:
        """Stop the server."""
        if self._loop is not None and self._server is not None and self._loop.is_running():
            fut = asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop)
            with contextlib.suppress(Exception):
                fut.result(timeout=5.0)
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._server = None

    def __enter__(self) -> ModbusDeviceServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def endpoints(self) -> list[str]:
        """One line per device: where and which registers."""
        return [f"modbus:{s.device}: tcp://{self.host}:{self.port} unit {s.unit_id} {s.kind} registers "
                f"{s.first_register}..{s.first_register + s.n_registers - 1}" for s in self.stores.values()]
