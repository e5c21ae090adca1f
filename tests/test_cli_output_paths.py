"""Unwritable output paths and a full disk end ``validate``, ``record`` and ``acquire`` with one line,
before any work is done, and leave what is already there untouched."""

from __future__ import annotations

import shutil
from collections import namedtuple

import pytest

from benchtwin.cli import main

Usage = namedtuple("Usage", "total used free")


def _one_line(capsys) -> str:
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("benchtwin: error:"), cap.err
    assert "Traceback" not in cap.err
    return err[0]


def _argv(cmd: str, out: str) -> list[str]:
    return {
        "validate": ["validate", "--setup", "ideal", "--campaign", "quick", "--out", out],
        "record": ["record", "--setup", "ideal", "--port", "1", "--connect-timeout", "0.1", "--out", out + ".mf4"],
        "acquire": ["acquire", "--trace", "no-such-trace", "--setup", "ideal", "--logs", out, "--out",
                    out + ".mf4"],
    }[cmd]


@pytest.mark.parametrize("cmd", ["validate", "record", "acquire"])
def test_an_output_under_a_file_is_refused_first(cmd, tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("keep me")
    assert main(_argv(cmd, str(blocker / "out"))) == 2
    line = _one_line(capsys)
    assert ("cannot write there" in line or "is a file, not a folder" in line) and str(blocker) in line
    assert capsys.readouterr().out == ""  # nothing simulated, connected or encoded
    assert blocker.read_text() == "keep me"


@pytest.mark.parametrize("cmd", ["validate", "record", "acquire"])
def test_a_full_disk_is_refused_first(cmd, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(shutil, "disk_usage", lambda _p: Usage(10 * 2**30, 10 * 2**30 - 2**20, 2**20))
    out = tmp_path / "out"
    old = tmp_path / "out.mf4"
    old.write_bytes(b"an earlier recording")
    assert main(_argv(cmd, str(out))) == 2
    assert "disk full" in _one_line(capsys)
    assert old.read_bytes() == b"an earlier recording"


def test_acquire_logdir_refuses_an_unwritable_out(tmp_path, capsys):
    (tmp_path / "logs").mkdir()
    (tmp_path / "f").write_text("")
    assert main(["acquire", str(tmp_path / "logs"), "--out", str(tmp_path / "f" / "rec.mf4")]) == 2
    line = _one_line(capsys)
    assert "cannot write there" in line or "is a file, not a folder" in line
