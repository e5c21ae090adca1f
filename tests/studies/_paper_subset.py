"""A campaign of some of the paper campaign's tests, written beside a test (the plan spread tests' campaigns)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from benchtwin.config import scenario_path


def paper_subset(path: Path, keep: Callable[[str], bool], *, head: str = "quick") -> tuple[Path, int]:
    """Write to ``path`` a campaign of the paper campaign's tests whose TOML text ``keep`` accepts.

    The campaign's own settings (before its first ``[[tests]]``) are those of the shipped campaign ``head``, renamed
    to ``path``'s stem. Returns the path and the number of tests kept.
    """
    top = scenario_path("campaigns", f"{head}.toml").read_text(encoding="utf-8").split("[[tests]]")[0]
    tests = [t for t in scenario_path("campaigns", "paper.toml").read_text(encoding="utf-8").split("[[tests]]")[1:]
             if keep(t)]
    path.write_text(top.replace(f'name = "{head}"', f'name = "{path.stem}"') + "".join("[[tests]]" + t for t in tests),
                    encoding="utf-8")
    return path, len(tests)
