"""Peak resident memory and wall time of ``benchtwin validate --out DIR`` (or ``simulate --out``) on the paper
campaign, 1x, 3x and 10x.

Usage::

    python benchmarks/bench_stream.py [--sizes 1,3,10] [--repeat 3] [--setup paper] [--rss-limit-gb 12]
                                      [--keep DIR] [--python PYTHON] [--command validate|simulate]

With ``--command simulate`` each run is ``benchtwin simulate --campaign FILE --out DIR --no-progress`` (the
plant test by test, the Trace streamed to ``trace.mf4``); the table then gives the wall time, the peak RSS and
the Trace's size.

The long campaigns are the paper campaign's tests repeated (``paper.toml`` with its ``[[tests]]`` written
``N`` times, the copies' names suffixed ``_r1``, ``_r2``, ...), written to a temporary folder. Each run is a
fresh process (``benchtwin validate --campaign FILE --setup SETUP --out DIR``) whose resident set
is sampled from ``/proc`` every 50 ms (the peak, as ``/usr/bin/time -v`` reports it, is also read from
``getrusage`` of the child); a run whose resident set passes ``--rss-limit-gb`` is stopped and reported as
such (the machine is shared). The table gives, per size, the campaign's plant seconds, the median and range of
the wall time over the repeats, the real-time factor (plant seconds per wall second), the median peak RSS,
the timings the run reports (``validation.json``: simulate, chain, identify, predict) and the size of the
outputs. Run it under the shared lock: ``flock /tmp/benchtwin-heavy.lock nice -n 5 python
benchmarks/bench_stream.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "benchtwin" / "scenarios" / "campaigns" / "paper.toml"


def repeated_campaign(n: int, directory: Path, base: Path = PAPER) -> Path:
    """The campaign ``base`` with its tests written ``n`` times (copies renamed ``<name>_r<k>``)."""
    text = base.read_text(encoding="utf-8")
    head, sep, tests = text.partition("[[tests]]")
    if not sep:
        raise SystemExit(f"{base}: no [[tests]]")
    tests = sep + tests
    copies = [tests]
    for k in range(1, n):
        copies.append(re.sub(r'^(name\s*=\s*")([^"]*)(")', rf"\g<1>\g<2>_r{k}\g<3>", tests, flags=re.M))
    head = re.sub(r'^name\s*=\s*"([^"]*)"', rf'name = "\g<1>_x{n}"', head, count=1, flags=re.M)
    path = directory / f"{base.stem}_x{n}.toml"
    path.write_text(head + "\n".join(copies), encoding="utf-8")
    return path


def run_once(python: str, campaign: Path, setup: str, out: Path, limit_gb: float, command: str = "validate") -> dict:
    """One ``benchtwin validate --out`` (or ``simulate``) in a fresh process: wall, peak RSS, the run's timings."""
    if out.exists():
        shutil.rmtree(out)
    cmd = [python, "-c", "import sys; from benchtwin.cli import main; sys.exit(main(sys.argv[1:]))", command,
           "--campaign", str(campaign), "--out", str(out)]
    cmd += ["--setup", setup] if command == "validate" else ["--no-progress"]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    peak_kb, stopped = 0, False
    status = Path(f"/proc/{proc.pid}/status")
    while proc.poll() is None:
        try:
            m = re.search(r"VmRSS:\s+(\d+)", status.read_text())
        except OSError:
            m = None
        if m:
            peak_kb = max(peak_kb, int(m.group(1)))
            if peak_kb > limit_gb * 2**20:
                proc.kill()
                stopped = True
        time.sleep(0.05)
    wall = time.perf_counter() - t0
    err = proc.stderr.read() if proc.stderr else ""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)  # max over the children waited for so far
    res = {"wall_s": wall, "peak_rss_mb": max(peak_kb / 1024, 0.0), "children_maxrss_mb": usage.ru_maxrss / 1024,
           "returncode": proc.returncode, "stopped_at_limit": stopped}
    vj = out / "validation.json"
    if vj.exists():
        rep = json.loads(vj.read_text(encoding="utf-8"))
        res["timings_s"] = rep.get("timings_s", {})
        res["plant_s"] = rep.get("chain", {}).get("plant_seconds")
        res["checks_failed"] = [c["name"] for c in rep.get("checks", []) if not c.get("passed", True)]
    elif (out / "meta.json").exists() and command == "simulate" and proc.returncode == 0:
        segs = json.loads((out / "segments.json").read_text(encoding="utf-8"))
        res["plant_s"] = float(segs[-1]["end_s"] - segs[0]["start_s"]) if segs else 0.0
    elif not stopped:
        res["error"] = err.strip().splitlines()[-1] if err.strip() else "no validation.json"
    res["outputs_mb"] = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 2**20 if out.exists() else 0
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="1,3,10", help="campaign lengths in paper campaigns (default 1,3,10)")
    ap.add_argument("--repeat", default="3", help="runs per size: one number, or one per size (e.g. 3,3,1)")
    ap.add_argument("--campaign", type=Path, default=PAPER, help="campaign file repeated (default: paper.toml)")
    ap.add_argument("--setup", default="paper", help="setup name or file (default paper)")
    ap.add_argument("--rss-limit-gb", type=float, default=12.0, help="stop a run above this resident set")
    ap.add_argument("--keep", type=Path, default=None, help="keep the campaigns and outputs here")
    ap.add_argument("--python", default=sys.executable, help="interpreter with benchtwin installed")
    ap.add_argument("--json", type=Path, default=None, help="also write the results as JSON")
    ap.add_argument("--command", choices=("validate", "simulate"), default="validate",
                    help="the command measured (default validate)")
    args = ap.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]
    reps = [int(r) for r in args.repeat.split(",")]
    reps = reps * len(sizes) if len(reps) == 1 else reps
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_stream_"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    try:
        for n, rep in zip(sizes, reps, strict=True):
            camp = repeated_campaign(n, work, args.campaign)
            runs = [run_once(args.python, camp, args.setup, work / f"out_x{n}", args.rss_limit_gb, args.command)
                    for _ in range(rep)]
            rows.append({"size": n, "runs": runs})
            print(f"x{n}: " + "; ".join(f"{r['wall_s']:.1f} s, {r['peak_rss_mb']:.0f} MB"
                                        + (" (stopped at the RSS limit)" if r["stopped_at_limit"] else "")
                                        for r in runs), flush=True)
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    print(f"\n{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}, commit {commit.strip()}, command {args.command}, setup {args.setup}, "
          f"load average {os.getloadavg()[0]:.1f}\n")
    print("| campaign | plant s | runs | wall median (s) | min..max (s) | x real time | peak RSS median (MB) "
          "| simulate / chain / identify / predict (s) | outputs (MB) | failed checks |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        ok = [r for r in row["runs"] if not r["stopped_at_limit"] and "error" not in r]
        if not ok:
            why = "stopped at the RSS limit" if any(r["stopped_at_limit"] for r in row["runs"]) else \
                row["runs"][0].get("error", "failed")
            print(f"| {args.campaign.stem} x{row['size']} | | {len(row['runs'])} | {why} (RSS > "
                  f"{max(r['peak_rss_mb'] for r in row['runs']):.0f} MB) | | | | | | |")
            continue
        walls = [r["wall_s"] for r in ok]
        wall = statistics.median(walls)
        plant = ok[0].get("plant_s") or float("nan")
        tm = ok[len(ok) // 2].get("timings_s", {})
        stages = " / ".join(f"{tm.get(k, float('nan')):.1f}" for k in ("simulate", "chain", "identify", "predict"))
        print(f"| {args.campaign.stem} x{row['size']} | {plant:.0f} | {len(ok)} | {wall:.1f} "
              f"| {min(walls):.1f}..{max(walls):.1f} "
              f"| {plant / wall:.0f}x | {statistics.median(r['peak_rss_mb'] for r in ok):.0f} | {stages} "
              f"| {ok[0]['outputs_mb']:.0f} | {len(ok[0].get('checks_failed', []))} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
