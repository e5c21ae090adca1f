"""Where a coulomb-counted SOC is anchored (identification/soc_reference.py), on a simulated cell whose true SOC
is known: a static cell ``V = OCV(s) - I R`` with a linear OCV, 10 Ah, and a coulombic efficiency of 95 % on
charge (a recharge puts back more ampere-hours than it adds charge content: the ambiguous case of a log that
ends with a full recharge)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchtwin.cli import main
from benchtwin.errors import DataError
from benchtwin.identification.battery_map_free import identify_battery_ocv_rest
from benchtwin.identification.soc_reference import reference_soc
from benchtwin.recording import Channel, Recording

CAP_AH, R_OHM, ETA_CHARGE = 10.0, 0.01, 0.95


def _ocv(soc: np.ndarray) -> np.ndarray:
    return 3.4 + 0.8 * soc / 100.0


def _cell(start_soc: float, discharge_to: float, *, rests: bool = True) -> dict[str, np.ndarray]:
    """Rest, discharge at 20 A to ``discharge_to``, rest, charge at 10 A to 100 %, rest (1 s samples)."""
    rest = 600 if rests else 0
    n_dch = round((start_soc - discharge_to) / 100 * CAP_AH * 3600 / 20)
    n_ch = round((100 - discharge_to) / 100 * CAP_AH * 3600 / 10 / ETA_CHARGE)
    i = np.r_[np.zeros(rest), np.full(n_dch, 20.0), np.zeros(600), np.full(n_ch, -10.0), np.zeros(rest)]
    t = np.arange(i.size, dtype=float)
    # true charge content: discharge counts fully, charge at 95 %
    dq = np.where(i > 0, -i, -ETA_CHARGE * i) / 3600.0
    soc = np.minimum(start_soc + np.r_[0.0, np.cumsum(dq[:-1])] / CAP_AH * 100.0, 100.0)
    return {"t": t, "i": i, "v": _ocv(soc) - i * R_OHM, "soc": soc}


def _mid_rest_soc(c: dict[str, np.ndarray], soc: np.ndarray) -> tuple[float, float]:
    """(estimated, true) SOC at the end of the rest between discharge and charge."""
    k = int(np.flatnonzero(c["i"] < 0)[0]) - 1
    return float(soc[k]), float(c["soc"][k])


def test_a_full_start_and_a_closing_full_recharge_anchor_at_the_start():
    """Started full, 20 % out, 21 % of ampere-hours back: 100 % at the highest count would put every SOC 1.05 %
    low; both ends rest at the full OCV, so the start is 100 % and the mid-test SOC is exact (discharge is
    counted without loss; the only error is the sum over whole seconds, far below 0.01 %)."""
    c = _cell(100.0, 80.0)
    ref = reference_soc(c["t"], c["i"], CAP_AH, voltage_v=c["v"])
    assert ref.rule == "start_full_end_recharge" and not ref.ambiguous
    est, true = _mid_rest_soc(c, ref.soc_pct)
    assert est == pytest.approx(true, abs=0.01)
    assert np.max(ref.soc_pct) == pytest.approx(100.0)
    # without the voltage the data cannot decide: 100 % at the end, every SOC low by the charging loss,
    # 20 % x (1 / 0.95 - 1) = 1.05 %
    by_max = reference_soc(c["t"], c["i"], CAP_AH)
    assert by_max.ambiguous and by_max.rule == "max_charge"
    assert _mid_rest_soc(c, by_max.soc_pct)[0] == pytest.approx(true - 20 * (1 / ETA_CHARGE - 1), abs=0.05)


def test_a_partial_start_and_a_closing_full_recharge_anchor_at_the_end():
    """Started at 60 %: the end rests higher than the start, so the full point is the end (the rule of the highest
    charge content); the SOC is then exact at the end."""
    c = _cell(60.0, 40.0)
    ref = reference_soc(c["t"], c["i"], CAP_AH, voltage_v=c["v"])
    assert ref.rule == "max_charge" and "started below full" in ref.note
    assert ref.soc_pct[-1] == pytest.approx(100.0) and c["soc"][-1] == pytest.approx(100.0)
    assert ref.soc_pct[0] < 60.0  # the counted charging loss lands on the start, as the note's rule says


def test_a_declared_start_and_a_soc_channel_take_precedence():
    c = _cell(60.0, 40.0)
    ref = reference_soc(c["t"], c["i"], CAP_AH, voltage_v=c["v"], start_soc_pct=60.0)
    assert ref.rule == "declared_start"
    assert _mid_rest_soc(c, ref.soc_pct)[0] == pytest.approx(40.0, abs=0.01)
    assert reference_soc(c["t"], c["i"], CAP_AH, soc_channel_pct=c["soc"], start_soc_pct=60.0).rule == "channel"
    with pytest.raises(DataError, match=r"within 0\.\.100"):
        reference_soc(c["t"], c["i"], CAP_AH, start_soc_pct=120.0)


def test_without_rests_at_the_ends_the_reference_is_reported_ambiguous():
    c = _cell(100.0, 80.0, rests=False)
    ref = reference_soc(c["t"], c["i"], CAP_AH, voltage_v=c["v"])
    assert ref.ambiguous and "ambiguous" in ref.note


def test_ocv_from_rests_carries_the_rule():
    c = _cell(100.0, 80.0)
    rec = Recording()
    rec.add(Channel("battery_current_a", "A", c["t"], c["i"]))
    rec.add(Channel("battery_voltage_v", "V", c["t"], c["v"]))
    fit = identify_battery_ocv_rest(rec, capacity_ah=CAP_AH, min_rest_s=500.0)
    assert fit.data["soc_reference"]["rule"] == "start_full_end_recharge"
    # the OCV of each rest lands on the true OCV curve at its estimated SOC
    np.testing.assert_allclose(fit.data["ocv"], _ocv(fit.data["soc"]), atol=1e-4)


@pytest.mark.parametrize(("extra", "rule"), [([], "start_full_end_recharge"),
                                             (["--start-soc", "100"], "declared_start")])
def test_cli_reports_the_soc_reference(tmp_path, capsys, extra, rule):
    c = _cell(100.0, 80.0)
    log = tmp_path / "cell.csv"
    np.savetxt(log, np.column_stack([c["t"], c["v"], c["i"]]), delimiter=",", header="time_s,volts,amps",
               comments="", fmt="%.6f")
    smap = tmp_path / "map.toml"
    smap.write_text('[source]\ntime_column = "time_s"\n[channels.battery_voltage_v]\ncolumn = "volts"\n'
                    '[channels.battery_current_a]\ncolumn = "amps"\n'
                    "[battery]\ncapacity_ah = 10.0\nsoc_nodes_pct = [85.0, 95.0]\nmin_rest_s = 500.0\n",
                    encoding="utf-8")
    out = tmp_path / "out"
    assert main(["identify", str(log), "--signal-map", str(smap), "--out", str(out), "--no-figures", *extra]) == 0
    params = json.loads((out / "params.json").read_text(encoding="utf-8"))
    assert params["meta"]["soc_reference"]["rule"] == rule
    assert f"SOC reference: {rule}" in capsys.readouterr().out
