"""The paper fits' battery hold fit (validation.paper_r2) reads a long campaign's holds a block at a time.

A campaign repeated has many constant-speed holds, far apart. The fit's samples are the holds' (each with a second
either side), and the fit is eq. 30 on the common grid over them; on the acquisition's chunk files (lazy channels
that read blocks) neither the holds' samples of a channel nor a channel whole are ever in memory at once: the holds
are lazy views of the source channels (``validation._spans``), read around one block of grid points (or one block of
the time index, or of the typical-step walk) at a time, and the hold's end is found on the speed channel a block at a
time. The fit is the in-memory slice's, bit for bit.

The bound: the tracked block reads alive at once are at most two blocks of ``BLOCK`` samples (one block read of a
view, which takes its samples from at most two of the source's ranges, while the caller still holds the block before
it). The holds' samples of one channel are ``REPEATS`` x (600 + 400) s x ``RATE`` Hz = 40 k samples, 20 blocks.
"""

from __future__ import annotations

import numpy as np
import pytest
from _alive_reads import AliveReads, tracked_lazy

import benchtwin.identification._battery_used as battery_used
import benchtwin.identification._resample_blocks as resample_blocks
import benchtwin.identification._windows as windows
import benchtwin.validation.paper_r2 as pr
from benchtwin.config.vehicle import load_vehicle
from benchtwin.identification._windows import reads_by_block
from benchtwin.identification.battery import load_literature_maps
from benchtwin.recording import Channel, Recording
from benchtwin.segments import Segment

RATE = 10.0  #: samples per second of every channel
REPEATS = 4  #: the campaign's repeats, each a depletion hold and a charge hold
IDLE_S = 1000.0  #: standstill between the drives (samples at rest: the holds lie far apart)
BLOCK = 1024  #: samples per block read in these tests (time index, typical step, hold end)
STRIDE = 64  #: the time index's stride in these tests
SAMPLE_BYTES = 8 + 8 + 2  #: timestamp, value, flags
NAMES = ("battery_voltage_v", "battery_current_a", "displayed_soc_pct")


def _drive(t0: float, name: str, speed: float, hold_s: float, sign: int, soc0: float, vehicle) -> tuple:
    """A 30 s approach (speed ramp, current burst), a hold at the speed, a 15 s stop, then IDLE_S at rest."""
    n, maps, bat = vehicle.specs.n_cells_series, load_literature_maps(), vehicle.battery
    t = t0 + np.arange(0.0, 45.0 + hold_s + IDLE_S, 1.0 / RATE)
    rel = t - t0
    end = 30.0 + hold_s + 15.0
    v = np.interp(rel, [0.0, 25.0, 30.0 + hold_s, end], [speed - 30.0, speed, speed, 0.0])
    i = np.where(rel < 25.0, 150.0, 35.0 * sign) * np.where(rel > 30.0 + hold_s, 0.1, 1.0) + 2.0 * np.sin(rel / 7.0)
    i = np.where(rel > end, 0.0, i)
    q = np.r_[0.0, np.cumsum(-0.5 * (i[1:] + i[:-1]) * np.diff(t))] / 3600.0
    s = soc0 + 2.7 * q
    r = np.where(i > 0, bat.beta_discharge * maps.r_discharge(s), bat.beta_charge * maps.r_charge(s))
    u = (bat.alpha * maps.ocv(s) - i * r) * n
    seg = Segment(float(t0), float(t0 + end), "constant_drive", name,
                  {"speed_kmh": speed, "approach_s": 30.0, "hold_start_s": t0 + 30.0})
    return t, v, i, s, u, seg


def _campaign() -> tuple[Recording, object]:
    vehicle = load_vehicle()
    parts, t0 = [], 0.0
    for k in range(REPEATS):
        for name, speed, hold, sign, soc0 in (("deplete", 85.0, 600.0, 1, 90.0), ("charge", 50.0, 400.0, -1, 20.0)):
            p = _drive(t0, f"{name}_{k}", speed, hold, sign, soc0, vehicle)
            parts.append(p)
            t0 = float(p[0][-1]) + 1.0 / RATE
    t, v, i, s, u = (np.concatenate([p[k] for p in parts]) for k in range(5))
    rec = Recording(segments=[p[5] for p in parts])
    rec.add(Channel("vehicle_speed_kmh", "km/h", t, v, source="vehicle_can"))
    rec.add(Channel("battery_voltage_v", "V", t, u, source="ivt_battery"))
    rec.add(Channel("battery_current_a", "A", t, i, source="ivt_battery"))
    rec.add(Channel("displayed_soc_pct", "%", t, s, source="vehicle_can"))
    return rec, vehicle


@pytest.fixture
def small_blocks(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(windows, "INDEX_STRIDE", STRIDE)
    monkeypatch.setattr(windows, "INDEX_BLOCK", BLOCK)
    monkeypatch.setattr(resample_blocks, "_STEP_BLOCK", BLOCK)
    monkeypatch.setattr(battery_used, "BLOCK", BLOCK // 4)  # grid points: 25.6 s, read with 2 s and two strides
    monkeypatch.setattr(pr, "_BLOCK", BLOCK)


def test_the_hold_fit_reads_a_block_at_a_time_and_fits_as_the_slice(small_blocks, monkeypatch) -> None:
    rec, vehicle = _campaign()
    want = pr.battery_hold_fit(rec, vehicle)  # channels in memory: the holds sliced into memory
    reads = AliveReads()
    lazy = Recording(segments=rec.segments, meta=dict(rec.meta))
    for ch in rec.channels.values():
        lazy.add(tracked_lazy(ch, reads))  # a whole read fails
    seen = {}
    real = pr.identify_battery

    def spy(sub, specs, **kw):
        seen["by_block"] = all(reads_by_block(sub[n]) for n in NAMES)
        out = real(sub, specs, **kw)
        seen["loaded"] = sub.loaded()
        return out

    monkeypatch.setattr(pr, "identify_battery", spy)
    got = pr.battery_hold_fit(lazy, vehicle)
    # the fit's samples are the holds' as lazy views, never read whole
    assert seen == {"by_block": True, "loaded": set()}
    holds = sum(b - a + 2.0 for a, b, _ in pr.battery_hold_windows(rec)) * RATE
    assert holds > 20 * BLOCK
    assert 0 < reads.most <= 2 * BLOCK * SAMPLE_BYTES, reads.most
    # the same fit, bit for bit
    assert set(got.params) == set(want.params) == {"alpha", "beta_discharge", "beta_charge", "soc_per_ah"}
    for k, p in want.params.items():
        q = got.params[k]
        assert (q.value, q.std_error, q.ci95, q.status) == (p.value, p.std_error, p.ci95, p.status), k
    assert (got.r2, got.adj_r2, got.rmse, got.n_points) == (want.r2, want.adj_r2, want.rmse, want.n_points)
    assert set(got.data) == set(want.data)
    for k, a in want.data.items():
        np.testing.assert_array_equal(got.data[k], a, err_msg=k)
