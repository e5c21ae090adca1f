"""detect_lag gives the same bits whatever the number of BLAS threads: the type B re-runs of the converter
(identification/shaft_clock.py) run it on worker threads beside other BLAS calls, and a budget of re-runs must equal
the plain re-runs' exactly (tests/identification/test_type_b_fast.py)."""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_limits

from benchtwin.lag import detect_lag


def test_detect_lag_is_the_same_on_one_and_two_blas_threads() -> None:
    # 400 s at 100 Hz: 40,000 grid points, above the length OpenBLAS splits a dot product over its threads at
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 400.0, 0.01)
    x = np.cumsum(rng.normal(size=t.size))
    lags = {}
    for n in (1, 2):
        with threadpool_limits(limits=n, user_api="blas"):
            lags[n] = detect_lag(t, x, t + 0.0123, x, rate_hz=100.0, max_lag_s=0.5, min_correlation=0.5)
    assert lags[1] is not None and abs(lags[1] - 0.0123) < 0.002  # the lag found (one grid step of 10 ms)
    assert lags[1].hex() == lags[2].hex()  # exactly
