"""The acquisition's building blocks: frames grouped per identifier, whole-recording flags, bus load, declared errors.

Shared by the one-shot :func:`~benchtwin.chain.acquisition.acquire` and the chunked
:class:`~benchtwin.chain.acquisition.Acquisition` (which calls the same code on every chunk).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from benchtwin.chain.blocks import ChannelBlocks
from benchtwin.chain.streams import dlc_histogram
from benchtwin.sensors.base import Device, FrameDecoder
from benchtwin.wire.frames import FrameTable, TransportEvent
from benchtwin.wire.quality import FLAG

__all__ = ["BusLoad", "bus_load", "data_words", "declared_uncertainty", "decoders_of", "events_for",
           "flag_saturation", "flag_truncations", "group_ids"]


def events_for(events: list[TransportEvent], names: set[str]) -> np.ndarray:
    """End times of the drops, overruns and cut logs of ``names`` (or of every source): the next sample is flagged."""
    ends = []
    for e in events:
        if (e.source in names or e.source == "*") and e.kind in ("drop", "overrun", "truncated"):
            ends.append(e.end_s if np.isfinite(e.end_s) else e.time_s)
    return np.asarray(ends, dtype=np.float64)


def group_ids(frames: np.ndarray, ids_known: list[int]) -> tuple[dict[int, np.ndarray], dict[int, int]]:
    """Indices of the frames of each known id (time order) and counts of unknown ids."""
    ids = np.ascontiguousarray(frames["arbitration_id"])
    keys = sorted(ids_known)
    lut = np.zeros(0x801, dtype=np.uint8 if len(keys) < 255 else np.uint16)  # 0: unknown
    for k, cid in enumerate(keys):
        lut[cid] = k + 1
    code = lut[np.minimum(ids, 0x800)]
    ext = frames["is_extended"]
    if ext.any():
        code[ext] = 0
    order = np.argsort(code, kind="stable")  # radix sort on a small integer key
    counts = np.bincount(code, minlength=len(keys) + 1)
    bounds = np.concatenate([[0], np.cumsum(counts)])
    groups = {cid: order[bounds[k + 1]:bounds[k + 2]] for k, cid in enumerate(keys) if counts[k + 1]}
    unknown = order[:bounds[1]]
    u_ids, u_counts = np.unique(ids[unknown], return_counts=True)
    return groups, {int(i): int(c) for i, c in zip(u_ids, u_counts)}


def data_words(frames: np.ndarray) -> np.ndarray:
    """The 8 data bytes of every frame as one little-endian 8-byte word: a read-only view on the records."""
    if frames.flags["C_CONTIGUOUS"] and len(frames):
        offset = frames.dtype.fields["data"][1]
        words = np.ndarray((len(frames),), dtype="<u8", buffer=frames.data, offset=offset,
                           strides=(frames.dtype.itemsize,))
        words.flags.writeable = False
        return words
    return np.ascontiguousarray(frames["data"]).view("<u8")[:, 0]


def decoders_of(devs: list[Device], bus: str) -> dict[int, FrameDecoder]:
    """Identifier -> decoder of every device on ``bus``."""
    out: dict[int, FrameDecoder] = {}
    for d in devs:
        if d.bus == bus:
            out.update(d.frame_decoders())
    return out


def flag_saturation(view: ChannelBlocks, devs: list[Device]) -> None:
    """SATURATED where a channel sits at the output saturation its device's errors configure (block by block)."""
    for d in devs:
        for role, err in d.saturation().items():
            lo, hi = err.saturation_min, err.saturation_max
            if (lo is None and hi is None) or role not in view.rec:
                continue
            span = (hi - lo) if lo is not None and hi is not None else max(abs(lo or 0.0), abs(hi or 0.0), 1.0)
            tol = 1e-3 * span
            for _a, _t, v, f in view.blocks(role, write=True, columns="vf"):
                at = np.zeros(v.shape[0], dtype=bool)
                if hi is not None:
                    at |= v >= hi - tol
                if lo is not None:
                    at |= v <= lo + tol
                f[at] |= FLAG["SATURATED"]


def flag_truncations(view: ChannelBlocks, events: list[TransportEvent], of_bus: dict[str, set[str]]) -> None:
    """A bus log cut short (a ``truncated`` event): its channels' last sample before the cut and any sample in
    the missing span are flagged TRANSPORT_DROP | LOST_FRAME (nothing after the cut is complete); block by block."""
    bit = FLAG["TRANSPORT_DROP"] | FLAG["LOST_FRAME"]
    for e in events:
        if e.kind != "truncated":
            continue
        for name in of_bus.get(e.source, ()):
            if not view.length(name):
                continue
            k = view.count_at_or_before(name, e.time_s) - 1  # the last sample before the cut
            for a, t, _v, f in view.blocks(name, write=True, columns="tf"):
                at = (t >= e.time_s) & (t <= e.end_s)
                if a <= k < a + t.shape[0]:
                    at[k - a] = True
                f[at] |= bit


class BusLoad:
    """Mean bus load as a running computation: a histogram of (DLC, IDE) and the first and last frame times.

    Fed chunk by chunk it gives :meth:`FrameTable.bus_load <benchtwin.wire.frames.FrameTable.bus_load>`'s
    value of the whole bus (same bit counts: worst-case stuffing), bit for bit the same whatever the chunks.
    """

    def __init__(self, bitrate: int) -> None:
        self.bitrate = bitrate
        self.hist = np.zeros(32, dtype=np.int64)
        self.n = 0
        self.first = float("nan")
        self.last = float("nan")

    def add(self, frames: np.ndarray) -> None:
        """Count the frames of one chunk (time order, after the chunks before)."""
        if not len(frames):
            return
        self.hist += dlc_histogram(frames)
        if self.n == 0:
            self.first = float(frames["timestamp"][0])
        self.last = float(frames["timestamp"][-1])
        self.n += len(frames)

    def value(self) -> float:
        """The load (0..1) over the frames' span; 0 below two frames, NaN over a zero span."""
        if self.n < 2:
            return 0.0
        span = float(self.last - self.first)
        if span <= 0:
            return float("nan")
        dlc = np.arange(32) // 2
        ext = np.arange(32) % 2 == 1
        base = np.where(ext, 67.0, 47.0) + 8.0 * dlc
        stuffed = np.where(ext, 54.0, 34.0) + 8.0 * dlc
        bits = float(np.sum(self.hist * (base + np.floor((stuffed - 1.0) / 4.0))))
        return bits / (self.bitrate * span)


def bus_load(table: FrameTable) -> float:
    """FrameTable.bus_load (same bit counts: worst-case stuffing) from a histogram of (DLC, IDE)."""
    load = BusLoad(table.bitrate)
    load.add(table.frames)
    return load.value()


def declared_uncertainty(devs: list[Device], roles: set[str]) -> dict[str, dict[str, float]]:
    """The systematic errors the setup declares for each decoded role, for the identification's type B budget.

    Each declared error is read as the half-width of a rectangular distribution (a data sheet's
    "+-0.25 % FS"): the value the setup injects is the size of the error the bench may have, not its sign.

    Returns
    -------
    dict
        Role -> ``{"gain_frac": a_g, "offset": a_o, "resolution": q[, "group": device]}``: half-widths of
        the relative gain error and of the offset (role's unit), and the step of the role's representation
        (the wire's scaling or the converter step, e.g. the 12-bit AD module at the telemetry's K_TEL, or a
        declared extra quantisation, whichever is coarser). ``group`` names the device when one declared
        error table applies to several of its roles (the five pressure transducers): the emulator gives
        them the same gain and offset, so they are fully correlated. Roles with nothing declared are left
        out. The noise is not listed: it is random and the fits' scatter carries it.
    """
    out: dict[str, dict[str, Any]] = {}
    for d in devs:
        steps = {role: tc.resolution for role, tc in d.truth_channels().items()}
        budget = d.error_budget()
        shared: dict[int, list[str]] = {}
        for role, (err, _link, _extra) in budget.items():
            if err is not None and role in roles:
                shared.setdefault(id(err), []).append(role)
        for role in sorted(set(steps) | set(budget)):
            if role not in roles:
                continue
            err = budget.get(role, (None, None, 0.0))[0]
            gain = abs(err.gain_error_frac) if err is not None else 0.0
            offset = abs(err.offset) if err is not None else 0.0
            step = max(float(steps.get(role, 0.0)), err.quantisation_step if err is not None else 0.0)
            if gain > 0 or offset > 0 or step > 0:
                out[role] = {"gain_frac": float(gain), "offset": float(offset), "resolution": float(step)}
                if err is not None and len(shared[id(err)]) > 1:
                    out[role]["group"] = d.name
    return out
