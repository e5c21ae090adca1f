"""A gear on a borrowed transmission model: its turbine-torque offset from its own coupling points (milliseconds)."""

from __future__ import annotations

import numpy as np

from benchtwin.identification.torque_converter_points import ConverterPoints, borrowed_gear_offsets

GAMMA = 0.88


def _points(own_tr: float, offset: float) -> ConverterPoints:
    """Gear 2 (own model) at SR 0.90-0.95 with torque ratio ``own_tr``; gear 1 (gear 2's model) over SR 0.60-0.95:
    TR = 1 + 2 (GAMMA - SR) below GAMMA, 1 above, its turbine torque ``offset`` high."""
    sr2 = np.linspace(0.90, 0.95, 20)
    sr1 = np.linspace(0.60, 0.95, 71)
    t_p2, t_p1 = np.full(sr2.size, 80.0), np.full(sr1.size, 35.0)
    tr1 = 1.0 + 2.0 * np.clip(GAMMA - sr1, 0.0, None)
    sr, t_p = np.r_[sr2, sr1], np.r_[t_p2, t_p1]
    t_t = np.r_[own_tr * t_p2, tr1 * t_p1 + offset]
    w_p = np.full(sr.size, 100.0)
    gear = np.r_[np.full(sr2.size, 2), np.ones(sr1.size, dtype=int)]
    z = np.zeros(sr.size)
    return ConverterPoints(z, w_p, sr * w_p, t_p, t_t, z, gear, z, [], 0, 1.0, float("nan"), 0, borrowed={1: 2})


def test_offset_of_a_borrowed_gear_from_its_coupling_points() -> None:
    # gear 1's coupling points (SR >= 0.88) read its turbine torque exactly 8 Nm high: that is the offset, also when
    # the start is taken where the difference turns flat; the converter-mode points (8 + up to 19 Nm) are not used
    pts = _points(1.0, 8.0)
    for start in (False, True):
        off, why = borrowed_gear_offsets(pts, GAMMA, 0.0, 1.0, 10, start=start)
        assert not why and set(off) == {1}
        assert abs(off[1][0] - 8.0) < 1e-9 and off[1][2] == 15


def test_no_offset_without_the_coupling_mode_in_the_gears_with_their_own_model() -> None:
    # gear 2's torque ratio 1.10: no coupling mode seen to anchor gear 1's, which is left as it is, said why
    off, why = borrowed_gear_offsets(_points(1.10, 8.0), GAMMA, 0.0, 1.0, 10, start=True)
    assert off == {} and set(why) == {1} and "too little excitation" in why[1]


def test_too_few_coupling_points_of_the_borrowed_gear_are_said() -> None:
    # above SR 0.94 gear 1 has 3 points, fewer than the 10 needed
    off, why = borrowed_gear_offsets(_points(1.0, 8.0), 0.94, 0.0, 1.0, 10)
    assert off == {} and "coupling-mode points" in why[1]
