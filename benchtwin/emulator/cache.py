"""A disk cache of campaign Traces, keyed by content.

The Trace depends on the vehicle, the campaign (with its seed) and the plant's code, never on the
bench: sweeping sensors, noise or gains re-runs only sensors -> chain -> identification on one cached
Trace. The key is a SHA-256 over the vehicle's and the campaign's canonical JSON
(``model_dump_json``), ``benchtwin.__version__`` and a hash of every source file of
:mod:`benchtwin.emulator`, so a changed plant or model never serves a stale Trace.

The cache lives in ``$BENCHTWIN_CACHE`` or ``~/.cache/benchtwin/traces``; each entry is a directory
``<key>/`` holding ``trace.npz`` (every channel, uncompressed: a cached Trace of the paper campaign loads
in a fraction of a second, where the MF4 of :meth:`~benchtwin.trace.Trace.save` takes seconds) with
``segments.json`` and ``meta.json``. An entry is written into a temporary directory first and renamed
into place, so concurrent processes that miss on the same key never see half an entry (the loser of the
rename race keeps the winner's copy).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from benchtwin import __version__
from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.errors import DataError
from benchtwin.segments import segments_from_json, segments_to_json
from benchtwin.trace import Trace

_TIME = "__time_s__"

__all__ = ["cache_dir", "cached_campaign", "code_version", "trace_key"]

_EMULATOR_DIR = Path(__file__).resolve().parent


def cache_dir(path: str | Path | None = None) -> Path:
    """The cache directory: ``path``, else ``$BENCHTWIN_CACHE``, else ``~/.cache/benchtwin/traces``."""
    if path is not None:
        return Path(path)
    env = os.environ.get("BENCHTWIN_CACHE")
    if env:
        return Path(env)
    return Path.home() / ".cache" / "benchtwin" / "traces"


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """``benchtwin.__version__`` plus a short hash of every source file of the emulator package."""
    h = hashlib.sha256()
    for p in sorted(_EMULATOR_DIR.rglob("*.py")):
        h.update(p.relative_to(_EMULATOR_DIR).as_posix().encode())
        h.update(p.read_bytes())
    return f"{__version__}+{h.hexdigest()[:16]}"


def trace_key(vehicle: VehicleConfig, campaign: CampaignConfig) -> str:
    """Content hash of (vehicle, campaign with its seed, code version): the name of a cache entry."""
    doc = {
        "code": code_version(),
        "vehicle": json.loads(vehicle.model_dump_json()),
        "campaign": json.loads(campaign.model_dump_json()),
    }
    return hashlib.sha256(json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()).hexdigest()[:32]


def cached_campaign(vehicle: VehicleConfig, campaign: CampaignConfig, *, directory: str | Path | None = None,
                    progress: bool = False) -> tuple[Trace, bool]:
    """The campaign's Trace from the cache, simulating and storing it on a miss.

    Parameters
    ----------
    vehicle, campaign:
        The scenario (the campaign's ``seed`` is part of the key).
    directory:
        Cache directory (default :func:`cache_dir`).
    progress:
        Show the plant's progress bar on a miss.

    Returns
    -------
    trace, hit
        The Trace, and whether it came from the cache.
    """
    from benchtwin.emulator import simulate_campaign

    root = cache_dir(directory)
    entry = root / trace_key(vehicle, campaign)
    if (entry / "trace.npz").exists():
        try:
            return _load(entry), True
        except (DataError, OSError, ValueError, KeyError):
            shutil.rmtree(entry, ignore_errors=True)  # a damaged entry: simulate again
    trace = simulate_campaign(vehicle, campaign, progress=progress)
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".tmp-", dir=root))
    try:
        _save(trace, tmp)
        with contextlib.suppress(OSError):  # another process stored the same key first: keep its entry
            tmp.rename(entry)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return trace, False


def _save(trace: Trace, directory: Path) -> None:
    np.savez(directory / "trace.npz", **{_TIME: trace.time_s}, **trace.channels)
    (directory / "segments.json").write_text(segments_to_json(trace.segments), encoding="utf-8")
    (directory / "meta.json").write_text(json.dumps(trace.meta, default=_jsonable), encoding="utf-8")


def _load(directory: Path) -> Trace:
    with np.load(directory / "trace.npz") as z:
        time_s = z[_TIME]
        channels = {k: z[k] for k in z.files if k != _TIME}
    segs = segments_from_json((directory / "segments.json").read_text(encoding="utf-8"), str(directory))
    meta = json.loads((directory / "meta.json").read_text(encoding="utf-8"))
    return Trace(time_s, channels, segs, meta)


def _jsonable(x: object) -> object:
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)
