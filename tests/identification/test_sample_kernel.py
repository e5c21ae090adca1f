"""The grid sampling kernel against the NumPy expression of ``_signals._sample_block``: equal bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.identification import _signals
from benchtwin.identification._clock import ClockShift, to_ref
from benchtwin.identification._signals import _BAD, _sample_block


def _numpy_sample_block(ts, vs, fl, t, fidx, hold, shift_s, k0=0):
    """The NumPy expression the kernel replaces (kept here as the reference)."""
    n = ts.size
    first, last = to_ref(ts[0], shift_s), to_ref(ts[-1], shift_s)
    idx = np.floor(fidx).astype(np.int64)
    if k0:
        idx -= k0
    idx[t < first] = -1
    i0 = np.clip(idx, 0, n - 1)
    i1 = np.clip(idx + 1, 0, n - 1)
    v0 = vs[i0]
    flagged = ((fl[i0] & _BAD) != 0) | ~np.isfinite(v0)
    if hold:
        v = v0.astype(float)
    else:
        v1 = vs[i1]
        frac = fidx - (np.clip(idx, 0, None) + k0 if k0 else np.clip(idx, 0, None))
        with np.errstate(invalid="ignore"):
            v = v0 + frac * (v1 - v0)
        flagged |= (((fl[i1] & _BAD) != 0) | ~np.isfinite(v1)) & (to_ref(ts[i1], shift_s) > t)
    outside = (idx < 0) | (t > last)
    v[outside] = np.nan
    flagged &= ~outside
    return v, flagged


SHIFTS = [0.0, 0.0123456789, -1.5, ClockShift(0.25, 3e-5), ClockShift(-0.1, -7.1e-6)]


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("shift", SHIFTS)
@pytest.mark.parametrize("hold", [False, True])
@pytest.mark.parametrize("k0", [0, 12345])
def test_sample_block_equals_numpy(seed: int, shift, hold: bool, k0: int) -> None:
    rng = np.random.default_rng(seed)
    n = 3000
    ts = np.cumsum(rng.uniform(0.0005, 0.003, n)) + 100.0
    ts[rng.integers(1, n, 20)] = ts[rng.integers(1, n, 20) - 1]  # some repeated timestamps
    ts = np.sort(ts)
    vs = 1500.0 + np.cumsum(rng.normal(0.0, 1.0, n)) * rng.uniform(0.1, 3.0)
    vs[rng.random(n) < 0.01] = np.nan
    vs[rng.random(n) < 0.003] = -np.inf
    fl = np.zeros(n, dtype=np.uint16)
    fl[rng.random(n) < 0.02] = np.uint16(_BAD & -_BAD)
    ref = to_ref(ts, shift) if shift else ts
    # grid times past both ends, and some right on sample times
    t = np.sort(np.concatenate((rng.uniform(ref[0] - 0.5, ref[-1] + 0.5, 2000), ref[rng.integers(0, n, 50)])))
    fidx = np.interp(t, ref, np.arange(k0, k0 + n, dtype=float))
    got = _sample_block(ts, vs, fl, t, fidx, hold, shift, k0)
    want = _numpy_sample_block(ts, vs, fl, t, fidx, hold, shift, k0)
    assert got[0].tobytes() == want[0].tobytes()
    assert got[1].dtype == want[1].dtype and np.array_equal(got[1], want[1])
    assert np.isnan(got[0]).any() and got[1].any() and (~got[1]).any()  # the cases occur


def test_non_finite_index_and_other_dtypes_take_the_numpy_path(monkeypatch: pytest.MonkeyPatch) -> None:
    ts = np.arange(10.0)
    vs = np.arange(10.0) * 2.0
    fl = np.zeros(10, dtype=np.uint16)
    t = np.array([0.5, 3.25, 8.0])
    fidx = np.array([0.5, np.nan, 8.0])  # a grid time whose index is not finite
    with np.errstate(invalid="ignore"):
        want = _numpy_sample_block(ts, vs, fl, t, fidx, False, 0.0)
        got = _sample_block(ts, vs, fl, t, fidx, False, 0.0)
    assert got[0].tobytes() == want[0].tobytes() and np.array_equal(got[1], want[1])
    calls = []
    monkeypatch.setattr(_signals, "sample_block", lambda *a: calls.append(a) or (False, None, None))
    vs32 = vs.astype(np.float32)
    got = _sample_block(ts, vs32, fl, t, np.array([0.5, 3.25, 8.0]), False, 0.0)
    assert not calls  # float32 values: the NumPy path, as before
    assert got[0].tolist() == [1.0, 6.5, 16.0]


def test_edges_on_the_clock_map_and_the_sample_after() -> None:
    """Grid times right at the mapped first and last samples (where ``t + (offset + rate t)`` and ``(t + offset) +
    rate t`` can differ by an ulp), and a bad sample after that lies at the grid time itself (it is not used)."""
    shift = ClockShift(0.25, 3e-5)
    rng = np.random.default_rng(5)
    x = rng.uniform(100.0, 4000.0, 100000)
    differs = x[(x + (shift.offset_s + shift.rate * x)) != ((x + shift.offset_s) + shift.rate * x)]
    assert differs.size >= 2
    a, b = float(differs.min()), float(differs.max())  # both ends on such times
    assert b - a > 100.0
    ts = np.concatenate(([a], np.sort(rng.uniform(a + 1.0, a + 99.0, 500)), [b]))
    n = ts.size
    vs = np.linspace(0.0, 1.0, n)
    fl = np.zeros(n, dtype=np.uint16)
    ref = to_ref(ts, shift)
    t = np.array([ref[0], ref[-1], np.nextafter(ref[-1], np.inf), np.nextafter(ref[0], -np.inf)])
    fidx = np.interp(t, ref, np.arange(n, dtype=float))
    for hold in (False, True):
        got = _sample_block(ts, vs, fl, t, fidx, hold, shift)
        want = _numpy_sample_block(ts, vs, fl, t, fidx, hold, shift)
        assert got[0].tobytes() == want[0].tobytes() and np.array_equal(got[1], want[1])
    # repeated timestamps: the sample after lies at the grid time, its flag does not touch the point
    ts = np.array([0.0, 1.0, 1.0, 2.0])
    vs = np.array([0.0, 1.0, 5.0, 2.0])
    fl = np.array([0, 0, _BAD & -_BAD, 0], dtype=np.uint16)
    got = _sample_block(ts, vs, fl, np.array([1.0]), np.array([1.0]), False, 0.0)
    want = _numpy_sample_block(ts, vs, fl, np.array([1.0]), np.array([1.0]), False, 0.0)
    assert got[0].tolist() == want[0].tolist() == [1.0] and got[1].tolist() == want[1].tolist() == [False]
