"""The pressure module's poll log decoded block by block: what
:func:`~benchtwin.sensors.pressure_decode.decode_pressure_polls` gives, bit for bit, holding one block of polls at a
time however long the log (and the medians' values of at most :data:`HOLD_BLOCKS` blocks).

The whole-log decoder judges the module's clock over the whole log
(:func:`~benchtwin.sensors.poll_clock.poll_clock_evidence`): per-second medians of the answers' age, the medians of
their deviations (the acquisition's jitter) and of the age itself (the clock offset). Here the log is read in passes
of blocks:

1. a scan: the counts, the uptime unwrapping's carry at each block's start, the runs of timeouts, and the
   per-second medians of the age (a second that straddles a block edge is carried into the next block);
2. exact medians of the age and of its deviations (a radix selection on the values' bits, 16 bits a pass; a log of
   at most :data:`HOLD_BLOCKS` blocks of answers has its values held in the selection's first pass and the medians
   taken by a partial sort of them: one pass instead of four, the same values);
3. the median absolute deviation (the same selection);
4. the decode proper: flags (timeouts, exceptions, transport drops, late answers, the clock's steps and drift),
   the time base and the held values, each block handed to ``emit``.

The per-second medians (8 B a second of log) and the judgement made of them stay whole: 0.23 MB for a day.
A log whose times go back (never made by the batch chain or the live recorder) is decoded whole.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Protocol

import numpy as np

from benchtwin.config.setup import PressureConfig
from benchtwin.roles import unit_of_role
from benchtwin.sensors.poll_clock import RESTART_RUN, judge_age_medians
from benchtwin.sensors.pressure_decode import decode_pressure_polls, pressure_from_counts
from benchtwin.wire.frames import POLL_OK, POLL_TIMEOUT, PollLog
from benchtwin.wire.modbus_map import CHANNELS, REG_RAW, REG_STATUS, REG_UPTIME_HI, REG_UPTIME_LO, volts_to_counts
from benchtwin.wire.quality import FLAG, DecodeSink

__all__ = ["HOLD_BLOCKS", "PollBlocks", "decode_pressure_poll_blocks", "select_ranks"]

#: the median selections hold a value set whole (8 B a value) while it has at most this many blocks' values
HOLD_BLOCKS = 8

#: one block of a channel: (name, unit, timestamps, values, flags, source)
Emit = Callable[[str, str, np.ndarray, np.ndarray, np.ndarray, str], None]
_WRAP = 1 << 32
_HALF = 1 << 31


class PollBlocks(Protocol):
    """A poll log read by index ranges (a :class:`~benchtwin.wire.frames.PollLog`, or one spooled to files)."""

    device: str
    first_register: int

    def __len__(self) -> int: ...

    def part(self, start: int, stop: int) -> PollLog: ...


def _keys(x: np.ndarray) -> np.ndarray:
    """Unsigned keys in the order of the float64 values ``x`` (no NaN)."""
    b = np.ascontiguousarray(x, dtype=np.float64).view(np.uint64)
    neg = (b >> np.uint64(63)).astype(bool)
    return np.where(neg, ~b, b | np.uint64(1 << 63))


def _value(key: int) -> float:
    bits = key & ~(1 << 63) if key >> 63 else ~key & 0xFFFFFFFFFFFFFFFF
    return float(np.array([bits], dtype=np.uint64).view(np.float64)[0])


def select_ranks(blocks: Callable[[], Iterator[list[np.ndarray]]], ranks: list[list[int]], hold: int = 0
                 ) -> list[list[float]]:
    """Exact order statistics of several value sets read in blocks, four passes of 16 bits over the blocks.

    Parameters
    ----------
    blocks:
        Makes a new iterator over the blocks; each block is a list with one array per value set (float64, no NaN).
    ranks:
        Per value set, the sorted positions (0-based) wanted.
    hold:
        A value set of at most this many values is held whole in the first pass and its order statistics are
        taken from it by a partial sort (one pass over the blocks instead of four; the same values: both find the
        keys at those ranks); a larger set is held up to ``hold`` values and counted (0: every set counted).

    Returns
    -------
    list of list of float
        Per value set, the values at those positions of its sorted values.
    """
    prefix = [[0] * len(r) for r in ranks]
    left = [list(r) for r in ranks]
    found: list[list[float] | None] = [None] * len(ranks)
    for shift in (48, 32, 16, 0):
        hist = [[np.zeros(1 << 16, np.int64) for _ in r] for r in ranks]
        held: list[list[np.ndarray]] = [[] for _ in ranks]  # small blocks are counted together
        # in the first pass a set is held whole while it has at most `hold` values
        spilled = [shift != 48 or hold <= 0 or found[s] is not None for s in range(len(ranks))]

        def count(s: int, shift: int = shift, hist: list = hist, held: list = held) -> None:
            k = np.concatenate(held[s])
            held[s] = []
            for j in range(len(ranks[s])):
                kk = k if shift == 48 else k[(k >> np.uint64(shift + 16)) == np.uint64(prefix[s][j])]
                hist[s][j] += np.bincount(((kk >> np.uint64(shift)) & np.uint64(0xFFFF)).astype(np.intp),
                                          minlength=1 << 16)

        for arrays in blocks():
            for s, x in enumerate(arrays):
                if ranks[s] and x.size and found[s] is None:
                    held[s].append(_keys(x))
                    size = sum(a.size for a in held[s])
                    if not spilled[s] and size > hold:
                        spilled[s] = True
                    if spilled[s] and size >= 1 << 14:
                        count(s)
        for s in range(len(ranks)):
            if not spilled[s] and ranks[s]:  # held whole: the keys at the ranks by a partial sort
                k = np.concatenate(held[s]) if held[s] else np.zeros(0, np.uint64)
                held[s] = []
                k.partition(ranks[s])
                found[s] = [_value(int(k[r])) for r in ranks[s]]
            elif held[s]:
                count(s)
        for s in range(len(ranks)):
            if found[s] is not None:
                continue
            for j in range(len(ranks[s])):
                c = np.cumsum(hist[s][j])
                b = int(np.searchsorted(c, left[s][j], side="right"))
                left[s][j] -= int(c[b - 1]) if b else 0
                prefix[s][j] = (prefix[s][j] << 16) | b
        if all(f is not None or not r for f, r in zip(found, ranks)):
            break
    return [f if f is not None else [_value(p) for p in ps] for f, ps in zip(found, prefix)]


def _median_ranks(n: int) -> list[int]:
    """The two middle ranks (the same one twice for an odd count: the work does not depend on the parity)."""
    return [] if n == 0 else [(n - 1) // 2, n // 2]


def _median(vals: list[float]) -> float:
    """``np.median``'s value from the two middle values (for an odd count the middle one twice: (a + a) / 2 is a)."""
    return float(np.mean(np.array(vals, dtype=np.float64))) if vals[0] != vals[1] else vals[0]


class _Scan:
    """What the first pass carries and finds."""

    def __init__(self, has_uptime: bool) -> None:
        self.has_uptime = has_uptime
        #: per block: the uptime unwrapping's carry at its start (last good raw, correction, shift)
        self.starts: list[tuple[int | None, int, int]] = []
        self.n_ok = 0
        self.timeouts = 0
        self.exceptions: dict[int, int] = {}
        self.first: tuple[float, float] | None = None  # first good answer: (poll time, uptime)
        self.run: list[np.ndarray] = []  # an open run of timeouts: its poll times
        self.restarts: list[np.ndarray] = []
        self.hold_k = np.zeros(0, np.int64)
        self.hold_age = np.zeros(0)
        self.has: list[np.ndarray] = []
        self.med: list[np.ndarray] = []
        self.last_time = -np.inf
        self.sorted = True


def _uptime(part: PollLog, ok: np.ndarray, carry: tuple[int | None, int, int], scan: _Scan
            ) -> tuple[np.ndarray, tuple[int | None, int, int]]:
    """The module's uptime of each poll (s) as the whole log's unwrapping gives it, and the carry after the block."""
    if not scan.has_uptime:
        return part.times.copy(), carry
    raw = part.values[:, REG_UPTIME_HI].astype(np.int64) << 16 | part.values[:, REG_UPTIME_LO]
    out = raw.astype(np.int64).copy()
    idx = np.flatnonzero(ok)
    prev, corr, shift = carry
    if idx.size:
        g = out[idx]
        if prev is None:
            d = np.diff(g)
            cum = np.concatenate([[0], np.cumsum(np.where(d < -_HALF, _WRAP, 0) - np.where(d > _HALF, _WRAP, 0))])
            shift = _WRAP if g[0] >= _HALF else 0
        else:
            d = np.diff(np.concatenate([[prev], g]))
            cum = corr + np.cumsum(np.where(d < -_HALF, _WRAP, 0) - np.where(d > _HALF, _WRAP, 0))
        prev, corr = int(g[-1]), int(cum[-1])
        out[idx] = g + cum - shift
    return out / 1000.0, (prev, corr, shift)


def _bounds(n: int, block: int) -> list[tuple[int, int]]:
    return [(a, min(a + block, n)) for a in range(0, n, block)]


def _per_second(t: np.ndarray, first: float, block_s: float) -> np.ndarray:
    return np.floor((t - first) / block_s).astype(np.int64)


def decode_pressure_poll_blocks(src: PollBlocks, cfg: PressureConfig | None, sink: DecodeSink, drops: np.ndarray,
                                emit: Emit, block: int = 1 << 18) -> None:
    """Decode the pressure module's poll log ``block`` polls at a time, as
    :func:`~benchtwin.sensors.pressure_decode.decode_pressure_polls` decodes it whole.

    Parameters
    ----------
    src:
        The poll log, read by index ranges.
    cfg:
        The module's configuration (None: raw counts, no clock judgement's declared drift).
    sink:
        Counts, protocol errors and the fault evidence go here, as the whole-log decoder puts them.
    drops:
        Times of transport drops of the device.
    emit:
        Takes each block of each of the five channels, in time order (channel by channel within a block).
    block:
        Polls read at a time.
    """
    n = len(src)
    block = max(1, int(block))
    head = src.part(0, 0)
    if n == 0 or head.first_register != 0 or head.count <= REG_RAW + len(CHANNELS) - 1:
        decode_pressure_polls(src.part(0, n), cfg, sink, drops)  # counts and the protocol error, nothing decoded
        return
    bounds = _bounds(n, block)
    scan = _Scan(head.count > REG_UPTIME_LO)
    block_s = 1.0
    carry: tuple[int | None, int, int] = (None, 0, 0)
    for a, b in bounds:  # pass 1
        part = src.part(a, b)
        if part.times.size and (part.times[0] < scan.last_time or np.any(np.diff(part.times) < 0)):
            scan.sorted = False
            break
        if part.times.size:
            scan.last_time = float(part.times[-1])
        st = part.status
        ok = st == POLL_OK
        scan.starts.append(carry)
        up, carry = _uptime(part, ok, carry, scan)
        scan.n_ok += int(np.count_nonzero(ok))
        tout = st == POLL_TIMEOUT
        scan.timeouts += int(np.count_nonzero(tout))
        for c, k in zip(*np.unique(st[~ok & ~tout], return_counts=True)):
            scan.exceptions[int(c)] = scan.exceptions.get(int(c), 0) + int(k)
        _runs(scan, part.times, tout)
        if ok.any():
            tg, ag = part.times[ok], part.times[ok] - up[ok]
            if scan.first is None:
                scan.first = (float(tg[0]), float(up[ok][0]))
            _medians(scan, _per_second(tg, scan.first[0], block_s), ag, final=False)
    if not scan.sorted:
        decode_pressure_polls(src.part(0, n), cfg, sink, drops)
        emitted = sink.rec.channels
        for _trace, role in CHANNELS:  # hand the whole channels on as one block each
            ch = emitted.pop(role)
            emit(role, ch.unit, ch.timestamps, ch.values, ch.flags, ch.source)
        return
    _medians(scan, np.zeros(0, np.int64), np.zeros(0), final=True)
    if scan.run:
        _close_run(scan)
    sink.counts.setdefault("modbus", {})[src.device] = {
        "polls": n, "timeouts": scan.timeouts, "exceptions": dict(sorted(scan.exceptions.items()))}
    has = np.concatenate(scan.has) if scan.has else np.zeros(0, np.int64)
    m = np.concatenate(scan.med) if scan.med else np.zeros(0)

    def good(with_dev: bool) -> Iterator[list[np.ndarray]]:
        for (a, b), c in zip(bounds, scan.starts):
            part = src.part(a, b)
            ok = part.status == POLL_OK
            up, _ = _uptime(part, ok, c, scan)
            age = part.times[ok] - up[ok]
            if not with_dev:
                yield [age]
                continue
            k = _per_second(part.times[ok], scan.first[0], block_s) if scan.first else np.zeros(0, np.int64)
            yield [age, age - m[np.searchsorted(has, k)]]

    judge = scan.has_uptime and scan.n_ok >= 50
    offset = None
    judged = None
    if scan.n_ok:
        ranks = _median_ranks(scan.n_ok)
        got = select_ranks(lambda: good(judge), [ranks, ranks if judge else []], HOLD_BLOCKS * block)
        offset = _median(got[0])
        if judge:
            centre = _median(got[1])

            def spread() -> Iterator[list[np.ndarray]]:
                for _age, dev in good(True):
                    yield [np.abs(dev - centre)]

            jitter = 1.4826 * _median(select_ranks(spread, [ranks], HOLD_BLOCKS * block)[0])
            period = 1.0 / cfg.update_hz if cfg is not None else 0.005
            declared = cfg.link.clock_drift_ppm if cfg is not None else 0.0
            judged = judge_age_medians(scan.first[0] + (has + 0.5) * block_s, m, jitter, period, declared, block_s)
    for times in scan.restarts:
        sink.fault("modbus_restart", src.device, times)
    late_times: list[np.ndarray] = []
    v_max = (pressure_from_counts(volts_to_counts(np.array([cfg.output_max_v]))[0], cfg)[0]
             if cfg is not None else None)
    hold: tuple[float, float, np.ndarray] | None = None  # last good answer: (poll time, uptime, registers)
    t_max = -np.inf
    prev_last = -np.inf
    offset0 = scan.first[0] - scan.first[1] if scan.first is not None else 0.0
    for (a, b), c in zip(bounds, scan.starts):  # pass 4
        part = src.part(a, b)
        ok = part.status == POLL_OK
        up, _ = _uptime(part, ok, c, scan)
        times, values = part.times, part.values
        if hold is not None:  # the last good answer before the block, as element 0
            times = np.concatenate([[hold[0]], times])
            up = np.concatenate([[hold[1]], up])
            values = np.concatenate([hold[2][None, :], values])
            ok = np.concatenate([[True], ok])
        k0 = 0 if hold is None else 1
        nb = times.size
        last_good = np.maximum.accumulate(np.where(ok, np.arange(nb), -1))
        has_good = last_good >= 0
        lg = np.clip(last_good, 0, None)
        t = np.where(ok, up, up[lg] + (times - times[lg]))
        t = np.where(has_good, t, times - offset0)
        st = part.status
        flags = np.zeros(b - a, dtype=np.uint16)
        flags[st == POLL_TIMEOUT] |= FLAG["TIMEOUT"]
        flags[(st != POLL_OK) & (st != POLL_TIMEOUT)] |= FLAG["PROTOCOL_ERROR"]
        pt = part.times
        if drops.size and pt.size:
            d = drops[(drops > prev_last) & (drops <= pt[-1])]
            flags[np.searchsorted(pt, d, side="left")] |= FLAG["TRANSPORT_DROP"]
        if judged is not None:
            okb = part.status == POLL_OK
            tg = pt[okb]
            kb = _per_second(tg, scan.first[0], block_s)
            late = judged.late(tg, tg - up[k0:][okb], np.searchsorted(has, kb))
            if late.any():
                flags[np.flatnonzero(okb)[late]] |= FLAG["LATE"]
                late_times.append(tg[late])
            for ts, _size in judged.steps:
                flags[np.abs(pt - ts) <= 1.0] |= FLAG["CLOCK"]
            for lo, hi in judged.drifts:
                flags[(pt >= lo) & (pt < hi)] |= FLAG["CLOCK"]
        if pt.size:
            prev_last = float(pt[-1])
        t = np.maximum(np.maximum.accumulate(t[k0:]), t_max)
        if t.size:
            t_max = float(t[-1])
        lgb = lg[k0:]
        status = values[lgb, REG_STATUS].astype(np.int64) if head.count > REG_STATUS else np.zeros(b - a, np.int64)
        for k, (_trace, role) in enumerate(CHANNELS):
            counts = values[lgb, REG_RAW + k]
            v = pressure_from_counts(counts, cfg) if cfg is not None else counts.astype(np.float64)
            v = np.where(has_good[k0:], v, np.nan)
            f = flags.copy()
            f[((status >> k) & 1).astype(bool) | ((status >> (8 + k)) & 1).astype(bool)] |= FLAG["SATURATED"]
            if v_max is not None:  # at the transducer's output limit
                f[v >= v_max - 1e-9] |= FLAG["SATURATED"]
            emit(role, unit_of_role(role), t, v, f, src.device)
        if ok[k0:].any():
            j = int(np.flatnonzero(ok)[-1])
            hold = (float(times[j]), float(up[j]), values[j].copy())
    if late_times:
        sink.fault("modbus_slow", src.device, np.concatenate(late_times))
    if judged is not None:
        for ts, _size in judged.steps:
            sink.fault("clock_step", src.device, np.array([ts]))
        for lo, hi in judged.drifts:
            sink.fault("clock_drift", src.device, np.array([lo]), np.array([hi]))
    if offset is not None:
        sink.counts.setdefault("clock_offsets_s", {})["pressure->acquisition"] = offset


def _runs(scan: _Scan, times: np.ndarray, tout: np.ndarray) -> None:
    """Runs of timeouts (a run open at the block's end carried on)."""
    if not tout.size:
        return
    edges = np.flatnonzero(np.diff(np.concatenate([[0], tout.astype(np.int8), [0]])))
    for a, b in zip(edges[::2], edges[1::2]):
        if a == 0 and scan.run:
            scan.run.append(times[a:b])
        else:
            if scan.run:
                _close_run(scan)
            scan.run = [times[a:b]]
        if b < tout.size:
            _close_run(scan)
    if not tout[-1] and scan.run:
        _close_run(scan)


def _close_run(scan: _Scan) -> None:
    times = np.concatenate(scan.run)
    scan.run = []
    if times.size >= RESTART_RUN:
        scan.restarts.append(times)


def _medians(scan: _Scan, k: np.ndarray, age: np.ndarray, *, final: bool) -> None:
    """The per-second medians of the age (``_block_medians``'s), a second at the block's end held for the next."""
    k = np.concatenate([scan.hold_k, k])
    age = np.concatenate([scan.hold_age, age])
    if k.size == 0:
        return
    done = k.size if final else int(np.searchsorted(k, k[-1], side="left"))
    scan.hold_k, scan.hold_age = k[done:], age[done:]
    k, age = k[:done], age[:done]
    if not k.size:
        return
    u, starts, counts = np.unique(k, return_index=True, return_counts=True)
    order = np.lexsort((age, k))
    scan.has.append(u)
    scan.med.append(age[order][starts + counts // 2])
