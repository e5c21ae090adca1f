"""The Modbus pressure module's clock judged from its poll log: late answers, clock steps and drift from the age of
each good answer (poll time minus the module's uptime registers), for :mod:`benchtwin.sensors.pressure_decode` (the
whole log) and :mod:`benchtwin.sensors.pressure_polls` (the log by blocks).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CLOCK_DRIFT_PPM", "CLOCK_STEP_S", "LATE_S", "RESTART_RUN", "AgeJudgement", "judge_age_medians",
           "poll_clock_evidence"]


#: an answer this much older than its neighbours' (poll time minus module uptime) came late (LATE)
LATE_S = 0.012
#: a persistent change of the answers' age by this much is a step of the module's clock
CLOCK_STEP_S = 0.01
#: a drift of the age this far (ppm) from the recording's own over a minute is a clock drifting
CLOCK_DRIFT_PPM = 40.0
#: a run of this many timed-out polls in a row is the server down (single timeouts are the network)
RESTART_RUN = 3


def _block_medians(t: np.ndarray, x: np.ndarray, block_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block index of each sample, and per non-empty block its centre time and median."""
    k = np.floor((t - t[0]) / block_s).astype(np.int64)
    counts = np.bincount(k)
    order = np.lexsort((x, k))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    has = np.flatnonzero(counts)
    return k, t[0] + (has + 0.5) * block_s, x[order][starts[has] + counts[has] // 2]


def poll_clock_evidence(t: np.ndarray, up: np.ndarray, update_period_s: float, declared_ppm: float = 0.0,
                        block_s: float = 1.0
                        ) -> tuple[np.ndarray, list[tuple[float, float]], list[tuple[float, float]]]:
    """Late answers, clock steps and clock drift from the age of good answers (poll time ``t`` minus uptime ``up``).

    The age of an answer is its latency plus the time since the module's last register update: it moves in
    steps of one update period as the two clocks slide apart (a tick each time their drift adds up to one
    period). Per 1-s block: a persistent change of the median age over 5 blocks by more than
    :data:`CLOCK_STEP_S` is a clock step (a rise that falls back within a minute is a stretch of late
    answers instead); after removing steps, an answer more than :data:`LATE_S` older than the running
    median is late; the time between two one-period ticks gives the drift (one period per interval),
    and an interval whose drift differs from the ``declared_ppm`` of the setup by more than
    :data:`CLOCK_DRIFT_PPM` is a clock drifting.

    Returns
    -------
    late, steps, drifts
        Mask of late answers; ``(time, size)`` of each clock step; ``(start, end)`` of each drifting span.
    """
    age = t - up
    if t.size < 50:
        return np.zeros(t.size, bool), [], []
    k, tb, m = _block_medians(t, age, block_s)
    # the acquisition's own timing jitter (a busy logger, a live network): the thresholds never fall below a
    # multiple of it, so a loaded machine's scatter is not taken for a slow server or a clock step
    blk0 = np.searchsorted(np.flatnonzero(np.bincount(k)), k)
    dev = age - m[blk0]
    jitter = 1.4826 * float(np.median(np.abs(dev - np.median(dev))))
    judged = judge_age_medians(tb, m, jitter, update_period_s, declared_ppm, block_s)
    late = judged.late(t, age, blk0)
    return late, judged.steps, judged.drifts


@dataclass
class AgeJudgement:
    """What :func:`judge_age_medians` finds from the per-block medians of the answers' age."""

    #: ``(time, size)`` of each clock step
    steps: list[tuple[float, float]]
    #: ``(start, end)`` of each drifting span
    drifts: list[tuple[float, float]]
    #: an answer this much older than the running median is late
    late_s: float
    #: block centre times, and per block the steps' level and the running median after removing it (None: no
    #: block to take it from)
    tb: np.ndarray
    level: np.ndarray
    base_b: np.ndarray | None
    block_s: float

    def late(self, t: np.ndarray, age: np.ndarray, blk: np.ndarray) -> np.ndarray:
        """Mask of late answers among good answers at times ``t`` with ages ``age`` in blocks ``blk`` (the
        index of each answer's block among the non-empty ones); per answer: any part of the log gives the same."""
        if self.base_b is None:
            return np.zeros(t.size, bool)
        late = age - self.level[blk] - np.interp(t, self.tb, self.base_b) > self.late_s
        for ts, _ in self.steps:  # around a step the level is uncertain: those answers are flagged CLOCK instead
            late &= np.abs(t - ts) > 1.5 * self.block_s
        return late


def judge_age_medians(tb: np.ndarray, m: np.ndarray, jitter: float, update_period_s: float,
                      declared_ppm: float = 0.0, block_s: float = 1.0) -> AgeJudgement:
    """Clock steps, stretches of slow answers and clock drift from the per-block medians ``m`` (centre times ``tb``)
    of the answers' age, and the level a late answer is judged against (see :func:`poll_clock_evidence`).

    ``jitter``: the acquisition's own timing scatter (a scaled median absolute deviation of the answers' age about
    their block's median); the thresholds never fall below a multiple of it.
    """
    late_s = max(LATE_S, 8.0 * jitter)
    step_s = max(CLOCK_STEP_S, 4.0 * jitter)
    w = 5
    steps: list[tuple[float, float]] = []
    slow: list[tuple[float, float]] = []
    if m.size > 2 * w:
        from numpy.lib.stride_tricks import sliding_window_view

        fwd = np.median(sliding_window_view(m, w), axis=1)  # fwd[j] = median(m[j:j+w])
        c = np.zeros(m.size)
        c[w:m.size - w + 1] = fwd[w:] - fwd[:-w]
        cand = np.flatnonzero(np.abs(c) > step_s)
        groups = np.split(cand, np.flatnonzero(np.diff(cand) > 1) + 1) if cand.size else []
        found = []
        for g in groups:  # one change per group: the middle of its plateau (full size for w blocks around it)
            for sign in (1.0, -1.0):
                gs = g[np.sign(c[g]) == sign]
                if gs.size:
                    top = gs[np.abs(c[gs]) >= 0.8 * np.max(np.abs(c[gs]))]
                    i = int(top[top.size // 2])
                    found.append((float(tb[i] - 0.5 * block_s), float(c[i])))
        found.sort()
        used = set()
        for a, (ta, ca) in enumerate(found):  # a rise that falls back: a stretch of slow answers, not a clock
            if a in used or ca <= 0:
                continue
            for b in range(a + 1, len(found)):
                tb_, cb = found[b]
                if b not in used and cb < 0 and tb_ - ta < 60.0 and abs(ca + cb) < 0.5 * ca:
                    used |= {a, b}
                    slow.append((ta, tb_))
                    break
        steps = [s for j, s in enumerate(found) if j not in used]
    level = np.zeros(tb.size)
    for ts, size in steps:
        level += np.where(tb >= ts, size, 0.0)
    mc = m - level
    in_slow = np.zeros(tb.size, bool)
    for a, b in slow:
        in_slow |= (tb >= a - block_s) & (tb <= b + block_s)
    ref = np.flatnonzero(~in_slow)
    base_b = None
    if ref.size:
        from scipy.ndimage import median_filter

        base_b = np.interp(tb, tb[ref], median_filter(mc[ref], size=21, mode="nearest"))
    # drift: one-period ticks of the age, away from steps and slow answers
    quiet = ~in_slow
    for ts, _ in steps:
        quiet &= np.abs(tb - ts) > w * block_s
    d = np.diff(mc)
    tick = quiet[1:] & quiet[:-1] & (np.abs(np.abs(d) - update_period_s) < 0.4 * update_period_s)
    tt, sign = tb[1:][tick] - 0.5 * block_s, np.sign(d[tick])
    drifts: list[tuple[float, float]] = []
    for j in range(tt.size - 1):
        a, b = float(tt[j]), float(tt[j + 1])
        if not quiet[(tb >= a) & (tb <= b)].all():
            continue  # a step or slow answers in between: the interval says nothing of the rate
        ppm = -sign[j + 1] * update_period_s / (b - a) * 1e6  # the module ahead: its uptime gains, age falls
        if abs(ppm - declared_ppm) > CLOCK_DRIFT_PPM:
            if drifts and a <= drifts[-1][1]:
                drifts[-1] = (drifts[-1][0], b)
            else:
                drifts.append((a, b))
    return AgeJudgement(steps, drifts, late_s, tb, level, base_b, block_s)
