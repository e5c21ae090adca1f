"""``benchtwin gain --sweep --json``: the transmission validated at every K_TEL, as one JSON document."""

from __future__ import annotations

import json
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
