"""``Trace.interp`` reads a window of the Trace around the times: the whole channel's ``np.interp``, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.trace import SpooledTrace, Trace


def _trace() -> Trace:
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.005, 0.015, 5000))
    v = np.sin(t) * 300 + rng.normal(0, 1, t.size)
    v[[100, 2000, 2001]] = np.nan  # a NaN beside a grid time changes what the neighbouring interval gives
    return Trace(t, {"battery_voltage_v": v})


def _times(tr: Trace) -> list[np.ndarray]:
    t = tr.time_s
    rng = np.random.default_rng(6)
    return [rng.uniform(t[1000], t[1200], 300),  # inside
            np.array([t[99], t[100], t[101], t[1999], t[2002]]),  # exactly on grid times beside the NaN
            np.array([t[1990], t[1999]]),  # the last time on a grid time whose next sample is NaN
            np.array([t[0] - 5.0, t[10]]), np.array([t[-10], t[-1] + 3.0]),  # beyond either end: held
            np.array([t[-1] + 1.0]), np.array([t[0] - 1.0]), np.zeros(0), np.array([np.nan, t[50]])]


@pytest.mark.parametrize("spooled", [False, True])
def test_interp_equals_the_whole_channel(monkeypatch, spooled: bool) -> None:
    tr = _trace()
    whole = tr["battery_voltage_v"].copy()
    src: Trace = tr
    if spooled:
        src = SpooledTrace()
        half = len(tr) // 2
        src.append(Trace(tr.time_s[:half], {"battery_voltage_v": whole[:half]}))
        src.append(Trace(tr.time_s[half:], {"battery_voltage_v": whole[half:]}))
    reads: list[int] = []
    real = type(src).read

    def read(self, name, a=0, b=None):
        out = real(self, name, a, b)
        reads.append(len(out))
        return out

    monkeypatch.setattr(type(src), "read", read)
    for t in _times(tr):
        got = src.interp("battery_voltage_v", t)
        want = np.interp(t, tr.time_s, whole)
        np.testing.assert_array_equal(got, want)
    # each read is the samples between the times' ends and one more on each side
    assert reads[:-2] == [200, 1905, 11, 12, 10, 1, 1]
    assert reads[-2] == 1  # no time: one sample (np.interp needs one)
    assert reads[-1] == len(tr)  # a time that is not a number: the whole channel, as np.interp sees it
    if spooled:
        src.close()
