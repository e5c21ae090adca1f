"""Vehicle and campaign files: shipped files load, bad files give one clear line naming file, key and fix."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from benchtwin.cli import main
from benchtwin.config import load_campaign, load_vehicle, scenario_path
from benchtwin.config.campaign import CampaignConfig
from benchtwin.config.specs import VehicleSpecs
from benchtwin.errors import ConfigError


def _write_modified(tmp_path: Path, edit) -> Path:
    text = scenario_path("vehicles", "p2_phev_9at.toml").read_text(encoding="utf-8")
    text = edit(text)
    path = tmp_path / "vehicle.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_shipped_vehicles_load_with_paper_values_and_public_specs() -> None:
    v = load_vehicle()
    assert v.specs.gear_ratios == [5.36, 3.25, 2.26, 1.64, 1.22, 1.00, 0.87, 0.72, 0.61]
    assert v.specs.final_drive_ratio == 2.65 and v.specs.test_mass_kg == 2162.0
    assert (v.road_load.f0_n, v.road_load.f1_n_per_kmh, v.road_load.f2_n_per_kmh2) == (171.5, 0.833, 0.0280)
    assert isinstance(v.specs, VehicleSpecs)
    raw = tomllib.loads(scenario_path("vehicles", "p2_phev_9at.toml").read_text(encoding="utf-8"))
    assert set(raw["specs"]) == set(VehicleSpecs.model_fields)  # exactly the public fields
    br = v.brakes
    assert br.gain_front_nm_per_bar / (br.gain_front_nm_per_bar + br.gain_rear_nm_per_bar) == pytest.approx(0.66,
                                                                                                             abs=1e-4)
    alt = load_vehicle(scenario_path("vehicles", "p2_phev_alt.toml"))
    for a, b in [(alt.specs.gear_ratios, v.specs.gear_ratios), (alt.transmission.eta_m, v.transmission.eta_m),
                 (alt.motor.willans_e, v.motor.willans_e), (alt.battery.alpha, v.battery.alpha),
                 (alt.torque_converter.a_nm_per_radps2, v.torque_converter.a_nm_per_radps2),
                 (alt.shift_schedule.up_v0_kmh, v.shift_schedule.up_v0_kmh),
                 (alt.specs.n_cells_series, v.specs.n_cells_series), (alt.road_load.f0_n, v.road_load.f0_n),
                 (alt.engine.bsfc_g_per_kwh, v.engine.bsfc_g_per_kwh)]:
        assert a != b


@pytest.mark.parametrize("name", ["paper.toml", "quick.toml", "wltc.toml"])
def test_shipped_campaigns_load(name: str) -> None:
    c = load_campaign(name)
    assert isinstance(c, CampaignConfig) and c.plant_rate_hz == 100.0 and c.tests


def test_missing_key_is_one_line(tmp_path: Path) -> None:
    path = _write_modified(tmp_path, lambda t: t.replace("f0_n = 171.5\n", ""))
    with pytest.raises(ConfigError) as exc:
        load_vehicle(path)
    msg = str(exc.value)
    assert "\n" not in msg
    assert str(path) in msg and "missing key 'road_load.f0_n'" in msg


def test_wrong_unit_is_an_unknown_key_with_did_you_mean(tmp_path: Path) -> None:
    path = _write_modified(tmp_path, lambda t: t.replace("f1_n_per_kmh = 0.833", "f1_n_per_mps = 3.0"))
    with pytest.raises(ConfigError) as exc:
        load_vehicle(path)
    lines = str(exc.value).splitlines()
    unknown = [ln for ln in lines if "unknown key" in ln]
    assert len(unknown) == 1
    assert str(path) in unknown[0] and "'road_load.f1_n_per_mps'" in unknown[0]
    assert "did you mean 'f1_n_per_kmh'" in unknown[0]


def test_negative_mass_is_one_line_naming_key_and_value(tmp_path: Path) -> None:
    path = _write_modified(tmp_path, lambda t: t.replace("test_mass_kg = 2162.0", "test_mass_kg = -2162.0"))
    with pytest.raises(ConfigError) as exc:
        load_vehicle(path)
    msg = str(exc.value)
    assert "\n" not in msg
    assert "'specs.test_mass_kg' = -2162.0" in msg and "greater than 0" in msg


def test_inconsistent_vehicle_is_rejected(tmp_path: Path) -> None:
    path = _write_modified(tmp_path, lambda t: t.replace("eta_m = [0.955, ", "eta_m = ["))
    with pytest.raises(ConfigError, match="one value per gear"):
        load_vehicle(path)
    path = _write_modified(tmp_path, lambda t: t.replace("down_v0_kmh = [6.0,", "down_v0_kmh = [16.0,"))
    with pytest.raises(ConfigError, match="below its upshift line"):
        load_vehicle(path)


def test_campaign_errors(tmp_path: Path) -> None:
    bad = tmp_path / "c.toml"
    bad.write_text('name = "x"\nseed = 1\n[[tests]]\nkind = "ramp_up"\ngear = 3\nspeed_mps = 20.0\n'
                   'pedal_steps_pct = [10.0]\n', encoding="utf-8")
    with pytest.raises(ConfigError) as exc:
        load_campaign(bad)
    msg = str(exc.value)
    assert "speed_mps" in msg and "speed_kmh" in msg and str(bad) in msg
    bad.write_text('name = "x"\nseed = 1\n[[tests]]\nkind = "warp"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match="kind"):
        load_campaign(bad)
    bad.write_text('name = "x"\nseed = 1\nplant_rate_hz = 100.0\noutput_rate_hz = 3.0\n[[tests]]\nkind = "cycle"\n',
                   encoding="utf-8")
    with pytest.raises(ConfigError, match="divide"):
        load_campaign(bad)


def test_cli_simulate_writes_trace_and_reports_bad_files_in_one_line(tmp_path: Path, capsys) -> None:
    from benchtwin.trace import Trace

    camp = tmp_path / "c.toml"
    camp.write_text('name = "small"\nseed = 3\n[[tests]]\nkind = "deceleration"\nname = "d"\n'
                    'start_speed_kmh = 40.0\ndecel_mps2 = 2.0\n', encoding="utf-8")
    out = tmp_path / "out"
    assert main(["simulate", "--campaign", str(camp), "--out", str(out), "--no-progress"]) == 0
    back = Trace.load(out)
    assert back.segments[0].name == "d" and len(back) > 1000
    assert "energy balance residual" in capsys.readouterr().out
    assert main(["simulate", "--campaign", str(tmp_path / "nope.toml"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("benchtwin: error:") and "nope.toml" in err and "\n" not in err
