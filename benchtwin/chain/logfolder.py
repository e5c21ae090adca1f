"""The files of a raw-log folder beside the bus logs, and the rule that tells a bus log cut short.

Shared by the whole-run writer (:func:`benchtwin.chain.batch.write_logs`), the chunked chain
(:func:`benchtwin.chain.stream.run_chunked`) and the reader (:func:`benchtwin.chain.batch.read_logs`).
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Mapping
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.chain.polllog import write_poll_csv, write_poll_log
from benchtwin.chain.pollspool import PollSpool
from benchtwin.config.setup import SetupConfig
from benchtwin.segments import Segment, save_segments
from benchtwin.sensors import devices, write_bus_dbcs
from benchtwin.wire.frames import PollLog, TransportEvent

__all__ = ["EVENTS_KEY", "LOG_START_KEY", "TRUNCATION_TOLERANCE_S", "bus_channel", "damaged_from_spans",
           "write_side_files"]

#: a bus whose time base ends this much before the segment table or another source is flagged as cut short
TRUNCATION_TOLERANCE_S = 0.5

#: key of ``meta.json`` holding the logs' start time (time 0 of every log in the folder)
LOG_START_KEY = "log_start_utc"
#: key of ``meta.json`` holding the transport events of the run (time, source, kind, end, detail)
EVENTS_KEY = "transport_events_logged"



def bus_channel(setup: SetupConfig, bus: str) -> int:
    """The bus's channel number in its log (``CAN_DataFrame.BusChannel``): its place among the setup's buses."""
    return 1 + sorted(setup.buses).index(bus) if bus in setup.buses else 1


def write_side_files(out: Path, setup: SetupConfig, segments: list[Segment], meta: dict[str, Any],
                     events: list[TransportEvent], start: datetime, *,
                     polls: Mapping[str, PollLog | PollSpool] | None = None, poll_csv: bool = False) -> dict[str, Path]:
    """The files of a log folder beside the bus logs: the poll logs, the DBCs and EDS to decode the buses,
    ``setup.json``, ``segments.json`` and ``meta.json`` (``meta`` with the start time and the transport events).
    """
    paths: dict[str, Path] = {}
    for dev, plog in (polls or {}).items():
        if isinstance(plog, PollSpool):  # written block by block
            paths[f"{dev}.polls.npz"] = plog.write_npz(out / f"{dev}.polls.npz")
        else:
            paths[f"{dev}.polls.npz"] = write_poll_log(plog, out / f"{dev}.polls.npz")
        if poll_csv:
            paths[f"{dev}.polls.csv"] = write_poll_csv(plog, out / f"{dev}.polls.csv")
    for bus, p in write_bus_dbcs(setup, out).items():
        paths[f"{bus}.dbc"] = p
    for d in devices(setup):  # the object dictionary of every CANopen node, to decode its PDOs
        node = d.canopen_endpoint()
        if node is not None:
            paths[node.eds.name] = Path(shutil.copyfile(node.eds, out / node.eds.name))
    paths["setup.json"] = out / "setup.json"
    paths["setup.json"].write_text(setup.model_dump_json(indent=1), encoding="utf-8")
    paths["segments.json"] = save_segments(segments, out / "segments.json")
    paths["meta.json"] = out / "meta.json"
    rows = [[e.time_s, e.source, e.kind, e.end_s, e.detail] for e in events]
    paths["meta.json"].write_text(json.dumps({**meta, LOG_START_KEY: start.isoformat(), EVENTS_KEY: rows},
                                             indent=1, default=str), encoding="utf-8")
    return paths


def damaged_from_spans(buses: dict[str, tuple[float, float, int]], polled: list[tuple[float, float]],
                        seg: list[tuple[float, float]], file_damage: dict[str, tuple[str, str | None]],
                        tol_s: float = TRUNCATION_TOLERANCE_S) -> list[dict[str, Any]]:
    """The buses whose log is damaged or cut short, from each bus's first and last frame time and frame count
    (NaN, NaN, 0: no frame), the poll logs' and the segments' spans and what each file says of itself."""
    spans = {b: (a, z) for b, (a, z, n) in buses.items() if n}
    out = []
    for bus, (_a, _z, count) in sorted(buses.items()):
        file, reason = file_damage.get(bus, (bus, None))
        reasons = [reason] if reason else []
        refs = [("the segment table", a, b) for a, b in seg]
        refs += [(f"bus {o}", a, b) for o, (a, b) in spans.items() if o != bus]
        refs += [("the poll logs", a, b) for a, b in polled]
        first, last = spans.get(bus, (float("nan"), float("nan")))
        exp_start = min([a for _, a, _ in refs] + ([first] if np.isfinite(first) else []), default=first)
        exp_end = max([b for _, _, b in refs] + ([last] if np.isfinite(last) else []), default=last)
        if not count:
            reasons.append("no frame in the log")
        elif exp_end - last > tol_s:
            by = next(name for name, _, b in refs if b == exp_end)
            reasons.append(f"its frames end at {last:.3f} s, {exp_end - last:.3f} s before {by} ({exp_end:.3f} s)")
        if reasons:
            covered_end = last if np.isfinite(last) else exp_start
            out.append({"bus": bus, "file": file, "reason": "; ".join(reasons), "frames_read": count,
                        "covered_s": [first if np.isfinite(first) else exp_start, covered_end],
                        "expected_s": [exp_start, exp_end]})
    return out
