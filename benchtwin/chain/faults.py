"""Fault detection: what the acquisition saw go wrong, as fault spans (kind, device or bus, channel, time span).

The decoders flag samples (:class:`~benchtwin.recording.Flag`) and report device-specific evidence to the
sink (an IVT-S mux byte that does not match, a thermocouple input reading open, a Modbus server down, late
answers, the pressure module's clock stepping or drifting). :func:`detect_faults` adds what is judged from
the decoded channels and the wire alone, then merges every piece of evidence into spans:

* gaps: a stream silent for 10 periods (and 0.2 s) not explained by a transport drop is a ``silent``
  device when its counter continued (or it has none), a ``frame_loss_burst`` when the counter jumped;
  shorter counter or cycle gaps are ``frame_loss``; repeated counters or a second frame within a quarter
  cycle ``duplicate``; a counter going back without a gap ``reorder``;
* status bits (``ivt_error``), a wrong data length (``wrong_dlc``, counted per identifier while decoding),
  an output held at its rail for 0.5 s or more (``clip``: SATURATED without OUT_OF_RANGE, and not a value
  held over timed-out polls);
* ``stuck``: bit-identical readings in a row on a channel whose setup declares noise — with noise
  ``sigma`` and step ``q`` two readings agree with probability at most ``erf(q / 2 sigma)``, so a run of
  ``L`` identical readings with ``p**(L-1) < 1e-6 / N`` is not a steady hold but a frozen output (the
  run is flagged STALE). A channel without declared noise, or with noise far below its step, is not judged;
* transport events: a ``drop`` span is a ``transport_disconnect``, a ``truncated`` log a ``log_truncation``.

Random evidence the setup declares (a link's ``drop_prob``, ``duplicate_prob``, ``reorder_prob``) is not a
fault: such evidence makes a span only where its density in a 2-s window exceeds what the declared
probability gives with a chance below 1e-3 over the recording (Poisson). The result is
``Recording.meta["faults_detected"]``: a list of ``{kind, device | bus, channel, start_s, end_s, evidence}``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from benchtwin.chain.blocks import ChannelBlocks
from benchtwin.recording import Flag
from benchtwin.sensors.base import Device
from benchtwin.wire.frames import TransportEvent
from benchtwin.wire.quality import stale_length

__all__ = ["CLIP_MIN_S", "GAP_MIN_PERIODS", "GAP_MIN_S", "WINDOW_S", "detect_faults"]

#: a stream silent this many periods (and at least GAP_MIN_S) is a silent device or a burst loss
GAP_MIN_PERIODS = 10
GAP_MIN_S = 0.2
#: an output at its rail this long is clipped (shorter excursions are the signal beyond the range)
CLIP_MIN_S = 0.5
#: evidence closer than this is one fault; density window of random evidence
WINDOW_S = 2.0
#: kinds whose evidence the setup may declare as random link errors -> LinkErrors field
_DECLARED = {"frame_loss": "drop_prob", "duplicate": "duplicate_prob", "reorder": "reorder_prob"}


def _period(view: ChannelBlocks, name: str, n: int) -> float:
    """The median sample step of ``name`` over every ``max(1, (n - 1) // 100_000)``-th step, block by block
    (at most 200,000 steps held, whatever the length)."""
    step = max(1, (n - 1) // 100_000)
    picked = np.empty(len(range(0, n - 1, step)), np.float64)
    got = 0
    prev: np.ndarray = np.zeros(0, np.float64)
    for a, t, _v, _f in view.blocks(name, columns="t"):
        dt = np.diff(np.concatenate([prev, t]))  # steps a - len(prev) .. a + len(t) - 2
        some = dt[(prev.shape[0] - a) % step::step]
        picked[got:got + some.shape[0]] = some
        got += some.shape[0]
        prev = t[-1:].copy()
    return float(np.median(picked, overwrite_input=True))


def _period_of(t: np.ndarray) -> float:
    """:func:`_period` of a channel whose samples are all in ``t`` (one block: the same steps picked, the same
    median)."""
    step = max(1, (t.shape[0] - 1) // 100_000)
    return float(np.median(np.diff(t)[::step].copy(), overwrite_input=True))


def _channel_evidence(view: ChannelBlocks, devs: dict[str, Device]
                      ) -> list[tuple[str, str, str, np.ndarray, np.ndarray]]:
    """Evidence judged from each decoded channel's flags, timing and values (see the module docstring).

    Works on the few flagged samples and long gaps only (a clean channel costs one ``diff``), one block of a
    channel at a time: what spans a block edge (the sample before, a gap ending at the edge, a run of saturated
    samples) is carried to the next block."""
    out = []
    lost_bits = int(Flag.LOST_FRAME | Flag.OUT_OF_ORDER)
    kinds = ("frame_loss_burst", "silent", "frame_loss", "reorder", "duplicate", "ivt_error")
    for name, ch in view.rec.channels.items():
        dev = devs.get(ch.source)
        n = view.length(name)
        if dev is None or n < 10:
            continue
        # a channel in one block: its period from the block the loop reads (read once)
        one_block = n <= view.size
        period = math.nan if one_block else _period(view, name, n)
        thr = max(GAP_MIN_PERIODS * period, GAP_MIN_S)
        counters = bool(getattr(dev, "counters", False))
        got: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {k: [] for k in kinds}
        clip: list[tuple[float, float]] = []
        run: list[float] | None = None  # the open run of saturated samples: [first time, last time, last index]
        t_prev = math.nan
        for a, t, _v, f in view.blocks(name, write=True, columns="tf"):
            m = t.shape[0]
            if one_block:
                period = _period_of(t)
                thr = max(GAP_MIN_PERIODS * period, GAP_MIN_S)
            # gaps: before sample i of the block (i >= 1 globally), against the sample before it
            t_before = np.concatenate([[t_prev], t[:-1]]) if a > 0 else np.concatenate([[t[0]], t[:-1]])
            dt = t - t_before
            after = np.flatnonzero(dt > thr)
            if a == 0:
                after = after[after >= 1]
            after = after[(f[after] & int(Flag.TRANSPORT_DROP)) == 0]
            if after.size:
                jumped = (f[after] & lost_bits) != 0 if counters else np.zeros(after.size, bool)
                for kind, g in (("frame_loss_burst", after[jumped]), ("silent", after[~jumped])):
                    if g.size:
                        got[kind].append((t_before[g], t[g]))
                f[after[~jumped]] |= int(Flag.LOST_FRAME)  # nothing came for a while: not continuous
            t_prev = float(t[-1])
            idx = np.flatnonzero(f)
            if idx.size == 0:
                if run is not None:
                    clip.append((run[0], run[1]))
                    run = None
                continue
            fi = f[idx]
            gi = idx + a
            after_gap = np.zeros(m, bool)
            after_gap[after] = True
            short = gi >= 1
            short[short] = ~after_gap[idx[short]] & ((fi[short] & int(Flag.TRANSPORT_DROP)) == 0)
            dti = np.where(gi >= 1, t[idx] - t_before[idx], 0.0)
            # a gap after frames dropped as malformed is theirs (PROTOCOL_ERROR), not a loss
            loss = short & ((fi & int(Flag.LOST_FRAME)) != 0) & (dti > 1.5 * period)
            loss &= (fi & int(Flag.DUPLICATE | Flag.PROTOCOL_ERROR)) == 0
            reorder = short & ((fi & int(Flag.OUT_OF_ORDER)) != 0) & (dti < 1.5 * period)
            for kind, sel in (("frame_loss", loss), ("reorder", reorder),
                              ("duplicate", (fi & int(Flag.DUPLICATE)) != 0),
                              ("ivt_error", (fi & int(Flag.STATUS_ERROR)) != 0)):
                if sel.any():
                    times = t[idx[sel]]
                    got[kind].append((times, times))
            sat = ((fi & int(Flag.SATURATED)) != 0) & ((fi & int(Flag.OUT_OF_RANGE | Flag.TIMEOUT)) == 0)  # not held
            si = idx[sat]
            if run is not None and (si.size == 0 or si[0] + a != run[2] + 1):
                clip.append((run[0], run[1]))
                run = None
            if si.size:
                cut = np.flatnonzero(np.diff(si) != 1) + 1
                starts = si[np.concatenate([[0], cut])]
                ends = si[np.concatenate([cut - 1, [si.size - 1]])]
                for j, (i0, i1) in enumerate(zip(starts, ends)):
                    if j == 0 and run is not None:  # the run from the block before goes on
                        run[1], run[2] = float(t[i1]), float(i1 + a)
                    else:
                        if run is not None:
                            clip.append((run[0], run[1]))
                        run = [float(t[i0]), float(t[i1]), float(i1 + a)]
                if run is not None and run[2] != a + m - 1:  # ends inside the block
                    clip.append((run[0], run[1]))
                    run = None
        if run is not None:
            clip.append((run[0], run[1]))
        for kind in kinds:
            if got[kind]:
                out.append((kind, ch.source, "", np.concatenate([p[0] for p in got[kind]]),
                            np.concatenate([p[1] for p in got[kind]])))
        long_sat = [(x, y) for x, y in clip if y - x >= CLIP_MIN_S]
        if long_sat:
            out.append(("clip", ch.source, name, np.array([x for x, _ in long_sat]),
                        np.array([y for _, y in long_sat])))
    return out


def _stuck_evidence(view: ChannelBlocks, devs: list[Device]) -> list[tuple[str, str, str, np.ndarray, np.ndarray]]:
    """Frozen outputs where the setup declares noise; the runs are flagged STALE.

    Block by block (:func:`~benchtwin.wire.quality.stale_runs`'s runs, a run that spans a block edge carried to the
    next block), then the long runs flagged in a second pass."""
    out = []
    held = int(Flag.SATURATED | Flag.OUT_OF_RANGE | Flag.TIMEOUT | Flag.STATUS_ERROR | Flag.PROTOCOL_ERROR)
    for d in devs:
        truth = d.truth_channels()
        for role, (err, _link, _extra) in d.error_budget().items():
            if err is None or err.noise_std <= 0 or role not in view.rec or role not in truth:
                continue
            n = view.length(role)
            length = stale_length(n, err.noise_std, max(truth[role].resolution, err.quantisation_step))
            if length is None:
                continue
            starts: list[np.ndarray] = []
            stops: list[np.ndarray] = []
            open_at = -1  # first reading of the run of equal readings open at the block's end, or -1
            v_prev, u_prev = math.nan, False
            for a, _t, v, f in view.blocks(role, columns="vf"):
                usable = ((f & held) == 0) & np.isfinite(v)
                vv = np.concatenate([[v_prev], v]) if a > 0 else v
                uu = np.concatenate([[u_prev], usable]) if a > 0 else usable
                same = (vv[1:] == vv[:-1]) & uu[1:] & uu[:-1]  # pair k: readings first + k, first + k + 1
                first = a - 1 if a > 0 else 0
                v_prev, u_prev = float(v[-1]), bool(usable[-1])
                before = np.concatenate([[open_at >= 0], same[:-1]])
                s_at = np.flatnonzero(same & ~before) + first
                e_at = np.flatnonzero(~same & before) + first + 1  # readings up to this one (exclusive) were equal
                if open_at >= 0 and e_at.size:
                    s_at = np.concatenate([[open_at], s_at])
                    open_at = -1
                elif open_at >= 0:
                    continue
                if s_at.size > e_at.size:  # the last run goes on into the next block
                    open_at = int(s_at[-1])
                    s_at = s_at[:-1]
                keep = e_at - s_at >= length
                starts.append(s_at[keep])
                stops.append(e_at[keep])
            if open_at >= 0 and n - open_at >= length:
                starts.append(np.array([open_at]))
                stops.append(np.array([n]))
            ia = np.concatenate(starts).astype(np.int64) if starts else np.zeros(0, np.int64)
            ib = np.concatenate(stops).astype(np.int64) if stops else np.zeros(0, np.int64)
            if ia.size:
                ta, tb = _flag_stale(view, role, ia, ib)
                out.append(("stuck", view.rec.channels[role].source, role, ta, tb))
    return out


def _flag_stale(view: ChannelBlocks, name: str, ia: np.ndarray, ib: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flag readings ``ia[k]:ib[k]`` of ``name`` STALE; the times of each run's first and last reading."""
    ta, tb = np.zeros(ia.size), np.zeros(ia.size)
    for a, t, _v, f in view.blocks(name, write=True, columns="tf"):
        m = t.shape[0]
        k0, k1 = int(np.searchsorted(ib, a, side="right")), int(np.searchsorted(ia, a + m, side="left"))
        if k1 <= k0:
            continue
        lo, hi = np.maximum(ia[k0:k1], a) - a, np.minimum(ib[k0:k1], a + m) - a
        mark = np.zeros(m + 1, np.int64)
        np.add.at(mark, lo, 1)
        np.add.at(mark, hi, -1)
        f[np.cumsum(mark[:-1]) > 0] |= int(Flag.STALE)
        first = (ia[k0:k1] >= a) & (ia[k0:k1] < a + m)
        ta[k0:k1][first] = t[ia[k0:k1][first] - a]
        last = (ib[k0:k1] - 1 >= a) & (ib[k0:k1] - 1 < a + m)
        tb[k0:k1][last] = t[ib[k0:k1][last] - 1 - a]
    return ta, tb


def _threshold(kind: str, dev: Device | None, rate_hz: float, duration_s: float) -> int:
    """Events in a WINDOW_S window that make a fault, given the random rate the setup declares."""
    field = _DECLARED.get(kind)
    prob = float(getattr(dev.link, field, 0.0)) if (dev is not None and field) else 0.0
    if prob <= 0:
        return 1
    from scipy.stats import poisson

    lam = prob * rate_hz * WINDOW_S
    windows = max(duration_s / WINDOW_S, 1.0)
    k = 1
    while poisson.sf(k - 1, lam) * windows >= 1e-3:
        k += 1
    return k


def _spans(t0: np.ndarray, t1: np.ndarray, k: int) -> list[tuple[float, float, int]]:
    """Merge evidence into spans; with ``k > 1`` only where ``k`` pieces fall in one window."""
    order = np.argsort(t0, kind="stable")
    t0, t1 = t0[order], t1[order]
    if k > 1:
        hi = np.searchsorted(t0, t0 + WINDOW_S, side="right")
        dense = np.flatnonzero(hi - np.arange(t0.size) >= k)
        keep = np.zeros(t0.size, bool)
        for i in dense:
            keep[i:hi[i]] = True
        t0, t1 = t0[keep], t1[keep]
    out: list[tuple[float, float, int]] = []
    for a, b in zip(t0, t1):
        if out and a <= out[-1][1] + WINDOW_S:
            s, e, n = out[-1]
            out[-1] = (s, max(e, float(b)), n + 1)
        else:
            out.append((float(a), float(b), 1))
    return out


def detect_faults(view: ChannelBlocks, devs: list[Device],
                  evidence: list[tuple[str, str, str, np.ndarray, np.ndarray]],
                  events: list[TransportEvent]) -> list[dict[str, Any]]:
    """Every fault the acquisition can tell, as spans (see the module docstring); flags STALE and LOST_FRAME.

    ``view`` gives the Recording's channels a block at a time (one block of one channel is read at a time)."""
    by_name: dict[str, Device] = {}
    for d in devs:
        by_name[d.name] = d
        if d.poll_device is not None:
            by_name[d.poll_device] = d
    ev = list(evidence) + _channel_evidence(view, by_name) + _stuck_evidence(view, devs)
    spans_all = []
    rate: dict[str, float] = {}
    for name, ch in view.rec.channels.items():
        n = view.length(name)
        if n:
            first, last = view.sample(name, 0), view.sample(name, -1)
            spans_all.append((first, last))
        if n > 1:
            rate[ch.source] = rate.get(ch.source, 0.0) + n / max(last - first, 1e-9)
    duration = (max(s[1] for s in spans_all) - min(s[0] for s in spans_all)) if spans_all else 0.0
    grouped: dict[tuple[str, str, str], list[tuple[np.ndarray, np.ndarray]]] = {}
    for kind, source, channel, a, b in ev:
        grouped.setdefault((kind, source, channel), []).append((a, b))
    out: list[dict[str, Any]] = []
    for (kind, source, channel), parts in sorted(grouped.items()):
        a = np.concatenate([p[0] for p in parts])
        b = np.concatenate([p[1] for p in parts])
        if channel == "":  # one piece of evidence per time, whichever channel of the device showed it
            a, keep = np.unique(a, return_index=True)
            b = b[keep]
        k = _threshold(kind, by_name.get(source), rate.get(source, 0.0), duration)
        for s, e, n in _spans(a, b, k):
            out.append({"kind": kind, "device": source, "channel": channel or None, "start_s": s, "end_s": e,
                        "evidence": n})
    for e in events:
        kind = {"drop": "transport_disconnect", "truncated": "log_truncation"}.get(e.kind)
        if kind is not None:
            end = e.end_s if math.isfinite(e.end_s) else e.time_s
            out.append({"kind": kind, "bus": e.source, "channel": None, "start_s": float(e.time_s),
                        "end_s": float(end), "evidence": 1})
    out.sort(key=lambda d: (d["start_s"], d["kind"]))
    return out
