"""The shipped NEDC speed trace is the regulation's cycle (check values of nedc.SOURCE.txt, UN ECE R83/R101).

The expected values are the regulation's (durations, top speeds, theoretical distances), not read off the file;
each tolerance says what separates a 1 Hz sampled file from the regulation's table. Runs in well under a second.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.config._base import scenario_path
from benchtwin.emulator.protocols import load_cycle

#: UN ECE R83 Annex 4a: the elementary urban cycle (ECE-15) is 195 s, four of them, then the 400 s EUDC
ECE_S, EUDC_S = 195, 400
#: the regulation's theoretical distances (km) and top speeds (km/h)
ECE_KM, EUDC_KM = 1.013, 6.955
ECE_VMAX_KMH, EUDC_VMAX_KMH = 50.0, 120.0
#: the file's speeds are km/h steps converted to m/s with 6 significant digits (33.3334 m/s for 120 km/h)
SPEED_ROUNDING_KMH = 1e-3
#: the regulation's ramps and 2 s gear-change holds sampled at 1 Hz shift an urban cycle by a few metres
#: (one second at 15 km/h is 4.2 m, 0.4 % of 1.013 km); the EUDC's long ramps land on whole seconds
ECE_DIST_REL, EUDC_DIST_REL = 0.005, 0.001


@pytest.fixture(scope="module")
def nedc() -> tuple[np.ndarray, np.ndarray]:
    return load_cycle("nedc.csv")


def test_nedc_lasts_1180_s_at_1_hz_and_stops_at_both_ends(nedc) -> None:
    t, v = nedc
    assert len(t) == 4 * ECE_S + EUDC_S
    np.testing.assert_array_equal(t, np.arange(4 * ECE_S + EUDC_S, dtype=float))
    assert v[0] == 0.0 and v[-1] == 0.0 and np.all(v >= 0.0)


def test_nedc_four_identical_urban_cycles_to_50_kmh(nedc) -> None:
    t, v = nedc
    ece = v[:ECE_S]
    for k in range(1, 4):
        np.testing.assert_array_equal(v[k * ECE_S:(k + 1) * ECE_S], ece)
    assert abs(3.6 * ece.max() - ECE_VMAX_KMH) < SPEED_ROUNDING_KMH
    km = np.trapezoid(ece, t[:ECE_S]) / 1e3  # the cycle starts and ends at rest: the last interval is 0 m
    assert abs(km - ECE_KM) / ECE_KM < ECE_DIST_REL, km


def test_nedc_extra_urban_part_to_120_kmh_and_total_distance(nedc) -> None:
    t, v = nedc
    a = 4 * ECE_S
    eudc_km = np.trapezoid(v[a - 1:], t[a - 1:]) / 1e3  # from the last urban sample (at rest) on
    assert abs(eudc_km - EUDC_KM) / EUDC_KM < EUDC_DIST_REL, eudc_km
    assert abs(3.6 * v.max() - EUDC_VMAX_KMH) < SPEED_ROUNDING_KMH
    assert 3.6 * v[:a].max() < ECE_VMAX_KMH + SPEED_ROUNDING_KMH  # the 120 km/h is in the EUDC
    total = np.trapezoid(v, t) / 1e3
    want = 4 * ECE_KM + EUDC_KM
    assert abs(total - want) / want < ECE_DIST_REL, total


def test_every_shipped_cycle_has_its_source_beside_it() -> None:
    folder = scenario_path("cycles", "nedc.csv").parent
    for csv in folder.glob("*.csv"):
        src = csv.with_name(csv.stem + ".SOURCE.txt")
        assert src.is_file(), csv.name
        text = src.read_text(encoding="utf-8")
        assert "commit" in text and "Check values" in text, src.name
