"""The streamed plant and chain of ``validate`` with the chain's whole producer in a forked child.

The child makes each test (:func:`~benchtwin.emulator.iter_campaign`), spools it into the truth's files
(:class:`~benchtwin.trace.SpooledTrace`, its copy of the parent's spool) and encodes and delivers it
(:func:`benchtwin.chain.stream.run_chunked` with ``producer_mode="fork"``); the parent decodes the chunks and counts
what the child's spool counted, the plant's seconds and the progress bar from the notes sent with them.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from benchtwin.chain.stream import run_chunked, time_slices
from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.setup import SetupConfig
from benchtwin.config.vehicle import VehicleConfig
from benchtwin.emulator import iter_campaign
from benchtwin.emulator.protocols import lazy_protocol
from benchtwin.recording import Recording
from benchtwin.trace import SpooledTrace, Trace

__all__ = ["fork_if_alone", "measured_forked"]


def fork_if_alone(mode: str) -> str:
    """``mode``, but ``"thread"`` where ``mode`` is ``"fork"`` and this process already runs other Python threads.

    A child forked beside a running thread inherits every lock that thread holds (the logging module's, an I/O
    buffer's, a library's) in whatever state it is, and may wait on one for ever; so ``validate`` called from a program
    with threads of its own (a GUI, a server, a worker's thread pool) keeps its chain's producer in a thread of this
    process: the same results (the producer's items are the same wherever it runs), without the fork's speed. tqdm's
    monitor (left running by an earlier progress bar) is not counted: it waits on an event between its looks at the
    bars, and the child touches no bar.
    """
    here = threading.current_thread()
    others = [t for t in threading.enumerate() if t is not here and type(t).__name__ != "TMonitor"]
    return "thread" if mode == "fork" and others else mode


def measured_forked(vehicle: VehicleConfig, setup: SetupConfig, campaign: CampaignConfig,
                    out_dir: str | Path | None, cleanup: ExitStack, truth: SpooledTrace,
                    progress: bool) -> tuple[Recording, float]:
    """The campaign's Recording (read from the acquisition's chunk files, ``recording.mf4`` written into ``out_dir``
    when its pending save runs; closed with ``cleanup``) and the plant's seconds (making the tests and spooling them
    into ``truth``, in the child), the chain's producer in a forked child.

    Parameters
    ----------
    vehicle, setup, campaign:
        The scenario.
    out_dir:
        Where the raw logs and ``recording.mf4`` go (None: temporary chunk files only).
    cleanup:
        Closes the Recording (and the progress bar).
    truth:
        An empty spool: the child appends the truth into its files; this process counts it.
    progress:
        Show the plant's progress bar (made in this process after the fork).
    """
    notes: list[Any] = []
    plant_s = 0.0
    bar = None

    def pieces() -> Iterator[Trace]:  # in the child
        tests = iter_campaign(vehicle, campaign)
        for k in itertools.count():
            t = time.perf_counter()
            piece = next(tests, None)
            if piece is None:
                return
            truth.append(piece)
            notes.append((k, time.perf_counter() - t, truth.counted()))
            yield from time_slices([piece])  # the chain's memory bounded by a slice, not by the longest test

    def on_notes(taken: list[Any]) -> None:  # here, once per chunk
        nonlocal plant_s, bar
        for k, seconds, counted in taken:
            truth.take_counted(counted)
            plant_s += seconds
            if progress:
                from tqdm import tqdm

                steps = lazy_protocol(campaign).steps
                if bar is None:  # made after the fork: its monitor thread is this process's alone
                    bar = cleanup.enter_context(tqdm(total=round(sum(steps) / campaign.plant_rate_hz),
                                                     unit="s sim", desc=campaign.name, leave=False))
                bar.update(round(sum(steps[:k + 1]) / campaign.plant_rate_hz) - bar.n)

    # while the child makes the first chunk this process loads the plant's compiled code (inherited by the side
    # stages' child, which runs the plant again for the held-out prediction)
    rec = run_chunked(pieces(), setup, campaign.seed, out_dir, keep_chunks=True, defer_save=out_dir is not None,
                      producer_mode="fork", notes=notes, on_notes=on_notes,
                      while_forked=lambda: next(iter_campaign(vehicle, campaign), None))
    cleanup.callback(rec.close)
    return rec, plant_s
