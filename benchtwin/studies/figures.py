"""Summary figures of a sweep: parameter error against each axis, pass rate per setup (matplotlib PNGs)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["summary_figures"]

#: at most this many checks per panel (the worst by median |error|), so a figure stays legible
MAX_LINES = 10


def _safe(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)


def summary_figures(table: Any, axes: list[str], out_dir: str | Path) -> list[Path]:
    """Draw ``error_vs_<axis>.png`` for every axis and ``pass_rate.png``; return the files written.

    Parameters
    ----------
    table:
        The sweep table (:func:`~benchtwin.studies.sweep.read_table`).
    axes:
        The axis columns.
    out_dir:
        Where to write the PNGs.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    ok = table[table["status"] == "ok"]
    written: list[Path] = []
    err_cols = [c for c in ok.columns if c.startswith("error:") and not c.startswith("error:chain.")
                and not c.endswith("r2") and ok[c].notna().any()]
    groups: dict[str, list[str]] = {}
    for c in err_cols:
        groups.setdefault(c[len("error:"):].split(".", 1)[0], []).append(c)
    for axis in axes:
        if not groups or ok.empty:
            break
        numeric = _numeric(ok[axis])
        x_key = numeric if numeric is not None else ok[axis].astype(str)
        xs = sorted(set(x_key))
        fig, panels = plt.subplots(len(groups), 1, figsize=(8, 2.6 * len(groups)), squeeze=False)
        for ax, (group, cols) in zip(panels[:, 0], sorted(groups.items())):
            med = {c: ok[c].abs().groupby(x_key).median().reindex(xs) for c in cols}
            worst = sorted(cols, key=lambda c: -np.nan_to_num(med[c].max(), nan=-1.0))[:MAX_LINES]
            pos = xs if numeric is not None else list(range(len(xs)))
            for c in worst:
                ax.plot(pos, med[c].to_numpy(dtype=float), marker="o", label=c[len("error:"):])
            ax.set_yscale("symlog", linthresh=1e-4)
            ax.set_ylabel("|error| (median)")
            ax.set_title(f"{group}: the {len(worst)} largest of {len(cols)} checks", fontsize=9)
            ax.legend(fontsize=6, loc="best")
            if numeric is None:
                ax.set_xticks(pos, xs)
        panels[-1, 0].set_xlabel(axis)
        fig.tight_layout()
        path = out / f"error_vs_{_safe(axis)}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        written.append(path)
    if not ok.empty:
        setup_axes = [a for a in axes if a == "setup" or a.startswith("setup.")] or list(axes)
        rate = (ok["n_checks"] - ok["n_failed"]) / ok["n_checks"].where(ok["n_checks"] > 0)
        labels = (ok[setup_axes].astype(str).agg(", ".join, axis=1) if setup_axes
                  else ok["run_key"].map(lambda _k: "base setup"))
        per = rate.groupby(labels).mean()
        fig, ax = plt.subplots(figsize=(8, 0.35 * len(per) + 1.5))
        ax.barh(range(len(per)), 100.0 * per.to_numpy(dtype=float))
        ax.set_yticks(range(len(per)), list(per.index), fontsize=7)
        ax.set_xlabel("checks passed, % (mean over seeds and the other axes)")
        ax.set_xlim(0, 100)
        ax.set_title(", ".join(setup_axes) if setup_axes else "pass rate", fontsize=9)
        fig.tight_layout()
        path = out / "pass_rate.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        written.append(path)
    return written


def _numeric(col: Any) -> Any:
    import pandas as pd

    num = pd.to_numeric(col, errors="coerce")
    return num if num.notna().all() else None
