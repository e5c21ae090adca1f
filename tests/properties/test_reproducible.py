"""The same seed gives the same report, byte for byte (validation.json without its wall-clock timings:
``timings_s`` and the identification's ``meta.seconds``); another seed a different one.

Each run simulates afresh (no cache) and writes its own output directory, so nothing is shared between the
two runs but the inputs.
"""

from __future__ import annotations

import json
from pathlib import Path

from _profiles import profile
from hypothesis import given
from hypothesis import strategies as st
from strategies import DrawnSetup, campaign_for, seeds, setups, vehicles

from benchtwin.config.vehicle import VehicleConfig
from benchtwin.validation.run import validate


def _report_bytes(vehicle: VehicleConfig, drawn: DrawnSetup, family: str, seed: int, out: Path) -> bytes:
    kinds = {"brakes": ("neutral_braking",), "road_load": ("coastdown",)}[family]
    campaign = campaign_for(vehicle, kinds, seed=seed)
    validate(vehicle, drawn.setup, campaign, families=[family], profile="realistic", out_dir=out)
    doc = json.loads((out / "validation.json").read_text(encoding="utf-8"))
    doc.pop("timings_s")  # wall-clock timings: the run's and each identification method's
    doc["identification"]["meta"].pop("seconds")
    return json.dumps(doc, sort_keys=True).encode()


@profile(max_examples=2)
@given(vehicles(), setups().filter(lambda d: d.noise > 0.05), seeds, st.sampled_from(["brakes", "road_load"]),
       st.data())
def test_same_seed_same_report_other_seed_other_report(tmp_path_factory, vehicle: VehicleConfig,
                                                        drawn: DrawnSetup, seed: int, family: str,
                                                        data: st.DataObject) -> None:
    root = tmp_path_factory.mktemp("repro")
    a = _report_bytes(vehicle, drawn, family, seed, root / "a")
    b = _report_bytes(vehicle, drawn, family, seed, root / "b")
    assert a == b
    other = data.draw(seeds.filter(lambda s: s != seed), label="other seed")
    c = _report_bytes(vehicle, drawn, family, other, root / "c")
    assert c != a
