"""The one-pass median of the chain checks' time steps (:func:`benchtwin.validation.chain._median_of`): a bracket
guessed from a sample, the values inside it gathered or counted by distinct value; a bracket that misses falls back
to the selection in passes. The result is ``np.median``'s, whatever the sample."""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.validation import chain as vchain


def _parts(x: np.ndarray, size: int = 97):
    return lambda: (x[a:a + size] for a in range(0, x.size, size))


def _steps(rng: np.random.Generator, n: int) -> np.ndarray:
    """Time steps like a channel's: the period and a few rounding neighbours, a few gaps and NaN."""
    x = 0.01 + rng.integers(-3, 4, n) * np.spacing(0.01)
    x[rng.integers(0, n, 5)] = 30.0  # gaps between tests
    x[rng.integers(0, n, 3)] = np.nan
    return x


@pytest.mark.parametrize("n", [2001, 2000])
@pytest.mark.parametrize("cap", [50, 5000])  # counted by distinct value / gathered whole
def test_median_of_few_distinct_steps_equals_numpy(monkeypatch: pytest.MonkeyPatch, n: int, cap: int) -> None:
    """Over the cap the bracket counts distinct values; the rank is read from their cumulative counts. Mutant: the
    rank searched with ``side="left"`` returns the next distinct value at a count boundary: fails (ties here)."""
    monkeypatch.setattr(vchain, "MEDIAN_CAP", cap)
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = _steps(rng, n)
        want = np.sort(x)[[n // 2] if n % 2 else [n // 2 - 1, n // 2]]
        ks = [n // 2] if n % 2 else [n // 2 - 1, n // 2]
        got = vchain._bracketed(_parts(x), ks, n, x[:400])
        assert got is not None and got == [float(w) for w in want]
        assert vchain._median_of(_parts(x), n, lambda a, b, x=x: x[a:b]) == float(np.mean(want))


def test_a_misleading_sample_falls_back(monkeypatch: pytest.MonkeyPatch) -> None:
    """A sample unlike the whole (its quantiles far from the median) gives a bracket that misses: None, and the
    median selected in passes is still numpy's. Mutant: the check that every rank lies inside the bracket removed:
    a value of the bracket is returned as the median (wrong) and the test fails."""
    monkeypatch.setattr(vchain, "MEDIAN_CAP", 50)
    rng = np.random.default_rng(5)
    x = rng.normal(size=3001)
    sample = np.full(100, 10.0)  # a bracket around 10, far above the median (~0)
    assert vchain._bracketed(_parts(x), [1500], 3001, sample) is None
    assert vchain._median_of(_parts(x), 3001, lambda a, b: np.full(b - a, 10.0)) == float(np.median(x))


def test_distinct_values_too_many_fall_back(monkeypatch: pytest.MonkeyPatch) -> None:
    """A bracket holding more than the cap of continuous values: their distinct values exceed the limit, None (then
    selected in passes). Mutant: no limit on the distinct values: a result, and the test fails."""
    monkeypatch.setattr(vchain, "MEDIAN_CAP", 80)
    x = np.random.default_rng(7).uniform(size=4001)
    wide = np.r_[np.zeros(50), np.ones(50)]  # its quantiles around the middle: 0 and 1, the whole range
    assert vchain._bracketed(_parts(x), [2000], 4001, wide) is None
    assert vchain._median_of(_parts(x), 4001, lambda a, b: x[a:b]) == float(np.median(x))


def test_a_rank_on_a_count_boundary(monkeypatch: pytest.MonkeyPatch) -> None:
    """1000 ones and 1001 twos (over the cap: counted by distinct value): the rank 1000 is the first two, exactly
    where the ones' cumulative count ends. Mutant: ``side="left"`` gives 1.0: fails."""
    monkeypatch.setattr(vchain, "MEDIAN_CAP", 50)
    x = np.random.default_rng(9).permutation(np.r_[np.ones(1000), np.full(1001, 2.0)])
    assert vchain._bracketed(_parts(x), [1000], 2001, x) == [2.0]


def test_a_sample_in_many_pieces_follows_steps_that_change_along_the_channel(monkeypatch: pytest.MonkeyPatch) -> None:
    """Steps whose values change along the channel (a channel's times round differently as they grow): the first
    2.5 % of the steps are a value found nowhere else. The sample's pieces spread over the whole give the first
    part its share, the bracket holds the median, and no selection pass is made. Mutant: ``SAMPLE_PIECES = 8`` (one
    piece of eight lies in the first part: 12.5 % of the sample, the bracket [0.5, 0.5] misses the median 0):
    ``_kth`` is called and the test fails."""
    monkeypatch.setattr(vchain, "MEDIAN_CAP", 200)
    monkeypatch.setattr(vchain, "SAMPLE_VALUES", 2048)
    rng = np.random.default_rng(11)
    n = 20_000
    rest = np.where(rng.random(n - 500) < 0.52 / 0.975, 0.0, 1.0)  # 52 % of the whole 0.0, 45.5 % 1.0
    x = np.r_[np.full(500, 0.5), rest]
    passes: list[int] = []
    kth = vchain._kth
    monkeypatch.setattr(vchain, "_kth", lambda arrays, k, bins=4096: passes.append(k) or kth(arrays, k, bins))
    n_vals = n - 1  # an even count: the median is the mean of two ranks, as for a channel's steps
    got = vchain._median_of(_parts(x[:n_vals]), n_vals, lambda a, b: x[a:b])
    assert got == float(np.median(x[:n_vals])) == 0.0
    assert passes == []
