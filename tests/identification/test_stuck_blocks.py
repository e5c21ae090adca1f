"""``stuck_channels`` reads a lazy channel by blocks: the same verdict as on the whole channel, never a whole read.

``_whole`` is the whole-array rule ``stuck_channels`` applied before it read by blocks (the reference): the finite
samples, at least ``STUCK_MIN_SAMPLES`` of them, all equal to the first and that one not zero.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.identification import stuck as idstuck
from benchtwin.identification.stuck import STUCK_MIN_SAMPLES, stuck_channels
from benchtwin.recording import Channel, Recording


def _whole(values: np.ndarray) -> float | None:
    v = values[np.isfinite(values)]
    if v.size >= STUCK_MIN_SAMPLES and v[0] != 0.0 and np.all(v == v[0]):
        return float(v[0])
    return None


def _cases(n: int = 30_000) -> dict[str, np.ndarray]:
    """Motor-torque value arrays: stuck, stuck with NaN runs (one longer than a block), stuck at zero, changing
    only after the head, changing only in the last sample, too few finite samples, all NaN."""
    stuck = np.full(n, 150.0)
    holes = stuck.copy()
    holes[:5000] = np.nan  # the head and whole blocks without a finite sample
    holes[np.random.default_rng(3).random(n) < 0.1] = np.nan
    late = stuck.copy()
    late[20_000] = 151.0
    last = stuck.copy()
    last[-1] = 149.0
    few = np.full(n, np.nan)
    few[-(STUCK_MIN_SAMPLES - 1):] = 7.0
    enough = np.full(n, np.nan)
    enough[-STUCK_MIN_SAMPLES:] = 7.0
    return {"stuck": stuck, "holes": holes, "zero": np.zeros(n), "late": late, "last": last, "few": few,
            "enough": enough, "nan": np.full(n, np.nan)}


@pytest.mark.parametrize("block", [97, 4096, 1 << 20])
@pytest.mark.parametrize("case", list(_cases()))
def test_stuck_by_blocks_equals_the_whole_rule(blocks_only, monkeypatch, case: str, block: int) -> None:
    values = _cases()[case]
    monkeypatch.setattr(idstuck, "STUCK_BLOCK", block)
    monkeypatch.setattr(idstuck, "STUCK_HEAD", 64)  # the head settles nothing here: the blocks decide
    n = len(values)
    ch = Channel("em_torque_nm", "Nm", np.arange(n) * 0.01, values, np.zeros(n, np.uint16), "motor")
    want = _whole(values)
    expected = {} if want is None else {"em_torque_nm": want}
    assert stuck_channels(Recording({"em_torque_nm": blocks_only(ch)})) == expected
    assert stuck_channels(Recording({"em_torque_nm": ch})) == expected  # in memory: the same
    # the cases cover both verdicts
    assert {c: _whole(v) is not None for c, v in _cases().items()} == {
        "stuck": True, "holes": True, "zero": False, "late": False, "last": False, "few": False, "enough": True,
        "nan": False}
