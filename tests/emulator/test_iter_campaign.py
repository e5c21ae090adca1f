"""The plant test by test: iter_campaign's chunks put end to end are simulate_campaign's Trace bit for bit."""

from __future__ import annotations

import numpy as np

from benchtwin.config import load_campaign, load_vehicle
from benchtwin.emulator import iter_campaign, simulate_campaign
from benchtwin.trace import TRACE_CHANNELS


def test_chunks_end_to_end_equal_the_whole_campaign() -> None:
    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    whole = simulate_campaign(vehicle, campaign)
    chunks = list(iter_campaign(vehicle, campaign))
    assert len(chunks) == len(campaign.tests) == len(whole.segments)
    np.testing.assert_array_equal(np.concatenate([c.time_s for c in chunks]), whole.time_s)
    for name in TRACE_CHANNELS:  # thermal lumps included: their state runs on across the chunks
        np.testing.assert_array_equal(np.concatenate([c[name] for c in chunks]), whole[name], err_msg=name)
    assert [s for c in chunks for s in c.segments] == whole.segments
    for c, seg in zip(chunks, whole.segments):  # each chunk covers its test
        assert c.time_s[0] >= seg.start_s - 1e-9 and c.time_s[-1] <= seg.end_s + 1e-9
    assert chunks[-1].meta == whole.meta  # the ledger to the campaign's end
    assert chunks[0].meta["energy_ledger_j"] != whole.meta["energy_ledger_j"]


def test_commands_are_built_per_test_on_demand_equal_to_the_whole_protocol() -> None:
    from benchtwin.emulator.protocols import build_protocol, lazy_protocol

    campaign = load_campaign("quick.toml")
    whole, lazy = build_protocol(campaign), lazy_protocol(campaign)
    assert lazy.blocks == [] and lazy.segments == whole.segments and lazy.steps == whole.steps
    for k, block in enumerate(whole.blocks):
        np.testing.assert_array_equal(lazy.block(k), block)


def test_a_campaign_longer_than_one_trace_runs_test_by_test(monkeypatch) -> None:
    import pytest

    from benchtwin.emulator import protocols
    from benchtwin.errors import ConfigError

    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    steps = protocols.protocol_steps(campaign)
    monkeypatch.setattr(protocols, "MAX_PLANT_SAMPLES", max(steps))  # every test fits, the campaign does not
    with pytest.raises(ConfigError, match="the limit is"):
        simulate_campaign(vehicle, campaign)
    first = next(iter_campaign(vehicle, campaign))
    assert first.segments[0].name == campaign.tests[0].name
    monkeypatch.setattr(protocols, "MAX_PLANT_SAMPLES", max(steps) - 1)  # now the longest test does not fit
    k = steps.index(max(steps))
    with pytest.raises(ConfigError, match=rf"tests\[{k}\] .* the limit for one test is"):
        next(iter_campaign(vehicle, campaign))


def test_repeat_and_tests_from_expand_a_campaign(tmp_path) -> None:
    import pytest

    from benchtwin.errors import ConfigError

    quick = load_campaign("quick.toml")
    path = tmp_path / "endurance.toml"
    path.write_text('name = "endurance"\nseed = 3\ntests_from = "quick.toml"\nrepeat = 3\n', encoding="utf-8")
    c = load_campaign(path)
    n = len(quick.tests)
    assert len(c.tests) == 3 * n and c.repeat == 1 and c.seed == 3
    assert [t.name for t in c.tests[:n]] == [t.name for t in quick.tests]
    assert [t.name for t in c.tests[2 * n:]] == [f"{t.name}_r3" for t in quick.tests]
    assert [t.model_dump(exclude={"name"}) for t in c.tests[n:2 * n]] == [t.model_dump(exclude={"name"})
                                                                          for t in quick.tests]
    shipped = load_campaign("paper_x10.toml")
    assert len(shipped.tests) == 10 * len(load_campaign("paper.toml").tests)
    for text, msg in (('tests_from = "quick.toml"\n[[tests]]\nkind = "coastdown"\n', "either 'tests' or"),
                      ('tests_from = "nowhere.toml"\n', "no shipped scenario file"),
                      ('tests_from = "sub/nowhere.toml"\n', "no campaign file"),
                      ('tests_from = "c.toml"\n', "names the file itself"),
                      ('tests_from = 3\n', "must be a campaign file name")):
        bad = tmp_path / "c.toml"
        bad.write_text('name = "c"\nseed = 1\n' + text, encoding="utf-8")
        with pytest.raises(ConfigError, match=msg) as exc:
            load_campaign(bad)
        assert "\n" not in str(exc.value)
