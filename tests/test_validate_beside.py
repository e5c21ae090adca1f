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


#: a container the parent holds before it forks (the child inherits it)
_INHERITED: list[Any] = []


def _gc_state(ch: Any) -> None:
    import gc

    own: list[Any] = []
    ch.put("state", (any(o is _INHERITED for o in gc.get_objects()), any(o is own for o in gc.get_objects())))


def test_a_forked_childs_collections_leave_out_what_it_inherited() -> None:
    """The forked child freezes the objects it inherited from the parent: its garbage collections walk only what the
    job makes (full collections over the parent's heap cost the paper campaign's child ~0.2 s of CPU and copied the
    pages they touched). The job's results are the same either way (the other tests of this module)."""
    import gc

    assert any(o is _INHERITED for o in gc.get_objects())  # tracked by the parent's collections
    with Beside(_gc_state, "fork") as side:
        inherited, own = side.get("state")
    assert own  # the job's own objects are collected as before
    assert not inherited  # mutant: no gc.freeze() in Beside._child_main -> the inherited list is walked
    assert any(o is _INHERITED for o in gc.get_objects())  # the parent is not frozen
    assert gc.get_freeze_count() == 0


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


# -- report.html's figures, drawn by the forked child from the nominal identification (validation/figures_beside.py) --

def _waits_for_the_parent_then_reads(ch: Any, sent: Any) -> None:
    # the parent sets ``sent`` only once its put of a value larger than the pipe holds has returned: a put that
    # waited for this job to read would never get there (the guard's 60 s are a deadlock's, never reached otherwise)
    ch.put("sent in time", sent.wait(60))
    ch.put("got", (ch.get("big"), ch.get("small")))


def test_a_put_larger_than_the_pipe_returns_before_the_child_reads_and_sends_the_value_as_it_was() -> None:
    sent = multiprocessing.get_context("fork").Event()
    big = np.arange(1_000_000.0)  # 8 MB: a pipe holds 64 KiB
    with Beside(lambda ch: _waits_for_the_parent_then_reads(ch, sent), "fork") as side:
        side.put("big", big)
        big[:] = -1.0  # changed after the put (as the type B re-runs add to the nominal result): not sent
        side.put("small", 2)
        sent.set()
        assert side.get("sent in time") is True
        got_big, got_small = side.get("got")
    np.testing.assert_array_equal(got_big, np.arange(1_000_000.0))
    assert got_small == 2
    assert multiprocessing.active_children() == []


def _images(page: str) -> list[tuple[str, bytes]]:
    import base64
    import re

    return [(alt, base64.b64decode(data)) for alt, data in
            re.findall(r'<img alt="([^"]*)" src="data:image/png;base64,([^"]*)">', page)]


def test_report_html_figures_drawn_beside_are_the_ones_drawn_in_line(monkeypatch: pytest.MonkeyPatch,
                                                                     tmp_path: Any) -> None:
    """The quick campaign with its type B re-runs (which add to the result after the child got the nominal one):
    report.html is the in-line run's but for its wall-time line, every figure's PNG byte for byte."""
    vehicle, setup = load_vehicle(), load_setup("paper")
    pages = {}
    for mode in ("off", "fork"):
        monkeypatch.setattr(vrun, "SIDE_MODE", mode)
        vrun.validate(vehicle, setup, load_campaign("quick.toml"), out_dir=tmp_path / mode)
        pages[mode] = (tmp_path / mode / "report.html").read_text(encoding="utf-8")
    imgs = {m: _images(p) for m, p in pages.items()}
    assert len(imgs["off"]) == 8 and "fig08_transmission_efficiency" in dict(imgs["off"])  # the quick campaign's
    assert imgs["fork"] == imgs["off"]

    def without_wall(page: str) -> list[str]:
        return [line for line in page.splitlines() if not line.startswith("<p>wall time")]

    assert without_wall(pages["fork"]) == without_wall(pages["off"])
    assert multiprocessing.active_children() == []


@pytest.mark.parametrize("mode", ["off", "thread", "fork"])
def test_a_figure_that_fails_is_raised_by_the_parent_after_the_results_are_written(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Any, mode: str) -> None:
    from benchtwin.identification import figures

    def boom(result: Any, path: Any) -> None:
        raise RuntimeError("figure 8 drawn wrong")

    monkeypatch.setitem(figures.FIGURES, "fig08_transmission_efficiency", boom)
    monkeypatch.setattr(vrun, "SIDE_MODE", mode)
    with pytest.raises(RuntimeError, match="figure 8 drawn wrong"):
        vrun.validate(*_small(), type_b=False, out_dir=tmp_path)
    # where the in-line run raises it: params.json and validation.json written, report.html not
    assert (tmp_path / "validation.json").exists() and (tmp_path / "params.json").exists()
    assert not (tmp_path / "report.html").exists()
    assert multiprocessing.active_children() == []
