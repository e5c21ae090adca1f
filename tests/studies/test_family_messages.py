"""A family run's vehicle CAN sends only the messages whose roles the family reads, with the same draws."""

from __future__ import annotations

import json

import numpy as np
import pytest

import benchtwin.sensors.vehicle as vehicle_can
import benchtwin.validation.run as run
from benchtwin.config import load_campaign, load_vehicle, scenario_path
from benchtwin.config.setup import SetupConfig, load_setup
from benchtwin.emulator import simulate_campaign
from benchtwin.sensors.blocks import Block, block_rng
from benchtwin.trace import Trace
from benchtwin.validation.families import FAMILIES, family_setup

#: the vehicle-CAN messages and their roles (vehicle.dbc): the converter family reads none of these three
UNREAD_BY_CONVERTER = {"ENG_Fuel": {"fuel_mass_flow_gps"}, "PEDALS": {"pedal_pct", "brake_pedal_pct"},
                       "HYB_Status": {"hybrid_mode", "displayed_soc_pct"}}


def _paper() -> SetupConfig:
    return load_setup(scenario_path("setups", "paper.toml"))


def _faulty(setup: SetupConfig) -> SetupConfig:
    """The paper bench with a lossy vehicle CAN and noise on signals of sent and unsent messages alike: a message
    left out without its draws would shift the noise and the frame faults of the messages sent after it."""
    d = setup.model_dump()
    d["vehicle_can"]["link"].update(drop_prob=0.02, duplicate_prob=0.01, reorder_prob=0.01)
    d["vehicle_can"]["errors"].update({"fuel_mass_flow_gps": {"noise_std": 0.05}, "pedal_pct": {"noise_std": 0.5},
                                       "vehicle_speed_kmh": {"noise_std": 0.05}})
    return SetupConfig.model_validate(d)


def test_the_converter_bench_leaves_out_the_roles_it_does_not_read() -> None:
    bench = family_setup(_paper(), FAMILIES["torque_converter"].reads())
    assert set(bench.vehicle_can.not_recorded) == set().union(*UNREAD_BY_CONVERTER.values())
    ids = {c.name: c.frame_id for c in vehicle_can.message_codecs("vehicle")}
    assert vehicle_can.unsent_messages("vehicle", bench.vehicle_can) == {ids[m] for m in UNREAD_BY_CONVERTER}
    # a message with one read role is sent whole
    one_read = bench.vehicle_can.model_copy(update={"not_recorded": ["brake_pedal_pct", "hybrid_mode"]})
    assert vehicle_can.unsent_messages("vehicle", one_read) == frozenset()


def test_a_converter_run_encodes_no_unread_message(monkeypatch: pytest.MonkeyPatch) -> None:
    measured: set[str] = set()
    real = vehicle_can.measure

    def spy(*args: object, key: str = "", **kwargs: object) -> np.ndarray:
        measured.add(key.split(".")[0])
        return real(*args, key=key, **kwargs)

    monkeypatch.setattr(vehicle_can, "measure", spy)
    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    report = run.validate(vehicle, _paper(), campaign, families=["torque_converter"], profile="realistic",
                          chain_checks=False)
    # the dyno's two messages: the shaft torque's clock is lined up with its axle forces, after its own drift is
    # taken out on its roller speed (identification/shaft_clock.py)
    assert measured == {"ENG_Status", "EM_Status", "TCU_Status", "VEH_Speed", "DYNO_Force", "DYNO_Speed"}
    assert report.meta["chain_checks"].startswith("skipped")
    assert not [c for c in report.checks if c.group == "chain"]


def _trace(seconds: float = 130.0, rate_hz: float = 100.0) -> Trace:
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    rng = np.random.default_rng(1)
    names = {s.trace for s in vehicle_can.SIGNAL_MAP["vehicle"].values() if s.trace is not None}
    ch = {n: np.cumsum(rng.normal(0.0, 0.1, t.size)) + 20.0 for n in names}
    for n in ("engine_on", "gear_target", "gear_actual", "lockup_closed", "k0_closed", "hybrid_mode"):
        ch[n] = (t // 7 % 2).astype(float) + (n.startswith("gear"))
    return Trace(t, ch, [], {})


def test_unsent_messages_keep_the_sent_ones_draw_for_draw() -> None:
    # the sent messages' frames are the same bytes whether or not the others are sent (noise and frame faults drawn
    # from one generator per block, message after message)
    cfg = _faulty(_paper()).vehicle_can
    part = cfg.model_copy(update={"not_recorded": sorted(set().union(*UNREAD_BY_CONVERTER.values()))})
    unsent = vehicle_can.unsent_messages("vehicle", part)
    tr = _trace()
    for k in range(3):
        a, b = 60.0 * k, min(60.0 * (k + 1), float(tr.time_s[-1]) + 1e-9)
        whole = vehicle_can.encode_can_device(tr, "vehicle", cfg, None, (),  # type: ignore[arg-type]
                                              Block(tr, a, b, k, k == 2, block_rng(7, "vehicle_can", k), {}, 0, 0.01))
        sent = vehicle_can.encode_can_device(tr, "vehicle", part, None, (),  # type: ignore[arg-type]
                                             Block(tr, a, b, k, k == 2, block_rng(7, "vehicle_can", k), {}, 0, 0.01))
        assert not np.isin(sent["arbitration_id"], list(unsent)).any()
        kept = whole[~np.isin(whole["arbitration_id"], list(unsent))]
        assert len(kept) > 0.7 * len(whole)
        assert kept.tobytes() == sent.tobytes()


def test_the_converter_family_identifies_as_with_every_message_and_a_chunk_per_test(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # the fast family run (unread messages not sent, the chain fed 600-s chunks) against the run as it was (every
    # message, a chunk per test), on a lossy, noisy vehicle CAN: the same estimates, intervals and notes
    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    setup = _faulty(_paper())
    trace = simulate_campaign(vehicle, campaign)

    def ident() -> str:
        rep = run.validate(vehicle, setup, campaign, trace=trace, families=["torque_converter"], profile="realistic",
                           chain_checks=False)
        d = rep.identification.to_dict()
        d["meta"].pop("seconds")
        return json.dumps([d, [(c.name, c.identified, c.error) for c in rep.checks]], sort_keys=True, default=str)

    fast = ident()
    real_setup = run.family_setup

    def every_message(s: SetupConfig, roles: object) -> SetupConfig:
        bench = real_setup(s, roles)  # type: ignore[arg-type]
        return bench.model_copy(update={"vehicle_can": bench.vehicle_can.model_copy(update={"not_recorded": []})})

    monkeypatch.setattr(run, "family_setup", every_message)
    monkeypatch.setattr(run, "FAMILY_CHUNK_S", None)
    assert '"transmission.gear' in fast and "torque_converter" in fast
    assert fast == ident()
