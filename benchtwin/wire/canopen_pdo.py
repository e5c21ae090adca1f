"""The thermo module's object dictionary (EDS) and vectorised TPDO packing/unpacking from its mapping.

The EDS shipped in the package (``thermo_module.eds``) is read with canopen's own
``import_od``; the TPDO communication (0x1800+n: COB-ID, event timer) and mapping (0x1A00+n)
parameters give the frame layout. Batch delivery packs a :class:`~benchtwin.wire.frames.ProcessImage`
into PDO frames with it, the acquisition unpacks them, and the live CANopen node (canopen
``LocalNode``) uses the same object dictionary, so batch and live share one layout.

Values in 0x9130 (AI input PV) are INTEGER16 in 10^-n degC with n from 0x6132 (AI decimal digits
PV, default 1); 0x7FFF marks a positive overload and -0x8000 a negative overload or open circuit.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from benchtwin.errors import CanopenError
from benchtwin.wire.frames import FRAME_DTYPE, ProcessImage

if TYPE_CHECKING:
    from canopen import ObjectDictionary

__all__ = [
    "AI_OVERLOAD_NEG",
    "AI_OVERLOAD_POS",
    "EDS_PATH",
    "PdoLayout",
    "TpdoLayout",
    "load_od",
    "pdo_layout",
]

EDS_PATH = Path(__file__).resolve().parent / "thermo_module.eds"
AI_OVERLOAD_POS = 0x7FFF
AI_OVERLOAD_NEG = -0x8000

# CANopen data types (CiA 301) -> (numpy dtype, bits)
_TYPES: dict[int, tuple[str, int]] = {
    0x2: ("i1", 8), 0x3: ("i2", 16), 0x4: ("i4", 32), 0x5: ("u1", 8), 0x6: ("u2", 16), 0x7: ("u4", 32),
    0x8: ("f4", 32),
}


def load_od(node_id: int, eds: str | Path = EDS_PATH) -> ObjectDictionary:
    """Import the thermo module's object dictionary for ``node_id`` with canopen.

    Raises
    ------
    CanopenError
        If the EDS cannot be read.
    """
    import canopen

    try:
        return canopen.import_od(str(eds), node_id)
    except Exception as exc:  # canopen raises several kinds for a bad file
        raise CanopenError(f"{eds}: cannot import the object dictionary ({exc})") from exc


@dataclass(frozen=True)
class TpdoLayout:
    """One TPDO: identifier, timing and the mapped entries with their byte offsets."""

    number: int
    cob_id: int
    event_ms: int
    entries: tuple[tuple[int, int], ...]
    dtypes: tuple[str, ...]
    offsets: tuple[int, ...]
    length: int


@dataclass(frozen=True)
class PdoLayout:
    """All TPDOs of a node plus the scaling of its analogue inputs."""

    node_id: int
    tpdos: tuple[TpdoLayout, ...]
    decimals: dict[int, int]

    @property
    def entries(self) -> list[tuple[int, int]]:
        """Every mapped entry, in TPDO order (the columns of the node's ProcessImage)."""
        return [e for t in self.tpdos for e in t.entries]

    def by_cob_id(self) -> dict[int, TpdoLayout]:
        """COB-ID -> TPDO."""
        return {t.cob_id: t for t in self.tpdos}

    def pack(self, image: ProcessImage, times: np.ndarray | None = None) -> np.ndarray:
        """Pack a process image into TPDO frames (one frame per TPDO per row), sorted by time.

        Parameters
        ----------
        image:
            Values per update; its ``entries`` must contain every mapped entry.
        times:
            Frame timestamps (defaults to ``image.times``).
        """
        col = {e: k for k, e in enumerate(image.entries)}
        missing = [e for e in self.entries if e not in col]
        if missing:
            raise CanopenError(f"process image lacks mapped entries {[f'{i:04X}:{s}' for i, s in missing]}")
        t = image.times if times is None else np.asarray(times, dtype=np.float64)
        n = t.shape[0]
        parts = []
        for tp in self.tpdos:
            fr = np.zeros(n, dtype=FRAME_DTYPE)
            fr["timestamp"] = t
            fr["arbitration_id"] = tp.cob_id
            fr["dlc"] = tp.length
            buf = np.zeros((n, 8), dtype=np.uint8)
            for e, dt, off in zip(tp.entries, tp.dtypes, tp.offsets):
                v = np.ascontiguousarray(image.values[:, col[e]]).astype("<" + dt)
                size = np.dtype(dt).itemsize
                buf[:, off:off + size] = v.view(np.uint8).reshape(n, size)
            fr["data"] = buf
            parts.append(fr)
        out = np.concatenate(parts) if parts else np.zeros(0, FRAME_DTYPE)
        return out[np.argsort(out["timestamp"], kind="stable")]

    def unpack(self, tp: TpdoLayout, data: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
        """Unpack ``(n, 8)`` data bytes of one TPDO into entry -> raw values (int64 or float64)."""
        data = np.ascontiguousarray(data, dtype=np.uint8)
        out: dict[tuple[int, int], np.ndarray] = {}
        for e, dt, off in zip(tp.entries, tp.dtypes, tp.offsets):
            size = np.dtype(dt).itemsize
            v = np.ascontiguousarray(data[:, off:off + size]).view("<" + dt)[:, 0]
            out[e] = v.astype(np.float64 if dt.startswith("f") else np.int64)
        return out

    def unpack_words(self, tp: TpdoLayout, words_le: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
        """:meth:`unpack` from the data as little-endian 64-bit words."""
        w = np.asarray(words_le, dtype=np.uint64)
        out: dict[tuple[int, int], np.ndarray] = {}
        for e, dt, off in zip(tp.entries, tp.dtypes, tp.offsets):
            size = np.dtype(dt).itemsize
            u = (w >> np.uint64(8 * off)) & np.uint64((1 << (8 * size)) - 1)
            v = u.astype("u" + str(size)).view(dt)
            out[e] = v.astype(np.float64 if dt.startswith("f") else np.int64)
        return out

    def scale(self, entry: tuple[int, int]) -> float:
        """Engineering value per count of an analogue input entry (10^-decimals)."""
        index, sub = entry
        if index == 0x9130:
            return 10.0 ** (-self.decimals.get(sub, 1))
        if index == 0x2100:
            return 0.1
        return 1.0


@functools.cache
def pdo_layout(node_id: int, eds: str = str(EDS_PATH)) -> PdoLayout:
    """Read the TPDO layout of the node from its EDS (through canopen's ObjectDictionary).

    Raises
    ------
    CanopenError
        If a mapping points to an object the dictionary lacks or does not fit in 8 bytes.
    """
    od = load_od(node_id, eds)
    tpdos = []
    for n in range(512):
        comm_idx, map_idx = 0x1800 + n, 0x1A00 + n
        if comm_idx not in od or map_idx not in od:
            break
        cob = int(od[comm_idx][1].default)
        if cob & 0x80000000:  # PDO not valid
            continue
        event_ms = int(od[comm_idx][5].default) if 5 in od[comm_idx] else 0
        count = int(od[map_idx][0].default)
        entries, dtypes, offsets = [], [], []
        bit = 0
        for s in range(1, count + 1):
            word = int(od[map_idx][s].default)
            index, sub, bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
            try:
                var = od[index] if sub == 0 and not hasattr(od[index], "subindices") else od[index][sub]
            except KeyError:
                raise CanopenError(f"TPDO{n + 1} maps {index:04X}:{sub} which the EDS lacks",
                                   code=0x06020000) from None
            dt = _TYPES.get(int(var.data_type))
            if dt is None or dt[1] != bits or bit % 8:
                raise CanopenError(f"TPDO{n + 1} entry {index:04X}:{sub}: unsupported type/size", code=0x06040041)
            entries.append((index, sub))
            dtypes.append(dt[0])
            offsets.append(bit // 8)
            bit += bits
        if bit > 64:
            raise CanopenError(f"TPDO{n + 1} maps {bit} bits (> 64)", code=0x06040042)
        tpdos.append(TpdoLayout(n + 1, cob & 0x7FF, event_ms, tuple(entries), tuple(dtypes), tuple(offsets),
                                bit // 8))
    decimals = {}
    if 0x6132 in od:
        for s in range(1, int(od[0x6132][0].default) + 1):
            decimals[s] = int(od[0x6132][s].default)
    return PdoLayout(node_id, tuple(tpdos), decimals)
