"""``benchtwin gain --sweep --json``: the transmission validated at every K_TEL, as one JSON document."""

from __future__ import annotations

import json
from itertools import pairwise
from pathlib import Path

import pytest

from benchtwin.cli import main
from benchtwin.config.setup import K_TEL_STEPS


def test_gain_sweep_json(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("BENCHTWIN_CACHE", str(tmp_path / "cache"))
    rc = main(["gain", "--campaign", "quick", "--sweep", "--json", "--workers", "0", "--out", str(tmp_path / "g")])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["recommended"] in K_TEL_STEPS and len(doc["options"]) == len(K_TEL_STEPS)
    errs = doc["transmission_errors"]
    assert sorted(int(k) for k in errs) == list(K_TEL_STEPS)
    # the gain the setup recommends identifies gear 5's efficiency within a few per cent
    assert abs(errs[str(doc["recommended"])]["transmission.gear5.eta_m"]) < 0.05
    assert (tmp_path / "g" / "runs.parquet").exists()


def test_gain_json_without_the_sweep(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
                                     tmp_path: Path) -> None:
    # Table 2 as JSON: K_TOT halves as K_TEL doubles, a gain clips exactly when its range is below the campaign's
    # peak, and the recommendation is the highest gain whose range covers the peak times the margin (1.8 here,
    # so that the margin, not the clipping, decides: the quick campaign's peak is ~1,300 Nm)
    monkeypatch.setenv("BENCHTWIN_CACHE", str(tmp_path / "cache"))
    assert main(["gain", "--campaign", "quick", "--json", "--margin", "1.8"]) == 0
    doc = json.loads(capsys.readouterr().out)
    opts = doc["options"]
    assert [o["k_tel"] for o in opts] == list(K_TEL_STEPS)
    for a, b in pairwise(opts):
        assert b["range_nm"] == pytest.approx(a["range_nm"] * a["k_tel"] / b["k_tel"], rel=1e-12)
    peak = doc["peak_shaft_torque_nm"]
    for o in opts:
        assert (o["clipped_frac"] > 0) == (o["range_nm"] < peak), o
    covering = [o["k_tel"] for o in opts if o["range_nm"] >= 1.8 * peak]
    assert doc["margin"] == 1.8 and doc["recommended"] == max(covering)
    assert any(o["range_nm"] >= peak and o["k_tel"] > doc["recommended"] for o in opts)  # the margin decided
