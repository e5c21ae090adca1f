"""Draws of the shaft torque shared by the converter's points, its calibration and the transmission table.

The converter's turbine torque (eq. 32) goes through the transmission table a bench finds on the same seed:
``eta_m`` and ``C0`` of each gear are fitted to window means of the very shaft-torque readings the turbine-torque
calibration (lock-up closed, K0 open, nearly steady: the electric ramp-ups' holds) then divides the motor torque
by. A reading's error that raises a window mean raises that gear's ``eta_m`` with it, and eq. 32 divides it out
again: the calibration's ratios ``T_motor / T_t`` carry the fit's residual, not the readings' error plus an
independent error of the table. Drawn independently, the turbine-torque scale scattered 3-4 times its spread over
20 seeds on the paper campaign.

So one draw here is one error per shaft-torque reading (the quantised noisy reading at its noise-free value:
the truth with the sensor's gain and offset, lagged as the bench reads it), from which follow, together:

- the error of each grid sample (the converter's points and the calibration's), interpolated between the two
  readings around it: on the shaft torque's own (telemetry) timestamps, or for the sets of times named in
  ``mapped`` on the reference clock (the telemetry's clock map, as the identification's grid takes them). The
  turbine-torque calibration's samples are taken mapped: its scale is a median over several gears' medians of
  ratios whose readings sit on quantisation levels (2.1 Nm steps, 0.3 Nm noise on the paper bench), so a sample
  must carry the error of the very reading whose noise-free value it holds; on the telemetry's own timestamps the
  paper campaign's samples took readings 64 ms away and the gears' medians moved (gear 9: 0.98380 over the draws
  against 0.98358 over 20 seeds; 0.98360 mapped);
- the error of each gear's ``(eta_m, C0)``: the drive fit (eq. 14) linearised in its windows' mean shaft
  torque, ``d eta_i = eta_i / T_out,i d T_out,i``, at the windows the identification finds on the plan's
  Recording. What the table's planned variance holds beyond the shaft torque's noise in those windows (other
  channels' noise, windows that move with the noise) is drawn independently, as before.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import BenchtwinError
from benchtwin.identification._clock import source_shifts, to_ref
from benchtwin.identification.transmission import transmission_points
from benchtwin.identification.transmission_eq14 import direction_points, efficiency_design
from benchtwin.recording import Recording
from benchtwin.studies.plan_noise import ChannelNoise, reading_variance

__all__ = ["SharedDraw", "shared_shaft_draws"]

SHAFT = "shaft_torque_nm"


@dataclass
class SharedDraw:
    """One draw: the shaft torque's error at each set of grid times, and each gear's table error."""

    grid: list[np.ndarray]
    table: dict[int, tuple[float, float]]


@dataclass
class _GearMap:
    """The drive fit of one gear linearised in its windows' mean shaft torque."""

    lo: np.ndarray
    hi: np.ndarray
    gain: np.ndarray  # d x / d mean T_out per window, x = (eta_m, eta_m C0): shape [2, n]
    eta_m: float
    k: float
    extra: tuple[float, float]  # std of d eta_m, d C0 drawn independently


def _grid_index(ts: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    k = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, ts.size - 2)
    a = np.clip((t - ts[k]) / np.maximum(ts[k + 1] - ts[k], 1e-12), 0.0, 1.0)
    return k, a


def shared_shaft_draws(view: Recording, specs: VehicleSpecs, cn: ChannelNoise, times: list[np.ndarray],
                       table: Mapping[int, tuple[float, float, float, float]], mapped: Sequence[bool] = ()
                       ) -> Callable[[np.random.Generator], SharedDraw] | None:
    """A sampler of shared shaft-torque draws (module docstring); None when the view has no shaft torque.

    Parameters
    ----------
    view:
        The plan's Recording with the shaft torque as the bench's sensor reads it, noise-free (the truth with
        its gain and offset, lagged): the value each reading is quantised at.
    specs:
        Gear ratios (the transmission's steady points).
    cn:
        The shaft torque's random error (``sigma`` and step ``q``; gain and offset are already in ``view``).
    times:
        Grid times whose interpolated error each draw returns (one array per set).
    table:
        Gear -> ``(eta_m, C0, se eta_m, se C0)``: the table and its planned standard errors; a gear whose
        windows are not found keeps independent draws of its planned errors.
    mapped:
        Per set of ``times``: True to interpolate between the readings on the reference clock (their timestamps
        through the view's clock map, :func:`~benchtwin.identification._clock.source_shifts`, as the
        identification's grid reads them), False (and for sets beyond its length) on their own timestamps.
    """
    if SHAFT not in view or len(view[SHAFT]) < 2:
        return None
    ch = view[SHAFT]
    ts, y, good = ch.timestamps, ch.values, ch.good
    flags = [bool(m) for m in mapped][:len(times)] + [False] * max(len(times) - len(mapped), 0)
    ref = np.asarray(to_ref(ts, source_shifts(view).get(ch.source, 0.0)), dtype=float) if any(flags) else ts
    if any(flags) and np.any(np.diff(ref) < 0):
        raise BenchtwinError(f"{SHAFT}: the clock map reorders its readings")
    idx = [_grid_index(ref if m else ts, np.asarray(t, dtype=float)) for t, m in zip(times, flags, strict=True)]
    try:
        tp = transmission_points(view, specs)
    except BenchtwinError:
        tp = None
    ratios = np.asarray(specs.gear_ratios, dtype=float)
    fits: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float]] = {}
    for g in table:
        if tp is None or tp.windows is None or not 1 <= g <= ratios.size:
            continue
        m, dom, c, eta = direction_points(tp, g, "drive", ratios[g - 1])
        c, eta = c[dom], eta[dom]
        if c.size < 3:
            continue
        j = np.flatnonzero(m)[dom]
        lo = np.searchsorted(ts, [tp.windows.windows[i].start_s for i in j], side="left")
        hi = np.searchsorted(ts, [tp.windows.windows[i].end_s for i in j], side="left")
        A, w = efficiency_design(c)
        aw = A * w[:, None]
        x = np.linalg.solve(A.T @ aw, aw.T @ eta)
        gain = np.linalg.solve(A.T @ aw, aw.T) * (eta / tp.t_out[j])  # d x / d mean T_out of each window
        fits[g] = (lo, hi, gain, x, float(x[0]), float(x[1]))
    # only the readings a draw needs: those around the grid times and those inside the windows
    need = np.unique(np.concatenate([np.r_[k, k + 1] for k, _a in idx]
                                    + [np.arange(a, b) for f in fits.values() for a, b in zip(f[0], f[1], strict=True)]
                                    + [np.zeros(0, dtype=int)]).astype(int))
    yn, gn = y[need], good[need]
    pos = [(np.searchsorted(need, k), np.searchsorted(need, k + 1), a) for k, a in idx]
    vn = np.where(gn, np.asarray(reading_variance(cn.sigma, cn.q, yn)), 0.0)
    cgood = np.concatenate(([0], np.cumsum(gn.astype(int))))
    cv = np.concatenate(([0.0], np.cumsum(vn)))
    maps: dict[int, _GearMap] = {}
    for g, (lo, hi, gain, _x, eta_m, k) in fits.items():
        lo, hi = np.searchsorted(need, lo), np.searchsorted(need, hi)
        n = np.maximum(cgood[hi] - cgood[lo], 1)
        # the shaft torque's share of the planned variance, at the readings' own variances
        cov = (gain * ((cv[hi] - cv[lo]) / n**2)) @ gain.T
        grad_c0 = np.array([-k / eta_m**2, 1.0 / eta_m])
        v_eta, v_c0 = float(cov[0, 0]), float(grad_c0 @ cov @ grad_c0)
        se_eta, se_c0 = table[g][2], table[g][3]
        maps[g] = _GearMap(lo, hi, gain / n, eta_m, k,
                           (np.sqrt(max(se_eta**2 - v_eta, 0.0)), np.sqrt(max(se_c0**2 - v_c0, 0.0))))

    def draw(rng: np.random.Generator) -> SharedDraw:
        r = yn + rng.normal(0.0, cn.sigma, yn.shape)
        if cn.q > 0:
            r = cn.q * np.rint(r / cn.q)
        e = r - yn
        grid = [(1.0 - a) * e[k0] + a * e[k1] for k0, k1, a in pos]
        ce = np.concatenate(([0.0], np.cumsum(np.where(gn, e, 0.0))))
        tab: dict[int, tuple[float, float]] = {}
        for g, (_eta, _c0, se_eta, se_c0) in table.items():
            gm = maps.get(g)
            if gm is None:
                tab[g] = (rng.normal(0.0, se_eta), rng.normal(0.0, se_c0))
                continue
            dx = gm.gain @ (ce[gm.hi] - ce[gm.lo])
            d_eta = float(dx[0])
            d_c0 = float(dx[1] / gm.eta_m - gm.k / gm.eta_m**2 * dx[0])
            tab[g] = (d_eta + rng.normal(0.0, gm.extra[0]), d_c0 + rng.normal(0.0, gm.extra[1]))
        return SharedDraw(grid, tab)

    return draw
