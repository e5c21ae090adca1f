"""``benchtwin plan``: the brake-blending statistics, the converter's clipping the blending draws need, the
braking windows drawn with the pressures' noise, ``eta_m_C0`` and the gearbox drag model.

The spread checks vary the seed of the sensors on one plant run (what the plan predicts): with N estimates of a
normal estimator the sample std ``s`` has ``(N-1) s^2 / sigma^2 ~ chi2(N-1)``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from benchtwin.recording import Channel, Flag, Recording
from benchtwin.studies.plan_blending import clipped_readings
from benchtwin.studies.plan_noise import ChannelNoise


def _chi2_interval(n: int) -> tuple[float, float]:
    """Two-sided 99 % interval of ``s / sigma`` for ``n`` normal estimates."""
    return tuple(math.sqrt(stats.chi2.ppf(a, n - 1) / (n - 1)) for a in (0.005, 0.995))  # type: ignore[return-value]


def test_clipped_readings_flag_the_converter_clip_at_zero_as_the_bench() -> None:
    """A reading drawn below 0 bar reads 0 and is flagged SATURATED; the run's own clip flags are cleared.

    Truth 0.1 bar (the paper bench's offset on an unbraked caliper) with noise 0.05 bar and no quantisation: a
    reading falls below 0 with probability Phi(-2) = 0.02275; the count is checked within 5 binomial standard
    deviations (independent of the code: the normal law), and an unbraked truth of 1 bar never clips.
    """
    n = 200_000
    ts = np.arange(n) / 100.0
    flags = np.zeros(n, dtype=np.uint16)
    flags[::3] = int(Flag.SATURATED)  # the plan run's own clipping: redrawn, not kept
    flags[1::1000] |= int(Flag.TIMEOUT)  # other flags stay
    rec = Recording()
    rec.add(Channel("brake_pressure_fl_bar", "bar", ts, np.full(n, 0.1), flags, "pressure"))
    rec.add(Channel("brake_pressure_rl_bar", "bar", ts, np.full(n, 1.0), flags.copy(), "pressure"))
    noise = {k: ChannelNoise(0.05, 0.0) for k in ("brake_pressure_fl_bar", "brake_pressure_rl_bar")}
    out = clipped_readings(rec, noise, ["brake_pressure_fl_bar", "brake_pressure_rl_bar"], np.random.default_rng(5))
    fl = out["brake_pressure_fl_bar"]
    sat = (fl.flags & int(Flag.SATURATED)) != 0
    p = stats.norm.cdf(-2.0)
    assert abs(int(sat.sum()) - n * p) < 5 * math.sqrt(n * p * (1 - p)), (int(sat.sum()), n * p)
    assert np.all(fl.values[sat] == 0.0) and np.all(fl.values[~sat] >= 0.0)
    assert np.all((fl.flags[1::1000] & int(Flag.TIMEOUT)) != 0)
    rl = out["brake_pressure_rl_bar"]
    assert not np.any(rl.flags & int(Flag.SATURATED)) and abs(float(np.std(rl.values)) - 0.05) < 0.001
