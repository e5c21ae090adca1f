"""Chunked batch delivery: what the bench's acquisition receives of the devices' outputs, chunk by chunk.

:class:`ChunkDeliverer` takes :class:`~benchtwin.wire.frames.DeviceOutputs` as a
:class:`~benchtwin.sensors.ChunkEncoder` gives them (or a whole run's at once) and returns
:class:`~benchtwin.chain.acquisition.AcquisitionInput` pieces whose frame tables and poll logs put end to end
are the same bytes for any chunking. It works in fixed blocks (:data:`~benchtwin.sensors.blocks.BLOCK_S`):

- per bus, blocks of log time: the CANopen nodes' TPDO frames of the block (with the node's link faults,
  stream ``<node>_pdo``), then the bus's injected faults (stream ``faults:<bus>``) and transport
  disconnects; a block is delivered once the encoder's outputs are complete past its end
  (:func:`~benchtwin.sensors.encoder.complete_before`); a duplicate sent past the block's end waits for
  the next block;
- per polled device, blocks of request time (stream ``modbus_poll``), once the register updates the
  block's requests read are encoded; the client's wait after a timeout is carried to the next block.

Each block's draws come from :func:`~benchtwin.sensors.blocks.block_rng` keyed by the block index.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator

import numpy as np

from benchtwin.chain.acquisition import AcquisitionInput
from benchtwin.chain.buslog import DEFAULT_START
from benchtwin.config.setup import SetupConfig
from benchtwin.sensors import ChunkEncoder, devices
from benchtwin.sensors.blocks import BLOCK_S, block_rng
from benchtwin.sensors.encoder import complete_before
from benchtwin.sensors.imperfections import disconnect, span_frame_faults
from benchtwin.trace import Trace
from benchtwin.wire.frames import FRAME_DTYPE, DeviceOutputs, FrameTable, PollLog, ProcessImage, RegisterSnapshots
from benchtwin.wire.merge import concat_frames, insert_frames, merge_frames

__all__ = ["ChunkDeliverer", "iter_delivered"]

#: a poll block is delivered once the plant is encoded this far past its last request's reach
_POLL_MARGIN_S = 1e-3


def _cat_image(a: ProcessImage | None, b: ProcessImage) -> ProcessImage:
    if a is None or len(a.times) == 0:
        return b
    return ProcessImage(b.node, b.node_id, np.concatenate([a.times, b.times]), b.entries,
                        np.concatenate([a.values, b.values]))


def _image_rows(im: ProcessImage, rows: slice) -> ProcessImage:
    return ProcessImage(im.node, im.node_id, im.times[rows], im.entries, im.values[rows])


class ChunkDeliverer:
    """Deliver a run's device outputs chunk by chunk (see the module docstring).

    Parameters
    ----------
    setup:
        The bench.
    seed:
        Campaign seed.
    start_s:
        Start of polling (plant time); default: the first register update.
    block_s:
        Block length (the unit of the keyed draws).
    """

    def __init__(self, setup: SetupConfig, seed: int | None = 0, *, start_s: float | None = None,
                 block_s: float = BLOCK_S) -> None:
        self.setup = setup
        self.seed = seed
        self.block_s = float(block_s)
        self.devices = devices(setup)
        self.start_s = start_s
        self._frames: dict[str, np.ndarray] = {}
        self._carry: dict[str, np.ndarray] = {}
        self._images: dict[str, ProcessImage | None] = {}
        self._bus_k: dict[str, int | None] = {}
        self._snaps: dict[str, RegisterSnapshots] = {}
        self._poll_k: dict[str, int | None] = {}
        self._state: dict[str, dict] = {d.name: {} for d in self.devices}
        self._events_sent = False
        self.finished = False

    def feed(self, outputs: DeviceOutputs, *, end_s: float | None = None) -> AcquisitionInput:
        """Deliver what ``outputs`` completes (all of it when ``outputs.until_s`` is None: the run's end).

        Parameters
        ----------
        outputs:
            The devices' outputs since the previous call.
        end_s:
            End of polling (plant time) at the run's end; default: the last register update.
        """
        from benchtwin.errors import DataError

        if self.finished:
            raise DataError("the delivery's run has ended (the final outputs were delivered)")
        final = outputs.until_s is None
        edge = math.inf if final else complete_before(self.devices, outputs.until_s)
        got = AcquisitionInput(start_time=DEFAULT_START)
        for bus in list(self.setup.buses) + [b for b in outputs.can if b not in self.setup.buses]:
            table = outputs.can.get(bus)
            new = table.frames if table is not None else np.zeros(0, FRAME_DTYPE)
            old = self._frames.get(bus)
            self._frames[bus] = new if old is None or not len(old) else concat_frames([old, new])
            got.can[bus] = FrameTable(bus, self._deliver_bus(bus, outputs, edge, final), self.setup.bitrate(bus)
                                      if bus in self.setup.buses else (table.bitrate if table else 500_000))
        for d in self.devices:
            if d.wire == "modbus":
                log = self._deliver_polls(d, outputs, final, end_s)
                if log is not None:
                    got.polls[log.device] = log
        if not self._events_sent:
            from benchtwin.wire.frames import TransportEvent

            for bus in self.setup.buses:
                _, spans = disconnect(np.zeros(0, FRAME_DTYPE), self.setup.faults_of(bus))
                got.events += [TransportEvent(a, bus, "drop", b, "injected transport disconnect") for a, b in spans]
            self._events_sent = True
        self.finished = final
        return got

    # ------------------------------------------------------------------ buses

    def _deliver_bus(self, bus: str, outputs: DeviceOutputs, edge: float, final: bool) -> np.ndarray:
        nodes = [d for d in self.devices if d.wire == "canopen" and d.bus == bus]
        for d in nodes:
            if d.name in outputs.canopen:
                self._images[d.name] = _cat_image(self._images.get(d.name), outputs.canopen[d.name])
        frames = self._frames[bus]
        images = {d.name: self._images.get(d.name) for d in nodes}
        k = self._bus_k.get(bus)
        if k is None:
            firsts = [float(frames["timestamp"][0])] if len(frames) else []
            firsts += [float(im.times[0]) for im in images.values() if im is not None and len(im.times)]
            if not firsts:
                return np.zeros(0, FRAME_DTYPE)
            k = math.floor(min(firsts) / self.block_s)
        faults = self.setup.faults_of(bus)
        out: list[np.ndarray] = []
        carry = self._carry.get(bus, np.zeros(0, FRAME_DTYPE))
        times = np.ascontiguousarray(frames["timestamp"])  # searched once per block: no strided copy each time
        pos = 0
        while True:
            hi_t = (k + 1) * self.block_s
            if not final and hi_t > edge:
                break
            left = len(frames) - pos + sum(len(im.times) for im in images.values() if im is not None)
            if final and left == 0:
                break
            cut = pos + int(np.searchsorted(times[pos:], hi_t, side="left"))
            blk = frames[pos:cut]
            pos = cut
            for d in nodes:
                im = images[d.name]
                if im is None or not len(im.times):
                    continue
                n = int(np.searchsorted(im.times, hi_t, side="left"))
                if n:
                    sent = d.deliver(_image_rows(im, slice(0, n)), block_rng(self.seed, f"{d.name}_pdo", k),
                                     (k * self.block_s, hi_t), self._state[d.name])
                    blk = insert_frames(blk, sent.frames)
                    images[d.name] = _image_rows(im, slice(n, None))
            if faults and len(blk):
                blk = span_frame_faults(blk, blk["arbitration_id"].astype(np.int64), faults,
                                        block_rng(self.seed, f"faults:{bus}", k))
                blk, _ = disconnect(blk, faults)
            merged = merge_frames([carry, blk])
            n_out = int(np.searchsorted(merged["timestamp"], hi_t, side="left"))
            out.append(merged[:n_out])
            carry = merged[n_out:]
            k += 1
        if final and len(carry):
            out.append(carry)
            carry = np.zeros(0, FRAME_DTYPE)
        self._bus_k[bus] = k
        self._carry[bus] = carry
        self._frames[bus] = frames[pos:]
        for name, im in images.items():
            self._images[name] = im
        return merge_frames(out) if len(out) > 1 else (out[0] if out else np.zeros(0, FRAME_DTYPE))

    # ------------------------------------------------------------------ polls

    def _deliver_polls(self, d, outputs: DeviceOutputs, final: bool, end_s: float | None) -> PollLog | None:
        name = d.poll_device
        new = outputs.modbus.get(name)
        held = self._snaps.get(name)
        if new is not None:
            held = new if held is None or not len(held.times) else RegisterSnapshots(
                new.device, new.unit_id, new.first_register, np.concatenate([held.times, new.times]),
                np.concatenate([held.registers, new.registers]), new.kind)
        if held is None:
            return None
        self._snaps[name] = held
        k = self._poll_k.get(name)
        if k is None:
            if self.start_s is None and not len(held.times):
                return None
            self.start_s = float(held.times[0]) if self.start_s is None else self.start_s
            k = math.floor(self.start_s / self.block_s)
        end = None
        if final:
            end = end_s if end_s is not None else (float(held.times[-1]) if len(held.times) else self.start_s)
        reach = d.poll_reach_s()
        clock = d.clock()
        logs: list[PollLog] = []
        while True:
            a, b = max(self.start_s, k * self.block_s), (k + 1) * self.block_s
            if final:
                if a >= end:
                    break
                b = min(b, end)
            elif outputs.until_s < b + reach + _POLL_MARGIN_S:
                break
            logs.append(d.deliver(held, block_rng(self.seed, "modbus_poll", k), (a, b), self._state[d.name]).polls)
            # keep the last update the next block's first request can read, and what follows
            first = max(int(np.searchsorted(held.times, float(clock.to_device(np.array([b + reach]))[0]),
                                            side="right")) - 1, 0)
            held = RegisterSnapshots(held.device, held.unit_id, held.first_register, held.times[first:],
                                     held.registers[first:], held.kind)
            k += 1
        self._snaps[name] = held
        self._poll_k[name] = k
        if not logs:
            if not len(held.registers):
                return None
            count = held.registers.shape[1]
            return PollLog(held.device, held.unit_id, 4, held.first_register, np.zeros(0),
                           np.zeros((0, count), np.uint16), np.zeros(0, np.int16))
        return PollLog(logs[0].device, logs[0].unit_id, logs[0].function_code, logs[0].first_register,
                       np.concatenate([g.times for g in logs]), np.concatenate([g.values for g in logs]),
                       np.concatenate([g.status for g in logs]))


def iter_delivered(chunks: Iterable[Trace], setup: SetupConfig, seed: int | None = 0, *,
                   block_s: float = BLOCK_S) -> Iterator[AcquisitionInput]:
    """Encode and deliver a Trace given chunk by chunk (e.g. :func:`~benchtwin.emulator.iter_campaign`).

    Yields one :class:`~benchtwin.chain.acquisition.AcquisitionInput` per chunk (the frames and polls it
    completes, with the chunk's segments); put end to end they are the whole run's
    ``deliver(encode(trace, setup, seed), setup, seed=seed, span_s=(first, last sample))``, byte for byte.
    Polling runs from the first sample to the last; one chunk is read ahead to know which is the last.
    """
    enc = ChunkEncoder(setup, seed, block_s=block_s)
    dl: ChunkDeliverer | None = None
    pending: Trace | None = None

    def one(chunk: Trace, final: bool) -> AcquisitionInput:
        nonlocal dl
        if dl is None:
            dl = ChunkDeliverer(setup, seed, start_s=float(chunk.time_s[0]), block_s=block_s)
        got = dl.feed(enc.feed(chunk, final=final), end_s=float(chunk.time_s[-1]) if final else None)
        got.segments = list(chunk.segments)
        return got

    for chunk in chunks:
        if not len(chunk):
            continue
        if pending is not None:
            yield one(pending, False)
        pending = chunk
    if pending is not None:
        yield one(pending, True)
