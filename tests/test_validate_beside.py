"""The stages of validate run beside the identification (benchtwin.validation.beside): the same report as in line,
and every failure of either side raised, never lost and never waited on forever."""

from __future__ import annotations

import multiprocessing
import os
import time
from typing import Any

import numpy as np
import pytest

import benchtwin.validation.run as vrun
from benchtwin.config import load_campaign, load_setup, load_vehicle
from benchtwin.errors import DataError
from benchtwin.validation.beside import SIDE_MAX_CAMPAIGN_S, Beside, SideStageError, side_stages_beside

MODES = ("fork", "thread")


def _exchange(ch: Any) -> None:
    ch.put("a", np.arange(3.0))
    x = ch.get("tols")
    ch.put("b", {"twice": 2 * x})


@pytest.mark.parametrize("mode", MODES)
def test_values_travel_both_ways_in_order(mode: str) -> None:
    with Beside(_exchange, mode) as side:  # type: ignore[arg-type]
        np.testing.assert_array_equal(side.get("a"), [0.0, 1.0, 2.0])
        side.put("tols", 21)
        assert side.get("b") == {"twice": 42}


def _fails_after_a(ch: Any) -> None:
    ch.put("a", 1)
    raise DataError("channel speed_kmh: no samples")


@pytest.mark.parametrize("mode", MODES)
def test_the_jobs_exception_is_raised_by_the_parent_with_its_type_and_message(mode: str) -> None:
    with Beside(_fails_after_a, mode) as side:  # type: ignore[arg-type]
        assert side.get("a") == 1
        with pytest.raises(DataError, match="channel speed_kmh: no samples") as info:
            side.get("b")
    if mode == "fork":  # where it was raised, in the child
        assert "_fails_after_a" in "".join(getattr(info.value, "__notes__", []))


class _UnpicklableError(Exception):
    def __init__(self, a: int, b: int) -> None:  # pickle rebuilds it with one argument: fails
        super().__init__(f"{a} and {b}")


def _raises_unpicklable(ch: Any) -> None:
    raise _UnpicklableError(1, 2)


def test_an_exception_that_does_not_pickle_comes_back_as_its_text() -> None:
    with Beside(_raises_unpicklable, "fork") as side, pytest.raises(SideStageError, match="1 and 2"):  # type: ignore[arg-type]
        side.get("a")


def _dies(ch: Any) -> None:
    os._exit(3)


def test_a_child_that_dies_is_an_error_not_a_hang() -> None:
    with Beside(_dies, "fork") as side, pytest.raises(SideStageError, match="exit code 3"):  # type: ignore[arg-type]
        side.get("a")


def _returns(ch: Any) -> None:
    ch.put("a", 1)


@pytest.mark.parametrize("mode", MODES)
def test_a_job_that_returns_without_the_value_asked_is_an_error(mode: str) -> None:
    with Beside(_returns, mode) as side:  # type: ignore[arg-type]
        assert side.get("a") == 1
        with pytest.raises(SideStageError, match="without sending 'b'"):
            side.get("b")


def _waits(ch: Any) -> None:
    ch.put("ready", os.getpid())
    ch.get("tols")
    time.sleep(600)  # never reached when the parent fails first


@pytest.mark.parametrize("mode", MODES)
def test_the_parents_failure_ends_a_job_waiting_for_it(mode: str) -> None:
    t = time.monotonic()
    with pytest.raises(RuntimeError, match="identification failed"), Beside(_waits, mode) as side:  # type: ignore[arg-type]
        side.get("ready")
        raise RuntimeError("identification failed")
    assert time.monotonic() - t < 60  # not the job's 600 s
    assert multiprocessing.active_children() == []


# -- validate itself: a small streamed campaign (the two first tests of quick.toml, no type B; a few seconds) -------

def _small() -> tuple[Any, Any, Any]:
    campaign = load_campaign("quick.toml")
    return load_vehicle(), load_setup("paper"), campaign.model_copy(update={"tests": campaign.tests[:2]})


def _without_seconds(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _without_seconds(v) for k, v in d.items() if k not in ("timings_s", "seconds")}
    if isinstance(d, list):
        return [_without_seconds(v) for v in d]
    return d


def test_validate_beside_gives_the_report_made_in_line(monkeypatch: pytest.MonkeyPatch) -> None:
    reports = {}
    for mode in ("off", "fork"):
        monkeypatch.setattr(vrun, "SIDE_MODE", mode)
        reports[mode] = vrun.validate(*_small(), type_b=False)
    a, b = (_without_seconds(reports[m].to_dict()) for m in ("off", "fork"))
    assert any(c["group"] == "chain" for c in a["checks"])  # the side stages' checks are there
    assert repr(a) == repr(b)  # NaN-safe, order included


@pytest.mark.parametrize("stage", ["chain_checks", "paper_estimation_fits", "_prediction"])
def test_validate_raises_a_side_stages_exception(monkeypatch: pytest.MonkeyPatch, stage: str) -> None:
    def boom(*args: object, **kwargs: object) -> None:
        raise DataError(f"{stage} failed here")

    monkeypatch.setattr(vrun, "SIDE_MODE", "fork")
    monkeypatch.setattr(vrun, stage, boom)
    with pytest.raises(DataError, match=f"{stage} failed here"):
        vrun.validate(*_small(), type_b=False)
    assert multiprocessing.active_children() == []


def test_validate_raises_the_identifications_exception_and_ends_the_side_stages(
        monkeypatch: pytest.MonkeyPatch) -> None:
    def identify(*args: object, **kwargs: object) -> None:
        raise DataError("identification failed here")

    monkeypatch.setattr(vrun, "SIDE_MODE", "fork")
    monkeypatch.setattr(vrun, "identify_all", identify)
    with pytest.raises(DataError, match="identification failed here"):
        vrun.validate(*_small(), type_b=False)
    assert multiprocessing.active_children() == []


@pytest.mark.parametrize("mode", MODES)
def test_the_side_stages_send_in_the_inline_order_and_the_prediction_waits_for_the_tolerances(
        monkeypatch: pytest.MonkeyPatch, mode: str) -> None:
    from functools import partial

    from benchtwin.recording import Recording
    from benchtwin.validation.report import ValidationReport

    def prediction(report: ValidationReport, *args: object, tols: Any = None, **kwargs: object) -> list[Any]:
        report.prediction = {"held_out": "wltc"}
        return ["predicted", tols()["motor.motoring.e"]]

    monkeypatch.setattr(vrun, "chain_checks", lambda *a, **k: ["chain"])
    monkeypatch.setattr(vrun, "paper_estimation_fits", lambda *a, **k: {"paper": 1})
    monkeypatch.setattr(vrun, "_prediction", prediction)
    vehicle, setup, campaign = _small()
    job = partial(vrun._side_stages, ValidationReport(), vehicle, setup, campaign, None, Recording(), setup,
                  "realistic", True, True)
    with Beside(job, mode) as side:  # type: ignore[arg-type]
        assert side.get("chain") == ["chain"]
        assert side.get("paper") == {"paper": 1}
        side.put("tols", {"motor.motoring.e": 0.03})
        pred, checks, seconds = side.get("prediction")
    assert pred == {"held_out": "wltc"} and checks == ["predicted", 0.03] and seconds >= 0


def test_which_runs_fork_their_side_stages() -> None:
    """Only a streamed whole-campaign run no longer than SIDE_MAX_CAMPAIGN_S, with a mode other than off."""
    limit = SIDE_MAX_CAMPAIGN_S
    assert 10_464.0 <= limit < 2 * 10_464.0  # the paper campaign forks; twice it does not (measured at 10x: 1,014 MB)
    assert side_stages_beside("fork", streamed=True, families=None, campaign_s=10_464.0)
    assert side_stages_beside("thread", streamed=True, families=None, campaign_s=limit)
    assert not side_stages_beside("fork", streamed=True, families=None, campaign_s=np.nextafter(limit, np.inf))
    assert not side_stages_beside("fork", streamed=True, families=None, campaign_s=10 * 10_464.0)
    assert not side_stages_beside("off", streamed=True, families=None, campaign_s=100.0)
    assert not side_stages_beside("fork", streamed=False, families=None, campaign_s=100.0)
    assert not side_stages_beside("fork", streamed=True, families=["battery"], campaign_s=100.0)
    assert not side_stages_beside("fork", streamed=True, families=None, campaign_s=0.0)


def test_a_campaign_over_the_limit_runs_its_side_stages_in_line(monkeypatch: pytest.MonkeyPatch) -> None:
    """The small campaign with the limit set under its length: no Beside is made, and the report is the forked one."""
    import benchtwin.validation.beside as beside_mod

    monkeypatch.setattr(vrun, "SIDE_MODE", "fork")
    forked = vrun.validate(*_small(), type_b=False)

    def no_beside(*a: Any, **k: Any) -> Any:
        raise AssertionError("a Beside was made for a campaign over the limit")

    monkeypatch.setattr(beside_mod, "SIDE_MAX_CAMPAIGN_S", 1.0)
    monkeypatch.setattr(vrun, "Beside", no_beside)
    in_line = vrun.validate(*_small(), type_b=False)
    assert repr(_without_seconds(in_line.to_dict())) == repr(_without_seconds(forked.to_dict()))
