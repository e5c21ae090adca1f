"""The Trace cache key and the family selection of validate()."""

from __future__ import annotations

import pytest

from benchtwin.config import load_campaign, load_vehicle
from benchtwin.emulator import cache
from benchtwin.errors import ConfigError
from benchtwin.segments import Segment
from benchtwin.validation.families import FAMILIES, family_spans, resolve_families


def test_the_key_follows_vehicle_campaign_seed_and_code(monkeypatch: pytest.MonkeyPatch) -> None:
    v, c = load_vehicle(), load_campaign("quick.toml")
    k = cache.trace_key(v, c)
    assert k == cache.trace_key(load_vehicle(), load_campaign("quick.toml"))
    assert k != cache.trace_key(v, c.model_copy(update={"seed": c.seed + 1}))
    assert k != cache.trace_key(v.model_copy(update={"name": "other"}), c)
    monkeypatch.setattr(cache, "code_version", lambda: "0.0.0+changed-plant")
    assert k != cache.trace_key(v, c)


def test_cache_dir_from_the_environment(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    monkeypatch.setenv("BENCHTWIN_CACHE", str(tmp_path))
    assert cache.cache_dir() == tmp_path
    monkeypatch.delenv("BENCHTWIN_CACHE")
    assert cache.cache_dir().parts[-3:] == (".cache", "benchtwin", "traces")


def test_family_spans_join_neighbouring_tests() -> None:
    segs = [Segment(0, 10, "ramp_up", "a"), Segment(10, 20, "ramp_up", "b"), Segment(20, 30, "coastdown", "c"),
            Segment(30, 40, "ramp_up", "d")]
    assert family_spans(segs, FAMILIES["transmission"].kinds) == [(0, 20), (30, 40)]
    assert family_spans(segs, FAMILIES["road_load"].kinds) == [(20, 30)]
    assert family_spans(segs, FAMILIES["battery"].kinds) == []


def test_unknown_family_names_the_allowed_ones() -> None:
    with pytest.raises(ConfigError, match="allowed: transmission, torque_converter"):
        resolve_families(["gearbox"])
    assert [f.name for f in resolve_families(["battery", "battery"])] == ["battery"]


def test_a_family_bench_delivers_what_the_whole_bench_delivers(monkeypatch: pytest.MonkeyPatch) -> None:
    # a family run keeps only the devices whose channels its methods read; each device draws from its own
    # stream, so identification must come out identical to a run on the whole bench (a role the family
    # reads but does not declare would change it: motor's DC/DC LV side, the brakes' dyno forces)
    import json

    import benchtwin.validation.run as run
    from benchtwin.config import scenario_path
    from benchtwin.config.setup import load_setup
    from benchtwin.emulator import simulate_campaign

    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    setup = load_setup(scenario_path("setups", "paper.toml"))
    trace = simulate_campaign(vehicle, campaign)

    def ident(family: str) -> tuple[str, list[str]]:
        rep = run.validate(vehicle, setup, campaign, trace=trace, families=[family], profile="realistic")
        d = rep.identification.to_dict()
        d["meta"].pop("seconds")
        # the whole-recording diagnostic of channels that never change names what the bench records: the whole
        # bench's engine torque sits at its ECU offset through the road-load family's coastdown, a channel the
        # family does not read (its bench does not send it); no fit reads it
        d["meta"].pop("stuck_channels", None)
        checks = [(c.name, c.passed, c.error) for c in rep.checks if c.group != "chain"]
        return json.dumps([d, checks], sort_keys=True, default=str), rep.meta["devices"]

    pruned = {f: ident(f) for f in FAMILIES}
    monkeypatch.setattr(run, "family_setup", lambda s, roles: s)
    for f in FAMILIES:
        whole, devices = ident(f)
        assert pruned[f][0] == whole, f"family {f}: the bench of {pruned[f][1]} identifies differently"
        assert len(pruned[f][1]) < len(devices)
