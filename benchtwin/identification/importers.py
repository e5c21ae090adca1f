"""Import real-car logs (CSV or MF4) into a :class:`~benchtwin.recording.Recording` through a signal map.

Identification runs unchanged on the result: every mapped column becomes a channel named by its
role, in the role's unit, with all-OK quality flags (NaN cells stay NaN and are skipped by
identification). Columns that are not mapped are left out.
"""

from __future__ import annotations

import contextlib
import csv
import io
import logging
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.errors import ConfigError, DataError, MissingChannelError
from benchtwin.identification.signal_map import SignalMap, convert_units, load_signal_map
from benchtwin.recording import Channel, Flag, Recording
from benchtwin.roles import ROLES, plausible_range

log = logging.getLogger(__name__)

__all__ = ["import_csv", "import_log", "import_mf4", "read_csv_table"]


def read_csv_table(path: str | Path, *, delimiter: str | None = None, comment: str = "#", header_row: int = 0,
                   datetime_columns: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """Read a delimited text table into column name -> float array.

    Parameters
    ----------
    path:
        The file.
    delimiter:
        Column separator; sniffed among comma, tab, semicolon and space when ``None``.
    comment:
        Lines starting with this (after leading blanks) are skipped.
    header_row:
        Index of the header line among the non-comment, non-blank lines; lines before it are skipped.
    datetime_columns:
        Columns that may hold ISO 8601 date-times (``2024-05-03 14:02:07.250``) instead of numbers; they
        are returned as seconds since their first value.

    Returns
    -------
    dict
        Column name -> values; cells that are not numbers become NaN, columns that hold no number at all
        are dropped.

    Raises
    ------
    DataError
        Missing file, no header or no data rows.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc.strerror})") from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not (comment and ln.lstrip().startswith(comment))]
    if len(lines) <= header_row + 1:
        raise DataError(f"{path}: no header and data rows after {header_row} skipped line(s)")
    lines = lines[header_row:]
    if delimiter is None:
        try:
            delimiter = csv.Sniffer().sniff("\n".join(lines[:20]), delimiters=",\t; ").delimiter
        except csv.Error:
            delimiter = ","
    out: dict[str, np.ndarray] = {}
    try:
        import pandas as pd  # installed with asammdf; its C parser is ~50x faster on long logs
    except ImportError:  # pragma: no cover - asammdf requires pandas
        pd = None
    if pd is not None:
        frame = pd.read_csv(io.StringIO("\n".join(lines)), sep=delimiter, skipinitialspace=True,
                            engine="c" if len(delimiter) == 1 else "python", low_memory=False)
        for name in frame.columns:
            key = str(name).strip()
            if not key or key.startswith("Unnamed:"):
                continue
            raw = frame[name]
            if key in datetime_columns and raw.dtype.kind not in "iufb":
                dt = _parse_datetimes([str(x) for x in raw])
                if dt is not None:
                    out[key] = dt
                    continue
            if raw.dtype.kind in "iuf":
                col = raw.to_numpy(dtype=float)
            else:  # text cells among numbers ("n/a", "---"): NaN
                col = pd.to_numeric(raw.astype(str).str.strip(), errors="coerce").to_numpy(dtype=float)
            if np.isfinite(col).any():
                out[key] = col
    else:
        rows = list(csv.reader(io.StringIO("\n".join(lines)), delimiter=delimiter, skipinitialspace=True))
        header = [h.strip() for h in rows[0]]
        data = rows[1:]
        for j, name in enumerate(header):
            if not name:
                continue
            if name in datetime_columns:
                dt = _parse_datetimes([row[j] if j < len(row) else "" for row in data])
                if dt is not None:
                    out[name] = dt
                    continue
            col = np.full(len(data), np.nan)
            for r, row in enumerate(data):
                if j < len(row):
                    with contextlib.suppress(ValueError):
                        col[r] = float(row[j])
            if np.isfinite(col).any():
                out[name] = col
    if not out:
        raise DataError(f"{path}: no numeric column found (delimiter {delimiter!r})")
    return out


def _parse_datetimes(cells: list[str]) -> np.ndarray | None:
    """ISO 8601 date-times -> seconds since the first one (NaN where a cell does not parse); None if none do."""
    vals = np.full(len(cells), np.nan)
    first = None
    for k, c in enumerate(cells):
        c = c.strip().replace("T", " ")
        if not c:
            continue
        try:
            d = np.datetime64(c.replace(" ", "T"), "us")
        except ValueError:
            continue
        if first is None:
            first = d
        vals[k] = (d - first) / np.timedelta64(1, "s")
    return vals if first is not None else None


def _to_recording(table_time: np.ndarray, columns: dict[str, tuple[np.ndarray, np.ndarray, str]], smap: SignalMap,
                  origin: str) -> Recording:
    rec = Recording(meta={"imported_from": origin, "source_format": smap.source.format or "",
                          "signal_map_roles": sorted(smap.channels)})
    for role, cm in smap.channels.items():
        if cm.column not in columns:
            avail = ", ".join(sorted(columns))
            raise MissingChannelError(f"{origin}: signal map channels.{role}.column = {cm.column!r} is not in the log "
                                      f"(columns: {avail})")
        t, values, file_unit = columns[cm.column]
        unit = cm.unit if cm.unit is not None else (file_unit or ROLES[role][0])
        conv = convert_units(values, unit, ROLES[role][0], key=f"channels.{role}.unit")
        conv = conv * cm.scale + cm.offset
        keep = np.isfinite(t)
        ts, vs = t[keep], np.asarray(conv, dtype=float)[keep]
        back = np.flatnonzero(np.diff(ts) < 0)
        if back.size:
            k = int(back[0])
            raise DataError(f"{origin}: time of {role} ({cm.column}) goes back from {ts[k]:.6g} s to {ts[k + 1]:.6g} s "
                            f"at sample {k + 1} ({back.size} such step(s)): a clock restart or logs joined together; "
                            "split the log at the restart or give a monotonic time column")
        lo, hi = plausible_range(role)
        bad = (vs < lo) | (vs > hi)
        flags = np.where(bad | ~np.isfinite(vs), int(Flag.OUT_OF_RANGE), 0).astype(np.uint16)
        if bad.any():
            rec.meta.setdefault("implausible_samples", {})[role] = int(bad.sum())
            log.warning("%s: %d sample(s) of %s outside %g..%g %s flagged OUT_OF_RANGE", origin, int(bad.sum()), role,
                        lo, hi, ROLES[role][0])
        rec.add(Channel(role, ROLES[role][0], ts, vs, flags, source=smap.source.source_name))
    return rec


def import_csv(path: str | Path, smap: SignalMap) -> Recording:
    """Import a CSV/TSV log into a Recording.

    The time column holds numbers in ``source.time_unit``, or ISO 8601 date-times (then the time is
    seconds since the first row).

    Parameters
    ----------
    path:
        The log file.
    smap:
        The signal map (columns, units, time column, delimiter).

    Raises
    ------
    DataError, MissingChannelError, ConfigError
        Unreadable file, a mapped column missing, or no time column.
    """
    src = smap.source
    tcol = src.time_column
    table = read_csv_table(path, delimiter=src.delimiter, comment=src.comment, header_row=src.header_row)
    is_datetime = False
    if tcol is not None and tcol not in table:
        # not numbers: perhaps date-times
        table = read_csv_table(path, delimiter=src.delimiter, comment=src.comment, header_row=src.header_row,
                               datetime_columns=(tcol,))
        is_datetime = tcol in table
    if tcol is None:
        cands = [c for c in table if c.lower().startswith("time")]
        if not cands:
            raise ConfigError(f"{path}: set source.time_column in the signal map (no column named time*)")
        tcol = cands[0]
    if tcol not in table:
        raise MissingChannelError(f"{path}: time column {tcol!r} not in the log (columns: {', '.join(table)})")
    t = table[tcol] if is_datetime else convert_units(table[tcol], src.time_unit, "s", key="source.time_unit")
    cols = {name: (t, vals, "") for name, vals in table.items()}
    return _to_recording(t, cols, smap, str(path))


def import_mf4(path: str | Path, smap: SignalMap, *, lazy: bool = False) -> Recording:
    """Import an MF4 log (asammdf) into a Recording; each mapped channel keeps its own time base.

    The unit of a mapped channel is taken from the file when the signal map gives none.

    Parameters
    ----------
    path:
        The MF4 file.
    smap:
        The signal map (``column`` = MF4 channel name).
    lazy:
        Read no values now: each role is a :class:`~benchtwin.recording.LazyChannel` read from the file
        (and converted) when first used, and dropped again by identification after each method, so a
        day-long log is never in memory whole (see :func:`_import_mf4_lazy`). Not with a
        ``source.time_column`` (the time then comes from another channel): read at once.

    Raises
    ------
    DataError, MissingChannelError, ConfigError
        Unreadable file, a mapped channel missing or not numeric, an unknown unit.
    """
    from benchtwin.recording import open_mdf

    path = Path(path)
    if lazy and not smap.source.time_column:
        rec = _import_mf4_lazy(path, smap)
        if rec is not None:
            return rec
    mdf = open_mdf(path)
    cols: dict[str, tuple[np.ndarray, np.ndarray, str]] = {}
    with mdf:
        for role, cm in smap.channels.items():
            try:
                sig = mdf.get(cm.column)
            except Exception:  # asammdf raises MdfException for an unknown name
                continue
            t = np.asarray(sig.timestamps, dtype=float)
            if smap.source.time_column:
                try:
                    tsig = mdf.get(smap.source.time_column)
                    t = np.interp(t, tsig.timestamps, np.asarray(tsig.samples, dtype=float))
                except Exception as exc:
                    raise MissingChannelError(f"{path}: time channel {smap.source.time_column!r}: {exc}") from None
            t = convert_units(t, smap.source.time_unit, "s", key="source.time_unit")
            try:
                vals = np.asarray(sig.samples, dtype=float)
            except (TypeError, ValueError):
                raise DataError(f"{path}: channel {cm.column!r} (for {role}) is not numeric") from None
            cols[cm.column] = (t, vals, str(sig.unit or ""))
    return _to_recording(np.array([]), cols, smap, str(path))


#: samples converted at a time by a lazily imported channel
_BLOCK = 1 << 20

#: channel dtypes kept as float32 in memory when imported lazily: the file holds no more precision than that
_NARROW = (np.float32, np.int8, np.uint8, np.int16, np.uint16)


def _import_mf4_lazy(path: Path, smap: SignalMap) -> Recording | None:
    """The lazy form of :func:`import_mf4` (None: a time base with non-finite times; import it at once).

    The checks that need no values run here: every mapped channel present and numeric, every unit
    convertible, every time base increasing. Each role's values are read, converted to the role's unit,
    scaled and checked against its plausible range when first used; samples outside it are flagged
    OUT_OF_RANGE then (and counted in ``meta["implausible_samples"]``).

    Precision: a channel the file stores as float32 or as an integer of at most 16 bits stays float32 in
    memory after conversion (half the memory of float64): its relative rounding (6e-8) is far below the
    resolution the file itself holds (float32: the same 6e-8; 16-bit integers: 1.5e-5 of full scale), so
    no information is lost. Times stay float64 (float32 steps 8 ms at 24 h: coarser than 100 Hz).
    """
    from benchtwin.mdf import ChannelFile
    from benchtwin.recording import LazyChannel

    src = ChannelFile(path)
    mdf = src.mdf()
    origin = str(path)
    rec = Recording(meta={"imported_from": origin, "source_format": smap.source.format or "",
                          "signal_map_roles": sorted(smap.channels), "read_on_demand": True})
    checked: set[int] = set()
    plans = []
    for role, cm in smap.channels.items():
        where = mdf.channels_db.get(cm.column)
        if not where:
            src.close()
            avail = ", ".join(sorted(n for n in mdf.channels_db if not n.startswith("$")))
            raise MissingChannelError(f"{origin}: signal map channels.{role}.column = {cm.column!r} is not in the log "
                                      f"(columns: {avail})")
        gi, ci = where[0]
        ch = mdf.groups[gi].channels[ci]
        if int(getattr(ch, "data_type", 0)) > 5 or getattr(ch, "component_addr", 0):
            src.close()
            raise DataError(f"{path}: channel {cm.column!r} (for {role}) is not numeric")
        conv = ch.conversion
        file_unit = str((getattr(conv, "unit", "") if conv is not None else "") or ch.unit or "")
        unit = cm.unit if cm.unit is not None else (file_unit or ROLES[role][0])
        convert_units(np.zeros(0), unit, ROLES[role][0], key=f"channels.{role}.unit")  # a bad unit: now
        if gi not in checked:  # one time base at a time: read, checked, let go
            checked.add(gi)
            t = convert_units(src.times(gi), smap.source.time_unit, "s", key="source.time_unit")
            if not np.isfinite(t).all():
                src.close()
                return None
            back = np.flatnonzero(np.diff(t) < 0)
            if back.size:
                k = int(back[0])
                src.close()
                raise DataError(f"{origin}: time of {role} ({cm.column}) goes back from {t[k]:.6g} s to "
                                f"{t[k + 1]:.6g} s at sample {k + 1} ({back.size} such step(s)): a clock restart or "
                                "logs joined together; split the log at the restart or give a monotonic time column")
            del t
        numeric = conv is not None and getattr(conv, "conversion_type", None) not in (7, 11)
        plans.append((role, cm, gi, ci, unit, numeric, int(mdf.groups[gi].channel_group.cycles_nr)))
    cache: dict[int, weakref.ref[np.ndarray]] = {}  # converted times, shared while a channel of the group is loaded
    last: list[np.ndarray] = []  # and the last one used, kept: channels are often read group by group

    def time_of(gi: int) -> np.ndarray:
        ref = cache.get(gi)
        t = ref() if ref is not None else None
        if t is None:
            t = convert_units(src.times(gi), smap.source.time_unit, "s", key="source.time_unit")
            cache[gi] = weakref.ref(t)
        last[:] = [t]
        return t

    def loader(role: str, cm: Any, gi: int, ci: int, unit: str, numeric: bool
               ) -> Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]]:
        def load() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            t = time_of(gi)
            raw = src.read(cm.column, gi, ci, numeric)
            vs = np.empty(raw.shape, np.float32 if raw.dtype in _NARROW else np.float64)
            for k in range(0, raw.size, _BLOCK):  # in float64 block by block: bounded temporaries
                part = convert_units(raw[k:k + _BLOCK], unit, ROLES[role][0], key=f"channels.{role}.unit")
                if cm.scale != 1.0:
                    part *= cm.scale
                if cm.offset != 0.0:
                    part += cm.offset
                vs[k:k + _BLOCK] = part
            del raw
            lo, hi = plausible_range(role)
            bad = ~((vs >= lo) & (vs <= hi))  # NaN too
            if bad.any():
                fl = np.where(bad, int(Flag.OUT_OF_RANGE), 0).astype(np.uint16)
                implausible = int(np.count_nonzero(bad & np.isfinite(vs)))
                if implausible and role not in rec.meta.get("implausible_samples", {}):
                    rec.meta.setdefault("implausible_samples", {})[role] = implausible
                    log.warning("%s: %d sample(s) of %s outside %g..%g %s flagged OUT_OF_RANGE", origin, implausible,
                                role, lo, hi, ROLES[role][0])
            else:  # all plausible: one shared zero, no flag array
                fl = np.broadcast_to(np.zeros(1, np.uint16), vs.shape)
            return t, vs, fl

        return load

    for role, cm, gi, ci, unit, numeric, n in plans:
        rec.add(LazyChannel(role, ROLES[role][0], smap.source.source_name, n,
                            loader(role, cm, gi, ci, unit, numeric)))
    rec.own(src)
    return rec


def import_log(path: str | Path, signal_map: SignalMap | str | Path, *, lazy: bool = False) -> Recording:
    """Import a CSV or MF4 log through a signal map (format from the map, else the file extension).

    Parameters
    ----------
    path:
        The log file.
    signal_map:
        A :class:`SignalMap` or the path of its TOML file.

    lazy:
        An MF4 log: read each channel when first used (:func:`import_mf4`); a CSV is read at once.

    Returns
    -------
    Recording
        One channel per mapped role, in the role's unit.
    """
    smap = signal_map if isinstance(signal_map, SignalMap) else load_signal_map(signal_map)
    fmt = smap.source.format or ("mf4" if Path(path).suffix.lower() in (".mf4", ".mdf", ".dat") else "csv")
    return import_mf4(path, smap, lazy=lazy) if fmt == "mf4" else import_csv(path, smap)
