"""validate --out with the side stages forked: recording.mf4 is written once, by the child while it waits for the
parent's tolerances, and it is the file the in-line run writes (the parent no longer compresses it)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import benchtwin.validation.run as vrun
from benchtwin.chain.deferred_save import DeferredSave
from benchtwin.config import load_campaign, load_setup, load_vehicle
from benchtwin.recording import Recording


def _small() -> tuple[Any, Any, Any]:  # the two first tests of quick.toml (as tests/test_validate_beside.py)
    campaign = load_campaign("quick.toml")
    return load_vehicle(), load_setup("paper"), campaign.model_copy(update={"tests": campaign.tests[:2]})


@pytest.mark.parametrize("mode", ["fork", "thread"])
def test_the_side_stages_write_recording_mf4_once_and_the_same(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                              mode: str) -> None:
    runs = tmp_path / "runs.txt"
    run = DeferredSave.run

    def logged(self: DeferredSave, workers: int = 2) -> Path:
        with open(runs, "a") as fh:  # appended by whichever process saves
            fh.write(f"{os.getpid()} {self.done} {workers}\n")
        return run(self, workers)

    monkeypatch.setattr(DeferredSave, "run", logged)
    monkeypatch.setattr(vrun, "SIDE_MODE", "off")
    vrun.validate(*_small(), type_b=False, out_dir=tmp_path / "off")
    assert runs.read_text().split() == [str(os.getpid()), "False", "2"]  # in line: right after the chain, here
    runs.unlink()
    monkeypatch.setattr(vrun, "SIDE_MODE", mode)
    vrun.validate(*_small(), type_b=False, out_dir=tmp_path / mode)
    pid, done, workers = runs.read_text().split()  # one save, not repeated when the parent closes its Recording
    assert done == "False" and (pid != str(os.getpid())) == (mode == "fork")
    assert workers == "1"  # beside the parent's identification: one core
    a, b = Recording.load(tmp_path / "off" / "recording.mf4"), Recording.load(tmp_path / mode / "recording.mf4")
    assert list(a.channels) == list(b.channels) and a.channels
    for name in a.channels:
        for field in ("timestamps", "values", "flags"):
            np.testing.assert_array_equal(getattr(a[name], field), getattr(b[name], field), err_msg=name)
    assert a.meta == b.meta and a.segments == b.segments
