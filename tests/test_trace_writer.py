"""The Trace written test by test (TraceWriter, ``benchtwin simulate``) is the Trace written whole."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchtwin.config import load_campaign, load_vehicle
from benchtwin.emulator import iter_campaign, simulate_campaign
from benchtwin.errors import DataError
from benchtwin.trace import Trace, TraceWriter


@pytest.fixture(scope="module")
def quick() -> tuple[Trace, list[Trace]]:
    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    return simulate_campaign(vehicle, campaign), list(iter_campaign(vehicle, campaign))


def test_pieces_written_one_by_one_load_as_the_whole_trace(quick, tmp_path: Path) -> None:
    whole, pieces = quick
    whole.save(tmp_path / "whole")
    with TraceWriter(tmp_path / "pieces") as w:
        for p in pieces:
            w.append(p)
    a, b = Trace.load(tmp_path / "whole"), Trace.load(tmp_path / "pieces")
    np.testing.assert_array_equal(a.time_s, b.time_s)
    assert list(a.channels) == list(b.channels)
    for name in a.channels:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
        np.testing.assert_array_equal(b[name], whole[name], err_msg=name)
    assert a.segments == b.segments == whole.segments
    assert json.loads((tmp_path / "pieces" / "meta.json").read_text()) == json.loads(
        (tmp_path / "whole" / "meta.json").read_text())
    assert w.span_s == (float(whole.time_s[0]), float(whole.time_s[-1]))


def test_a_piece_out_of_order_or_with_other_channels_is_refused(quick, tmp_path: Path) -> None:
    _whole, pieces = quick
    with TraceWriter(tmp_path) as w:
        w.append(pieces[1])
        with pytest.raises(DataError, match="not after the last one"):
            w.append(pieces[0])
        odd = Trace(pieces[2].time_s, {k: v for k, v in list(pieces[2].channels.items())[1:]}, [], {})
        with pytest.raises(DataError, match="unlike the first piece"):
            w.append(odd)
    assert len(Trace.load(tmp_path)) == len(pieces[1])  # what was appended before the refusals is kept


def test_simulate_command_streams_the_campaign(tmp_path: Path, capsys) -> None:
    from benchtwin.cli import main

    assert main(["simulate", "--campaign", "quick", "--out", str(tmp_path), "--no-progress"]) == 0
    whole = simulate_campaign(load_vehicle(), load_campaign("quick.toml"))
    got = Trace.load(tmp_path)
    for name in whole.channels:
        np.testing.assert_array_equal(got[name], whole[name], err_msg=name)
    assert got.segments == whole.segments
    assert "Trace written" in capsys.readouterr().out
