"""A Recording's ``save`` put off: the acquisition's ``recording.mf4`` written when (and where) the caller chooses.

:meth:`Acquisition.finish <benchtwin.chain.acquisition.Acquisition.finish>` with ``defer_save`` returns the Recording
read from the chunk files at once and leaves the file to a :class:`DeferredSave` it owns: ``validate`` has the side
stages' forked child write it while that child waits for the parent's tolerances (its idle time, on the other core),
so the 1.4 s of compressing ``recording.mf4`` leave the run's critical path. The file is the one ``finish`` would
have written: the Recording saved is a copy taken at ``finish`` (its meta and segments deep-copied, its channels the
chunk files' own, read only), whatever the caller does to the Recording it was given.

A DeferredSave is written at most once in this process: :meth:`run` writes it (or re-raises the first failure);
:meth:`done_elsewhere` records that another process (the forked child) wrote it; closing the Recording runs it if
neither happened, before the chunk files go, so a caller that never asks still gets the file.
"""

from __future__ import annotations

import copy
import threading
from pathlib import Path
from typing import Any

from benchtwin.recording import Recording

__all__ = ["DeferredSave", "pending_save"]


class DeferredSave:
    """``rec.save(path)`` for later (a copy of ``rec``'s meta and segments taken now).

    Parameters
    ----------
    rec:
        The Recording to save (its lazy channels must stay readable until the save: the owner closes this before
        their files).
    path:
        Where ``recording.mf4`` goes.
    """

    def __init__(self, rec: Recording, path: str | Path) -> None:
        rec.meta = copy.deepcopy(rec.meta)
        rec.segments = copy.deepcopy(rec.segments)
        self._rec: Recording | None = rec
        self.path = Path(path)
        self._lock = threading.Lock()
        self._saved: Path | None = None
        self._error: BaseException | None = None

    @property
    def done(self) -> bool:
        """Whether the file was written (here or, per :meth:`done_elsewhere`, in another process)."""
        return self._saved is not None

    def run(self, workers: int = 2) -> Path:
        """Write the file (once; a later call returns the path, or re-raises the first call's exception), compressed on
        ``workers`` threads (the same bytes for any number)."""
        with self._lock:
            if self._saved is not None:
                return self._saved
            if self._error is not None:
                raise self._error
            assert self._rec is not None
            try:
                self._saved = self._rec.save(self.path, workers=workers)
            except BaseException as exc:
                self._error = exc
                raise
            finally:
                self._rec.drop()
                self._rec = None
            return self._saved

    def done_elsewhere(self, path: Any) -> None:
        """Record that another process wrote the file (``path``, as its :meth:`run` returned it)."""
        with self._lock:
            if self._saved is None and self._error is None:
                self._saved = Path(path)
                self._rec = None

    def close(self) -> None:
        """Write the file if nobody did (a closing Recording's last use of the chunk files); errors are raised."""
        if not self.done and self._error is None:
            self.run()


def pending_save(rec: Recording) -> DeferredSave | None:
    """The :class:`DeferredSave` ``rec`` owns (from ``Acquisition.finish(defer_save=True)``), else None."""
    for f in getattr(rec, "_files", ()):
        if isinstance(f, DeferredSave):
            return f
    return None
