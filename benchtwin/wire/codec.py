"""Vectorised CAN signal packing and unpacking driven by cantools Signal definitions.

cantools encodes and decodes one message at a time; a campaign has tens of millions of frames. This
module compiles each cantools :class:`~cantools.database.can.Message` once into shifts and masks on
a 64-bit integer view of the eight data bytes, then packs or unpacks whole columns of a frame table
with numpy. The layout (start bit, length, byte order, signedness, scale, offset) is read from the
cantools Signal, so the DBC stays the single source of truth; tests check the result against
``cantools``' own ``encode``/``decode`` frame by frame. Unpacking runs in one small numba kernel per call
(:func:`_unpack_kernel`: every wanted signal of a column of words, no GIL held) with the same integer arithmetic as
the numpy expressions it replaced (:func:`_unpack_numpy`, kept as its reference:
``tests/chain/test_decode_kernels.py``).

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

import numba
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


@numba.njit(cache=True, nogil=True)
def _unpack_kernel(le: np.ndarray, shift: np.ndarray, mask: np.ndarray, little: np.ndarray, signed: np.ndarray
                   ) -> np.ndarray:  # pragma: no cover - numba
    """Raw int64 values, one row per signal: ``(word >> shift) & mask`` of the little- or big-endian word,
    sign-extended (the top bit of the signal moved to bit 63, then an arithmetic shift back) when signed."""
    nsig, n = shift.size, le.size
    out = np.empty((nsig, n), np.int64)
    s8, s16, s32 = np.uint64(8), np.uint64(16), np.uint64(32)
    m8, m16 = np.uint64(0x00FF00FF00FF00FF), np.uint64(0x0000FFFF0000FFFF)
    for j in range(nsig):  # one plain loop per signal and case (vectorised by the compiler)
        sh, mk, row = shift[j], mask[j], out[j]
        k = np.uint64(64 - signed[j])
        ki = np.int64(k)
        if little[j]:
            if signed[j]:
                for i in range(n):
                    row[i] = np.int64(((le[i] >> sh) & mk) << k) >> ki
            else:
                for i in range(n):
                    row[i] = np.int64((le[i] >> sh) & mk)
        else:  # the byte swap: adjacent bytes, then 16-bit halves, then 32-bit halves
            for i in range(n):
                w = le[i]
                w = ((w >> s8) & m8) | ((w & m8) << s8)
                w = ((w >> s16) & m16) | ((w & m16) << s16)
                w = (w >> s32) | (w << s32)
                u = (w >> sh) & mk
                row[i] = np.int64(u << k) >> ki if signed[j] else np.int64(u)
    return out


#: columns shorter than this are unpacked by NumPy, not by the compiled kernel (the same values): a live device's
#: frame or two gains nothing from it, and where no compiled copy is cached (a new machine or kernel) its first call
#: compiles for seconds, longer than a live command's answer may take
KERNEL_MIN_WORDS = 256


def _unpack_numpy(sigs: list[SignalLayout], words_le: np.ndarray) -> list[np.ndarray]:
    """The numpy reference of :func:`_unpack_kernel` (what :meth:`MessageCodec.unpack_words` computed before it)."""
    le = np.asarray(words_le, dtype=np.uint64)
    be = le.byteswap()
    out = []
    for sig in sigs:
        u = ((le if sig.little_endian else be) >> np.uint64(sig.shift)) & sig.mask
        if sig.signed:
            k = 64 - sig.length
            out.append(np.ascontiguousarray(u << np.uint64(k)).view(np.int64) >> np.int64(k))
        else:
            out.append(u.astype(np.int64))
    return out


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
        self._plans: dict[tuple[str, ...], tuple[np.ndarray, ...]] = {}

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
        want = tuple(names) if names is not None else tuple(self.signals)
        plan = self._plans.get(want)
        if plan is None:  # the layout arrays of these signals (``signed``: the signal's length, 0 if unsigned)
            sigs = [self.signals[n] for n in want]
            plan = self._plans[want] = (
                np.array([s.shift for s in sigs], np.uint64), np.array([int(s.mask) for s in sigs], np.uint64),
                np.array([s.little_endian for s in sigs], np.bool_),
                np.array([s.length if s.signed else 0 for s in sigs], np.int64))
        le = np.ascontiguousarray(words_le, dtype=np.uint64)
        if le.ndim != 1 or le.size < KERNEL_MIN_WORDS:  # the kernel takes a column of words, worth it when long
            return dict(zip(want, _unpack_numpy([self.signals[n] for n in want], le)))
        return dict(zip(want, _unpack_kernel(le, *plan)))

    def decode(self, data: np.ndarray, names: list[str] | None = None) -> dict[str, np.ndarray]:
        """Unpack and scale to physical values (float64)."""
        return {k: self.to_physical(k, v) for k, v in self.unpack(data, names).items()}
