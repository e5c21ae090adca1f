"""The segment table: which test of the campaign ran when.

Shared by the Trace (emulator output) and the Recording (acquisition output). Identification may use
it when present, but never requires it.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.errors import DataError

__all__ = ["Segment", "SegmentIndex", "inside_any", "load_segments", "save_segments", "segments_from_json",
           "segments_to_json", "touched"]


@dataclass(frozen=True)
class Segment:
    """One test of a campaign.

    Attributes
    ----------
    start_s, end_s:
        Start and end time on the plant clock, seconds.
    kind:
        Test kind: ``ramp_up``, ``constant_drive``, ``acceleration``, ``deceleration``,
        ``neutral_braking``, ``cycle``, ``coastdown`` (or a user's own label for real logs).
    name:
        Unique name within the campaign (``ramp_up_g5_85kmh``).
    settings:
        The test's own settings (gear, speed, pedal steps, hybrid mode, ...), JSON-serialisable.
    """

    start_s: float
    end_s: float
    kind: str
    name: str
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        """Length of the segment in seconds."""
        return self.end_s - self.start_s

    def contains(self, t_s: Any) -> Any:
        """Return whether time(s) ``t_s`` fall inside ``[start_s, end_s)``."""
        return (t_s >= self.start_s) & (t_s < self.end_s)


def _bounds(segments: Sequence[Segment]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    starts = np.fromiter((s.start_s for s in segments), dtype=np.float64, count=len(segments))
    ends = np.fromiter((s.end_s for s in segments), dtype=np.float64, count=len(segments))
    return starts, ends, ~(np.isnan(starts) | np.isnan(ends))


def inside_any(segments: Sequence[Segment], t: Any) -> np.ndarray:
    """Whether each time of ``t`` falls inside any of ``segments``: ``mask |= s.contains(t)`` over the segments, the
    same booleans.

    On sorted float64 times each segment's samples are found by bisection (one pass over ``t`` and a bisection per
    segment, not a pass per segment: a campaign's hundreds of tests against its whole grid); other times (unsorted,
    NaN, another dtype) take the pass per segment.

    Parameters
    ----------
    segments:
        The segments (any order, may overlap).
    t:
        Times, seconds on the plant clock.

    Returns
    -------
    numpy.ndarray
        Boolean mask of ``t``'s shape.
    """
    t = np.asarray(t)
    mask = np.zeros(t.shape, dtype=bool)
    if not len(segments) or not t.size:
        return mask
    if t.ndim == 1 and t.dtype == np.float64 and bool(np.all(t[1:] >= t[:-1])):  # sorted, no NaN
        starts, ends, ok = _bounds(segments)
        a = np.searchsorted(t, starts, side="left")  # first time >= start
        b = np.searchsorted(t, ends, side="left")  # first time >= end: [a, b) is start <= t < end
        hit = ok & (b > a)
        for i, j in zip(a[hit].tolist(), b[hit].tolist(), strict=True):
            mask[i:j] = True
        return mask
    for s in segments:
        mask |= s.contains(t)
    return mask


def touched(segments: Sequence[Segment], t: Any) -> list[bool]:
    """Per segment, whether any time of ``t`` falls inside it: ``bool(np.any(s.contains(t)))``, the same answers,
    from one sort of ``t`` and a bisection per segment (float64 times; other dtypes take a pass per segment).

    Parameters
    ----------
    segments:
        The segments.
    t:
        Times, seconds on the plant clock (any order; NaN falls in no segment).

    Returns
    -------
    list of bool
        One per segment, in their order.
    """
    t = np.asarray(t)
    if not len(segments):
        return []
    if t.dtype != np.float64:
        return [bool(np.any(s.contains(t))) for s in segments]
    ts = t if t.ndim == 1 and bool(np.all(t[1:] >= t[:-1])) else np.sort(t[~np.isnan(t)], axis=None)
    starts, ends, ok = _bounds(segments)
    hit = ok & (np.searchsorted(ts, ends, side="left") > np.searchsorted(ts, starts, side="left"))
    return [bool(h) for h in hit]


class SegmentIndex:
    """Which segment a time falls in, by bisection: ``next((s.name for s in segments if s.start_s <= t < s.end_s),
    "")`` per time, the same names, without a pass over the table per time (a campaign's windows against its tests).

    In a table in start order (a campaign's, whose tests may overlap by a rounding: an end a ulp past the next
    start), the segments starting at or before ``t`` are those up to the last start <= ``t`` (a bisection of the
    starts), and the first of them ending after ``t`` is the first whose running maximum of ends passes ``t`` (a
    bisection of that running maximum): the first segment containing ``t``. A table out of start order or with a
    NaN bound is searched in its order.

    Parameters
    ----------
    segments:
        The segment table.
    """

    def __init__(self, segments: Sequence[Segment]) -> None:
        self.segments = list(segments)
        self._starts, ends, ok = _bounds(self.segments)
        s = self._starts
        self._sorted = bool(np.all(s[1:] >= s[:-1]) and ok.all())  # NaN fails both
        self._reach = np.maximum.accumulate(ends) if self._sorted else ends  # non-decreasing: bisectable

    def names_at(self, times: Any) -> list[str]:
        """The name of the first segment containing each time, ``""`` where none does.

        Parameters
        ----------
        times:
            Times, seconds on the plant clock (1-D).

        Returns
        -------
        list of str
            One name per time.
        """
        tm = np.asarray(times, dtype=np.float64).reshape(-1)
        if not self.segments:
            return [""] * tm.size
        if not self._sorted:
            return [next((s.name for s in self.segments if s.start_s <= t < s.end_s), "") for t in tm]
        k = np.searchsorted(self._starts, tm, side="right") - 1  # the last segment starting at or before t
        j = np.searchsorted(self._reach, tm, side="right")  # the first whose end (or an earlier one's) is after t
        hit = j <= k  # NaN t: j is the table's length
        return [self.segments[i].name if h else "" for i, h in zip(j.tolist(), hit.tolist(), strict=True)]


def segments_to_json(segments: list[Segment]) -> str:
    """Serialise a segment table to JSON text."""
    return json.dumps([asdict(s) for s in segments], indent=1)


def segments_from_json(text: str, source: str = "<segments>") -> list[Segment]:
    """Parse a segment table from JSON text.

    Raises
    ------
    DataError
        If the text is not a list of segment objects.
    """
    try:
        rows = json.loads(text)
        return [
            Segment(
                start_s=float(r["start_s"]),
                end_s=float(r["end_s"]),
                kind=str(r["kind"]),
                name=str(r["name"]),
                settings=dict(r.get("settings", {})),
            )
            for r in rows
        ]
    except (ValueError, KeyError, TypeError) as exc:
        raise DataError(f"{source}: not a valid segment table ({exc})") from exc


def save_segments(segments: list[Segment], path: str | Path) -> Path:
    """Write the segment table as JSON to ``path`` and return the path."""
    path = Path(path)
    path.write_text(segments_to_json(segments), encoding="utf-8")
    return path


def load_segments(path: str | Path) -> list[Segment]:
    """Read a segment table written by :func:`save_segments`."""
    path = Path(path)
    return segments_from_json(path.read_text(encoding="utf-8"), source=str(path))
