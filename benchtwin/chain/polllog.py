"""Poll logs of the polled devices (Modbus): ``.npz`` files written and read back, and a CSV export to read by eye.

Beside the bus logs of :mod:`benchtwin.chain.buslog`, which re-exports these functions.
"""

from __future__ import annotations

import csv
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from benchtwin.errors import DataError
from benchtwin.wire.frames import PollLog

__all__ = ["read_poll_log", "write_poll_csv", "write_poll_log"]


def write_poll_log(log: PollLog, path: str | Path) -> Path:
    """Save a poll log as ``.npz``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, device=np.array(log.device), unit_id=log.unit_id, function_code=log.function_code,
             first_register=log.first_register, times=log.times, values=log.values, status=log.status)
    return path


def read_poll_log(path: str | Path) -> PollLog:
    """Load a poll log written by :func:`write_poll_log`.

    Raises
    ------
    DataError
        If the file is missing or not a poll log.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            return PollLog(str(z["device"]), int(z["unit_id"]), int(z["function_code"]), int(z["first_register"]),
                           z["times"], z["values"], z["status"])
    except FileNotFoundError:
        raise DataError(f"{path}: no such poll log") from None
    except (KeyError, ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        why = "not an .npz archive" if "pickle" in str(exc) else (str(exc) or type(exc).__name__)
        raise DataError(f"{path}: not a poll log ({why})") from None


def write_poll_csv(log: PollLog | Any, path: str | Path) -> Path:
    """Human-readable CSV of a poll log (or a :class:`~benchtwin.chain.pollspool.PollSpool`, read by blocks): time,
    unit, function code, status, then one column per register."""
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "unit_id", "function_code", "status",
                    *[f"reg{log.first_register + k}" for k in range(log.count)]])
        for part in (log.blocks() if hasattr(log, "blocks") else [log]):  # a spooled log: block by block
            for k in range(len(part)):
                w.writerow([f"{part.times[k]:.6f}", part.unit_id, part.function_code, int(part.status[k]),
                            *part.values[k].tolist()])
    return path
