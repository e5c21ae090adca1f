"""The one base of every instrument of the bench: what it reads, what it puts on which wire, how it is decoded.

A device kind is one module of this package with one :class:`Device` subclass, named in
:data:`benchtwin.sensors.registry.DEVICE_KINDS` by the setup section that configures it. The
subclass is the device and its mirror in the acquisition, over one wire description (a DBC message,
an EDS mapping, a register map), as canopen's LocalNode and RemoteNode mirror each other:

==========================  ==================================================================
emulation                   :meth:`Device.encode` (a block of the Trace -> frames / image / registers)
batch delivery              :meth:`Device.deliver` (what an acquisition receives of the output)
wire description            :meth:`Device.database` (cantools messages on its bus)
acquisition                 :meth:`Device.frame_decoders` (CAN ids), :meth:`Device.decode_polls`
checks against the truth    :meth:`Device.truth_channels`, :meth:`Device.error_budget`,
                            :meth:`Device.saturation`
live bench                  :meth:`Device.command_device`, :meth:`Device.modbus_endpoint`,
                            :meth:`Device.canopen_endpoint`, :meth:`Device.triggers`
==========================  ==================================================================

Everything but :meth:`Device.encode` has a default (the device does not take part), so a new kind
writes only what it does. The acquisition, the batch and live delivery and the validation loop over
the devices of a setup and never name a kind.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from benchtwin.config.setup import ChannelErrors, LinkErrors, SetupConfig
from benchtwin.sensors.blocks import Block
from benchtwin.sensors.imperfections import DeviceClock
from benchtwin.wire.frames import PollLog, ProcessImage, RegisterSnapshots
from benchtwin.wire.quality import DecodeSink, FrameStream

if TYPE_CHECKING:
    from cantools.database.can import Database

__all__ = [
    "CanopenEndpoint",
    "Delivered",
    "Device",
    "FrameDecoder",
    "ModbusEndpoint",
    "TriggerSpec",
    "TruthChannel",
]

#: what :meth:`Device.encode` returns, by wire: CAN frames (FRAME_DTYPE), a CANopen process image, registers
DeviceOutput = np.ndarray | ProcessImage | RegisterSnapshots


@dataclass(frozen=True)
class TruthChannel:
    """How a decoded channel relates to the Trace: the validation's oracle for one role.

    Attributes
    ----------
    trace:
        Trace channel measured.
    factor:
        Trace SI value times ``factor`` is the role's unit.
    hold:
        Discrete state (zero-order hold, not interpolated).
    resolution:
        One step of the wire's representation, in the role's unit.
    span:
        The values the wire's representation can carry, in the role's unit (None: unbounded for the check). A
        truth outside it reaches the acquisition saturated at the nearer end, so the chain's check is valid
        only inside it.
    """

    trace: str
    factor: float
    hold: bool
    resolution: float
    span: tuple[float, float] | None = None


@dataclass(frozen=True)
class FrameDecoder:
    """Decodes the frames of one CAN identifier into the sink.

    Attributes
    ----------
    length:
        Data length of a good frame (0: not checked).
    decode:
        ``decode(stream, sink)``.
    """

    length: int
    decode: Callable[[FrameStream, DecodeSink], None]


@dataclass
class Delivered:
    """What an acquisition receives of one device's output (batch delivery)."""

    frames: np.ndarray | None = None  #: CAN frames to insert into the device's bus
    polls: PollLog | None = None  #: a poll log of a polled device


@dataclass(frozen=True)
class ModbusEndpoint:
    """A Modbus TCP device of the bench: how the live bench serves it and the acquisition polls it."""

    device: str
    unit_id: int
    port: int
    function_code: int
    first_register: int
    count: int
    poll_hz: float
    holding: dict[int, int] = field(default_factory=dict)
    faults: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class CanopenEndpoint:
    """A CANopen node of the bench: its name, node id, EDS and bus."""

    name: str
    node_id: int
    eds: Path
    bus: str


@dataclass(frozen=True)
class TriggerSpec:
    """Trigger commands the acquisition sends to a device (live)."""

    bus: str
    command_id: int
    mask: int
    period_s: float


class Device(ABC):
    """One instrument of the bench, configured by one setup section.

    Parameters
    ----------
    name:
        Device name, also the key of its random stream (``ivt_battery``, ``telemetry``, ...).
    cfg:
        Its setup section.
    setup:
        The whole bench (bit rates, other devices).
    """

    #: setup section that configures this kind (the registry key)
    section: ClassVar[str]
    #: ``can``, ``canopen`` or ``modbus``
    wire: ClassVar[str]
    #: every frame carries a cyclic counter (a gap with the counter running on is a loss, not a silence)
    counters: ClassVar[bool] = False

    def __init__(self, name: str, cfg: Any, setup: SetupConfig) -> None:
        self.name = name
        self.cfg = cfg
        self.setup = setup

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"

    @classmethod
    def from_setup(cls, setup: SetupConfig) -> list[Device]:
        """The devices of this kind in a setup (default: one, named after the section, if it is there)."""
        cfg = getattr(setup, cls.section, None)
        return [] if cfg is None else [cls(cls.section, cfg, setup)]

    @property
    def bus(self) -> str | None:
        """The CAN bus the device sends on (None for a Modbus device)."""
        return getattr(self.cfg, "bus", None)

    @property
    def link(self) -> LinkErrors:
        """The device's link imperfections (clock, latency, frame faults)."""
        return self.cfg.link

    # ------------------------------------------------------------------ emulation

    @abstractmethod
    def encode(self, blk: Block) -> DeviceOutput:
        """What the device puts on its wire over one block of plant time (``blk``: window, draws, carried state)."""

    def deliver(self, output: DeviceOutput, rng: np.random.Generator, span_s: tuple[float, float],
                state: dict[str, Any]) -> Delivered:
        """What an acquisition receives of one block of ``output`` beyond the raw CAN frames (batch delivery).

        Parameters
        ----------
        output:
            The device's output of one block (a polled device: the updates the block's polls can read).
        rng:
            The block's generator of the delivery's stream.
        span_s:
            The block's span (a polled device: of poll requests, plant time).
        state:
            What the delivery carries from one block to the next.

        CAN devices' frames are already on their bus: the default delivers nothing more.
        """
        return Delivered()

    def clock(self) -> DeviceClock:
        """The device's clock (device time of a plant time), with its injected clock faults."""
        return DeviceClock.of(self.link)

    def poll_reach_s(self) -> float:
        """A polled device: how far past a request (plant seconds) the updates it reads may lie."""
        return 0.0

    # ------------------------------------------------------------------ wire description

    def database(self) -> Database | None:
        """The device's CAN messages as a cantools Database (None: nothing on a CAN bus)."""
        return None

    # ------------------------------------------------------------------ acquisition

    def frame_decoders(self) -> dict[int, FrameDecoder]:
        """CAN identifier -> decoder, for the frames this device sends or answers."""
        return {}

    def decode_polls(self, log: PollLog, sink: DecodeSink, drops: np.ndarray) -> None:  # noqa: B027
        """Decode this device's poll log (polled devices only; the default decodes nothing)."""

    def decode_poll_blocks(self, log: Any, sink: DecodeSink, drops: np.ndarray,
                           emit: Callable[[str, str, np.ndarray, np.ndarray, np.ndarray, str], None],
                           block: int) -> None:
        """Decode this device's poll log read by blocks (``log``: ``len()`` and ``part(start, stop)`` giving a
        :class:`~benchtwin.wire.frames.PollLog`); each block of a channel goes to ``emit(name, unit, t, v, flags,
        source)``, counts and evidence to ``sink``. The default reads the whole log into :meth:`decode_polls`
        (its channels land in ``sink.rec``)."""
        self.decode_polls(log.part(0, len(log)), sink, drops)

    @property
    def poll_device(self) -> str | None:
        """Name of the poll log this device's polls are logged under (polled devices only)."""
        return None

    # ------------------------------------------------------------------ checks against the truth

    def truth_channels(self) -> dict[str, TruthChannel]:
        """Role -> how it relates to the Trace (what the chain checks compare)."""
        return {}

    def error_budget(self) -> dict[str, tuple[ChannelErrors | None, LinkErrors, float]]:
        """Role -> (declared errors, link errors, extra static error) for the realistic chain checks."""
        return {}

    def saturation(self) -> dict[str, ChannelErrors]:
        """Role -> the errors whose configured output saturation the acquisition flags."""
        return {}

    # ------------------------------------------------------------------ live bench

    def command_device(self) -> Any | None:
        """A state machine answering the device's command channel live (None: no commands)."""
        return None

    def modbus_endpoint(self, seed: int | None) -> ModbusEndpoint | None:
        """The Modbus TCP endpoint the device serves (None: not a Modbus device)."""
        return None

    def canopen_endpoint(self) -> CanopenEndpoint | None:
        """The CANopen node the device is (None: not a CANopen node)."""
        return None

    def triggers(self) -> list[TriggerSpec]:
        """Trigger commands the acquisition sends it."""
        return []
