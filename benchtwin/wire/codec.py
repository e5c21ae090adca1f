"""Vectorised CAN signal packing and unpacking driven by cantools Signal definitions.

cantools encodes and decodes one message at a time; a campaign has tens of millions of frames. This
module compiles each cantools :class:`~cantools.database.can.Message` once into shifts and masks on
a 64-bit integer view of the eight data bytes, then packs or unpacks whole columns of a frame table
with numpy. The layout (start bit, length, byte order, signedness, scale, offset) is read from the
cantools Signal, so the DBC stays the single source of truth; tests check the result against
``cantools``' own ``encode``/``decode`` frame by frame.

Bit numbering: for a little-endian (Intel) signal, cantools' ``start`` is the position of the least
significant bit in the little-endian 64-bit integer of the data. For a big-endian (Motorola) signal,
``start`` is the most significant bit in the "sawtooth" numbering (byte ``start // 8``, bit
``start % 8``); in the big-endian 64-bit integer of the data that bit is
``(7 - start // 8) * 8 + start % 8``, and the signal's least significant bit lies ``length - 1``
below it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from benchtwin.errors import FrameError

if TYPE_CHECKING:
    from cantools.database.can import Message, Signal

__all__ = ["MessageCodec", "SignalLayout", "bytes_to_u64", "u64_to_bytes"]


@dataclass(frozen=True)
class SignalLayout:
    """Where one signal lives in the 64-bit view of a frame and how raw maps to physical."""

    name: str
    shift: int
    length: int
    little_endian: bool
    signed: bool
    scale: float
    offset: float
    unit: str

    @property
    def raw_min(self) -> int:
        """Smallest raw value the bits can hold."""
        return -(1 << (self.length - 1)) if self.signed else 0

    @property
    def raw_max(self) -> int:
        """Largest raw value the bits can hold."""
        return (1 << (self.length - 1)) - 1 if self.signed else (1 << self.length) - 1

    @property
    def mask(self) -> np.uint64:
        """Mask of ``length`` low bits."""
        return np.uint64((1 << self.length) - 1)


def bytes_to_u64(data: np.ndarray, little_endian: bool) -> np.ndarray:
    """View ``(n, 8)`` uint8 data as ``n`` unsigned 64-bit integers in the given byte order."""
    data = np.ascontiguousarray(data, dtype=np.uint8)
    if data.ndim != 2 or data.shape[1] != 8:
        raise FrameError(f"data must be (n, 8) bytes, got {data.shape}")
    return data.view("<u8" if little_endian else ">u8")[:, 0].astype(np.uint64)


def u64_to_bytes(words: np.ndarray, little_endian: bool) -> np.ndarray:
    """Inverse of :func:`bytes_to_u64`: ``n`` 64-bit integers to ``(n, 8)`` uint8."""
    words = np.ascontiguousarray(words, dtype=np.uint64)
    return words.astype("<u8" if little_endian else ">u8").view(np.uint8).reshape(-1, 8)


def _layout(signal: Signal) -> SignalLayout:
    little = signal.byte_order == "little_endian"
    if little:
        shift = signal.start
    else:
        msb = (7 - signal.start // 8) * 8 + signal.start % 8
        shift = msb - (signal.length - 1)
    if shift < 0 or shift + signal.length > 64:
        raise FrameError(f"signal {signal.name!r} does not fit in 8 bytes (start {signal.start}, "
                         f"length {signal.length})")
    return SignalLayout(signal.name, int(shift), int(signal.length), little, bool(signal.is_signed),
                        float(signal.scale), float(signal.offset), signal.unit or "")


class MessageCodec:
    """A cantools message compiled for column-wise packing and unpacking.

    Parameters
    ----------
    message:
        A cantools ``Message`` (from a DBC).
    """

    def __init__(self, message: Message) -> None:
        self.message = message
        self.frame_id = int(message.frame_id)
        self.name = str(message.name)
        self.length = int(message.length)
        self.is_extended = bool(message.is_extended_frame)
        self.signals: dict[str, SignalLayout] = {s.name: _layout(s) for s in message.signals}

    def __repr__(self) -> str:
        return f"MessageCodec({self.name}, 0x{self.frame_id:X}, {list(self.signals)})"

    def to_raw(self, name: str, physical: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Physical values to raw integers, rounded and clipped to what the bits hold.

        Returns
        -------
        raw, clipped
            int64 raw values and a boolean mask of values that had to be clipped. NaN becomes the
            raw maximum (the DBC convention for "not available" used here) and counts as clipped.
        """
        sig = self.signals[name]
        x = np.asarray(physical, dtype=np.float64)
        nan = ~np.isfinite(x)
        r = np.rint((np.where(nan, 0.0, x) - sig.offset) / sig.scale)
        clipped = (r < sig.raw_min) | (r > sig.raw_max)
        raw = np.clip(r, sig.raw_min, sig.raw_max).astype(np.int64)
        raw[nan] = sig.raw_max
        return raw, clipped | nan

    def to_physical(self, name: str, raw: np.ndarray) -> np.ndarray:
        """Raw integers to physical values (``raw * scale + offset``)."""
        sig = self.signals[name]
        return np.asarray(raw, dtype=np.float64) * sig.scale + sig.offset

    def pack(self, raw: dict[str, np.ndarray], n: int | None = None) -> np.ndarray:
        """Pack raw signal columns into ``(n, 8)`` data bytes.

        Parameters
        ----------
        raw:
            Signal name -> integer column (scalars broadcast). Every signal of the message is
            required, as in cantools' ``encode``.
        n:
            Number of frames (needed when every column is a scalar).
        """
        missing = set(self.signals) - set(raw)
        if missing:
            raise FrameError(f"message {self.name}: missing signals {sorted(missing)}")
        if n is None:
            n = max(np.size(v) for v in raw.values())
        words_le = np.zeros(n, dtype=np.uint64)
        words_be = np.zeros(n, dtype=np.uint64)
        for name, sig in self.signals.items():
            v = np.asarray(raw[name], dtype=np.int64)
            if v.shape != (n,):  # a scalar (or a shorter column numpy can broadcast)
                v = np.broadcast_to(v, (n,))
            bits = (v.astype(np.uint64) & sig.mask) << np.uint64(sig.shift)
            if sig.little_endian:
                words_le |= bits
            else:
                words_be |= bits
        out = u64_to_bytes(words_le, True)
        if words_be.any():
            out |= u64_to_bytes(words_be, False)
        return out

    def unpack(self, data: np.ndarray, names: list[str] | None = None) -> dict[str, np.ndarray]:
        """Unpack ``(n, 8)`` data bytes into raw int64 columns (all signals, or ``names``)."""
        return self.unpack_words(bytes_to_u64(data, True), names)

    def unpack_words(self, words_le: np.ndarray, names: list[str] | None = None) -> dict[str, np.ndarray]:
        """Like :meth:`unpack`, from the data as little-endian 64-bit words (``bytes_to_u64(data, True)``)."""
        want = names if names is not None else list(self.signals)
        need_be = any(not self.signals[n].little_endian for n in want)
        le = np.asarray(words_le, dtype=np.uint64)
        be = le.byteswap() if need_be else None
        out: dict[str, np.ndarray] = {}
        for name in want:
            sig = self.signals[name]
            words = le if sig.little_endian else be
            u = (words >> np.uint64(sig.shift)) & sig.mask
            if sig.signed:  # sign-extend: the signal's top bit to bit 63, then an arithmetic shift back
                k = 64 - sig.length
                v = np.ascontiguousarray(u << np.uint64(k)).view(np.int64) >> np.int64(k)
            else:
                v = u.astype(np.int64)
            out[name] = v
        return out

    def decode(self, data: np.ndarray, names: list[str] | None = None) -> dict[str, np.ndarray]:
        """Unpack and scale to physical values (float64)."""
        return {k: self.to_physical(k, v) for k, v in self.unpack(data, names).items()}
