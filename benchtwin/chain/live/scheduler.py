"""The live scheduler: plays time-stamped device outputs onto their transports in real time or faster.

Every output is a :class:`Stream`: sorted plant times and a ``deliver(i0, i1)`` callback that puts
items ``i0..i1-1`` on the wire (CAN frames on a bus, a register snapshot into the Modbus store, a
process-image row into the CANopen node). The scheduler merges all streams on one monotonic clock:
item ``i`` is due at ``wall0 + (t_i - t_start) / speedup``. It sleeps until shortly before the next
deadline and busy-waits the short tail (``spin_s``), and it batches the items of one stream that are
due within the same ``batch_window_s`` of wall time into one delivery (one socket write for a
burst of frames). A failing delivery is logged and counted as lost; it never stops the run.

The :class:`PacingReport` gives, per stream and overall, the pacing error (time the delivery call
returned minus the item's deadline; items of a batch can be up to one window early), the items
sent and lost, and for CAN streams the nominal bus load on the emulated bus.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from benchtwin.errors import ConfigError, DataError

__all__ = ["LiveScheduler", "PacingReport", "Stream", "StreamStats", "bus_load_fraction", "format_table",
           "restore_policy", "use_realtime_priority"]

log = logging.getLogger(__name__)


def bus_load_fraction(frames: np.ndarray, bitrate: int, span_s: float) -> float:
    """Bus load (0..1) of frames over ``span_s`` seconds at ``bitrate`` (worst-case bit stuffing)."""
    if len(frames) == 0 or span_s <= 0:
        return 0.0
    dlc = frames["dlc"].astype(np.float64)
    ext = frames["is_extended"]
    base = np.where(ext, 67.0, 47.0) + 8.0 * dlc
    stuffed = np.where(ext, 54.0, 34.0) + 8.0 * dlc
    bits = float(np.sum(base + np.floor((stuffed - 1.0) / 4.0)))
    return bits / (bitrate * span_s)


def use_realtime_priority(priority: int) -> tuple[int, Any] | None:
    """Put the calling thread under ``SCHED_FIFO`` at ``priority`` (1..99), as real-time test benches do.

    Threads started afterwards inherit the policy, so call it before starting the servers: then the
    pacing thread and every thread it waits for (the GIL holders) run at the same priority, and other
    processes cannot delay a deadline. Needs root or CAP_SYS_NICE; without, a warning is logged.

    Returns
    -------
    The previous (policy, param) to give to :func:`restore_policy`, or ``None`` when nothing changed.
    """
    if not 1 <= priority <= 99:
        raise ConfigError(f"real-time priority must be 1..99, got {priority}")
    try:
        previous = (os.sched_getscheduler(0), os.sched_getparam(0))
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        log.warning("real-time priority unavailable (%s); pacing runs at normal priority", exc)
        return None
    return previous


def restore_policy(previous: tuple[int, Any] | None) -> None:
    """Undo :func:`use_realtime_priority` for the calling thread."""
    if previous is not None:
        try:
            os.sched_setscheduler(0, previous[0], previous[1])
        except OSError as exc:
            log.warning("could not restore the scheduling policy: %s", exc)


@dataclass
class Stream:
    """One time-stamped output to play.

    Attributes
    ----------
    name:
        Shown in reports (``can:powertrain``, ``modbus:pressure``, ``canopen:thermo``).
    times:
        Plant times of the items, seconds, ascending.
    deliver:
        ``deliver(i0, i1) -> int``: put items ``i0..i1-1`` on the wire, return how many went out.
    kind:
        ``can``, ``modbus``, ``canopen`` or anything else.
    frames:
        For CAN streams, the frame rows (for the bus load).
    bitrate:
        For CAN streams, the emulated bus's bit rate.
    """

    name: str
    times: np.ndarray
    deliver: Callable[[int, int], int]
    kind: str = "can"
    frames: np.ndarray | None = None
    bitrate: int = 500_000

    def __post_init__(self) -> None:
        self.times = np.asarray(self.times, dtype=np.float64)
        if self.times.ndim != 1:
            raise DataError(f"stream {self.name!r}: times must be 1-D")
        if len(self.times) > 1 and np.any(np.diff(self.times) < 0):
            raise DataError(f"stream {self.name!r}: times are not sorted")


@dataclass
class StreamStats:
    """Pacing and delivery figures of one stream (times in milliseconds of wall time)."""

    name: str
    kind: str
    items: int
    sent: int
    lost: int
    deliveries: int
    pacing_p50_ms: float
    pacing_p99_ms: float
    pacing_max_ms: float
    pacing_min_ms: float
    rate_per_s: float  #: items per second of wall time
    bus_load: float | None = None  #: nominal load of the emulated bus (0..1), CAN only


@dataclass
class PacingReport:
    """What a run of the scheduler achieved."""

    speedup: float
    plant_start_s: float
    plant_end_s: float
    wall_s: float
    completed: bool
    streams: dict[str, StreamStats] = field(default_factory=dict)
    pacing_p50_ms: float = float("nan")
    pacing_p99_ms: float = float("nan")
    pacing_max_ms: float = float("nan")

    @property
    def sent(self) -> int:
        """Items delivered over all streams."""
        return sum(s.sent for s in self.streams.values())

    @property
    def lost(self) -> int:
        """Items whose delivery failed over all streams."""
        return sum(s.lost for s in self.streams.values())

    @property
    def achieved_speedup(self) -> float:
        """Plant seconds played per wall second."""
        return (self.plant_end_s - self.plant_start_s) / self.wall_s if self.wall_s > 0 else float("nan")

    @property
    def late_s(self) -> float:
        """How much later than planned the run ended, wall seconds (0 with an infinite speed-up)."""
        if not np.isfinite(self.speedup):
            return 0.0
        return self.wall_s - (self.plant_end_s - self.plant_start_s) / self.speedup

    def speedup_held(self, tolerance: float = 0.05, slack_s: float = 0.25) -> bool:
        """True when the run ended no later than ``tolerance`` of its planned wall time (at least
        ``slack_s``) after plan, i.e. the achieved speed-up is within ~5 % of the requested one."""
        if not np.isfinite(self.speedup):
            return True
        planned = (self.plant_end_s - self.plant_start_s) / self.speedup
        return self.late_s <= max(tolerance * planned, slack_s)

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form (for JSON)."""
        d = asdict(self)
        d["sent"], d["lost"], d["achieved_speedup"] = self.sent, self.lost, self.achieved_speedup
        d["late_s"], d["speedup_held"] = self.late_s, self.speedup_held()
        return d

    def format(self) -> str:
        """A table for the terminal: one row per stream and a total, every column fixed-width.

        Column widths are taken from the widest cell, so long stream names, large counts and missing
        figures (``-``) keep the columns aligned.
        """
        head = (f"played {self.plant_end_s - self.plant_start_s:.3f} s of plant time in {self.wall_s:.3f} s "
                f"(speed-up {self.speedup:g}, achieved {self.achieved_speedup:.2f}); "
                f"{'complete' if self.completed else 'STOPPED EARLY'}")
        rows = []
        for s in self.streams.values():
            rows.append([s.name, str(s.items), str(s.sent), str(s.lost), _ms(s.pacing_p50_ms), _ms(s.pacing_p99_ms),
                         _ms(s.pacing_max_ms), _num(s.rate_per_s, ".0f"),
                         f"{100 * s.bus_load:.1f} %" if s.bus_load is not None else "-"])
        rows.append(["all", str(sum(s.items for s in self.streams.values())), str(self.sent), str(self.lost),
                     _ms(self.pacing_p50_ms), _ms(self.pacing_p99_ms), _ms(self.pacing_max_ms), "-", "-"])
        headers = ["stream", "items", "sent", "lost", "p50 ms", "p99 ms", "max ms", "rate/s", "bus load"]
        return "\n".join([head, *format_table(headers, rows, align="<" + ">" * (len(headers) - 1))])


def _num(x: float, spec: str) -> str:
    return format(x, spec) if np.isfinite(x) else "-"


def _ms(x: float) -> str:
    return _num(x, ".3f")


def format_table(headers: list[str], rows: list[list[str]], align: str | None = None, sep: str = "  ") -> list[str]:
    """Lines of a fixed-width text table: each column as wide as its widest cell.

    Parameters
    ----------
    headers:
        Column titles.
    rows:
        Cells as text, one list per row (as many cells as headers).
    align:
        One character per column, ``<`` left or ``>`` right (default: first left, the rest right).
    sep:
        Text between columns.
    """
    n = len(headers)
    align = align or "<" + ">" * (n - 1)
    if len(align) != n or any(len(r) != n for r in rows):
        raise ValueError("format_table: every row and the alignment need one entry per column")
    widths = [max(len(str(c)) for c in col) for col in zip(headers, *rows)]
    return [sep.join(f"{c!s:{a}{w}}" for c, a, w in zip(r, align, widths)) for r in [headers, *rows]]


def _quantiles_ms(err_s: np.ndarray) -> tuple[float, float, float, float]:
    if err_s.size == 0:
        return (float("nan"),) * 4
    a = np.abs(err_s)
    p50, p99 = np.percentile(a, [50, 99])
    return 1e3 * float(p50), 1e3 * float(p99), 1e3 * float(a.max()), 1e3 * float(err_s.min())


class LiveScheduler:
    """Paces streams on a monotonic clock.

    Parameters
    ----------
    streams:
        What to play.
    speedup:
        Plant seconds per wall second (1 = real time); ``inf`` plays as fast as the transports take it.
    start_s, end_s:
        Plant-time slice to play (default: everything).
    batch_window_s:
        Items of one stream due within this much wall time go out in one delivery.
    spin_s:
        Busy-wait this long before a deadline instead of sleeping (sleep overshoots by ~0.1 ms).
    switch_interval_s:
        Python's thread switch interval while playing (``sys.setswitchinterval``; default 5 ms would let
        a server thread holding the GIL delay a deadline by up to that much); restored afterwards.
    """

    def __init__(self, streams: Sequence[Stream], *, speedup: float = 1.0, start_s: float | None = None,
                 end_s: float | None = None, batch_window_s: float = 0.00025, spin_s: float = 0.0015,
                 switch_interval_s: float | None = 0.0002) -> None:
        if not speedup > 0:
            raise ConfigError(f"speed-up must be > 0, got {speedup}")
        if batch_window_s <= 0:
            raise ConfigError(f"batch window must be > 0 s, got {batch_window_s}")
        self.streams = list(streams)
        if len({s.name for s in self.streams}) != len(self.streams):
            raise ConfigError("stream names must be unique")
        self.speedup = float(speedup)
        self.batch_window_s = float(batch_window_s)
        self.spin_s = float(spin_s)
        self.switch_interval_s = switch_interval_s
        self._stop = threading.Event()
        self.interrupted = False
        #: Unix time of plant time ``start_s`` while :meth:`run` plays (NaN before)
        self.epoch_unix = float("nan")
        firsts = [s.times[0] for s in self.streams if len(s.times)]
        lasts = [s.times[-1] for s in self.streams if len(s.times)]
        self.start_s = float(start_s) if start_s is not None else (float(min(firsts)) if firsts else 0.0)
        self.end_s = float(end_s) if end_s is not None else (float(max(lasts)) if lasts else 0.0)
        self._plan()

    # ------------------------------------------------------------------ planning
    def _plan(self) -> None:
        """Group items into deliveries: (deadline, stream, i0, i1), in deadline order."""
        ts, sid, idx = [], [], []
        self._ranges: list[tuple[int, int]] = []
        for k, s in enumerate(self.streams):
            lo = int(np.searchsorted(s.times, self.start_s, side="left"))
            hi = int(np.searchsorted(s.times, self.end_s, side="right"))
            self._ranges.append((lo, hi))
            ts.append(s.times[lo:hi])
            sid.append(np.full(hi - lo, k, dtype=np.int64))
            idx.append(np.arange(lo, hi, dtype=np.int64))
        t = np.concatenate(ts) if ts else np.zeros(0)
        sid_a = np.concatenate(sid) if sid else np.zeros(0, dtype=np.int64)
        idx_a = np.concatenate(idx) if idx else np.zeros(0, dtype=np.int64)
        # wall offsets are computed when run() knows the speed-up; with inf they are all zero
        self._event_t, self._event_sid, self._event_idx = t, sid_a, idx_a
        offset = (t - self.start_s) / self.speedup if np.isfinite(self.speedup) else np.zeros_like(t)
        bucket = np.floor(offset / self.batch_window_s).astype(np.int64)
        if not np.isfinite(self.speedup):
            bucket = idx_a // 256  # as fast as possible: deliveries of up to 256 items per stream
        key = bucket * max(1, len(self.streams)) + sid_a
        order = np.lexsort((offset, key))
        k_sorted = key[order]
        starts = np.flatnonzero(np.r_[True, k_sorted[1:] != k_sorted[:-1]]) if len(order) else np.zeros(0, int)
        ends = np.r_[starts[1:], len(order)] if len(order) else np.zeros(0, int)
        g_deadline = offset[order[starts]] if len(order) else np.zeros(0)
        g_sid = sid_a[order[starts]] if len(order) else np.zeros(0, dtype=np.int64)
        g_i0 = idx_a[order[starts]] if len(order) else np.zeros(0, dtype=np.int64)
        g_i1 = idx_a[order[ends - 1]] + 1 if len(order) else np.zeros(0, dtype=np.int64)
        gorder = np.argsort(g_deadline, kind="stable")
        self._g_deadline = g_deadline[gorder]
        self._g_sid = g_sid[gorder]
        self._g_i0 = g_i0[gorder]
        self._g_i1 = g_i1[gorder]
        # per event: its delivery group (for the pacing error) and its own deadline
        group_of_sorted = np.repeat(np.arange(len(starts)), ends - starts) if len(order) else np.zeros(0, int)
        inv = np.empty_like(gorder)
        inv[gorder] = np.arange(len(gorder))
        self._event_group = np.empty(len(order), dtype=np.int64)
        self._event_group[order] = inv[group_of_sorted] if len(order) else group_of_sorted
        self._event_offset = offset

    def to_unix(self, t_plant: np.ndarray) -> np.ndarray:
        """Unix times at which plant times ``t_plant`` are due in the current run."""
        if not np.isfinite(self.speedup):
            return np.full(np.shape(t_plant), time.time())
        return self.epoch_unix + (np.asarray(t_plant, dtype=np.float64) - self.start_s) / self.speedup

    @property
    def n_deliveries(self) -> int:
        """Number of delivery calls the plan makes."""
        return len(self._g_deadline)

    def stop(self) -> None:
        """Ask a running :meth:`run` to return after the current delivery."""
        self._stop.set()

    # ------------------------------------------------------------------ running
    def run(self, progress: Callable[[float], None] | None = None, progress_every_s: float = 1.0) -> PacingReport:
        """Play the plan; return the pacing report (also after :meth:`stop` or Ctrl-C).

        Parameters
        ----------
        progress:
            Called with the plant time about every ``progress_every_s`` wall seconds.
        """
        n = len(self._g_deadline)
        done_at = np.full(n, np.nan)
        sent = np.zeros(n, dtype=np.int64)
        deadlines = self._g_deadline.tolist()
        sids = self._g_sid.tolist()
        i0s = self._g_i0.tolist()
        i1s = self._g_i1.tolist()
        delivers = [s.deliver for s in self.streams]
        names = [s.name for s in self.streams]
        clock = time.perf_counter
        spin = self.spin_s
        sleep = time.sleep
        completed = False
        wall0 = clock()
        self.epoch_unix = time.time() + (wall0 - clock())
        next_progress = wall0 + progress_every_s
        self.interrupted = False
        previous_switch = sys.getswitchinterval()
        if self.switch_interval_s:
            sys.setswitchinterval(self.switch_interval_s)
        try:
            for g in range(n):
                if self._stop.is_set():
                    break
                target = wall0 + deadlines[g]
                now = clock()
                if target - now > spin:
                    sleep(target - now - spin)
                    now = clock()
                while now < target:
                    sleep(0)  # yield the GIL to the servers' threads while spinning
                    now = clock()
                k = sids[g]
                try:
                    sent[g] = delivers[k](i0s[g], i1s[g])
                except Exception as exc:  # a failing delivery never stops the run
                    log.error("delivery on %s failed: %s", names[k], exc)
                    sent[g] = 0
                done_at[g] = clock() - wall0
                if progress is not None and done_at[g] + wall0 >= next_progress:
                    next_progress += progress_every_s
                    progress(self.start_s + deadlines[g] * (self.speedup if np.isfinite(self.speedup) else 0.0))
            else:
                completed = True
        except KeyboardInterrupt:
            self.interrupted = True  # Ctrl-C: report what was played
        finally:
            sys.setswitchinterval(previous_switch)
        wall = clock() - wall0
        if n == 0:
            completed = True
        return self._report(done_at, sent, wall, completed)

    def _report(self, done_at: np.ndarray, sent: np.ndarray, wall_s: float, completed: bool) -> PacingReport:
        played = np.isfinite(done_at)
        err_all = done_at[self._event_group] - self._event_offset
        ev_played = played[self._event_group]
        plant_end = self.end_s
        if not completed:
            last_t = self._event_t[ev_played]
            plant_end = float(last_t.max()) if last_t.size else self.start_s
        rep = PacingReport(speedup=self.speedup, plant_start_s=self.start_s, plant_end_s=plant_end, wall_s=wall_s,
                           completed=completed)
        span = plant_end - self.start_s
        errs = []
        for k, s in enumerate(self.streams):
            ev = (self._event_sid == k) & ev_played
            gk = (self._g_sid == k) & played
            items = int(np.count_nonzero(self._event_sid == k))
            n_sent = int(sent[gk].sum())
            n_played = int(np.count_nonzero(ev))
            e = err_all[ev] if np.isfinite(self.speedup) else np.zeros(0)
            errs.append(e)
            p50, p99, pmax, pmin = _quantiles_ms(e)
            load = None
            if s.frames is not None:
                lo, hi = self._ranges[k]
                fr = s.frames[lo:hi]
                fr = fr[fr["timestamp"] <= plant_end] if not completed else fr
                load = bus_load_fraction(fr, s.bitrate, span)
            rep.streams[s.name] = StreamStats(
                name=s.name, kind=s.kind, items=items, sent=n_sent, lost=max(0, n_played - n_sent),
                deliveries=int(np.count_nonzero(gk)), pacing_p50_ms=p50, pacing_p99_ms=p99, pacing_max_ms=pmax,
                pacing_min_ms=pmin, rate_per_s=n_sent / wall_s if wall_s > 0 else float("nan"), bus_load=load)
        allerr = np.concatenate(errs) if errs else np.zeros(0)
        rep.pacing_p50_ms, rep.pacing_p99_ms, rep.pacing_max_ms, _ = _quantiles_ms(allerr)
        return rep
