"""GUM type B: the setup's declared systematic errors propagated into every identified parameter.

A fit's standard error carries only the scatter of its points (type A). A sensor's gain error or offset,
the same over the whole recording, does not scatter: it moves every point alike and the fit follows it.
The acquisition writes what the setup declares for each role into ``Recording.meta
["declared_uncertainty"]`` (:func:`benchtwin.chain.acquisition.declared_uncertainty`):

=============  ==========================================  ====================================
declared       read as                                     standard uncertainty (JCGM 100 4.3.7)
=============  ==========================================  ====================================
``gain_frac``  relative gain error, rectangular +-a         ``a / sqrt(3)`` (relative)
``offset``     offset, rectangular +-a                      ``a / sqrt(3)``
``resolution`` step q of the wire or converter, +-q/2       ``q / sqrt(12)`` (JCGM 100 F.2.2.1)
=============  ==========================================  ====================================

For each method and each gain or offset of each role the method reads, the method is run again on
the Recording with that channel perturbed by one standard uncertainty (``x (1 + u_g)`` or ``x + u_o``);
the change of every parameter is its sensitivity times ``u``, i.e. its contribution (JCGM 100 5.1.3,
with the sensitivity by a finite difference, which also follows the fits' point selection, outlier
rejection and derived parameters). An error one declaration gives to several roles (``group``) moves
them together (correlation 1). A fit that splits its points by a discrete decision (the converter's mode split)
publishes it as ``data["split"]``: a re-run whose split differs from the nominal one crossed a discontinuity, and
its difference is a jump, not a sensitivity; the step is then taken the other way and smaller (-1, +-1/2, +-1/4 u)
until the split holds, the change divided by the step (a finite difference inside one split, stated in
``meta["type_b"]["split_held"]`` and in the fit's reasons).

The rounding to each role's step is not one offset: a steady point holds one rounding error, the next point
another, and a fit's intercept weighs them with signs. It is propagated by Monte Carlo draws of independent
rounding errors per level (:func:`dithered`, JCGM 101), the RMS change of the parameter being its contribution,
with as many degrees of freedom as draws. Contributions are combined in quadrature with the standard error
(:meth:`~benchtwin.identification._fit.ParameterEstimate.combine_type_b`), the coverage factor from the
Welch-Satterthwaite effective degrees of freedom.

A Recording without a declared budget (a real log) gets no type B term: its total interval is the
statistical one, and ``meta["type_b"]`` says so.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from benchtwin.identification._fit import IdentificationResult
from benchtwin.identification._level_errors import BAD_BITS, add_level_errors, block_level_errors
from benchtwin.identification._reuse import moved_by, reusing, sharing_outputs
from benchtwin.identification._windows import reads_by_block, share_time_index
from benchtwin.identification.type_b_share import TypeBShare, run_shared
from benchtwin.recording import Channel, Flag, LazyChannel, Recording

__all__ = ["Component", "components", "dithered", "perturbed", "propagate_type_b"]

#: meta key the acquisition writes the declared budget under
META_KEY = "declared_uncertainty"
#: Monte Carlo draws of the rounding errors (their estimate of u carries this many degrees of freedom, a relative
#: standard uncertainty of about 1 / sqrt(2 N): 29 % at 6, which the Welch-Satterthwaite coverage factor takes in;
#: more draws narrow the spread of the intervals' widths, not their coverage: benchmarks/RESULTS.md, branch mcres)
RESOLUTION_DRAWS = 6
#: width of the level intervals sharing one rounding error, in steps: a reading whose noise flickers it by
#: one step about a steady level keeps one error (its rounding is not dithered by that flicker)
BIN_STEPS = 2.0
#: seed of those draws: the same Recording gives the same report
RESOLUTION_SEED = 20260
#: samples read at a time by the rounding's pass over a channel read by blocks (its lowest and highest level)
ROUNDING_BLOCK = 1 << 16
#: key of a fit's discrete split of its points (``FitResult.data``): equal in a re-run that stays on its side
SPLIT_KEY = "split"
#: fractions of one standard uncertainty tried, in order, until a re-run keeps every split (the first: one u)
SPLIT_STEPS = (1.0, -1.0, 0.5, -0.5, 0.25, -0.25)


@dataclass(frozen=True)
class Component:
    """One type B component: the roles it moves together, its kind and its standard uncertainty.

    Attributes
    ----------
    source:
        Key of the parameters' budget: ``<role>.<kind>``, or ``<group>.<kind>`` for an error shared by
        several roles.
    roles:
        The channels moved together (several for a shared, fully correlated error).
    kind:
        ``gain`` (relative, the channel is scaled by ``1 + u``), ``offset`` (``+ u``) or ``resolution``
        (Monte Carlo, see :func:`dithered`).
    u:
        Standard uncertainty (gain, offset).
    steps:
        Resolution: the step of each role.
    """

    source: str
    roles: tuple[str, ...]
    kind: str
    u: float
    steps: tuple[float, ...] = ()


def components(recording: Recording, roles: Iterable[str]) -> list[Component]:
    """The type B components of ``roles`` that the Recording declares (see the module docstring).

    A gain and an offset are a component each. An error a group of roles shares (``group`` in the
    declaration) is one component moving every role of the group the Recording holds (correlation 1,
    JCGM 100 5.2). The resolutions of all roles are one Monte Carlo component (:func:`dithered`).

    Parameters
    ----------
    recording:
        The Recording; its ``meta["declared_uncertainty"]`` is read.
    roles:
        Roles of interest (those absent from the Recording are skipped).
    """
    table: Mapping[str, Mapping[str, Any]] = recording.meta.get(META_KEY) or {}
    out: dict[str, Component] = {}
    steps: dict[str, float] = {}
    for role in roles:
        d = table.get(role)
        if d is None or role not in recording:
            continue
        gain = float(d.get("gain_frac", 0.0) or 0.0)
        offset = float(d.get("offset", 0.0) or 0.0)
        step = float(d.get("resolution", 0.0) or 0.0)
        group = d.get("group")
        if group:
            members = tuple(r for r, e in table.items() if e.get("group") == group and r in recording)
            if gain > 0:
                out.setdefault(f"{group}.gain", Component(f"{group}.gain", members, "gain", gain / math.sqrt(3.0)))
            if offset > 0:
                out.setdefault(f"{group}.offset",
                               Component(f"{group}.offset", members, "offset", offset / math.sqrt(3.0)))
        else:
            if gain > 0:
                out[f"{role}.gain"] = Component(f"{role}.gain", (role,), "gain", gain / math.sqrt(3.0))
            if offset > 0:
                out[f"{role}.offset"] = Component(f"{role}.offset", (role,), "offset", offset / math.sqrt(3.0))
        if step > 0:
            steps[role] = step
    comps = list(out.values())
    if steps:
        comps.append(Component("resolution", tuple(steps), "resolution", 0.0, tuple(steps.values())))
    return comps


class _Rounding:
    """What every draw of :func:`dithered` over one role shares: its good samples and their scaled levels.

    The scaling ``(v - lo) / (BIN_STEPS q)`` does not depend on the draw, only the grid phase added to it does,
    so the draws of one component compute it once (the same floating-point operations as a draw on its own,
    hence the same errors). The largest level index of a draw is that of the largest reading (``floor`` of a
    monotone expression), so the number of errors drawn is known without a maximum over the indices.

    A lazy channel that reads blocks from its store (:func:`reads_by_block`, the chunk files ``validate --out``
    identifies from) is not held: one pass by blocks finds ``lo`` and the top level (a minimum and a maximum, the
    same numbers block by block), and each draw is a lazy channel that adds the draw's errors to every block it
    reads (:meth:`moved_lazily`): the same per-sample operations, so the same values, and a re-run that reads
    windows of it never holds it whole.
    """

    def __init__(self, ch: Any, q: float) -> None:
        self.q = q
        #: whether the draws move blocks as they are read (the channel is never held whole)
        self.by_block = reads_by_block(ch)
        if self.by_block:
            self._scan_blocks(ch)
            return
        v = ch.values
        # the good samples only: a flagged sample (clipped, lost, out of range) is excluded by every method, so
        # its value must not move the grid of the others' rounding errors
        fin = ch.good
        self.usable = bool(fin.any()) and q > 0
        if not self.usable:
            return
        all_good = bool(fin.all())
        #: the good samples' indices (none: every sample is good)
        self.positions = np.empty(0, dtype=np.int64) if all_good else np.flatnonzero(fin).astype(np.int64)
        vf = v if all_good else v[fin]
        self.lo = float(vf.min())
        self.scaled = (vf - self.lo) / (BIN_STEPS * q)
        self.top = float(self.scaled.max())

    def _scan_blocks(self, ch: Any) -> None:
        """``lo`` (lowest good reading) and ``top`` (highest scaled level) of a channel read by blocks."""
        lo, hi = math.inf, -math.inf
        for a in range(0, len(ch), ROUNDING_BLOCK):
            _ts, v, f = ch.block(a, a + ROUNDING_BLOCK)
            vf = v[_good(v, f)]
            if vf.size:
                lo, hi = min(lo, float(vf.min())), max(hi, float(vf.max()))
        self.usable = math.isfinite(lo) and self.q > 0
        if self.usable:
            self.lo = lo
            # the maximum of (v - lo) / (2 q) over the samples is that of the largest v: floating-point subtraction
            # and division by a positive number are monotone, so this is the whole pass's maximum bit for bit
            self.top = float((np.float64(hi) - lo) / (BIN_STEPS * self.q))

    def _draw(self, rng: np.random.Generator) -> tuple[float, np.ndarray]:
        """One draw's grid phase and level errors (in this order from ``rng``)."""
        phase = rng.uniform(0.0, 1.0)
        n_levels = math.floor(self.top + phase) + 1
        return phase, rng.uniform(-0.5 * self.q, 0.5 * self.q, n_levels)

    def moved(self, ch: Any, rng: np.random.Generator) -> np.ndarray:
        """The channel's values with one draw of level-wise rounding errors added (see :func:`dithered`)."""
        phase, errors = self._draw(rng)
        return add_level_errors(ch.values, self.scaled, phase, errors, self.positions)

    def moved_lazily(self, ch: Any, rng: np.random.Generator) -> LazyChannel:
        """One draw as a lazy channel that adds the draw's errors to each block it reads (a channel read by blocks)."""
        phase, errors = self._draw(rng)
        scale = BIN_STEPS * self.q
        lo = self.lo

        def read(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            ts, v, f = ch.block(a, b)
            if v.dtype == np.float64:  # one pass (the same numbers); another dtype rounds (v - lo) in its own
                return ts, block_level_errors(v, f, BAD_BITS, lo, scale, phase, errors), f
            good = _good(v, f)
            if good.all():
                return ts, add_level_errors(v, (v - lo) / scale, phase, errors, np.empty(0, dtype=np.int64)), f
            positions = np.flatnonzero(good).astype(np.int64)
            return ts, add_level_errors(v, (v[good] - lo) / scale, phase, errors, positions), f

        out = LazyChannel(ch.name, ch.unit, ch.source, len(ch), lambda: read(0, len(ch)), ch.value_texts,
                          block_loader=read)
        share_time_index(out, ch)  # the same timestamps: the re-run finds spans without indexing them again
        return out


def _good(values: np.ndarray, flags: np.ndarray) -> np.ndarray:
    """:attr:`Channel.good` of a block: free of :meth:`Flag.bad` flags and finite."""
    return ((flags & int(Flag.bad())) == 0) & np.isfinite(values)


def dithered(recording: Recording, comp: Component, rng: np.random.Generator,
             shared: dict[str, _Rounding] | None = None) -> Recording:
    """One Monte Carlo draw of the rounding errors of the component's roles (GUM Supplement 1, JCGM 101).

    A reading rounded to a step ``q`` is off by an error uniform in ``+-q/2`` (JCGM 100 F.2.2.1) that is a
    function of the level: a steady point holds one error, a point at another level another. Each draw
    gives every interval of width ``BIN_STEPS q`` of the reading (on a grid of random phase) an independent
    error ``U(-q/2, q/2)`` and adds to each sample the error of its interval: a steady point moves as a
    whole (also when its noise flickers it by a step), points at other levels move independently, and a
    channel whose noise spreads it over many steps averages its errors out, as the rounding does.

    ``shared`` (role -> work shared by the draws, filled on first use) lets several draws of one component
    skip what they have in common; the draws are the same with or without it. A channel read by blocks from its
    store stays so: its draw is a lazy channel moving each block it reads (the same numbers, see :class:`_Rounding`).
    """
    channels = dict(recording.channels)
    for role, q in zip(comp.roles, comp.steps, strict=True):
        ch = recording.channels[role]
        r = shared.get(role) if shared is not None else None
        if r is None:
            r = _Rounding(ch, q)
            if shared is not None:
                shared[role] = r
        if not r.usable:
            continue
        channels[role] = r.moved_lazily(ch, rng) if r.by_block else ch.with_values(r.moved(ch, rng))
    return Recording(channels=channels, segments=recording.segments, meta=recording.meta,
                     start_time=recording.start_time)


def _moved(ch: Channel, comp: Component) -> Channel:
    """The channel with its values moved by one standard uncertainty of ``comp``: in memory, or, for a lazy channel
    whose store reads blocks, a lazy channel that moves what it reads (the same numbers: the move is per sample)."""
    def move(v: np.ndarray) -> np.ndarray:
        return v * (1.0 + comp.u) if comp.kind == "gain" else v + comp.u

    if not reads_by_block(ch):
        return ch.with_values(move(ch.values))

    def load() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ts, v, f = ch.block(0, len(ch))
        return ts, move(v), f

    def read(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ts, v, f = ch.block(a, b)
        return ts, move(v), f

    out = LazyChannel(ch.name, ch.unit, ch.source, len(ch), load, ch.value_texts, block_loader=read)
    share_time_index(out, ch)  # the same timestamps: the re-run finds spans without indexing them again
    return out


def perturbed(recording: Recording, comp: Component) -> Recording:
    """A shallow copy of the Recording with the component's channels moved by one standard uncertainty (a channel
    read by blocks from its store stays so: a method that reads windows of it never holds it whole)."""
    channels = dict(recording.channels)
    for role in comp.roles:
        channels[role] = _moved(recording.channels[role], comp)
    return Recording(channels=channels, segments=recording.segments, meta=recording.meta,
                     start_time=recording.start_time)


#: threads the re-runs share on a Recording held in memory (the machine's cores, at most 2: the fits' large
#: array operations release the GIL, their Python glue does not, so a third thread gains little)
WORKERS = max(1, min(2, os.cpu_count() or 1))

#: one unit of work: the method's fits (names), its nominal parameters, the component, the function that runs it,
#: the nominal splits of its fits (:func:`splits`)
_Task = tuple[list[str], dict[str, Any], Component, Callable[[Recording], IdentificationResult], dict[str, tuple]]
#: what one unit of work gives: per parameter the changes of its value, re-runs, failures, notes on held splits
_Done = tuple[dict[str, list[float]], int, list[str], list[str]]


def splits(fits: Mapping[str, Any], names: Iterable[str]) -> dict[str, tuple]:
    """The discrete splits (``data["split"]``) of the fits ``names`` that publish one, as tuples of numbers."""
    return {fk: tuple(float(x) for x in np.asarray(fits[fk].data[SPLIT_KEY], dtype=float).ravel())
            for fk in names if fk in fits and SPLIT_KEY in fits[fk].data}


def _changes(nominal: Mapping[str, Any], other: Mapping[str, Any], scale: float = 1.0) -> dict[str, float]:
    """Per parameter of ``nominal`` that ``other`` also has finite: the change of its value, divided by ``scale``."""
    out = {}
    for key, p in nominal.items():
        q = other.get(key)
        if q is not None and math.isfinite(q.value) and math.isfinite(p.value):
            out[key] = (q.value - p.value) / scale
    return out


def _propagate_one(recording: Recording, task: _Task, draws: int = RESOLUTION_DRAWS) -> _Done:
    """The re-runs of one method for one component: per parameter, the changes of its value (per standard
    uncertainty); re-runs; failures; notes on splits held (see the module docstring)."""
    fits, nominal, comp, run, split0 = task
    if comp.kind != "resolution":
        return _propagate_step(recording, task)
    rng = np.random.default_rng(RESOLUTION_SEED)
    shared: dict[str, _Rounding] = {}
    deltas: dict[str, list[float]] = {}
    failed: list[str] = []
    flipped = 0
    for _ in range(draws):
        rec = dithered(recording, comp, rng, shared)
        try:
            res = run(rec)
        except Exception as exc:  # a perturbed run that breaks leaves the draw out, said in meta
            failed.append(f"{fits[0]} / {comp.source}: {type(exc).__name__}: {exc}")
            continue
        flipped += splits(res.fits, fits) != split0
        for key, d in _changes(nominal, res.parameters()).items():
            deltas.setdefault(key, []).append(d)
    notes = [f"{fits[0]} / {comp.source}: {flipped} of {draws} draws changed a split (kept: a draw is a possible "
             "rounding, not a step)"] if flipped else []
    return deltas, draws, failed, notes


def _propagate_step(recording: Recording, task: _Task) -> _Done:
    """A gain or offset: the re-run at one standard uncertainty; if it changes a split (``data["split"]``), the
    re-runs at the further :data:`SPLIT_STEPS` until one keeps every split, its change divided by its step."""
    fits, nominal, comp, run, split0 = task
    first: dict[str, float] = {}
    first_split: dict[str, tuple] = {}
    for n, f in enumerate(SPLIT_STEPS, start=1):
        step = comp if f == 1.0 else replace(comp, u=comp.u * f)
        try:
            # the same base and step: the same moved channels (a method that another re-runs first is run once)
            with moved_by((id(recording), step.source, step.roles, step.kind, step.u)):
                res = run(perturbed(recording, step))
        except Exception as exc:  # a perturbed run that breaks: the last good difference (if any), said in meta
            fail = f"{fits[0]} / {comp.source}: {type(exc).__name__}: {exc}" + (f" (at {f:+g} u)" if n > 1 else "")
            note = [f"{fits[0]} / {comp.source}: a split changes at +1 u ({_diff(split0, first_split)}); the "
                    f"re-run at {f:+g} u broke: the difference at +1 u kept (a jump)"] if n > 1 else []
            return {k: [v] for k, v in first.items()}, n, [fail], note
        moved = _changes(nominal, res.parameters(), f)
        now = splits(res.fits, fits)
        if n == 1:
            first, first_split = moved, now
        if now == split0:
            note = [] if n == 1 else [
                f"{fits[0]} / {comp.source}: a split changes at +1 u ({_diff(split0, first_split)}); the sensitivity "
                f"is the difference at {f:+g} u divided by {f:+g}"]
            return {k: [v] for k, v in moved.items()}, n, [], note
    return {k: [v] for k, v in first.items()}, len(SPLIT_STEPS), [], [
        f"{fits[0]} / {comp.source}: a split changes at every step tried ({', '.join(f'{f:+g}' for f in SPLIT_STEPS)}"
        f" u; {_diff(split0, first_split)}): the difference at +1 u kept (a jump: not smooth in this error)"]


def _diff(a: Mapping[str, tuple], b: Mapping[str, tuple]) -> str:
    """The splits that differ, ``fit: nominal -> moved``."""
    def text(x: tuple) -> str:
        return ", ".join(f"{v:.4g}" for v in x)

    return "; ".join(f"{k}: {text(a.get(k, ()))} -> {text(b.get(k, ()))}"
                     for k in sorted(a.keys() | b.keys()) if a.get(k) != b.get(k))


def propagate_type_b(result: IdentificationResult, recording: Recording,
                     plan: Iterable[tuple[Iterable[str], Iterable[str], Callable[[Recording], IdentificationResult]]],
                     *, workers: int | None = None, draws: int | None = None,
                     share: TypeBShare | None = None) -> dict[str, Any]:
    """Add the type B budget to every parameter of ``result`` (in place).

    Parameters
    ----------
    result:
        The nominal identification result.
    recording:
        The Recording it came from.
    plan:
        Per method: the names of the fits it produced, the roles it reads, and a function that runs it
        (with whatever it depends on) on another Recording and returns its fits.
    workers:
        Threads that share the re-runs (default :data:`WORKERS`). Each re-run is independent of the others
        and the contributions are put together in the plan's order, so the budget is the same for any
        count. A lazy Recording (:meth:`Recording.open`) is worked through method by method (the method's
        re-runs on the threads), each method's channels dropped before the next's are read (its memory stays
        bounded by one method).
    draws:
        Monte Carlo draws of the rounding errors (default :data:`RESOLUTION_DRAWS`, at least 2): the resolution
        term's degrees of freedom; its relative standard uncertainty, about ``1 / sqrt(2 draws)``, is
        ``resolution_rel_u`` of the summary.
    share:
        Another worker that runs a share of the re-runs, from the tail of the list (e.g. a forked process,
        :mod:`~benchtwin.identification.type_b_share`); this side runs the head on ``share.threads`` threads (if
        set). Each unit's result depends on the unit only: the budget is the same.

    Returns
    -------
    dict
        Summary for ``result.meta["type_b"]``: components propagated, re-runs, the re-runs that changed a fit's
        split and the step taken instead (``split_held``), and why a parameter has no type B term when the
        Recording declares none.
    """
    n_draws = RESOLUTION_DRAWS if draws is None else int(draws)
    if n_draws < 2:
        raise ValueError(f"resolution draws must be at least 2 (got {draws}): the RMS of one draw has one degree of "
                         "freedom, and its relative uncertainty (1 / sqrt(2 N)) is 71 %")
    table = recording.meta.get(META_KEY)
    if not table:
        return {"declared": False, "note": "the recording declares no systematic uncertainties (e.g. a real log "
                                           "without a budget): the total interval equals the statistical one"}
    tasks: list[list[_Task]] = []
    for fits, roles, run in plan:
        fits = sorted(fits)
        nominal = {f"{fk}.{pk}": p for fk in fits if fk in result.fits for pk, p in result.fits[fk].params.items()}
        if nominal:
            split0 = splits(result.fits, fits)
            tasks.append([(fits, nominal, comp, run, split0) for comp in components(recording, roles)])
    with sharing_outputs():  # what one method's re-runs give another's (the transmission inside the converter's)
        done = _dispatch(recording, tasks, n_draws, workers, share)
    return _combine(result, tasks, done, n_draws, sorted(table))


def _dispatch(recording: Recording, tasks: list[list[_Task]], n_draws: int, workers: int | None,
              share: TypeBShare | None) -> list[_Done]:
    """The units' results in the tasks' order: on a shared worker, method by method (a lazy Recording), or all on
    the threads."""
    lazy = any(isinstance(c, LazyChannel) for c in recording.channels.values())
    n_threads = max(1, int(workers if workers is not None else WORKERS))
    if share is not None and tasks:
        done = run_shared(share, recording, tasks, lambda t: _propagate_one(recording, t, n_draws),
                          threads=share.threads or n_threads, lazy=lazy)
    elif lazy:
        kept = recording.loaded()
        done = []
        for method_tasks in tasks:
            # a lazy Recording: what one method's re-runs read goes before the next method's; the method's re-runs
            # share the threads and what they have in common (the channels a re-run does not move), then it goes
            recording.drop(recording.loaded() - kept)
            with reusing(), ThreadPoolExecutor(max_workers=n_threads, thread_name_prefix="type_b") as pool:
                futures = [pool.submit(_propagate_one, recording, t, n_draws) for t in method_tasks]
                done += [f.result() for f in futures]
        recording.drop(recording.loaded() - kept)
    else:
        flat = [t for method_tasks in tasks for t in method_tasks]
        # the Monte Carlo components (several re-runs each) first, so that the threads end together
        order = sorted(range(len(flat)), key=lambda i: flat[i][2].kind != "resolution")
        # the channels a re-run does not move are resampled and averaged once for all re-runs (see _reuse)
        with reusing(), ThreadPoolExecutor(max_workers=n_threads, thread_name_prefix="type_b") as pool:
            futures = {i: pool.submit(_propagate_one, recording, flat[i], n_draws) for i in order}
            done = [futures[i].result() for i in range(len(flat))]
    return done


def _combine(result: IdentificationResult, tasks: list[list[_Task]], done: list[_Done], n_draws: int,
             roles: list[str]) -> dict[str, Any]:
    """Each parameter's type B contributions from the units' changes (in place), and the summary (``roles``: those
    the Recording declares)."""
    contrib: dict[str, dict[str, float]] = {}
    dof: dict[str, dict[str, float]] = {}
    reruns, failed, held = 0, [], []
    for (_fits, _nominal, comp, _run, split0), (deltas, n, fails, notes) in zip(
            [t for method_tasks in tasks for t in method_tasks], done, strict=True):
        reruns += n
        failed += fails
        held += notes
        if comp.kind != "resolution":  # the step taken is part of the fits' budget: said where they are read
            for fk in split0:
                result.fits[fk].reasons.extend(f"type B: {note}" for note in notes)
        for key, d in deltas.items():
            contrib.setdefault(key, {})[comp.source] = float(np.sqrt(np.mean(np.square(d))))
            if comp.kind == "resolution":
                dof.setdefault(key, {})[comp.source] = float(len(d))
    for fk, fit in result.fits.items():
        for pk, p in fit.params.items():
            c = contrib.get(f"{fk}.{pk}")
            if c:
                p.combine_type_b(c, dof.get(f"{fk}.{pk}"), keep=True)
    return {"declared": True, "roles": roles, "reruns": reruns, "resolution_draws": n_draws,
            "resolution_rel_u": round(1.0 / math.sqrt(2.0 * n_draws), 4), "failed": failed, "split_held": held}
