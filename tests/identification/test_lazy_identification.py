"""Identification from a Recording read on demand (``Recording.open``) gives exactly the parameters of the same
Recording held in memory, and leaves no channel loaded behind it."""

from __future__ import annotations

import json

from benchtwin.identification.run import identify_all
from benchtwin.recording import Recording


def _params(result) -> str:
    d = result.to_dict()
    d["meta"].pop("seconds", None)  # wall times differ run to run
    return json.dumps(d, sort_keys=True, default=str)


def test_identification_from_a_lazy_recording_equals_the_in_memory_one(quick_ideal, tmp_path) -> None:
    vehicle, rec = quick_ideal
    want = _params(identify_all(rec, vehicle.specs))
    with Recording.open(rec.save(tmp_path / "recording.mf4")) as lazy:
        got = _params(identify_all(lazy, vehicle.specs))
        assert lazy.loaded() == set()  # each method's channels were dropped after it
    assert got == want
