"""A thermo module's inputs left open on a family run's bench (``[thermo] not_recorded``)."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from benchtwin.config import load_setup, scenario_path
from benchtwin.config.setup import ThermoConfig
from benchtwin.sensors import devices
from benchtwin.sensors.synthetic import synthetic_trace
from benchtwin.sensors.thermocouple import encode_thermo
from benchtwin.validation.families import FAMILIES, family_setup
from benchtwin.wire.canopen_pdo import AI_OVERLOAD_NEG

PAPER = load_setup(scenario_path("setups", "paper.toml"))


def test_the_read_inputs_draw_as_on_the_whole_module() -> None:
    # the paper module's probes are noisy (0.05 degC), drawn input by input from one generator: the inputs left
    # open must still take their draws, or every later input reads other noise (a mutant that skips the draws
    # moves gearbox_oil_degc, the 10th input, by about the noise)
    cfg = PAPER.thermo
    assert cfg is not None and cfg.errors.noise_std > 0 and cfg.places[-1] == "gearbox_oil_degc"
    trace = synthetic_trace(30.0)
    whole = encode_thermo(trace, cfg, np.random.default_rng(7))
    kept = ["engine_coolant_out_degc", "gearbox_oil_degc"]
    part = encode_thermo(trace, cfg.model_copy(update={"not_recorded": [p for p in cfg.places if p not in kept]}),
                         np.random.default_rng(7))
    assert np.array_equal(whole.times, part.times) and whole.entries == part.entries
    for k, place in enumerate(cfg.places):
        col = whole.entries.index((0x9130, k + 1))
        if place in kept:
            assert np.array_equal(part.values[:, col], whole.values[:, col]), place
        else:
            assert np.all(part.values[:, col] == AI_OVERLOAD_NEG), place  # open: nothing converted


def test_a_family_bench_records_only_the_places_it_reads() -> None:
    # the transmission's drag reads the gearbox oil alone of the ten places; the module stays on the bench
    bench = family_setup(PAPER, FAMILIES["transmission"].reads())
    thermo = [d for d in devices(bench) if d.section == "thermo"]
    assert len(thermo) == 1 and set(thermo[0].truth_channels()) == {"gearbox_oil_degc"}
    assert set(bench.thermo.not_recorded) == set(PAPER.thermo.places) - {"gearbox_oil_degc"}
    assert set(thermo[0].error_budget()) == {"gearbox_oil_degc"}
    # the whole bench records every place
    whole = next(d for d in devices(PAPER) if d.section == "thermo")
    assert set(whole.truth_channels()) == set(PAPER.thermo.places)


def test_not_recorded_names_places_of_the_module() -> None:
    with pytest.raises(ValidationError, match="not_recorded"):
        ThermoConfig(places=["gearbox_oil_degc"], not_recorded=["engine_coolant_in_degc"])
