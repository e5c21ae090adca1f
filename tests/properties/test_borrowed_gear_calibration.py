"""A gear on a borrowed transmission model: its turbine-torque offset read at its own coupling point, not the fit's.

The pinned draw ``examples/converter_borrowed_gear_kink.json`` (9-speed diesel, noise 0, K_TEL 8000, seed 1479):
gear 1 runs on gear 2's eq. 14 model, its eq. 32 turbine torque 4.14 Nm high (measured against the plant's truth on
its points near the coupling point, SR 0.86-0.92: 4.13-4.18 Nm). Split at the converter fit's Gamma, the
calibration took converter-mode points as coupling points and a fixed point at +4.61 Nm, Gamma 0.886 for 0.906,
the TR curve 4.3 % off near the coupling point. Here the shaft torque is lined up with the plant's exactly: the
acquisition leaves it 3 ms late on this draw (the shaft torque against the truth, 200 s windows, branch tr8diesel),
which happened to offset the bias (1.86 % as acquired); lined up, the bias shows alone. A single example, about 5 s.
"""

from __future__ import annotations

import numpy as np
import pytest
from _tolerance import property_checks
from strategies import FAMILY_PICKS, campaign_for, pinned

import benchtwin.identification.torque_converter_points as tc_points
from benchtwin.emulator import simulate_campaign
from benchtwin.identification._clock import ClockShift
from benchtwin.identification.torque_converter import STALL_END_SR
from benchtwin.validation.families import FAMILIES
from benchtwin.validation.parameters import _tc_curves
from benchtwin.validation.run import validate

#: the shaft torque's residual lag on the pinned draw as acquired (s; measured against the truth, see above)
SHAFT_LATE_S = 0.003


def test_borrowed_gear_offset_from_its_own_kink_with_the_shaft_torque_lined_up(monkeypatch: pytest.MonkeyPatch
                                                                               ) -> None:
    vehicle, drawn, seed = pinned("converter_borrowed_gear_kink")
    orig = tc_points.roller_aligned_shifts

    def lined_up(rec, shifts, **kw):  # type: ignore[no-untyped-def]
        out, note = orig(rec, shifts, **kw)
        out = dict(out)
        s = out.get("telemetry", 0.0)
        out["telemetry"] = (ClockShift(s.offset_s + SHAFT_LATE_S, s.rate) if isinstance(s, ClockShift)
                            else s + SHAFT_LATE_S)
        return out, note

    monkeypatch.setattr(tc_points, "roller_aligned_shifts", lined_up)
    fam = FAMILIES["torque_converter"]
    campaign = campaign_for(vehicle, fam.kinds, seed=seed, **FAMILY_PICKS[fam.name])
    report = validate(vehicle, drawn.setup, campaign, trace=simulate_campaign(vehicle, campaign),
                      families=[fam.name], profile="realistic")
    conv = report.identification.fits["torque_converter.converter"]
    checks = {c.name: c for c in property_checks(report.identification, vehicle, drawn.setup, drawn.noise, None,
                                                 {fam.name})}
    # the offset against the truth's 4.14 Nm, within the telemetry's resolution floor (0.3 Nm: the shaft torque is
    # not read finer; the old split's +4.61 is 0.47 Nm off)
    off = conv.value("turbine_torque_offset_g1")
    assert abs(off - 4.14) < drawn.setup.telemetry.resolution_floor_nm, off
    assert checks["torque_converter.converter.gamma_coupling"].passed
    # the TR curve over the converter-mode span the offset acts on, measured from above the stall end to 0.98 Gamma
    # (the stall end below SR 0.3, extrapolated from points at SR 0.21 and up, is 2.3 % off also with the exact
    # offset: not this calibration), within the property's tolerance for this draw (noise 0: 1.875 %); the old split
    # read 2.7 % at SR 0.80 and 4.3 % near Gamma
    tol = checks["torque_converter.torque_ratio_curve"].tolerance
    a_true = list(vehicle.torque_converter.a_nm_per_radps2)
    a_id = [conv.value(f"a{i}") for i in range(6)]
    sr = np.linspace(STALL_END_SR, 0.98 * conv.value("gamma_coupling"), 50)
    rel = np.abs(_tc_curves(a_id, sr)[0] / _tc_curves(a_true, sr)[0] - 1.0)
    assert float(rel.max()) < tol, (float(rel.max()), float(sr[np.argmax(rel)]), tol)
