"""Synthetic device outputs for the live-chain tests (small, a few seconds of plant time)."""

from __future__ import annotations

import os
import re
import subprocess
import time
from pathlib import Path

import numpy as np

from benchtwin.wire.frames import FRAME_DTYPE, DeviceOutputs, FrameTable, ProcessImage, RegisterSnapshots

DATA = Path(__file__).parent / "data"
MIN_EDS = DATA / "thermo_min.eds"


def synthetic_frames(duration_s: float, rate_hz: float, ids: list[int], seed: int = 0, t0: float = 0.0) -> np.ndarray:
    """Frames cycling through ``ids`` at ``rate_hz`` in total; data = a counter and random bytes."""
    n = round(duration_s * rate_hz)
    rng = np.random.default_rng(seed)
    f = np.zeros(n, dtype=FRAME_DTYPE)
    f["timestamp"] = t0 + np.arange(n) / rate_hz
    f["arbitration_id"] = np.asarray(ids, dtype=np.uint32)[np.arange(n) % len(ids)]
    f["dlc"] = 8
    f["data"] = rng.integers(0, 256, size=(n, 8), dtype=np.uint8)
    f["data"][:, 0] = (np.arange(n) & 0xFF).astype(np.uint8)
    f["data"][:, 1] = ((np.arange(n) >> 8) & 0xFF).astype(np.uint8)
    return f


def ivt_frames(duration_s: float, cycle_s: float = 0.02, base_id: int = 0x521) -> np.ndarray:
    """IVT-S current results (mux 0, counter, int32 mA) every ``cycle_s``."""
    n = round(duration_s / cycle_s)
    f = np.zeros(n, dtype=FRAME_DTYPE)
    f["timestamp"] = np.arange(n) * cycle_s + 0.001
    f["arbitration_id"] = base_id
    f["dlc"] = 6
    ma = (np.arange(n) * 100 - 5000).astype(">i4")
    f["data"][:, 1] = (np.arange(n) & 0xF).astype(np.uint8)
    f["data"][:, 2:6] = ma.view(np.uint8).reshape(n, 4)
    return f


def make_small_outputs() -> DeviceOutputs:
    """2 s of plant time: two CAN buses, a Modbus device at 100 Hz, a CANopen node at 10 Hz."""
    dur = 2.0
    pt = FrameTable("powertrain", synthetic_frames(dur, 1000.0, [0x100, 0x101, 0x102, 0x1A0], seed=1))
    inst = FrameTable.concat("instrument", [synthetic_frames(dur, 500.0, [0x310], seed=2), ivt_frames(dur)])
    t_mb = np.arange(0, dur, 0.01)
    regs = np.zeros((len(t_mb), 14), dtype=np.uint16)
    regs[:, 0] = (np.arange(len(t_mb)) * 97) % 65536
    regs[:, 11] = np.arange(len(t_mb)) % 65536
    snap = RegisterSnapshots("brake_pressure", 1, 0, t_mb, regs)
    t_pi = np.arange(0, dur, 0.1)
    ents = [(0x6401, k) for k in range(1, 9)]
    vals = (200 + np.arange(len(t_pi))[:, None] * 10 + np.arange(8)[None, :]).astype(np.int64)
    image = ProcessImage("thermo", 5, t_pi, ents, vals)
    return DeviceOutputs(can={"powertrain": pt, "instrument": inst}, modbus={"brake_pressure": snap},
                         canopen={"thermo": image})


#: pacing bounds (p50, p99 in ms) of the timing tests: tight when the test could take the real-time
#: policy (root or CAP_SYS_NICE), loose at normal priority on a loaded CI machine (a single stall of
#: another process spoils the p99 of a run this short); benchmarks/bench_live.py measures the real figures
PACING_BOUNDS_MS = {True: (1.0, 5.0), False: (2.0, 100.0)}


def serve_ok_but_for_speed(rc: int, err: str) -> bool:
    """``benchtwin serve`` kept its plan (exit 0), or missed only the speed-up on a loaded machine (exit 1 with
    "not held" as its only problem): what tests that do not check pacing accept."""
    problems = [line for line in err.splitlines() if "plan not kept" in line]
    return rc == 0 or (rc == 1 and bool(problems) and all("not held" in line for line in problems))


#: False under software emulation (the vcan guest of ``make test-vcan`` sets BENCHTWIN_EMULATED=1): there
#: wall-clock pacing says nothing about benchtwin, so the timing checks are left out and only what was
#: delivered (counts, order, ids, bytes) is judged
TIMING_JUDGED = os.environ.get("BENCHTWIN_EMULATED", "") != "1"


def wait_for_line(proc: subprocess.Popen, pattern: str, timeout: float, lines: list[str]) -> None:
    """Read ``proc``'s stdout into ``lines`` until a line matches ``pattern``; AssertionError on exit or timeout."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            if proc.poll() is not None:
                raise AssertionError(f"exited early:\n{''.join(lines)}\n{proc.stderr.read()}")
            continue
        lines.append(line)
        if re.search(pattern, line):
            return
    raise AssertionError(f"no line matching {pattern!r} within {timeout} s:\n{''.join(lines)}")
