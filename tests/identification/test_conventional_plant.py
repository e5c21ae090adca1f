"""A conventional car's emulated log (the conventional-layout plant, not the P2 plant driven as one) through
``benchtwin validate`` and ``benchtwin identify``.

``validate --vehicle conventional_9at --campaign conventional_quick --setup ideal``: the shunts on the pack and the
HPCU and the motor's thermocouple places are dropped by the setup rule, the vehicle CAN does not send the
motor's and the pack's roles, and every check passes against the vehicle file's truth with the tolerances the P2
path derives for the same chain (validation.parameters: transmission drive lines per gear, engine BSFC, converter
curves, shift lines, road load, brakes); no motor, battery or coast check is made (no truth of the kind), and
the recording has no motor or pack channel. Then ``identify`` on that recording with the vehicle's public specs
(no pack or rotor keys): the same methods run and give the same estimates, the motor and battery are skipped
for the layout. About 35 s (20 minutes simulated).
"""

from __future__ import annotations

import json

import pytest

from benchtwin.cli import main
from benchtwin.config._base import scenario_path
from benchtwin.config.vehicle import load_vehicle
from benchtwin.recording import Recording


@pytest.fixture(scope="module")
def validated(tmp_path_factory):
    out = tmp_path_factory.mktemp("conventional")
    code = main(["validate", "--vehicle", "conventional_9at", "--campaign", "conventional_quick", "--setup", "ideal",
                 "--out", str(out / "val"), "--no-type-b"])
    return code, out


def test_validate_runs_a_conventional_car_and_every_check_passes(validated):
    code, out = validated
    report = json.loads((out / "val" / "validation.json").read_text(encoding="utf-8"))
    failed = [(c["name"], c["note"]) for c in report["checks"] if not c["passed"]]
    assert code == 0 and not failed, failed
    groups = {c["group"] for c in report["checks"]}
    assert groups == {"chain", "transmission", "road_load", "brakes", "torque_converter", "shifts", "engine"}
    names = {c["name"] for c in report["checks"]}
    assert not any(n.startswith(("motor", "battery", "chain.battery", "chain.hpcu", "chain.em_")) for n in names)
    assert not any("_coast" in n for n in names)
    for must in ("transmission.gear1.eta_m", "transmission.gear7.C0", "engine.bsfc.bsfc_min", "engine.bsfc.map",
                 "torque_converter.torque_ratio_curve", "torque_converter.coupling_cf_curve", "shifts.up_1_2",
                 "shifts.down_9_8", "road_load.F2", "brakes.front.m_f"):
        assert must in names, must
    meta = report["meta"]
    assert meta["layout"] == "conventional"
    assert any(d.startswith("ivt.battery") for d in meta["dropped_devices"])
    assert any(n.startswith("no prediction") for n in report["prediction"]["notes"])


def test_identify_on_the_conventional_recording_needs_no_pack_or_motor_keys(validated, tmp_path):
    _code, out = validated
    vehicle = load_vehicle(scenario_path("vehicles", "conventional_9at.toml"))
    spec_file = tmp_path / "specs.toml"
    spec_file.write_text("\n".join(f"{k} = {json.dumps(v)}" for k, v in
                                   vehicle.specs.model_dump(exclude_none=True).items()), encoding="utf-8")
    assert "n_cells_series" not in spec_file.read_text(encoding="utf-8")
    rec_path = out / "val" / "recording.mf4"
    assert main(["identify", str(rec_path), "--specs", str(spec_file), "--out", str(tmp_path / "id"),
                 "--no-figures"]) == 0
    params = json.loads((tmp_path / "id" / "params.json").read_text(encoding="utf-8"))
    assert {"motor", "battery"} <= set(params["meta"]["skipped"])
    assert {"transmission", "engine", "torque_converter", "shifts", "road_load", "brakes"} <= set(
        params["meta"]["ran"])
    rec = Recording.load(rec_path)
    assert not any(r.startswith(("battery_", "hpcu_", "em_")) or r in ("k0_closed", "displayed_soc_pct")
                   for r in rec.channels)
    # the same recording and specs: the estimates validate judged against the truth come back from the command
    judged = json.loads((out / "val" / "params.json").read_text(encoding="utf-8"))["fits"]
    fits = params["fits"]
    assert set(fits) == set(judged)
    for key, fit in judged.items():
        for name, p in fit["params"].items():
            assert fits[key]["params"][name]["value"] == pytest.approx(p["value"], rel=1e-9, nan_ok=True), (key, name)
