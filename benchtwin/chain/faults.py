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
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from benchtwin.recording import Channel, Flag, Recording
from benchtwin.sensors.base import Device
from benchtwin.wire.frames import TransportEvent
from benchtwin.wire.quality import stale_runs

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


def _each(rec: Recording, release: Callable[[str], None] | None) -> Iterator[tuple[str, Channel]]:
    """The channels of ``rec``, each released (``release(name)``) once the loop's body is done with it."""
    for name, ch in rec.channels.items():
        yield name, ch
        if release is not None:
            release(name)


def _channel_evidence(rec: Recording, devs: dict[str, Device], release: Callable[[str], None] | None = None
                      ) -> list[tuple[str, str, str, np.ndarray, np.ndarray]]:
    """Evidence judged from each decoded channel's flags, timing and values (see the module docstring).

    Works on the few flagged samples and long gaps only (a clean channel costs one ``diff``)."""
    out = []
    lost_bits = int(Flag.LOST_FRAME | Flag.OUT_OF_ORDER)
    for name, ch in _each(rec, release):
        dev = devs.get(ch.source)
        if dev is None or len(ch) < 10:
            continue
        t, f = ch.timestamps, ch.flags
        dt = np.diff(t)
        period = float(np.median(dt[:: max(1, dt.size // 100_000)]))
        # gaps: before sample i + 1 for each i in gap
        gap = np.flatnonzero(dt > max(GAP_MIN_PERIODS * period, GAP_MIN_S))
        gap = gap[(f[gap + 1] & int(Flag.TRANSPORT_DROP)) == 0]
        if gap.size:
            counters = bool(getattr(dev, "counters", False))
            jumped = (f[gap + 1] & lost_bits) != 0 if counters else np.zeros(gap.size, bool)
            for kind, g in (("frame_loss_burst", gap[jumped]), ("silent", gap[~jumped])):
                if g.size:
                    out.append((kind, ch.source, "", t[g], t[g + 1]))
            f[gap[~jumped] + 1] |= int(Flag.LOST_FRAME)  # nothing came for a while: not continuous
        idx = np.flatnonzero(f)
        if idx.size == 0:
            continue
        fi = f[idx]
        short = idx >= 1
        short[short] = ~np.isin(idx[short] - 1, gap) & ((fi[short] & int(Flag.TRANSPORT_DROP)) == 0)
        dti = np.where(idx >= 1, t[idx] - t[np.maximum(idx - 1, 0)], 0.0)
        # a gap after frames dropped as malformed is theirs (PROTOCOL_ERROR), not a loss
        loss = short & ((fi & int(Flag.LOST_FRAME)) != 0) & (dti > 1.5 * period)
        loss &= (fi & int(Flag.DUPLICATE | Flag.PROTOCOL_ERROR)) == 0
        reorder = short & ((fi & int(Flag.OUT_OF_ORDER)) != 0) & (dti < 1.5 * period)
        for kind, m in (("frame_loss", loss), ("reorder", reorder), ("duplicate", (fi & int(Flag.DUPLICATE)) != 0),
                        ("ivt_error", (fi & int(Flag.STATUS_ERROR)) != 0)):
            if m.any():
                times = t[idx[m]]
                out.append((kind, ch.source, "", times, times))
        sat = ((fi & int(Flag.SATURATED)) != 0) & ((fi & int(Flag.OUT_OF_RANGE | Flag.TIMEOUT)) == 0)  # not held
        if sat.any():
            si = idx[sat]
            cut = np.flatnonzero(np.diff(si) != 1) + 1
            a = si[np.concatenate([[0], cut])]
            b = si[np.concatenate([cut - 1, [si.size - 1]])]
            long_sat = t[b] - t[a] >= CLIP_MIN_S
            if long_sat.any():
                out.append(("clip", ch.source, name, t[a[long_sat]], t[b[long_sat]]))
    return out


def _stuck_evidence(rec: Recording, devs: list[Device], release: Callable[[str], None] | None = None
                    ) -> list[tuple[str, str, str, np.ndarray, np.ndarray]]:
    """Frozen outputs where the setup declares noise; the runs are flagged STALE."""
    out = []
    held = int(Flag.SATURATED | Flag.OUT_OF_RANGE | Flag.TIMEOUT | Flag.STATUS_ERROR | Flag.PROTOCOL_ERROR)
    for d in devs:
        truth = d.truth_channels()
        for role, (err, _link, _extra) in d.error_budget().items():
            if err is None or err.noise_std <= 0 or role not in rec or role not in truth:
                continue
            ch = rec[role]
            q = max(truth[role].resolution, err.quantisation_step)
            usable = ((ch.flags & held) == 0) & np.isfinite(ch.values)
            a, b = stale_runs(ch.values, usable, err.noise_std, q)
            if a.size:
                for i, j in zip(a, b):
                    ch.flags[i:j] |= int(Flag.STALE)
                out.append(("stuck", ch.source, role, ch.timestamps[a], ch.timestamps[b - 1]))
            if release is not None:
                release(role)
    return out


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


def detect_faults(rec: Recording, devs: list[Device], evidence: list[tuple[str, str, str, np.ndarray, np.ndarray]],
                  events: list[TransportEvent], release: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Every fault the acquisition can tell, as spans (see the module docstring); flags STALE and LOST_FRAME.

    ``release(name)`` is called when a channel has been judged (a chunked acquisition unmaps it: one channel is
    mapped at a time)."""
    by_name: dict[str, Device] = {}
    for d in devs:
        by_name[d.name] = d
        if d.poll_device is not None:
            by_name[d.poll_device] = d
    ev = list(evidence) + _channel_evidence(rec, by_name, release) + _stuck_evidence(rec, devs, release)
    spans_all = []
    rate: dict[str, float] = {}
    for _name, ch in _each(rec, release):
        if len(ch):
            spans_all.append((float(ch.timestamps[0]), float(ch.timestamps[-1])))
        if len(ch) > 1:
            rate[ch.source] = rate.get(ch.source, 0.0) + len(ch) / max(float(ch.timestamps[-1] - ch.timestamps[0]),
                                                                         1e-9)
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
