"""Steady windows found segment piece by segment piece: memory bounded by one piece, not by the campaign.

:func:`~benchtwin.identification.steady.find_steady_windows` with segment kinds searches only the grid points inside
those segments. :func:`find_steady_windows_by_piece` gathers those points one piece of segments at a time (the
pieces of :func:`~benchtwin.identification._windows.segment_pieces`), on the very grid the whole search uses, finds
the windows in it and keeps only their means and standard deviations before the next piece. The windows are the
same; their statistics differ from the whole-grid ones at rounding level only (the sums start at the piece).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from benchtwin.identification._signals import Grid, source_shifts
from benchtwin.identification._sum_kernels import centred_sums
from benchtwin.identification._windows import piece_grids
from benchtwin.recording import Recording
from benchtwin.segments import SegmentIndex

__all__ = ["find_steady_windows_by_piece", "window_stats"]


def window_stats(grid: Grid, spans: list[tuple[int, int]]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per gathered channel, the means and standard deviations over each span ``[a, b)`` of the grid.

    From cumulative sums over the finite samples, shifted by the channel's median for the variance's accuracy; the
    whole search (:func:`~benchtwin.identification.steady.find_steady_windows`) and the piece-by-piece one share it.
    """
    a_idx = np.array([a for a, _ in spans], dtype=int)
    b_idx = np.array([b for _, b in spans], dtype=int)
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, x in grid.values.items():
        fin = np.isfinite(x)
        ref = float(np.nanmedian(x)) if fin.any() else 0.0  # shift for numerical accuracy of the variance
        if x.dtype == np.float64 and x.ndim == 1:  # one pass free of the GIL, the same numbers (_sum_kernels)
            c1, c2, _ci, cn = centred_sums(x, ref, False)
        else:
            xc = np.where(fin, np.where(fin, x, 0.0) - ref, 0.0)
            c1 = np.concatenate(([0.0], np.cumsum(xc)))
            c2 = np.concatenate(([0.0], np.cumsum(xc * xc)))
            cn = np.concatenate(([0], np.cumsum(fin)))
        cnt = cn[b_idx] - cn[a_idx]
        with np.errstate(invalid="ignore", divide="ignore"):
            m = (c1[b_idx] - c1[a_idx]) / cnt
            var = np.clip((c2[b_idx] - c2[a_idx]) / cnt - m * m, 0.0, None)
        out[name] = (np.where(cnt > 0, m + ref, np.nan), np.where(cnt > 0, np.sqrt(var), np.nan))
    return out


def find_steady_windows_by_piece(rec: Recording, channels: Sequence[str], state_names: Sequence[str],
                                 extra: Sequence[str], optional: Sequence[str], kinds: Sequence[str],
                                 rate_hz: float, window_s: float, min_duration_s: float,
                                 max_duration_s: float | None, trim_s: float, tols: Mapping[str, Any],
                                 detect: Callable[..., list[tuple[int, int]]], window: Callable[..., Any],
                                 windows: Callable[..., Any]) -> Any:
    """:func:`~benchtwin.identification.steady.find_steady_windows` over the segments of ``kinds``, piece by piece.

    ``tols`` are the channels' tolerances; ``detect``, ``window`` and ``windows`` are
    :func:`~benchtwin.identification.steady.detect_steady` and the classes ``SteadyWindow`` and ``SteadyWindows``
    (passed in: that module calls this one).

    Returns
    -------
    SteadyWindows or None
        None when the Recording has no segment of these kinds (search the whole recording instead). The windows'
        ``i0, i1`` index the whole grid; ``grid`` holds no samples (only which channels were gathered, the rate
        and the clock shifts): average derived quantities with
        :meth:`~benchtwin.identification.steady.SteadyWindows.raw_average`.
    """
    kept = rec.loaded()
    grids = piece_grids(rec, [*channels, *extra], rate_hz, kinds, optional=[*state_names, *optional],
                        what="steady-state detection")
    if grids is None:
        return None
    found: list[Any] = []
    n_excl = 0
    searched = 0
    required = [*channels, *extra]
    present = {n for n in [*state_names, *optional] if n in rec and len(rec[n]) and n not in required}
    names = dict.fromkeys([*required, *present])  # the channels the whole grid would hold
    shifts = source_shifts(rec)  # what the grids carry (none may come)
    dt = 1.0 / rate_hz
    index = SegmentIndex(rec.segments)
    for g in grids:
        t = g.t
        st = {s: g[s] for s in state_names if s in g}
        spans = detect(dt, {c: g[c] for c in channels}, tols, valid=~g.bad, states=st, window_s=window_s,
                       min_duration_s=min_duration_s, max_duration_s=max_duration_s, trim_s=trim_s)
        n_excl += int(g.flagged.sum())
        searched += t.size
        if spans:
            # the statistics as lists of floats once per piece, not an array item per window and channel
            stats = [(nm, m.tolist(), sd.tolist()) for nm, (m, sd) in window_stats(g, spans).items()]
            segnames = index.names_at([t[(a + b - 1) // 2] for a, b in spans])
            for k, (a, b) in enumerate(spans):
                means = {nm: m[k] for nm, m, _sd in stats if math.isfinite(m[k])}
                stds = {nm: sd[k] for nm, m, sd in stats if math.isfinite(m[k])}
                states_v = {s: float(g[s][a]) for s in st}
                off = g.first_index
                found.append(window(float(t[a]), float(t[b - 1] + dt), off + a, off + b, means, stds, states_v,
                                    segnames[k]))
        del g
    rec.drop(rec.loaded() - kept)  # a lazy Recording read whole here (no windowed reads): it goes again
    empty = np.zeros(0)
    grid = Grid(empty, {nm: empty for nm in names}, np.zeros(0, dtype=bool), np.zeros(0, dtype=bool), rate_hz,
                present, shifts)
    return windows(found, grid, n_excl, float(searched * dt), [], windowed=True)
