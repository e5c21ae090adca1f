"""The segment table: which test of the campaign ran when.

Shared by the Trace (emulator output) and the Recording (acquisition output). Identification may use
it when present, but never requires it.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from benchtwin.errors import DataError

__all__ = ["Segment", "load_segments", "save_segments", "segments_from_json", "segments_to_json"]


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
