"""``benchtwin demo`` prints the WLTC summary table of the embedded default vehicle."""

from __future__ import annotations

import re

from benchtwin.cli import main


def test_demo_prints_summary_with_tracking_and_energy_balance(capsys) -> None:
    assert main(["demo"]) == 0
    out = capsys.readouterr().out
    rms = float(re.search(r"RMS speed error\s+([0-9.]+) km/h", out).group(1))
    dist = float(re.search(r"distance\s+([0-9.]+) km", out).group(1))
    resid = float(re.search(r"energy balance residual\s+\S+ kJ \(([-0-9.]+) %\)", out).group(1))
    assert rms < 1.0 and abs(dist - 23.266) < 0.12 and abs(resid) < 0.5
    for key in ("fuel", "HV battery energy", "displayed SOC start -> end"):
        assert key in out
