"""Identification never marks a fit ``ok`` from garbage: corrupt cells, clocks that restart, too little data,
and intervals that would claim independent samples of a time series."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchtwin.config._base import scenario_path
from benchtwin.errors import DataError
from benchtwin.identification._fit import linear_fit, serial_inflation
from benchtwin.identification.battery_map_free import identify_battery_map_free
from benchtwin.identification.importers import import_log
from benchtwin.recording import Flag

INSIGHT = Path(__file__).resolve().parents[1] / "data" / "reference" / "advisor_insight_hev" / \
    "Hwy2x_Insight_test_data_69soc_hot.txt"
SMAP = scenario_path("signal_maps", "insight_hwy.toml")


def _insight_copy(tmp_path: Path, edit) -> Path:
    lines = INSIGHT.read_text(encoding="utf-8").splitlines()
    head = next(k for k, ln in enumerate(lines) if ln.split("\t")[0].strip() == "time_s")
    out = tmp_path / "insight.txt"
    out.write_text("\n".join(edit(lines, head)) + "\n", encoding="utf-8")
    return out


def test_a_corrupt_cell_is_flagged_and_does_not_reach_the_fit(tmp_path: Path) -> None:
    """One cell of 1e308 in the current: flagged OUT_OF_RANGE at import, the plain OCV/R fit is unchanged."""
    def corrupt(lines: list[str], head: int) -> list[str]:
        cols = lines[head].split("\t")
        k = head + 500
        cells = lines[k].split("\t")
        cells[cols.index("batt_amps")] = "1e308"
        return [*lines[:k], "\t".join(cells), *lines[k + 1:]]

    clean = import_log(INSIGHT, SMAP)
    dirty = import_log(_insight_copy(tmp_path, corrupt), SMAP)
    cur = dirty["battery_current_a"]
    assert int(np.count_nonzero(cur.flags & int(Flag.OUT_OF_RANGE))) == 1
    assert dirty.meta["implausible_samples"] == {"battery_current_a": 1}
    a = identify_battery_map_free(clean, capacity_ah=6.0)
    b = identify_battery_map_free(dirty, capacity_ah=6.0)
    for name, p in a.params.items():
        # one of ~15,000 samples left out: the estimate moves far less than its own standard error
        assert abs(b.value(name) - p.value) <= max(p.std_error, 1e-6 * abs(p.value)), name
        assert np.isfinite(b.value(name)) and abs(b.value(name)) < 1e3


def test_a_clock_that_restarts_is_refused_with_the_sample(tmp_path: Path) -> None:
    def restart(lines: list[str], head: int) -> list[str]:
        body = lines[head + 1:]
        return [*lines[:head + 1], *body[:2000], *body[:1000]]  # the first 100 s again after 200 s

    with pytest.raises(DataError, match=r"goes back .* at sample 2000"):
        import_log(_insight_copy(tmp_path, restart), SMAP)


def test_serial_inflation_of_an_ar1_series() -> None:
    rng = np.random.default_rng(1)
    e = np.zeros(20_000)
    for k in range(1, e.size):
        e[k] = 0.9 * e[k - 1] + rng.normal()
    rho, factor = serial_inflation(e)
    assert rho == pytest.approx(0.9, abs=0.02)
    assert factor == pytest.approx(1.9 / 0.1, rel=0.15)
    assert serial_inflation(rng.normal(size=20_000))[1] == pytest.approx(1.0, abs=0.05)


def test_serial_fit_intervals_cover_the_truth_on_correlated_noise() -> None:
    """A straight line through AR(1) noise: the serial intervals cover the truth about 95 % of the time, the
    independent-samples ones far less (what made short battery windows report intervals that miss)."""
    n, reps = 400, 200
    x = np.linspace(0.0, 1.0, n)
    A = np.column_stack([np.ones(n), x])
    hit_serial = hit_plain = 0
    rng = np.random.default_rng(7)
    for _ in range(reps):
        e = np.zeros(n)
        for k in range(1, n):
            e[k] = 0.95 * e[k - 1] + 0.1 * rng.normal()
        y = 2.0 + 0.5 * x + e
        for serial in (True, False):
            lo, hi = linear_fit(A, y, ["a", "b"], serial=serial)["b"].ci95
            if lo <= 0.5 <= hi:
                if serial:
                    hit_serial += 1
                else:
                    hit_plain += 1
    assert hit_serial / reps >= 0.85
    assert hit_plain / reps <= 0.5


def test_a_stuck_channel_is_not_identified_from(ramp_rec, specs) -> None:
    """A motor-torque channel frozen at one value over the whole log: the methods that need it are skipped with
    the reason, never fitted (an input-torque offset is indistinguishable from the transmission's C0)."""
    from benchtwin.identification.run import identify_all
    from benchtwin.recording import Channel, Recording

    rec = Recording(dict(ramp_rec.channels), list(ramp_rec.segments), dict(ramp_rec.meta))
    ch = rec["em_torque_nm"]
    rec.add(Channel(ch.name, ch.unit, ch.timestamps, np.full(len(ch), 150.0), ch.flags, ch.source))
    res = identify_all(rec, specs, methods=["transmission"])
    assert res.meta["stuck_channels"] == {"em_torque_nm": 150.0}
    assert "em_torque_nm holds 150" in res.meta["skipped"]["transmission"]
    assert not any(k.startswith("transmission") for k in res.fits)
    # the same recording with the real channel is fitted
    assert any(k.startswith("transmission") for k in identify_all(ramp_rec, specs, methods=["transmission"]).fits)
