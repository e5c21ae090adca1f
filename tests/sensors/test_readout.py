"""``read_out`` (one numba pass) against the numpy steps ``measure`` took before, bit for bit, on edge cases."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from benchtwin.config.setup import ChannelErrors
from benchtwin.sensors.imperfections import hold_sample, measure, sample
from benchtwin.sensors.readout import read_out


def _numpy_steps(t_src, x, ts, hold, gain, offset, noise, step, smin, smax) -> np.ndarray:
    """The reference: ``measure``'s numpy code before the kernel, line for line."""
    with np.errstate(invalid="ignore"):
        return _steps(t_src, x, ts, hold, gain, offset, noise, step, smin, smax)


def _steps(t_src, x, ts, hold, gain, offset, noise, step, smin, smax) -> np.ndarray:
    y = hold_sample(t_src, x, ts) if hold else sample(t_src, x, ts)
    if gain:
        y = y * (1.0 + gain)
    if offset:
        y = y + offset
    if noise is not None:
        y = y + noise
    if step > 0:
        y = np.rint(y / step) * step
    if smin is not None or smax is not None:
        y = np.clip(y, smin, smax)
    return y


def _signal() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    t_src = np.round(np.arange(0.0, 10.0, 0.01), 9)
    x = 40.0 * np.sin(t_src) + rng.normal(0.0, 3.0, t_src.size)
    x[[5, 6, 400]] = [np.nan, np.inf, -np.inf]  # a filtered signal keeps the non-finite samples
    x[100:110] = 0.0
    x[110:120] = -0.0
    x[200:210] = 2.5  # halfway between quantisation steps of 1 and 5 after the gain of 0
    # sample times: before the start, on samples exactly, between them, at and after the end, unsorted
    ts = np.concatenate([[-1.0, -1e-12, 0.0], t_src[::7], t_src[:-1:3] + 0.004, [t_src[-1], t_src[-1] + 1e-9, 20.0],
                         rng.uniform(-0.5, 10.5, 300)])
    return t_src, x, ts


CASES = list(itertools.product(
    (False, True),  # hold
    (0.0, 0.013, -1.0),  # gain error (-1: every value times 0, signed zeros)
    (0.0, -0.25),  # offset
    (False, True),  # noise
    (0.0, 1.0, 0.37),  # quantisation step
    ((None, None), (0.0, None), (None, 0.0), (-30.0, 25.0), (10.0, -10.0)),  # saturation (min above max too)
))


@pytest.mark.parametrize(("hold", "gain", "offset", "noisy", "step", "sat"), CASES)
def test_read_out_equals_the_numpy_steps(hold, gain, offset, noisy, step, sat) -> None:
    t_src, x, ts = _signal()
    noise = np.random.default_rng(9).normal(0.0, 0.7, ts.shape) if noisy else None
    want = _numpy_steps(t_src, x, ts, hold, gain, offset, noise, step, *sat)
    got = read_out(t_src, x, ts, hold=hold, gain_error_frac=gain, offset=offset, noise=noise, quantisation_step=step,
                   saturation_min=sat[0], saturation_max=sat[1])
    assert got.dtype == np.float64 and got.shape == want.shape
    assert got.tobytes() == want.tobytes()  # bit for bit: NaN payloads and signed zeros included


def test_read_out_of_strided_inputs_and_a_one_sample_signal() -> None:
    t_src, x, ts = _signal()
    got = read_out(t_src[::2], x[::2], ts[::3], hold=False, gain_error_frac=0.0, offset=0.0, noise=None,
                   quantisation_step=0.0, saturation_min=None, saturation_max=None)
    assert got.tobytes() == np.interp(ts[::3], t_src[::2], x[::2]).tobytes()
    for hold in (False, True):
        one = read_out(np.array([2.0]), np.array([7.5]), ts, hold=hold, gain_error_frac=0.0, offset=0.0, noise=None,
                       quantisation_step=0.0, saturation_min=None, saturation_max=None)
        assert np.all(one == 7.5)


def test_read_out_refuses_mismatched_inputs() -> None:
    t = np.arange(5.0)
    with pytest.raises(ValueError, match="noise"):
        read_out(t, t, t, hold=False, gain_error_frac=0.0, offset=0.0, noise=np.zeros(4), quantisation_step=0.0,
                 saturation_min=None, saturation_max=None)
    with pytest.raises(ValueError, match="non-empty"):
        read_out(t, t[:4], t, hold=False, gain_error_frac=0.0, offset=0.0, noise=None, quantisation_step=0.0,
                 saturation_min=None, saturation_max=None)


def test_measure_draws_the_same_noise_as_before() -> None:
    """``measure`` draws its noise from the generator as it did (one ``normal`` of the sample times' shape), so the
    generator is left where the next draw expects it."""
    t_src, x, ts = _signal()
    x = np.nan_to_num(x)
    err = ChannelErrors(noise_std=0.5, gain_error_frac=0.01, offset=0.1, quantisation_step=0.05)
    r1, r2 = np.random.default_rng(1), np.random.default_rng(1)
    got = measure(t_src, x, ts + 0.002, err, r1, latency_s=0.002)
    noise = r2.normal(0.0, 0.5, ts.shape)
    want = _numpy_steps(t_src, x, (ts + 0.002) - 0.002, False, 0.01, 0.1, noise, 0.05, None, None)
    assert got.tobytes() == want.tobytes()
    assert r1.random() == r2.random()
