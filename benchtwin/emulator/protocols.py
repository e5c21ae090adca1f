"""Campaign tests -> per-step command arrays and the segment table.

Each test of the campaign becomes a block of plant steps with the dyno mode and set speed, the driver's
mode (pedals from the protocol, or following a target speed), pedal and brake positions, gear hold,
hybrid mode, clutch and engine overrides and an end condition evaluated inside the loop (e.g. stop when
the displayed SOC reaches 13 %). Every test starts and ends at standstill.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from benchtwin.config._base import scenario_path
from benchtwin.config.campaign import (
    HYBRID_MODES,
    AccelerationTest,
    CampaignConfig,
    CoastdownTest,
    ConstantDriveTest,
    CycleTest,
    DecelerationTest,
    NeutralBrakingTest,
    RampDownTest,
    RampUpTest,
)
from benchtwin.emulator.params import (
    C_AREF,
    C_BRAKE,
    C_DRV_MODE,
    C_DYNO_MODE,
    C_DYNO_SET,
    C_END_KIND,
    C_END_VAL,
    C_ENG,
    C_GEAR,
    C_HMODE,
    C_K0,
    C_LU,
    C_LVLOAD,
    C_PEDAL,
    C_SEG,
    C_VPRE,
    C_VTGT,
    KMH,
    NC,
)
from benchtwin.errors import ConfigError
from benchtwin.segments import Segment

__all__ = ["MAX_PLANT_SAMPLES", "Protocol", "build_protocol", "check_size", "lazy_protocol", "load_cycle",
           "protocol_steps"]

#: the most plant steps a campaign may need (5e6: 13.9 h of plant time at 100 Hz, a few GiB of
#: command and output rows); the paper campaign needs about 1.4e6
MAX_PLANT_SAMPLES = 5_000_000

SEGMENT_KIND = {
    "ramp_up": "ramp_up", "constant_drive": "constant_drive", "acceleration": "acceleration",
    "deceleration": "deceleration", "ramp_down": "deceleration", "neutral_braking": "neutral_braking",
    "cycle": "cycle", "coastdown": "coastdown",
}
_FORCE = {"auto": -1, "on": 1, "off": 0, "closed": 1, "open": 0}


@dataclass
class Protocol:
    """Per-step commands (rows ``C_*``), one block per test, and the segment of each test.

    Segment times (and the ``*_s`` phase times in its settings) are relative to the test's start; a test
    may end before its block does (end condition reached and the car stopped), so the emulator fixes the
    absolute times while it runs.
    """

    blocks: list[np.ndarray] = field(default_factory=list)
    segments: list[Segment] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)
    #: the campaign the blocks are built from (:meth:`block` builds one on demand)
    campaign: CampaignConfig | None = None

    def block(self, k: int) -> np.ndarray:
        """Test ``k``'s command block: the one built already, or built now from the campaign (not kept)."""
        if k < len(self.blocks):
            return self.blocks[k]
        if self.campaign is None:
            raise IndexError(f"protocol has no block {k}")
        block = _build_test(self.campaign, k, dry=False)[2]
        assert block is not None
        return block

    @property
    def n_steps(self) -> int:
        """Number of plant steps if every test runs its full block."""
        return int(sum(self.steps)) if self.steps else int(sum(b.shape[1] for b in self.blocks))


def load_cycle(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Read a shipped cycle file (FASTSim layout: cycSecs, cycMps, ...) -> (time_s, speed_mps).

    Raises
    ------
    ConfigError
        The cycle is not shipped or not readable.
    """
    path = scenario_path("cycles", name)
    try:
        with path.open(encoding="utf-8-sig", newline="") as fh:
            rows = list(csv.DictReader(fh))
        t = np.array([float(r["cycSecs"]) for r in rows])
        v = np.array([float(r["cycMps"]) for r in rows])
    except (KeyError, ValueError) as exc:
        raise ConfigError(f"{path}: not a cycle file with columns cycSecs, cycMps ({exc})") from None
    return t, v


class _Builder:
    def __init__(self, dt: float, dry: bool = False) -> None:
        self.dt = dt
        self.dry = dry  # count the steps only (no arrays): the size check before anything is allocated
        self.blocks: list[np.ndarray] = []
        self.n = 0

    def phase(self, duration_s: float, *, seg: int, hmode: int, dyno_mode: int = 0, dyno_set: Any = np.nan,
              drv_mode: int = 0, pedal: Any = 0.0, brake: Any = 0.0, vtgt: Any = 0.0, gear: int = -1,
              k0: int = -1, lu: int = -1, eng: int = -1, end_kind: int = 0, end_val: float = 0.0) -> None:
        n = max(round(duration_s / self.dt), 1)
        if self.dry:
            self.n += n
            return
        b = np.empty((NC, n))
        tloc = np.arange(n) * self.dt
        for row, val in ((C_DYNO_SET, dyno_set), (C_PEDAL, pedal), (C_BRAKE, brake), (C_VTGT, vtgt)):
            b[row] = val(tloc) if callable(val) else val
        b[C_DYNO_MODE] = dyno_mode
        b[C_DRV_MODE] = drv_mode
        b[C_GEAR] = gear
        b[C_HMODE] = hmode
        b[C_K0] = k0
        b[C_LU] = lu
        b[C_ENG] = eng
        b[C_END_KIND] = end_kind
        b[C_END_VAL] = end_val
        b[C_SEG] = seg
        b[C_LVLOAD] = 0.0  # filled in by the emulator
        b[C_VPRE] = b[C_VTGT]
        b[C_AREF] = 0.0
        self.blocks.append(b)
        self.n += n

    @property
    def t(self) -> float:
        return self.n * self.dt


def _ramp(v0: float, v1: float, rate: float):
    """Speed ramp from v0 to v1 (m/s) at ``rate`` (m/s^2), then hold."""
    def f(t: np.ndarray) -> np.ndarray:
        if v1 >= v0:
            return np.minimum(v0 + rate * t, v1)
        return np.maximum(v0 - rate * t, v1)
    return f


def _steps(values: list[float], hold: float):
    arr = np.asarray(values, dtype=float)

    def f(t: np.ndarray) -> np.ndarray:
        idx = np.minimum((t // hold).astype(int), len(arr) - 1)
        return arr[idx]
    return f


def _dyno_stop(b: _Builder, v: float, seg: int, hm: int) -> None:
    """Dyno brings the car back to standstill (pedal off), then a short hold."""
    dur = v / 1.0 + 3.0
    b.phase(dur, seg=seg, hmode=hm, dyno_mode=1, dyno_set=_ramp(v, 0.0, 1.0), brake=lambda t: np.where(
        t > dur - 3.0, 20.0, 0.0))
    b.phase(1.0, seg=seg, hmode=hm, dyno_mode=0, brake=25.0)


def _driver_stop(b: _Builder, seg: int, hm: int, v: float, decel: float) -> None:
    b.phase(v / decel + 4.0, seg=seg, hmode=hm, drv_mode=1, vtgt=_ramp(v, 0.0, decel))


def protocol_steps(campaign: CampaignConfig) -> list[int]:
    """Plant steps of each test's full block, computed without building any array."""
    return _build(campaign, dry=True).steps


def check_size(campaign: CampaignConfig) -> int:
    """Return the campaign's plant steps; ConfigError if they exceed :data:`MAX_PLANT_SAMPLES`.

    The message says how long the campaign would run, the limit, and the longest test (where a
    duration key is most likely too large).
    """
    steps = protocol_steps(campaign)
    n = sum(steps)
    if n > MAX_PLANT_SAMPLES:
        dt = 1.0 / campaign.plant_rate_hz
        k = int(np.argmax(steps))
        test = campaign.tests[k]
        raise ConfigError(
            f"campaign {campaign.name!r}: the tests need {n * dt:.4g} s ({n * dt / 3600:.1f} h) of plant time, "
            f"{n:.3g} plant samples at {campaign.plant_rate_hz:g} Hz; the limit is {MAX_PLANT_SAMPLES:.3g} samples "
            f"({MAX_PLANT_SAMPLES * dt / 3600:.1f} h at this rate); the longest is tests[{k}] "
            f"({test.name or test.kind}, {steps[k] * dt:.4g} s): shorten its durations or split the campaign")
    return n


def build_protocol(campaign: CampaignConfig) -> Protocol:
    """Turn the campaign's tests into per-step commands and the segment table.

    Parameters
    ----------
    campaign:
        The validated campaign.

    Returns
    -------
    Protocol
        One command block per test (the 12 V load row is filled in by the emulator) and one Segment per test.

    Raises
    ------
    ConfigError
        The campaign needs more than :data:`MAX_PLANT_SAMPLES` plant steps (checked before allocating).
    """
    check_size(campaign)
    return _build(campaign, dry=False)


def lazy_protocol(campaign: CampaignConfig) -> Protocol:
    """The campaign's segments and steps, with each test's command block built when :meth:`Protocol.block` asks.

    Only one test's commands are held at a time, so the campaign's length is bounded per test (by
    :data:`MAX_PLANT_SAMPLES`), not in total: this is what :func:`benchtwin.emulator.iter_campaign` runs.

    Raises
    ------
    ConfigError
        A test needs more than :data:`MAX_PLANT_SAMPLES` plant steps.
    """
    proto = _build(campaign, dry=True)
    k = int(np.argmax(proto.steps))
    if proto.steps[k] > MAX_PLANT_SAMPLES:
        dt, test = 1.0 / campaign.plant_rate_hz, campaign.tests[k]
        raise ConfigError(
            f"campaign {campaign.name!r}: tests[{k}] ({test.name or test.kind}) needs {proto.steps[k] * dt:.4g} s "
            f"of plant time, {proto.steps[k]:.3g} plant samples at {campaign.plant_rate_hz:g} Hz; the limit for one "
            f"test is {MAX_PLANT_SAMPLES:.3g} samples ({MAX_PLANT_SAMPLES * dt / 3600:.1f} h at this rate): shorten "
            "its durations or split it into several tests")
    return proto


def _build(campaign: CampaignConfig, *, dry: bool) -> Protocol:
    segments: list[Segment] = []
    test_steps: list[int] = []
    names: set[str] = set()
    for k in range(len(campaign.tests)):
        seg, n, _ = _build_test(campaign, k, dry=True)
        if seg.name in names:
            raise ConfigError(f"campaign {campaign.name!r}: test name {seg.name!r} is used twice")
        names.add(seg.name)
        segments.append(seg)
        test_steps.append(n)
    proto = Protocol(segments=segments, steps=test_steps, campaign=campaign)
    if not dry:
        proto.blocks = [proto.block(k) for k in range(len(segments))]
    return proto


def _build_test(campaign: CampaignConfig, k: int, *, dry: bool) -> tuple[Segment, int, np.ndarray | None]:
    """Test ``k``'s segment (times from its start), its plant steps and (unless ``dry``) its command block."""
    dt = 1.0 / campaign.plant_rate_hz
    stop = campaign.driver.stop_decel_mps2
    test = campaign.tests[k]
    b = _Builder(dt, dry)
    t0 = 0.0
    hm = HYBRID_MODES[test.mode]
    settings: dict[str, Any] = test.model_dump(exclude_none=True)
    if isinstance(test, RampUpTest):
        v = test.speed_kmh * KMH
        lead = test.lead_in_s
        b.phase(lead, seg=k, hmode=hm, dyno_mode=1, dyno_set=_ramp(0.0, v, max(v / (0.6 * lead), 0.3)))
        steps = list(test.pedal_steps_pct)
        hold = test.step_hold_s
        common = {"seg": k, "hmode": hm, "dyno_mode": 1, "dyno_set": v, "gear": test.gear,
                  "k0": _FORCE[test.k0], "lu": _FORCE[test.lockup], "eng": _FORCE[test.engine]}
        b.phase(6.0, **common)  # gear engages, lock-up closes, engine starts
        settings["steps_start_s"] = b.t
        b.phase(hold * len(steps), pedal=_steps(steps, hold), **common)
        if test.brake_steps_pct:
            b.phase(hold * len(test.brake_steps_pct), brake=_steps(list(test.brake_steps_pct), hold), **common)
        settings["steps_end_s"] = b.t
        _dyno_stop(b, v, k, hm)
    elif isinstance(test, ConstantDriveTest):
        v = test.speed_kmh * KMH
        gear = test.gear if test.gear > 0 else -1
        b.phase(test.approach_s, seg=k, hmode=hm, drv_mode=1, vtgt=_ramp(0.0, v, max(v / (0.7 * test.approach_s),
                                                                                 0.3)))
        kind, val = (0, 0.0)
        if test.end_displayed_soc_pct is not None:
            kind = 2 if test.mode != "charge" else 3
            val = test.end_displayed_soc_pct
        settings["hold_start_s"] = b.t
        b.phase(test.max_duration_s, seg=k, hmode=hm, drv_mode=1, vtgt=v, gear=gear, end_kind=kind, end_val=val)
        b.phase(v / stop + 5.0, seg=k, hmode=hm, drv_mode=1, vtgt=_ramp(v, 0.0, stop), end_kind=4)
    elif isinstance(test, AccelerationTest):
        b.phase(3.0, seg=k, hmode=hm, brake=30.0)
        settings["pedal_start_s"] = b.t
        b.phase(test.max_duration_s, seg=k, hmode=hm, pedal=test.pedal_pct, end_kind=1,
                end_val=test.end_speed_kmh * KMH)
        b.phase(test.end_speed_kmh * KMH / stop + 5.0, seg=k, hmode=hm, drv_mode=1, end_kind=4)
    elif isinstance(test, DecelerationTest):
        v = test.start_speed_kmh * KMH
        b.phase(test.approach_s, seg=k, hmode=hm, drv_mode=1, vtgt=_ramp(0.0, v, max(v / (0.7 * test.approach_s),
                                                                                 0.3)))
        settings["decel_start_s"] = b.t
        _driver_stop(b, k, hm, v, test.decel_mps2)
    elif isinstance(test, RampDownTest):
        v0, v1 = test.start_speed_kmh * KMH, test.end_speed_kmh * KMH
        b.phase(test.lead_in_s, seg=k, hmode=hm, dyno_mode=1,
                dyno_set=_ramp(0.0, v0, max(v0 / (0.7 * test.lead_in_s), 0.3)))
        b.phase(4.0, seg=k, hmode=hm, dyno_mode=1, dyno_set=v0, pedal=test.pedal_pct)
        settings["ramp_start_s"] = b.t
        rate = test.rate_kmh_per_s * KMH
        b.phase((v0 - v1) / rate, seg=k, hmode=hm, dyno_mode=1, dyno_set=_ramp(v0, v1, rate), pedal=test.pedal_pct)
        if v1 > 0:
            _dyno_stop(b, v1, k, hm)
        else:
            b.phase(2.0, seg=k, hmode=hm, brake=25.0)
    elif isinstance(test, NeutralBrakingTest):
        v = test.speed_kmh * KMH
        b.phase(test.lead_in_s, seg=k, hmode=hm, dyno_mode=1,
                dyno_set=_ramp(0.0, v, max(v / (0.6 * test.lead_in_s), 0.3)))
        b.phase(2.0, seg=k, hmode=hm, dyno_mode=1, dyno_set=v, gear=0)
        settings["steps_start_s"] = b.t
        hold = test.step_hold_s
        steps = [*test.brake_steps_pct, 0.0]
        b.phase(hold * len(steps), seg=k, hmode=hm, dyno_mode=1, dyno_set=v, gear=0, brake=_steps(steps, hold))
        settings["steps_end_s"] = b.t
        _dyno_stop(b, v, k, hm)
    elif isinstance(test, CycleTest):
        tc, vc = load_cycle(test.cycle)
        t_end = float(tc[-1]) if test.to_s is None else min(test.to_s, float(tc[-1]))
        if test.from_s >= t_end:
            raise ConfigError(f"campaign {campaign.name!r}: test {k}: from_s {test.from_s} is past the end "
                              f"of {test.cycle} ({t_end:.0f} s)")
        grid = np.arange(test.from_s, t_end + 1e-9, 0.1)
        vg = np.interp(grid, tc, vc)
        settings["cycle_distance_m"] = float(np.sum(0.5 * (vg[1:] + vg[:-1]) * np.diff(grid)))
        dur = t_end - test.from_s + dt
        b.phase(dur, seg=k, hmode=hm, drv_mode=1,
                vtgt=lambda t, tc=tc, vc=vc, t0=test.from_s: np.interp(t + t0, tc, vc))
        if vg[-1] > 0.1:
            _driver_stop(b, k, hm, float(vg[-1]), stop)
    elif isinstance(test, CoastdownTest):
        v = (test.start_speed_kmh + 5.0) * KMH
        b.phase(test.approach_s, seg=k, hmode=hm, drv_mode=1, vtgt=_ramp(0.0, v, max(v / (0.75 * test.approach_s),
                                                                                 0.3)))
        settings["coast_start_s"] = b.t
        b.phase(test.max_duration_s, seg=k, hmode=hm, gear=0, eng=0, k0=0)
        b.phase(2.0, seg=k, hmode=hm, brake=25.0)
    else:  # pragma: no cover - the union is closed
        raise ConfigError(f"unknown test kind {test!r}")
    name = test.name or f"{test.kind}_{k:02d}"
    settings["mode"] = test.mode
    settings["protocol"] = test.kind
    seg = Segment(start_s=t0, end_s=b.t, kind=SEGMENT_KIND[test.kind], name=name, settings=settings)
    if dry:
        return seg, b.n, None
    block = np.ascontiguousarray(np.concatenate(b.blocks, axis=1))
    _driver_preview(block, dt, campaign.driver.preview_s)
    return seg, b.n, block


def _driver_preview(block: np.ndarray, dt: float, preview_s: float, half_window_s: float = 0.5) -> None:
    """Fill the previewed target speed and reference acceleration of every follow-mode run of a block.

    The driver looks ``preview_s`` ahead, never past the end of the run in which it follows a target; the
    reference acceleration is the slope of the target over +-``half_window_s`` around the preview point.
    """
    follow = block[C_DRV_MODE] == 1
    if not follow.any():
        return
    npre = round(preview_s / dt)
    nh = max(1, int(half_window_s / dt))
    edges = np.flatnonzero(np.diff(np.concatenate([[0], follow.astype(np.int8), [0]])))
    vt = block[C_VTGT]
    for a, b in zip(edges[0::2], edges[1::2], strict=True):
        i = np.arange(a, b)
        j = np.minimum(i + npre, b - 1)
        j1 = np.maximum(j - nh, a)
        j2 = np.minimum(j + nh, b - 1)
        block[C_VPRE, a:b] = vt[j]
        span = (j2 - j1) * dt
        block[C_AREF, a:b] = np.where(j2 > j1, (vt[j2] - vt[j1]) / np.where(span > 0, span, 1.0), 0.0)
