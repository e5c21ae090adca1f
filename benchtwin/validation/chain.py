"""The chain against the truth: every decoded channel of the Recording compared with the Trace.

Which Trace channel a role measures, to which resolution, and which imperfections the setup declares
for it are said by each device (:meth:`~benchtwin.sensors.base.Device.truth_channels`,
:meth:`~benchtwin.sensors.base.Device.error_budget`); this module names no device kind.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
from scipy.ndimage import maximum_filter1d

from benchtwin.config.setup import SetupConfig
from benchtwin.recording import Channel, Flag, Recording
from benchtwin.sensors import devices
from benchtwin.sensors.base import TruthChannel
from benchtwin.sensors.imperfections import hold_sample
from benchtwin.trace import Trace
from benchtwin.validation.report import Check

__all__ = ["chain_checks"]


def _chain_truth(setup: SetupConfig) -> dict[str, TruthChannel]:
    """Role -> its Trace channel, unit factor, hold and resolution, from every device of the setup."""
    out: dict[str, TruthChannel] = {}
    for d in devices(setup):
        out.update(d.truth_channels())
    return out


def _error_budget(setup: SetupConfig) -> dict[str, tuple[Any, Any, float]]:
    """Role -> (ChannelErrors or None, LinkErrors, extra static error) from every device of the setup."""
    out: dict[str, tuple[Any, Any, float]] = {}
    for d in devices(setup):
        out.update(d.error_budget())
    return out


def chain_checks(trace: Trace, recording: Recording, setup: SetupConfig, *, profile: str = "ideal",
                 roles: Iterable[str] | None = None) -> list[Check]:
    """Compare every decoded channel with the Trace.

    With the ``ideal`` profile each channel must equal the truth within half its resolution (plus the
    converter's rounding) and carry no flag. With ``realistic`` the error of each unflagged sample must
    be explained by the imperfections the setup declares for that sensor: a bound of
    ``|offset| + |gain error| |x| + 4 noise_std + resolution + |dx/dt| (latency + filter time constant +
    sample period + |clock offset| + |drift| t)``; at least 99 % of the samples must lie within it (the
    rest are stuck-at intervals, reordered frames and other faults the setup asked for).

    ``roles`` restricts the checks to those roles (default: every role of the setup's devices).

    Returns
    -------
    list of Check
        One check per channel; the worst sample (ideal) or the fraction inside the bound (realistic).
    """
    checks: list[Check] = []
    kept = recording.loaded()
    for role, check in _chain_checks(trace, recording, setup, profile, roles):
        checks.append(check)
        if role not in kept:  # a lazy Recording: one channel in memory at a time
            recording.drop([role])
    return checks


def _chain_checks(trace: Trace, recording: Recording, setup: SetupConfig, profile: str,
                  roles: Iterable[str] | None) -> Iterator[tuple[str, Check]]:
    """The checks of :func:`chain_checks`, one per role, as they are made."""
    budget = _error_budget(setup) if profile != "ideal" else {}
    wanted = set(roles) if roles is not None else None
    for role, tc in sorted(_chain_truth(setup).items()):
        if wanted is not None and role not in wanted:
            continue
        name, factor, hold, res = tc.trace, tc.factor, tc.hold, tc.resolution
        if role not in recording or name not in trace:
            yield role, Check("chain", f"chain.{role}", float("nan"), float("nan"), float("nan"), res, "abs", "",
                              False, "channel missing from the recording")
            continue
        ch: Channel = recording[role]
        x = trace[name] * factor
        truth = hold_sample(trace.time_s, x, ch.timestamps) if hold else np.interp(ch.timestamps, trace.time_s, x)
        ok = np.isfinite(truth) & np.isfinite(ch.values) & (ch.flags & int(Flag.bad()) == 0)
        n_flag = int(np.count_nonzero(ch.flags))
        if not ok.any():
            yield role, Check("chain", f"chain.{role}", float("nan"), float("nan"), float("nan"), res, "abs",
                              ch.unit, False, "no usable sample")
            continue
        err = ch.values[ok] - truth[ok]
        if profile == "ideal":
            # half a step; thermocouples add the 0.5 uV input converter (~0.013 degC at 39 uV/degC)
            tol = 0.5 * res + 0.0065 * (ch.unit == "degC") + 1e-9
            k = int(np.argmax(np.abs(err)))
            passed = bool(abs(err[k]) <= tol and n_flag == 0)
            note = f"{n_flag} flagged samples" if n_flag else "half a resolution step"
            yield role, Check("chain", f"chain.{role}", float(ch.values[ok][k]), float(truth[ok][k]),
                              float(err[k]), tol, "abs", ch.unit, passed, note)
            continue
        errs, link, extra = budget.get(role, (None, None, 0.0))
        t = ch.timestamps[ok]
        xv = truth[ok]
        dxdt = np.abs(np.gradient(x, trace.time_s)) if len(trace) > 1 else np.zeros_like(x)
        # the local slope over a window covering the lags (max of the slope around each sample)
        lag = 0.0
        bound = np.full(xv.shape, 0.5 * res * (1 + 1e-6) + 1e-9 + extra + 0.0065 * (ch.unit == "degC"))
        if errs is not None:
            bound += abs(errs.offset) + abs(errs.gain_error_frac) * np.abs(xv) + 4.0 * errs.noise_std
            bound += errs.quantisation_step
            if errs.bandwidth_hz > 0:
                lag += 3.0 / (2 * np.pi * errs.bandwidth_hz)
        dt_ch = float(np.median(np.diff(ch.timestamps))) if len(ch) > 1 else 0.0
        lag += dt_ch
        if link is not None:
            lag += link.latency_s + abs(link.clock_offset_s)
            lag_t = lag + abs(link.clock_drift_ppm) * 1e-6 * np.abs(t)
        else:
            lag_t = np.full(t.shape, lag)
        w = max(int(np.ceil(float(np.max(lag_t, initial=lag)) / max(trace.dt_s, 1e-9))) + 1, 1)
        slope = maximum_filter1d(dxdt, size=2 * w + 1, mode="nearest")
        bound += np.interp(t, trace.time_s, slope) * lag_t
        within = np.abs(err) <= bound
        inside = float(np.mean(within))

        yield role, Check("chain", f"chain.{role}", inside, 0.99, inside, 0.99, "min", "-", inside >= 0.99,
                          f"fraction of unflagged samples whose error the setup's declared imperfections explain; "
                          f"{n_flag} flagged samples")
