"""The converter plan's shared shaft-torque draws (studies/plan_converter_draws.py).

On a bench the transmission table eq. 32 goes through is fitted to window means of the same shaft-torque
readings the turbine-torque calibration then divides the motor torque by; the draws must carry that: a reading's
error that raises a gear's windows raises its ``eta_m``; and the turbine-torque calibration's samples must take the
error of the readings the identification's grid interpolates, on the telemetry's clock map. Quick campaign, paper
bench. Time: about 20 s.
"""

from __future__ import annotations

import numpy as np

from benchtwin.config import load_campaign, load_setup, load_vehicle, scenario_path
from benchtwin.emulator.cache import cached_campaign
from benchtwin.identification._clock import source_shifts, to_ref
from benchtwin.identification.transmission import transmission_points
from benchtwin.identification.transmission_eq14 import direction_points
from benchtwin.recording import Channel, Recording
from benchtwin.studies.plan import planned_recording
from benchtwin.studies.plan_converter import CONVERTER_RECORDED, MAPPED_SETS
from benchtwin.studies.plan_converter_draws import shared_shaft_draws
from benchtwin.studies.plan_fits import plan_transmission
from benchtwin.studies.plan_noise import ChannelNoise, noise_budget


def test_drawn_table_moves_with_the_readings_of_its_windows() -> None:
    vehicle, setup = load_vehicle(), load_setup(scenario_path("setups", "paper.toml"))
    campaign = load_campaign("quick.toml")
    trace, _ = cached_campaign(vehicle, campaign)
    _t, noise = noise_budget(setup)
    rec, raw = planned_recording(setup, campaign, trace, ["torque_converter"], recorded=CONVERTER_RECORDED)
    tx = {p.name: p for p in plan_transmission(rec, vehicle, noise, list(trace.segments), recorded=raw)}
    specs = vehicle.specs
    ratios = np.asarray(specs.gear_ratios, dtype=float)
    tp = transmission_points(rec, specs)
    table, wins = {}, {}
    for g in range(1, ratios.size + 1):
        eta, c0 = tx.get(f"transmission.gear{g}.eta_m"), tx.get(f"transmission.gear{g}.C0")
        if eta is None or not (eta.identifiable and c0.identifiable):
            continue
        table[g] = (eta.value, c0.value, eta.se, c0.se)
        m, dom, _c, _e = direction_points(tp, g, "drive", ratios[g - 1])
        wins[g] = np.flatnonzero(m)[dom]
    assert table, "the quick campaign has no drive fit"
    cn = noise["shaft_torque_nm"]
    # the value each reading is quantised at: the truth with the sensor's gain and offset (as the plan reads it)
    view = Recording(segments=list(rec.segments), meta=rec.meta)
    for name, ch in rec.channels.items():
        view.add(ch if name != "shaft_torque_nm" else Channel(name, ch.unit, ch.timestamps, (1.0 + cn.gain)
                                                              * ch.values + cn.offset, ch.flags, ch.source))
    ts = view["shaft_torque_nm"].timestamps
    # every reading inside each window: the mean of their drawn errors is the window mean's error
    keys = [(g, j) for g in sorted(table) for j in wins[g]]
    times = [ts[(ts >= tp.windows.windows[j].start_s) & (ts < tp.windows.windows[j].end_s)] for _g, j in keys]
    draw = shared_shaft_draws(view, specs, ChannelNoise(cn.sigma, cn.q), times, table)
    assert draw is not None
    rng = np.random.default_rng(7)
    n = 400
    d_tab = np.zeros((n, len(table), 2))
    e_win = np.zeros((n, len(keys)))
    for i in range(n):
        sd = draw(rng)
        d_tab[i] = [sd.table[g] for g in sorted(table)]
        e_win[i] = [float(np.mean(e)) for e in sd.grid]
    for k, g in enumerate(sorted(table)):
        # the drawn table carries the planned variance (400 draws: the std known to 3.5 %)
        assert abs(np.std(d_tab[:, k, 0], ddof=1) / table[g][2] - 1.0) < 0.15, (g, np.std(d_tab[:, k, 0]), table[g][2])
        assert abs(np.std(d_tab[:, k, 1], ddof=1) / table[g][3] - 1.0) < 0.15, (g, np.std(d_tab[:, k, 1]), table[g][3])
        # eq. 32's turbine torque at the gear's windows, T_out / (i_g eta_m) + C0, against the input torque: the
        # fit passes through its windows, so the table's error takes back part of the readings' (with k windows
        # and 2 unknowns about 2/k of it); drawn independently the two variances add
        eta, c0 = table[g][:2]
        sel = [i for i, key in enumerate(keys) if key[0] == g]
        c_in = tp.c_in[[keys[i][1] for i in sel]]
        reading = e_win[:, sel] / (ratios[g - 1] * eta)
        model = -(c_in - c0) / eta * d_tab[:, k, :1] + d_tab[:, k, 1:]
        together = float(np.sum(np.var(reading + model, axis=0)))
        apart = float(np.sum(np.var(reading, axis=0) + np.var(model, axis=0)))
        assert together < 0.8 * apart, (g, len(sel), together / apart)


def test_calibration_samples_take_the_readings_on_the_clock_map() -> None:
    """A drawn reading at a reading's time on the reference clock is a quantised reading, for the calibration's set.

    The identification's grid puts the telemetry's readings on the clock map before it interpolates them, so a
    calibration sample at a reading's mapped time holds that reading's noise-free value; its drawn error must be
    that reading's, and noise-free value plus error is then on the shaft torque's quantisation steps. Taken on the
    readings' own timestamps (the converter's points, ``mapped`` False), the same time falls between readings a few
    steps away (the quick campaign's clock map moves the telemetry by several reading periods) and the sum is off
    the steps. Mutant: the calibration's set read on the own timestamps (``MAPPED_SETS`` second entry False, or
    ``shared_shaft_draws`` ignoring ``mapped``) fails the first assertion.
    """
    assert MAPPED_SETS == (False, True), "the converter's points on their own clock, the calibration mapped"
    vehicle, setup = load_vehicle(), load_setup(scenario_path("setups", "paper.toml"))
    campaign = load_campaign("quick.toml")
    trace, _ = cached_campaign(vehicle, campaign)
    _t, noise = noise_budget(setup)
    rec, _raw = planned_recording(setup, campaign, trace, ["torque_converter"], recorded=CONVERTER_RECORDED)
    cn = noise["shaft_torque_nm"]
    assert cn.q > 0 and cn.sigma > 0
    shaft = rec["shaft_torque_nm"]
    ts = shaft.timestamps
    on_ref = np.asarray(to_ref(ts[::50], source_shifts(rec).get(shaft.source, 0.0)), dtype=float)
    step = float(np.median(np.diff(ts)))
    assert np.max(np.abs(on_ref - ts[::50])) > 2 * step, "no telemetry clock shift to map on this campaign"
    # the same times, once as the converter's points take them and once as the calibration's samples
    draw = shared_shaft_draws(rec, vehicle.specs, ChannelNoise(cn.sigma, cn.q), [on_ref, on_ref], {},
                              mapped=MAPPED_SETS)
    assert draw is not None
    rng = np.random.default_rng(3)
    for _ in range(3):
        sd = draw(rng)
        cal = (shaft.values[::50] + sd.grid[1]) / cn.q
        assert np.max(np.abs(cal - np.rint(cal))) < 1e-6, "a calibration sample took another reading's error"
        pts = (shaft.values[::50] + sd.grid[0]) / cn.q
        # off the steps wherever the readings a few steps away have another noise-free value (40 % of these
        # times: the rest sit in steady holds, where the neighbours read the same level)
        assert np.mean(np.abs(pts - np.rint(pts)) > 1e-3) > 0.1, "the points' set read on the clock map too"
