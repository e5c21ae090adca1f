"""Encode -> deliver chunk by chunk: the same bytes for any chunking, and the device state carried across blocks.

1. The quick campaign (922 s, 92 k plant samples) through the paper bench and the fault bench (every fault
   kind): ``deliver(encode(...))`` at once, and ``iter_delivered`` fed whole, test by test
   (``iter_campaign``) and in 37-s slices: every bus's frame table and the poll log are byte-identical.
2. Chunking cannot change the draws (they are keyed by block), so (1) alone would not notice a state that
   is not carried from one block to the next: every block would restart it the same way. A bench without
   random draws (the paper bench with noise and fault probabilities at zero, its filters, clocks and
   latencies kept, deterministic faults across a block edge) encoded in 60-s blocks must equal the same bench
   in one block (the whole-array algorithm). Mutants that drop the filter state, the counters or the
   charge integral at each block edge must break that equality: they do (checked here).

Cost: about 30 s of CPU (one quick-campaign simulation, eight chain runs), plus 10 s for (2).
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import pytest

from benchtwin.chain.batch import deliver
from benchtwin.chain.delivery import iter_delivered
from benchtwin.config import load_campaign, load_setup, load_vehicle
from benchtwin.config._base import validate_data
from benchtwin.config.setup import SetupConfig
from benchtwin.emulator import iter_campaign
from benchtwin.errors import DataError
from benchtwin.sensors import ChunkEncoder, encode
from benchtwin.sensors.blocks import Block
from benchtwin.sensors.synthetic import synthetic_trace
from benchtwin.trace import Trace

SEED = 7


@pytest.fixture(scope="module")
def quick_tests() -> list[Trace]:
    return list(iter_campaign(load_vehicle(), load_campaign("quick.toml")))


def _join(parts: list[Trace]) -> Trace:
    return Trace(np.concatenate([p.time_s for p in parts]),
                 {k: np.concatenate([p[k] for p in parts]) for k in parts[0].channels},
                 [s for p in parts for s in p.segments], dict(parts[0].meta))


def _slices(trace: Trace, step_s: float) -> list[Trace]:
    t0, t1 = float(trace.time_s[0]), float(trace.time_s[-1])
    edges = np.arange(t0, t1 + step_s, step_s)
    return [c for a, b in itertools.pairwise(edges) if len(c := trace.slice_time(a, b))]


def _chain(chunks: list[Trace], setup: SetupConfig, block_s: float = 60.0) -> dict[str, Any]:
    """Encode and deliver the chunks in turn; every bus's frames and every poll log, put end to end."""
    got: dict[str, list[np.ndarray]] = {}
    for rec in iter_delivered(chunks, setup, SEED, block_s=block_s):
        for bus, table in rec.can.items():
            got.setdefault(bus, []).append(table.frames)
        for dev, log in rec.polls.items():
            for field in ("times", "values", "status"):
                got.setdefault(f"{dev}.{field}", []).append(getattr(log, field))
    return {k: np.concatenate(v) for k, v in got.items()}


def _assert_same(a: dict[str, Any], b: dict[str, Any]) -> None:
    assert sorted(a) == sorted(b)
    for k in a:
        assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
        same = a[k].tobytes() == b[k].tobytes()  # a bool: pytest diffs no megabytes (CI=true shows diffs whole)
        assert same, f"{k} differs"


@pytest.mark.parametrize("setup_name", ["paper", "faults"])
def test_any_chunking_gives_the_same_bytes(quick_tests: list[Trace], setup_name: str) -> None:
    setup = load_setup(setup_name)
    trace = _join(quick_tests)
    once = deliver(encode(trace, setup, SEED), setup, seed=SEED, span_s=(trace.time_s[0], trace.time_s[-1]))
    whole = {bus: t.frames for bus, t in once.can.items()}
    whole.update({f"{d}.{f}": getattr(log, f) for d, log in once.polls.items() for f in ("times", "values", "status")})
    assert len(whole["instrument"]) > 1_000_000 and len(whole["brake_pressure.times"]) > 90_000
    for bus in ("vehicle", "instrument", "dyno"):
        assert np.all(np.diff(whole[bus]["timestamp"]) >= 0), bus
    _assert_same(whole, _chain([trace], setup))  # the whole-run API is the one-chunk case
    _assert_same(whole, _chain(quick_tests, setup))  # a test per chunk (iter_campaign)
    _assert_same(whole, _chain(_slices(_join(quick_tests), 37.0), setup))  # edges nowhere near a block's


def _draw_free() -> SetupConfig:
    """The paper bench with every random draw at zero, and deterministic faults across the 60-s block edge."""
    def zero(x: Any) -> Any:
        if isinstance(x, dict):
            return {k: (0.0 if (k == "noise_std" or k.endswith("_prob")) and v else zero(v)) for k, v in x.items()}
        return [zero(v) for v in x] if isinstance(x, list) else x

    data = zero(load_setup("paper").model_dump())
    data["faults"] = [
        {"kind": "stuck", "device": "ivt_battery", "channel": "battery_current_a", "start_s": 58.0, "duration_s": 5.0},
        {"kind": "modbus_restart", "device": "brake_pressure", "start_s": 59.9, "duration_s": 0.5},
        {"kind": "silent", "device": "telemetry", "start_s": 59.0, "duration_s": 2.0},
        {"kind": "clock_step", "device": "brake_pressure", "start_s": 90.0, "duration_s": 1.0, "offset_s": 0.1},
    ]
    return validate_data(SetupConfig, data, "draw-free paper bench")


def _forget(monkeypatch: pytest.MonkeyPatch, method: str, key: str) -> None:
    """A mutant: the block forgets one kind of carried state at every block edge."""
    real = getattr(Block, method)
    seen: dict[int, int] = {}

    def mutant(self: Block, *args: Any) -> Any:
        if seen.setdefault(id(self.state), self.index) != self.index:
            self.state.pop(key, None)
            seen[id(self.state)] = self.index
        return real(self, *args)

    monkeypatch.setattr(Block, method, mutant)


@pytest.fixture(scope="module")
def one_block() -> tuple[SetupConfig, Trace, dict[str, Any]]:
    setup, trace = _draw_free(), synthetic_trace(150.0, seed=3)
    return setup, trace, _chain([trace], setup, block_s=1e6)


@pytest.mark.parametrize("mutant", [None, ("filtered", "lti"), ("counter", "count"), ("accumulated", "sum")])
def test_blocks_carry_the_device_state(monkeypatch: pytest.MonkeyPatch, one_block: tuple, mutant: tuple | None) -> None:
    setup, trace, whole = one_block
    if mutant is not None:
        _forget(monkeypatch, *mutant)
    blocks = _chain(_slices(trace, 37.0), setup)
    if mutant is None:
        _assert_same(whole, blocks)
    else:
        with pytest.raises(AssertionError):
            _assert_same(whole, blocks)


def test_chunks_out_of_order_are_refused() -> None:
    trace = synthetic_trace(20.0)
    enc = ChunkEncoder(load_setup("paper"), SEED)
    enc.feed(trace.slice_time(0.0, 10.0))
    with pytest.raises(DataError, match="not after the previous chunk"):
        enc.feed(trace.slice_time(5.0, 20.0))
    enc.feed(trace.slice_time(10.0, 20.0), final=True)
    with pytest.raises(DataError, match="has ended"):
        enc.feed(trace)


def _outputs_bytes(outs: list) -> dict[str, bytes]:
    """Every array of a run's outputs, put end to end over its chunks."""
    got: dict[str, bytes] = {}

    def add(key: str, a: np.ndarray) -> None:
        got[key] = got.get(key, b"") + a.tobytes()

    for o in outs:
        for bus, table in o.can.items():
            add(f"can:{bus}", table.frames)
        for name, im in o.canopen.items():
            add(f"canopen:{name}.times", im.times)
            add(f"canopen:{name}.values", im.values)
        for name, snap in o.modbus.items():
            add(f"modbus:{name}.times", snap.times)
            add(f"modbus:{name}.registers", snap.registers)
    return got


def test_a_pool_of_threads_gives_the_same_outputs_and_lives_for_the_run() -> None:
    """``workers=2`` (one pool for the run) against the default (no threads), fed the same 30-s slices of a
    200-s trace (four 60-s blocks): the same outputs, chunk for chunk; the pool is the same between chunks and
    shut once the final chunk is encoded."""
    trace = synthetic_trace(200.0, seed=5)
    setup = load_setup("paper")
    chunks = _slices(trace, 30.0)
    plain, pooled = ChunkEncoder(setup, SEED), ChunkEncoder(setup, SEED, workers=2)
    assert plain.workers == 1 and plain._pool is None
    a, b, pools = [], [], []
    for i, chunk in enumerate(chunks):
        final = i == len(chunks) - 1
        a.append(plain.feed(chunk, final=final))
        b.append(pooled.feed(chunk, final=final))
        pools.append(pooled._pool)
        assert plain._pool is None
    assert pools[0] is not None and all(p is pools[0] for p in pools[:-1]) and pools[-1] is None
    assert pools[0]._shutdown
    assert [o.until_s for o in a] == [o.until_s for o in b]
    for x, y in zip(a, b):
        assert _outputs_bytes([x]) == _outputs_bytes([y])
    whole = _outputs_bytes([encode(trace, setup, SEED)])
    assert _outputs_bytes(a) == whole and len(whole) >= 3
