"""The clock offsets and drifts read only the time windows they use, with the bits of the whole-channel work.

:func:`~benchtwin.chain.alignment.clock_offsets` once loaded its seven channels whole (vehicle and dyno speeds, the
dyno forces, motor torque and speed, HPCU power); it now reads the central hour and each 15-minute drift window
(and the samples either side of them) a block at a time. ``_whole`` below is the old whole-channel work, written
with the public :func:`detect_lag` and :func:`slip_aware_lag`: the reference the windowed reads must equal to the
last bit. About 30 s in all on a loaded 2-core machine (two chunked acquisitions of the quick campaign, synthetic
recordings of 1.5 and 4.5 h).
"""

from __future__ import annotations

import tracemalloc
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import theilslopes

from benchtwin.chain.acquisition import Acquisition
from benchtwin.chain.alignment import (
    DRIFT_WINDOW_S,
    MIN_DRIVE_SPEED_KMH,
    clock_offsets,
    detect_lag,
    slip_aware_lag,
)
from benchtwin.chain.blocks import ChannelBlocks
from benchtwin.chain.channel_store import ChannelStore
from benchtwin.config import load_setup
from benchtwin.recording import Channel, Recording


def _whole(rec: Recording) -> tuple[dict[str, float], dict[str, float]]:
    """The offsets and drifts from the whole channels (the work before the windowed reads)."""
    pairs = []
    if "vehicle_speed_kmh" in rec and "dyno_speed_kmh" in rec:
        a, b = rec["vehicle_speed_kmh"], rec["dyno_speed_kmh"]
        forces = [(rec[n].timestamps, rec[n].values) for n in ("dyno_force_front_n", "dyno_force_rear_n")
                  if n in rec and rec[n].source == b.source]
        pairs.append(("vehicle_can->dyno", a.timestamps, a.values, b.timestamps, b.values, forces))
    if "em_torque_nm" in rec and "em_speed_rpm" in rec:
        p_name = "hpcu_power_w" if "hpcu_power_w" in rec else "battery_power_w"
        if p_name in rec:
            tq, sp, p = rec["em_torque_nm"], rec["em_speed_rpm"], rec[p_name]
            mech = tq.values * np.interp(tq.timestamps, sp.timestamps, sp.values) * (2 * np.pi / 60.0)
            pairs.append((f"vehicle_can->{p.source}", tq.timestamps, mech, p.timestamps, p.values, []))
    drive = ("em_torque_nm", "em_speed_rpm", "engine_torque_nm", "engine_speed_rpm", "vehicle_speed_kmh")
    if "shaft_torque_nm" in rec and all(n in rec for n in drive):
        tq, *others = (rec[n] for n in drive)
        w_em, q_e, w_e, v = (np.interp(tq.timestamps, o.timestamps, o.values) for o in others)
        with np.errstate(invalid="ignore", divide="ignore"):
            force = np.where(v >= MIN_DRIVE_SPEED_KMH,
                             (tq.values * w_em + q_e * w_e) * (2 * np.pi / 60.0) / (v / 3.6), np.nan)
        sh = rec["shaft_torque_nm"]
        pairs.append((f"vehicle_can->{sh.source}", tq.timestamps, force, sh.timestamps, sh.values, []))
    offsets, drifts = {}, {}
    for key, t_a, x_a, t_b, x_b, forces in pairs:
        lag = detect_lag(t_a, x_a, t_b, x_b)
        if lag is None:
            continue
        if forces:
            lag = slip_aware_lag(t_a, x_a, t_b, x_b, forces, lag)
        offsets[key] = lag
        t0, t1 = max(t_a[0], t_b[0]), min(t_a[-1], t_b[-1])
        n_win = int((t1 - t0) // DRIFT_WINDOW_S)
        if n_win >= 4:
            edges = np.linspace(t0, t1, n_win + 1)
            pts = [(0.5 * (a + b), detect_lag(t_a, x_a, t_b, x_b, window=(a, b), rate_hz=20.0))
                   for a, b in pairwise(edges)]
            pts = [(c, w) for c, w in pts if w is not None and abs(w) < 2.0 - 0.5 / 20.0]  # edge: no peak
            if len(pts) >= 3 and pts[-1][0] - pts[0][0] >= 2 * DRIFT_WINDOW_S:
                c, lw = np.array(pts).T
                drifts[key] = float(theilslopes(lw, c, alpha=0.6827)[0] * 1e6)
    return offsets, drifts


def _smooth(rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """A random signal with a few seconds' correlation time sampled at ``t`` (what the lags are found on)."""
    knots = np.arange(t[0] - 10.0, t[-1] + 10.0, 2.0)
    return np.interp(t, knots, np.cumsum(rng.normal(size=knots.size)))


def _synthetic(hours: float, seed: int = 3) -> list[Channel]:
    """The ten channels at 20 Hz over ``hours``: the dyno 0.137 s late on the vehicle CAN and drifting 40 ppm,
    the HPCU 0.05 s early, the telemetry 0.2 s late and drifting 25 ppm (its lag ``0.2 + 25e-6 t``); NaN runs
    (0.2-6 s) every 37-160 s in the vehicle speed, the motor speed and the HPCU power, a minute of them at the
    vehicle speed's start and 15 s of them where the central hours start and end (the samples the interpolation
    uses there are finite ones further out)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, 0.05)
    speed, force, torque, rpm = (_smooth(rng, t) for _ in range(4))
    t_dyno = t * (1 + 40e-6) + 0.137 + 0.003
    t_hpcu = t + 0.011

    def holes(x: np.ndarray, first: float = 0.0, at: tuple[float, ...] = ()) -> np.ndarray:
        x = x.copy()
        x[t < first] = np.nan
        for c in at:  # 15 s of NaN around where the central hour's grids start and end
            x[(t >= c - 10.0) & (t < c + 5.0)] = np.nan
        s = rng.uniform(37.0, 160.0)
        while s < t[-1]:
            x[(t >= s) & (t < s + rng.uniform(0.2, 6.0))] = np.nan
            s += rng.uniform(37.0, 160.0)
        return x

    def late(x: np.ndarray, by: float) -> np.ndarray:
        return np.interp(t - by, t, x)

    mech = torque * rpm * (2 * np.pi / 60.0)
    # the telemetry: its clock 0.2 s late and 25 ppm fast; the shaft torque follows the CAN's drive force
    q_e, w_e = _smooth(rng, t), _smooth(rng, t)
    v_can = 60.0 + 2.0 * speed
    shaft = 3.0 * (torque * rpm + q_e * w_e) / np.maximum(v_can, 1.0)
    t_tel = t * (1 + 25e-6) + 0.2
    mid = 0.5 * hours * 3600.0  # the central hours: about mid -+ 1800 s (the speeds' starting 60 s move them 30 s)
    edges_speed, edges_power = (mid + 30.0 - 1800.0, mid + 30.0 + 1800.0), (mid - 1800.0, mid + 1800.0)
    return [Channel("vehicle_speed_kmh", "km/h", t, holes(v_can, 60.0, edges_speed), source="vehicle_can"),
            Channel("dyno_speed_kmh", "km/h", t_dyno, late(v_can, 0.137), source="dyno"),
            Channel("dyno_force_front_n", "N", t_dyno, force, source="dyno"),
            Channel("dyno_force_rear_n", "N", t_dyno, 0.5 * force, source="dyno"),
            Channel("em_torque_nm", "N m", t, torque, source="vehicle_can"),
            Channel("em_speed_rpm", "rpm", t + 0.002, holes(rpm, 0.0, edges_power), source="vehicle_can"),
            Channel("hpcu_power_w", "W", t_hpcu, holes(late(mech, -0.05), 0.0, edges_power), source="hpcu"),
            Channel("engine_torque_nm", "N m", t, q_e, source="vehicle_can"),
            Channel("engine_speed_rpm", "rpm", t, w_e, source="vehicle_can"),
            Channel("shaft_torque_nm", "N m", t_tel, shaft, source="telemetry")]


def _stored(channels: list[Channel], directory: Path) -> tuple[Recording, ChannelStore]:
    """The channels appended to a store's files (in three pieces each) and its Recording of lazy channels."""
    store = ChannelStore(directory)
    for k, ch in enumerate(channels):
        for part in np.array_split(np.arange(len(ch)), 3):
            store.append(ch.name, ch.unit, ch.source, None, (k,), ch.timestamps[part], ch.values[part],
                         ch.flags[part])
    rec = Recording()
    for name in store.names():
        rec.add(store.reader(name))
    return rec, store


@pytest.fixture(scope="module")
def long_recording() -> list[Channel]:
    return _synthetic(1.5)


@pytest.mark.parametrize("block", [1, 997, 1 << 20])
def test_windowed_offsets_equal_the_whole_channel_work_on_a_long_recording(long_recording, tmp_path: Path,
                                                                          block: int) -> None:
    """1.5 h with NaN runs: the central hour, five drift windows, edges inside NaN runs; any block size gives the
    whole-channel offsets and drifts bit for bit (read from the store's files, and in memory)."""
    rec = Recording()
    for ch in long_recording:
        rec.add(ch)
    expected = _whole(rec)
    assert set(expected[0]) == {"vehicle_can->dyno", "vehicle_can->hpcu", "vehicle_can->telemetry"}
    assert set(expected[1]) == set(expected[0])  # the drifts are found: the windows' work is compared too
    assert clock_offsets(ChannelBlocks(rec, None, block)) == expected
    if block == 1:  # single-sample blocks on disk: slow in Python, the in-memory run above covers them
        return
    stored, store = _stored(long_recording, tmp_path)
    try:
        assert clock_offsets(ChannelBlocks(stored, store, block)) == expected
        assert not stored.loaded()  # nothing was read whole
    finally:
        store.cleanup()


@pytest.mark.parametrize(("setup_name", "block"), [("paper", 997), ("faults", 65_536)])
def test_the_quick_campaigns_offsets_are_unchanged(quick_inputs, setup_name: str, block: int,
                                                   tmp_path: Path) -> None:
    """The quick campaign (the faults setup's clock step, drops and cut dyno log included), acquired in chunks on
    disk with blocks of 997 and 64 Ki samples: the clock offsets finish() reports are those of the whole-channel
    work on the same Recording, bit for bit."""
    acq = Acquisition(load_setup(setup_name), tmp_path / "r.mf4", keep_chunks=True, block_samples=block)
    for chunk in quick_inputs[setup_name].split_by_time([200.0, 450.0, 700.05]):
        acq.feed(chunk)
    rec = acq.finish()
    try:
        expected = _whole(rec)
        # the faults setup's telemetry faults (3 s at the rail, reordered frames) leave it below 0.6: no offset
        assert set(expected[0]) == {"vehicle_can->dyno", f"vehicle_can->{rec['hpcu_power_w'].source}"} | (
            {"vehicle_can->telemetry"} if setup_name == "paper" else set())
        found = {k: v for k, v in rec.meta["clock_offsets_s"].items() if k in expected[0]}
        assert (found, rec.meta["clock_drift_ppm"]) == expected
    finally:
        rec.close()


def _traced_peak(channels: list[Channel], directory: Path, block: int, fn) -> int:
    rec, store = _stored(channels, directory)
    try:
        tracemalloc.start()
        try:
            base = tracemalloc.get_traced_memory()[0]
            fn(rec, store, block)
            return tracemalloc.get_traced_memory()[1] - base
        finally:
            tracemalloc.stop()
    finally:
        store.cleanup()


def _windowed(rec: Recording, store: ChannelStore, block: int) -> None:
    clock_offsets(ChannelBlocks(rec, store, block))


def _whole_read(rec: Recording, store: ChannelStore, block: int) -> None:
    _whole(rec)


def _no_work(*args: object, **kwargs: object) -> float:
    """A stand-in for the cross-correlations and fits: what is traced is then the reads alone (the FFTs' own
    buffers, tens of MB, change with the grid's length by a sample and would hide them)."""
    return 0.137


def test_the_offsets_hold_windows_not_channels(long_recording, tmp_path: Path, monkeypatch) -> None:
    """1.5 h -> 4.5 h (three times the samples: 216,000 more in each of the seven channels, 16 bytes each read
    whole: 24 MB): the windowed work's traced peak grows by less than a block of 20,000 samples (its reads of
    whole blocks) and 0.5 MB for the windows' list and the bisections; the whole-channel work grows by more than
    four times that. The correlations and fits are stubbed (:func:`_no_work`): their work is the same for any
    length (the central hour, the 15-minute windows)."""
    import sys

    import benchtwin.chain.alignment as alignment

    for name in ("_correlate", "_slip_fit", "detect_lag"):
        monkeypatch.setattr(alignment, name, _no_work)
    for name in ("detect_lag", "slip_aware_lag"):
        monkeypatch.setattr(sys.modules[__name__], name, _no_work)
    block = 20_000
    bound = 18 * block + 500_000
    longer = _synthetic(4.5)
    windowed = [_traced_peak(chs, tmp_path / f"w{k}", block, _windowed) for k, chs in enumerate((long_recording,
                                                                                                 longer))]
    assert windowed[1] - windowed[0] < bound, windowed
    whole = [_traced_peak(chs, tmp_path / f"a{k}", block, _whole_read) for k, chs in enumerate((long_recording,
                                                                                               longer))]
    assert whole[1] - whole[0] > 4 * bound, whole
    print("traced peaks (B): windowed", windowed, "whole", whole)


def test_the_telemetry_drift_is_found_from_the_drive_force(long_recording) -> None:
    """The telemetry's 25 ppm against the CAN's drive force (engine and motor power over the vehicle speed). The
    signals are noiseless: a window's lag is off by the parabola's refinement on the 20 Hz grid, well under a tenth
    of its 50 ms step (5 ms); five windows over 1.5 h then bound the slope's error by 2 x 5 ms / 3600 s = 2.8 ppm,
    and the offset (at the central hour's centre) by 5 ms."""
    rec = Recording()
    for ch in long_recording:
        rec.add(ch)
    detail: dict[str, dict[str, float]] = {}
    offsets, drifts = clock_offsets(rec, detail)
    key = "vehicle_can->telemetry"
    assert drifts[key] == pytest.approx(25.0, abs=2.8)
    t_ref = detail["clock_offset_time_s"][key]
    assert offsets[key] == pytest.approx(0.2 + 25e-6 * t_ref, abs=0.005)
    assert 0 < detail["clock_drift_se_ppm"][key] < 25.0 / np.sqrt(2)  # significant (see source_shifts)
    assert drifts["vehicle_can->dyno"] == pytest.approx(40.0, abs=2.8)
