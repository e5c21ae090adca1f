"""The socketcand ASCII protocol: frames to ``< frame ID SECONDS DATA >`` messages and ``< send ... >`` back.

Only the text of the protocol lives here (no sockets): the endpoint (:mod:`.socketcand_server`) and the
client (:mod:`.socketcand_client`) both speak it, and a test can check it without a connection.
"""

from __future__ import annotations

import re

import can
import numpy as np

__all__ = ["format_frames", "format_message", "parse_send"]


def _ts_text(t: float) -> str:
    sec = int(t)
    return f"{sec}.{round((t - sec) * 1e6) % 1_000_000:06d}"


def format_frames(frames: np.ndarray, timestamp: float | np.ndarray) -> bytes:
    """Rows of :data:`~benchtwin.wire.frames.FRAME_DTYPE` as socketcand ``< frame ... >`` messages.

    ``timestamp`` (Unix seconds) is one value for all rows or one per row.

    Standard identifiers are written with three hex digits and extended ones with eight (that is
    how clients tell them apart); the data bytes follow as one hex string, as socketcand does.
    """
    if np.ndim(timestamp):
        tss = [_ts_text(t) for t in np.asarray(timestamp, dtype=np.float64).tolist()]
    else:
        tss = [_ts_text(float(timestamp))] * len(frames)
    ids = frames["arbitration_id"].tolist()
    ext = frames["is_extended"].tolist()
    dlc = frames["dlc"].tolist()
    data = frames["data"].tobytes()
    parts = []
    for i in range(len(ids)):
        idt = f"{ids[i] & 0x1FFFFFFF:08X}" if ext[i] else f"{ids[i] & 0x7FF:03X}"
        n = min(dlc[i], 8)
        parts.append(f"< frame {idt} {tss[i]} {data[8 * i:8 * i + n].hex().upper()} >")
    return "".join(parts).encode("ascii")


def format_message(msg: can.Message, timestamp: float) -> bytes:
    """One python-can message as a socketcand ``< frame ... >`` message."""
    idt = f"{msg.arbitration_id & 0x1FFFFFFF:08X}" if msg.is_extended_id else f"{msg.arbitration_id & 0x7FF:03X}"
    return f"< frame {idt} {_ts_text(timestamp)} {bytes(msg.data[:msg.dlc]).hex().upper()} >".encode("ascii")


_HEX = re.compile(r"[0-9A-Fa-f]+")


def parse_send(body: str, timestamp: float) -> can.Message:
    """Parse the body of ``< send ID DLC B0 .. >`` (without the brackets) into a message.

    Raises
    ------
    ValueError
        Malformed command (bad hex, DLC not matching the bytes, DLC > 8, identifier too large).
    """
    parts = body.split()
    if len(parts) < 3 or parts[0] != "send":
        raise ValueError(f"not a send command: {body!r}")
    id_text = parts[1]
    # plain hex digits only: int(x, 16) alone takes "-1", "+7ff", "0x12" and "1_0"
    if not (_HEX.fullmatch(id_text) and len(id_text) <= 8 and _HEX.fullmatch(parts[2]) and len(parts[2]) <= 2
            and all(_HEX.fullmatch(b) and len(b) <= 2 for b in parts[3:])):
        raise ValueError(f"malformed send command: {body!r}")
    can_id = int(id_text, 16)
    dlc = int(parts[2], 16)
    data = bytes(int(b, 16) for b in parts[3:])
    is_ext = len(id_text) > 3 or can_id > 0x7FF
    if dlc > 8 or dlc != len(data) or can_id > 0x1FFFFFFF:
        raise ValueError(f"malformed send command: {body!r}")
    return can.Message(timestamp=timestamp, arbitration_id=can_id, is_extended_id=is_ext, dlc=dlc, data=data,
                       is_rx=True)
