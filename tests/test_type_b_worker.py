"""The type B re-runs shared with a forked worker (benchtwin.validation.type_b_worker): the same params.json and
validation.json as in line wherever each re-run unit ran, a unit that fails in the worker raised by the parent, and a
worker that dies a clear error, never waited on."""

from __future__ import annotations

import json
import multiprocessing
import os
from pathlib import Path
from typing import Any

import pytest

import benchtwin.identification.uncertainty as unc
import benchtwin.validation.run as vrun
import benchtwin.validation.type_b_worker as tbw
from benchtwin.config import load_campaign, load_setup, load_vehicle
from benchtwin.errors import DataError
from benchtwin.validation.beside import SideStageError
from benchtwin.validation.type_b_worker import ForkedShare


def _without_seconds(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _without_seconds(v) for k, v in d.items() if k not in ("timings_s", "seconds")}
    if isinstance(d, list):
        return [_without_seconds(v) for v in d]
    return d


def _outputs(out: Path) -> str:
    """params.json and validation.json but for the seconds, as text (NaN-safe, order included)."""
    return repr([_without_seconds(json.loads((out / f).read_text(encoding="utf-8")))
                 for f in ("params.json", "validation.json")])


def _run(out: Path, full: bool = True) -> Any:
    campaign = load_campaign("quick.toml")
    if not full:
        campaign = campaign.model_copy(update={"tests": campaign.tests[:2]})
    return vrun.validate(load_vehicle(), load_setup("paper"), campaign, out_dir=out, figures=False)


def _counted(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The number of units the worker ran, per collect (the share was used once per run)."""
    ran: list[int] = []
    collect = ForkedShare.collect

    def counted(self: ForkedShare) -> dict[int, Any]:
        got = collect(self)
        ran.append(len(got))
        return got

    monkeypatch.setattr(ForkedShare, "collect", counted)
    return ran


@pytest.fixture(scope="module")
def inline(tmp_path_factory: pytest.TempPathFactory) -> str:
    out = tmp_path_factory.mktemp("inline")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(vrun, "SIDE_MODE", "off")
        mp.setattr(tbw, "TYPE_B_WORKER", False)
        ran = _counted(mp)
        report = _run(out)
    assert ran == []  # in line: no worker
    assert report.identification.meta["type_b"]["reruns"] > 0  # the type B re-runs are there to share
    return _outputs(out)


@pytest.mark.parametrize("split", ["free", "free_one_thread", "all_in_worker", "all_in_parent", "side_off"])
def test_the_shared_run_writes_the_inline_outputs(inline: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                  split: str) -> None:
    if split == "all_in_worker":  # every unit where it does not run in line: its result must not depend on where
        monkeypatch.setattr(ForkedShare, "claim_head", lambda self, end: None)
    elif split == "all_in_parent":
        monkeypatch.setattr(ForkedShare, "_claim_tail", lambda self: None)
    elif split == "free_one_thread":
        monkeypatch.setattr(tbw, "HEAD_THREADS", 1)
    ran = _counted(monkeypatch)
    monkeypatch.setattr(vrun, "SIDE_MODE", "off" if split == "side_off" else "fork")
    monkeypatch.setattr(tbw, "TYPE_B_WORKER", True)
    report = _run(tmp_path)
    n = report.identification.meta["type_b"]["reruns"]
    assert len(ran) == 1  # the worker was used
    if split == "all_in_worker":
        assert 0 < ran[0] < n  # units (fewer than re-runs: a resolution unit is 6 draws)
    elif split == "all_in_parent":
        assert ran[0] == 0
    assert _outputs(tmp_path) == inline
    assert multiprocessing.active_children() == []


def _fails_in(parent: int, how: str) -> Any:
    one = unc._propagate_one

    def run(recording: Any, task: Any, draws: int = unc.RESOLUTION_DRAWS) -> Any:
        if os.getpid() != parent:
            if how == "raise":
                raise DataError("re-run unit failed in the worker")
            os._exit(3)  # the worker dies without a word
        return one(recording, task, draws)

    return run


def test_a_unit_that_fails_in_the_worker_is_raised_by_the_parent(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(unc, "_propagate_one", _fails_in(os.getpid(), "raise"))
    monkeypatch.setattr(ForkedShare, "claim_head", lambda self, end: None)  # the worker takes the units
    monkeypatch.setattr(vrun, "SIDE_MODE", "off")  # no side child: the worker is the only one
    monkeypatch.setattr(tbw, "TYPE_B_WORKER", True)
    with pytest.raises(DataError, match="re-run unit failed in the worker"):
        _run(tmp_path, full=False)
    assert multiprocessing.active_children() == []


@pytest.mark.parametrize("side", ["off", "fork"])
def test_a_worker_that_dies_is_a_clear_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, side: str) -> None:
    monkeypatch.setattr(unc, "_propagate_one", _fails_in(os.getpid(), "exit"))
    monkeypatch.setattr(vrun, "SIDE_MODE", side)
    monkeypatch.setattr(tbw, "TYPE_B_WORKER", True)
    with pytest.raises(SideStageError, match="exit code 3"):
        _run(tmp_path, full=False)
    assert multiprocessing.active_children() == []


def test_the_head_and_tail_claims_meet_once() -> None:
    share = ForkedShare()  # not started: the counters only
    ctx = multiprocessing.get_context("fork")
    share._lock, share._lo, share._hi = ctx.Lock(), ctx.RawValue("q", 0), ctx.RawValue("q", 5)
    got = [share.claim_head(2), share._claim_tail(), share.claim_head(2), share.claim_head(2), share.claim_head(9),
           share._claim_tail(), share.claim_head(9), share._claim_tail()]
    # the head stops at a method's end (2) until asked further; the two never take the same unit
    assert got == [0, 4, 1, None, 2, 3, None, None]


def test_the_worker_runs_only_where_the_side_stages_may_fork(monkeypatch: pytest.MonkeyPatch) -> None:
    from benchtwin.validation.beside import SIDE_MAX_CAMPAIGN_S

    monkeypatch.setattr(tbw, "TYPE_B_WORKER", True)
    assert tbw.type_b_worker_beside(streamed=True, families=None, campaign_s=SIDE_MAX_CAMPAIGN_S)
    assert not tbw.type_b_worker_beside(streamed=True, families=None, campaign_s=SIDE_MAX_CAMPAIGN_S * 1.01)
    assert not tbw.type_b_worker_beside(streamed=False, families=None, campaign_s=100.0)
    assert not tbw.type_b_worker_beside(streamed=True, families=["engine"], campaign_s=100.0)
    monkeypatch.setattr(tbw, "TYPE_B_WORKER", False)
    assert not tbw.type_b_worker_beside(streamed=True, families=None, campaign_s=100.0)
