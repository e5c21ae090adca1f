"""Signal maps and the CSV/MF4 importers: units, signs, delimiters, and the errors they name."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchtwin.config._base import scenario_path
from benchtwin.errors import ConfigError, MissingChannelError
from benchtwin.identification.importers import import_log, read_csv_table
from benchtwin.identification.signal_map import convert_units, load_signal_map, signal_map_from_dict
from benchtwin.recording import Recording

MAP = {
    "source": {"time_column": "Time", "time_unit": "ms"},
    "channels": {
        "vehicle_speed_kmh": {"column": "Speed", "unit": "mph"},
        "em_speed_rpm": {"column": "MotorW", "unit": "rad/s"},
        "battery_power_w": {"column": "Pbat", "unit": "kW"},
        "battery_current_a": {"column": "Ibat", "unit": "A", "scale": -1.0},
        "battery_temp_degc": {"column": "Tbat", "unit": "degF"},
        "brake_pressure_fl_bar": {"column": "pFL", "unit": "kPa", "offset": -0.5},
    },
}


def _write(path: Path, delimiter: str, preamble: str = "") -> Path:
    rows = ["Time,Speed,MotorW,Pbat,Ibat,Tbat,pFL,Unused".replace(",", delimiter)]
    for k in range(5):
        rows.append(delimiter.join(str(x) for x in (100 * k, 10 * k, 100.0 + k, 2.0 * k, 5.0 - k, 212.0, 300.0,
                                                      "n/a")))
    path.write_text(preamble + "\n".join(rows) + "\n", encoding="utf-8")
    return path


@pytest.mark.parametrize("delimiter", [",", "\t", ";"])
def test_csv_import_converts_units_signs_and_time(tmp_path, delimiter):
    path = _write(tmp_path / "log.csv", delimiter, preamble="# logger v1.2\n# car 42\n")
    rec = import_log(path, signal_map_from_dict(MAP))
    assert isinstance(rec, Recording)
    np.testing.assert_allclose(rec["vehicle_speed_kmh"].timestamps, [0.0, 0.1, 0.2, 0.3, 0.4])
    np.testing.assert_allclose(rec["vehicle_speed_kmh"].values[1], 10 * 1.609344, rtol=1e-9)
    np.testing.assert_allclose(rec["em_speed_rpm"].values[0], 100.0 * 60 / (2 * np.pi), rtol=1e-12)
    np.testing.assert_allclose(rec["battery_power_w"].values[2], 4000.0)
    np.testing.assert_allclose(rec["battery_current_a"].values[:2], [-5.0, -4.0])
    np.testing.assert_allclose(rec["battery_temp_degc"].values[0], 100.0, atol=1e-9)
    np.testing.assert_allclose(rec["brake_pressure_fl_bar"].values[0], 3.0 - 0.5)
    assert rec["brake_pressure_fl_bar"].unit == "bar"
    assert "Unused" not in rec


def test_header_row_skips_lines(tmp_path):
    path = _write(tmp_path / "log.txt", ",", preamble="Logger XYZ export\nDate 2024-01-01\n")
    m = dict(MAP, source={**MAP["source"], "header_row": 2, "comment": ""})
    rec = import_log(path, signal_map_from_dict(m))
    assert len(rec["vehicle_speed_kmh"]) == 5


def test_unknown_unit_names_the_key():
    bad = {"channels": {"vehicle_speed_kmh": {"column": "v", "unit": "furlong/fortnight"}}}
    with pytest.raises(ConfigError, match=r"channels\.vehicle_speed_kmh\.unit.*unknown unit"):
        signal_map_from_dict(bad, "m.toml")


def test_incompatible_unit_and_unknown_role_are_config_errors():
    with pytest.raises(ConfigError, match="cannot be converted"):
        signal_map_from_dict({"channels": {"vehicle_speed_kmh": {"column": "v", "unit": "rpm"}}})
    with pytest.raises(ConfigError, match=r"channels\.car_speed.*unknown role"):
        signal_map_from_dict({"channels": {"car_speed": {"column": "v", "unit": "km/h"}}})
    with pytest.raises(ConfigError, match="unknown key"):
        signal_map_from_dict({"channels": {"vehicle_speed_kmh": {"column": "v", "unit": "km/h", "gain": 2}}})


def test_missing_column_is_missing_channel(tmp_path):
    path = _write(tmp_path / "log.csv", ",")
    m = {"source": {"time_column": "Time"}, "channels": {"pedal_pct": {"column": "Pedal", "unit": "%"}}}
    with pytest.raises(MissingChannelError, match="Pedal"):
        import_log(path, signal_map_from_dict(m))


def test_convert_units_round_trip():
    x = np.array([0.0, 36.0, 100.0])
    np.testing.assert_allclose(convert_units(convert_units(x, "degC", "degF"), "degF", "degC"), x, atol=1e-12)
    np.testing.assert_allclose(convert_units(x, "km/h", "m/s"), x / 3.6)
    np.testing.assert_allclose(convert_units([1.0], "bar", "psi"), [14.503773773], rtol=1e-9)


def test_mf4_import_with_units_from_file(tmp_path):
    from asammdf import MDF, Signal

    t = np.arange(0.0, 1.0, 0.1)
    mdf = MDF(version="4.10")
    mdf.append([Signal(t * 10, t, name="VehSpd", unit="mph"), Signal(np.full(t.size, 3.0), t, name="GearTgt")])
    mdf.append([Signal(np.full(5, 1.5), t[::2] + 0.05, name="TrqProp", unit="kNm")])
    path = tmp_path / "car.mf4"
    mdf.save(path, overwrite=True)
    mdf.close()
    smap = signal_map_from_dict({
        "source": {"format": "mf4"},
        "channels": {"vehicle_speed_kmh": {"column": "VehSpd"}, "gear_target": {"column": "GearTgt"},
                     "shaft_torque_nm": {"column": "TrqProp"}},
    })
    rec = import_log(path, smap)
    np.testing.assert_allclose(rec["vehicle_speed_kmh"].values, t * 10 * 1.609344, rtol=1e-9)
    np.testing.assert_allclose(rec["shaft_torque_nm"].values, 1500.0)
    np.testing.assert_allclose(rec["shaft_torque_nm"].timestamps, t[::2] + 0.05)
    assert rec["gear_target"].values[0] == 3.0


def test_shipped_signal_maps_load():
    for name in ("insight_hwy.toml", "leaf_cell_hppc.toml"):
        smap = load_signal_map(scenario_path("signal_maps", name))
        assert "battery_current_a" in smap.channels
        assert smap.battery is not None and smap.battery.capacity_ah


def test_template_map_imports_an_mf4_log_with_specs(tmp_path):
    from asammdf import MDF, Signal

    smap = load_signal_map(scenario_path("signal_maps", "example_vehicle_mf4.toml"))
    assert smap.specs is not None and len(smap.specs.gear_ratios) == 9
    t = np.arange(0.0, 2.0, 0.02)
    mdf = MDF(version="4.10")
    sigs = []
    for cm in smap.channels.values():
        sigs.append(Signal(np.full(t.size, 1000.0), t, name=cm.column, unit=cm.unit or ""))
    mdf.append(sigs)
    path = tmp_path / "drive.mf4"
    mdf.save(path, overwrite=True)
    mdf.close()
    rec = import_log(path, smap)
    assert set(rec.channels) == set(smap.channels)
    np.testing.assert_allclose(rec["battery_current_a"].values, 1.0)  # mA -> A
    np.testing.assert_allclose(rec["fuel_mass_flow_gps"].values, 1000.0 / 3.6)  # kg/h -> g/s
    np.testing.assert_allclose(rec["dyno_force_front_n"].values, 1e6)  # kN -> N
    np.testing.assert_allclose(rec["em_speed_rpm"].values, 1000.0 * 60 / (2 * np.pi))


def test_datetime_time_column(tmp_path):
    p = tmp_path / "logger.csv"
    p.write_text("Timestamp;Speed\n2024-05-03 14:02:07.000;10\n2024-05-03 14:02:07.250;11\n"
                 "2024-05-03T14:02:08.500;12\n", encoding="utf-8")
    m = {"source": {"time_column": "Timestamp", "delimiter": ";"},
         "channels": {"vehicle_speed_kmh": {"column": "Speed", "unit": "km/h"}}}
    rec = import_log(p, signal_map_from_dict(m))
    np.testing.assert_allclose(rec["vehicle_speed_kmh"].timestamps, [0.0, 0.25, 1.5])
    np.testing.assert_allclose(rec["vehicle_speed_kmh"].values, [10.0, 11.0, 12.0])


def test_read_csv_table_drops_text_columns(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("a,b,c\n1,x,3\n2,y,4\n", encoding="utf-8")
    tab = read_csv_table(p)
    assert set(tab) == {"a", "c"}
