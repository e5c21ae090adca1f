"""The chunked encoder: every device of a setup over a Trace fed chunk by chunk, the same bytes for any chunking.

:class:`ChunkEncoder` takes the Trace in pieces (a test each from
:func:`~benchtwin.emulator.iter_campaign`, fixed slices, or all of it at once), encodes it in fixed blocks of
plant time (:class:`~benchtwin.sensors.blocks.Block`, :data:`~benchtwin.sensors.blocks.BLOCK_S`) with each
device's state carried from block to block, and returns what is complete so far as
:class:`~benchtwin.wire.frames.DeviceOutputs`. A block is encoded once the Trace reaches past its end (an
interpolation just before the end needs the next sample), so memory holds one block and one chunk.

What a chunk's outputs hold: the process images and register snapshots of the blocks encoded, and the CAN
frames stamped before :func:`complete_before` of the encoded span (no device can still send an earlier one);
the later frames wait for the next chunk, so the buses' frame tables put end to end are the whole run's, in
the same order (time, then device, then block). ``outputs.until_s`` says how far the plant was encoded
(``-inf`` before the first block; None once the run has ended).
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from benchtwin.config.setup import SetupConfig
from benchtwin.errors import DataError
from benchtwin.sensors.base import Device
from benchtwin.sensors.blocks import BLOCK_S, Block, block_rng, step_of
from benchtwin.sensors.registry import devices
from benchtwin.trace import Trace
from benchtwin.wire.frames import FRAME_DTYPE, DeviceOutputs, FrameTable, ProcessImage, RegisterSnapshots
from benchtwin.wire.merge import concat_frames, merge_frames, take_frames

__all__ = ["ChunkEncoder", "complete_before"]

#: margin below the devices' clock edge: a tick time is rounded at most this much below its device time
_EDGE_MARGIN_S = 1e-6


def complete_before(devs: Sequence[Device], until_s: float) -> float:
    """The log time before which every frame of a run encoded up to plant time ``until_s`` is known.

    Every later tick of a device lies at or after its clock's reading of ``until_s`` (clocks never go back),
    and the bench's own commands at or after ``until_s``.
    """
    edge = until_s
    for d in devs:
        edge = min(edge, float(d.clock().to_device(np.array([until_s]))[0]))
    return edge - _EDGE_MARGIN_S


def _sorted(frames: np.ndarray) -> np.ndarray:
    t = frames["timestamp"]
    if t.size < 2 or np.all(t[1:] >= t[:-1]):
        return frames
    return take_frames(frames, np.argsort(t, kind="stable"))


class ChunkEncoder:
    """Encode every device of a setup over a Trace given chunk by chunk (see the module docstring).

    Parameters
    ----------
    setup:
        The bench.
    seed:
        Campaign seed; each device draws from its own stream per block (:func:`block_rng`).
    block_s:
        Block of plant time (the unit of the keyed draws and of the memory held).
    workers:
        Threads encoding devices in parallel; the result does not depend on it. Default 1 (in the calling
        thread): the devices' encoders hold the GIL for most of their work (many small numpy steps), so threads
        did not pay on a block's nine devices and beside ``run_chunked``'s decoding thread they cost hand-offs
        (benchmarks/RESULTS.md, branch chainenc). With ``workers`` > 1 one pool serves the whole run (shut when
        the run ends or the encoder is dropped).
    """

    def __init__(self, setup: SetupConfig, seed: int | None = 0, *, block_s: float = BLOCK_S,
                 workers: int | None = None) -> None:
        if not block_s > 0:
            raise DataError(f"block_s must be positive, got {block_s}")
        self.setup = setup
        self.seed = seed
        self.block_s = float(block_s)
        self.devices = devices(setup)
        self.workers = 1 if workers is None else max(1, int(workers))
        self._pool: ThreadPoolExecutor | None = None
        self.tail_s = max([d.link.latency_s for d in self.devices] + [0.0]) + 1.0
        self._state: dict[str, dict] = {d.name: {} for d in self.devices}
        self._frames: dict[str, list[np.ndarray]] = {d.name: [] for d in self.devices if d.wire == "can"}
        self._t = np.zeros(0)
        self._ch: dict[str, np.ndarray] = {}
        self._meta: dict = {}
        self._first = 0  # index in the whole Trace of the buffer's first sample
        self._block: int | None = None
        self._start = 0.0
        self._dt = float("nan")
        self.until_s = -math.inf  # plant time encoded so far
        self.finished = False

    def feed(self, chunk: Trace | None, *, final: bool = False) -> DeviceOutputs:
        """Add the next piece of the Trace; return the outputs completed by it.

        Parameters
        ----------
        chunk:
            The Trace's samples after those fed so far (None: nothing more, with ``final``).
        final:
            The run ends with this chunk: everything left is encoded and returned.

        Raises
        ------
        DataError
            If a chunk goes back in time, after the final chunk, or if the run has fewer than two samples.
        """
        if self.finished:
            raise DataError("the encoder's run has ended (a final chunk was fed)")
        if chunk is not None and len(chunk):
            self._append(chunk)
        if final and self._first + self._t.size < 2:
            raise DataError("trace needs at least two samples to encode")
        if self._t.size == 0:
            return DeviceOutputs(until_s=self.until_s)
        done: list[tuple[Device, list]] = []
        if self.workers > 1 and self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=self.workers, thread_name_prefix="encode")
            weakref.finalize(self, self._pool.shutdown, wait=False)
        try:
            while not self.finished:
                blk = self._next_block(final)
                if blk is None:
                    break
                done.append(self._encode_block(blk, self._pool))
        finally:
            if self._pool is not None and self.finished:
                self._pool.shutdown()
                self._pool = None
        return self._emit(done)

    def finish(self) -> DeviceOutputs:
        """End the run: encode what is left."""
        return self.feed(None, final=True)

    # ------------------------------------------------------------------ internals

    def _append(self, chunk: Trace) -> None:
        t = chunk.time_s
        if self._t.size and not t[0] > self._t[-1]:
            raise DataError(f"trace chunk starts at {t[0]:.6f} s, not after the previous chunk's end "
                            f"{self._t[-1]:.6f} s")
        if np.any(np.diff(t) <= 0):
            raise DataError("trace chunk time is not strictly increasing")
        if self._block is None and self._t.size == 0:
            self._start = float(t[0])
            self._block = math.floor(self._start / self.block_s)
            self._ch = {k: np.asarray(v) for k, v in chunk.channels.items()}
            self._t = t
            self._meta = dict(chunk.meta)
            return
        self._t = _joined(self._t, t)
        self._ch = {k: _joined(v, chunk[k]) for k, v in self._ch.items()}

    def _next_block(self, final: bool) -> Block | None:
        j = self._block
        a = max(self._start, j * self.block_s)
        b = (j + 1) * self.block_s
        t = self._t
        last = t[-1] < b
        if last:
            if not final:
                return None
            b = float(t[-1]) + 1e-9
        lo = max(int(np.searchsorted(t, a - self.tail_s, side="right")) - 1, 0)
        hi = min(int(np.searchsorted(t, b, side="left")) + 1, t.size)
        window = Trace(t[lo:hi], {k: v[lo:hi] for k, v in self._ch.items()}, [], self._meta)
        if not np.isfinite(self._dt):
            self._dt = step_of(window.time_s)
        blk = Block(window, a, b, j, last, None, {}, self._first + lo, self._dt)  # type: ignore[arg-type]
        # drop what no later block reaches back to
        keep = max(int(np.searchsorted(t, b - self.tail_s, side="right")) - 1, 0)
        if keep > 0 and not last:
            self._t = t[keep:]
            self._ch = {k: v[keep:] for k, v in self._ch.items()}
            self._first += keep
        self._block = j + 1
        self.until_s = b
        self.finished = last
        return blk

    def _encode_block(self, blk: Block, pool: ThreadPoolExecutor | None) -> tuple[Device, list]:
        def run(d: Device):
            mine = Block(blk.trace, blk.start_s, blk.end_s, blk.index, blk.final,
                         block_rng(self.seed, d.name, blk.index), self._state[d.name], blk.first, blk.dt_s)
            return d.encode(mine)

        results = list(pool.map(run, self.devices)) if pool is not None else [run(d) for d in self.devices]
        return blk, results

    def _emit(self, done: list) -> DeviceOutputs:
        out = DeviceOutputs(until_s=None if self.finished else self.until_s)
        images: dict[str, list[ProcessImage]] = {}
        snaps: dict[str, list[RegisterSnapshots]] = {}
        for _blk, results in done:
            for d, res in zip(self.devices, results):
                if d.wire == "can":
                    self._frames[d.name].append(res)
                elif d.wire == "canopen":
                    images.setdefault(d.name, []).append(res)
                else:
                    snaps.setdefault(res.device, []).append(res)
        done.clear()  # the blocks' outputs are held once, by the lists above
        edge = np.inf if self.finished else complete_before(self.devices, self.until_s)
        per_bus: dict[str, list[np.ndarray]] = {b: [] for b in self.setup.buses}
        for d in self.devices:
            if d.wire != "can":
                continue
            parts, self._frames[d.name] = self._frames[d.name], []
            frames = _sorted(concat_frames(parts) if len(parts) > 1 else parts[0]) if parts else \
                np.zeros(0, FRAME_DTYPE)
            del parts  # the blocks' arrays go as soon as they are joined
            cut = int(np.searchsorted(frames["timestamp"], edge, side="left"))
            per_bus.setdefault(d.bus, []).append(frames[:cut])
            self._frames[d.name] = [frames[cut:]] if cut < len(frames) else []
        for bus, parts in per_bus.items():
            out.can[bus] = FrameTable(bus, merge_frames(parts), self.setup.bitrate(bus))
        for name, ims in images.items():
            out.canopen[name] = ProcessImage(ims[0].node, ims[0].node_id, np.concatenate([i.times for i in ims]),
                                             ims[0].entries, np.concatenate([i.values for i in ims]))
        for name, ss in snaps.items():
            out.modbus[name] = RegisterSnapshots(ss[0].device, ss[0].unit_id, ss[0].first_register,
                                                 np.concatenate([s.times for s in ss]),
                                                 np.concatenate([s.registers for s in ss]), ss[0].kind)
        return out


def _joined(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.concatenate([a, b])`` of two 1-D arrays; when ``b`` follows ``a`` in the memory of one array, at the same
    stride (the pieces of one Trace cut by :func:`~benchtwin.chain.stream.time_slices`, e.g. a family run's 600-s
    chunks; the plant's channels are rows or columns of a few 2-D arrays) a read-only view of that memory instead of
    a copy: the same values (a family run's converter example copied its 57 channels
    at each chunk, 0.01 s of 0.5)."""
    if (a.ndim == b.ndim == 1 and a.size and b.size and a.dtype == b.dtype and _owner(a) is _owner(b)
            and a.strides == b.strides and a.strides[0] > 0
            and a.__array_interface__["data"][0] + a.size * a.strides[0] == b.__array_interface__["data"][0]):
        return np.lib.stride_tricks.as_strided(a, shape=(a.size + b.size,), strides=a.strides, writeable=False)
    return np.concatenate([a, b])


def _owner(x: object) -> object:
    """The object that owns an array's memory (the end of its chain of ``base``)."""
    while getattr(x, "base", None) is not None:
        x = x.base  # type: ignore[attr-defined]
    return x
