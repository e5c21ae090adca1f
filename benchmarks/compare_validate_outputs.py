"""Whether two ``benchtwin validate --out`` folders hold the same results (a speed change must not move them).

Usage::

    python benchmarks/compare_validate_outputs.py BEFORE_DIR AFTER_DIR

``validation.json`` and ``params.json`` are compared field by field but for the run's seconds (``timings_s``,
``seconds``); each raw bus log (``<bus>.mf4``) frame by frame (the frame records' bytes as ``read_mf4`` gives them);
``recording.mf4`` channel by channel (timestamps, values, flags) and its meta data. Prints each difference and a
summary; exits 1 when anything differs.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

#: keys left out of the comparison: how long the run took
SKIP = {"timings_s", "seconds"}


def diff(x: Any, y: Any, path: str = "") -> int:
    """Print and count the differences between two JSON values (NaN equals NaN; ``SKIP`` keys left out)."""
    if type(x) is not type(y):
        print("type", path, type(x).__name__, type(y).__name__)
        return 1
    if isinstance(x, dict):
        n = 0
        for k in sorted(set(x) | set(y)):
            if k in SKIP:
                continue
            if k not in x or k not in y:
                print("key", path, k)
                n += 1
            else:
                n += diff(x[k], y[k], f"{path}/{k}")
        return n
    if isinstance(x, list):
        if len(x) != len(y):
            print("length", path, len(x), len(y))
            return 1
        return sum(diff(u, v, f"{path}[{i}]") for i, (u, v) in enumerate(zip(x, y, strict=True)))
    if x != y and not (isinstance(x, float) and x != x and y != y):
        print("value", path, repr(x)[:80], repr(y)[:80])
        return 1
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before", type=Path, help="one validate --out folder")
    ap.add_argument("after", type=Path, help="the other")
    args = ap.parse_args()
    from benchtwin.chain.buslog import read_mf4
    from benchtwin.recording import Recording

    a, b = args.before, args.after
    bad = 0
    for f in ("validation.json", "params.json"):
        n = diff(json.loads((a / f).read_text()), json.loads((b / f).read_text()), f)
        print(f"{f}: {n} differences")
        bad += n
    for p in sorted(a.glob("*.mf4")):
        if p.name == "recording.mf4":
            continue
        fa, fb = read_mf4(p, p.stem), read_mf4(b / p.name, p.stem)
        same = len(fa) == len(fb) and fa.frames.tobytes() == fb.frames.tobytes()
        print(f"{p.name}: {len(fa)} frames, {'identical' if same else 'DIFFERENT'}")
        bad += not same
    ra, rb = Recording.open(a / "recording.mf4"), Recording.open(b / "recording.mf4")
    differ = [n for n in ra.channels if n not in rb.channels or not all(
        np.array_equal(getattr(ra[n], k), getattr(rb[n], k), equal_nan=k != "flags")
        for k in ("timestamps", "values", "flags"))]
    extra = sorted(set(rb.channels) - set(ra.channels))
    meta = diff(json.loads(json.dumps(ra.meta, default=str)), json.loads(json.dumps(rb.meta, default=str)), "meta")
    print(f"recording.mf4: {len(ra.channels)} channels, different {differ}, only in the second {extra}, "
          f"{meta} meta differences")
    bad += len(differ) + len(extra) + meta
    print("identical" if not bad else f"{bad} differences")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
