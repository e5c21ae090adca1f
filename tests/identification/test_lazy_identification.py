"""Identification from a Recording read on demand (``Recording.open``) gives exactly the parameters of the same
Recording held in memory, and leaves no channel loaded behind it."""

from __future__ import annotations

import json

import numpy as np

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


def test_an_mf4_log_imported_on_demand_equals_the_one_imported_at_once(tmp_path) -> None:
    from asammdf import MDF, Signal

    from benchtwin.identification.importers import import_mf4
    from benchtwin.identification.signal_map import signal_map_from_dict
    from benchtwin.recording import Flag, LazyChannel

    t = np.arange(5000) * 0.01
    speed = np.abs(np.sin(t / 7)) * 40.0
    speed[100] = 1e4  # implausible: flagged OUT_OF_RANGE by both
    with MDF(version="4.10") as mdf:
        mdf.append([Signal(speed, t, name="VehSpd", unit="m/s"),
                    Signal((np.cos(t) * 3e5).astype(np.float32), t, name="IVT_I", unit="mA")])
        path = mdf.save(tmp_path / "log.mf4", overwrite=True)
    smap = signal_map_from_dict({"source": {"format": "mf4"}, "channels": {
        "vehicle_speed_kmh": {"column": "VehSpd"}, "battery_current_a": {"column": "IVT_I", "scale": -1.0}}})
    eager = import_mf4(path, smap)
    with import_mf4(path, smap, lazy=True) as lazy:
        assert all(isinstance(c, LazyChannel) and not c.loaded for c in lazy.channels.values())
        a, b = eager["vehicle_speed_kmh"], lazy["vehicle_speed_kmh"]
        assert a.values.tobytes() == b.values.tobytes() and a.timestamps.tobytes() == b.timestamps.tobytes()
        assert np.array_equal(a.flags, b.flags) and b.flags[100] == Flag.OUT_OF_RANGE
        # a float32 channel stays float32: the float64 conversion rounded once to the file's own precision
        a, b = eager["battery_current_a"], lazy["battery_current_a"]
        assert b.values.dtype == np.float32 and b.values.tobytes() == a.values.astype(np.float32).tobytes()
        assert lazy.meta["implausible_samples"] == eager.meta["implausible_samples"] == {"vehicle_speed_kmh": 1}
