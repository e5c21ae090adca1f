"""The property tests' draws do not depend on which of the project's modules are loaded (``_profiles``).

A derandomized ``ci`` example must be the same example whatever tests ran before it in the worker. Hypothesis
mixes the literals of loaded local modules into its draws unless ``freeze_local_constants`` holds; this test loads
a new local module full of literals inside the strategies' ranges between two derandomized runs of the same
strategy and asserts the two runs drew the same values.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st


def _draws() -> list[tuple[float, int]]:
    seen: list[tuple[float, int]] = []

    @settings(derandomize=True, database=None, max_examples=200, deadline=None,
              suppress_health_check=list(HealthCheck))
    @given(st.floats(0.80, 0.99), st.integers(1, 10_000))
    def collect(x: float, n: int) -> None:
        seen.append((x, n))

    collect()
    return seen


def test_loading_a_module_with_literals_does_not_move_the_draws(tmp_path: Path) -> None:
    before = _draws()
    # literals a fresh local module brings, all inside the ranges drawn above: the pool hypothesis would mix in
    literals = [f"C{i} = {0.8 + 0.0009 * i!r}\nN{i} = {17 + 37 * i}\n" for i in range(200)]
    (tmp_path / "bt_literal_pool_probe.py").write_text("".join(literals), encoding="utf-8")
    sys.path.insert(0, str(tmp_path))
    try:
        importlib.import_module("bt_literal_pool_probe")
        after = _draws()
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("bt_literal_pool_probe", None)
    assert len(before) == len(after) == 200
    assert before == after
