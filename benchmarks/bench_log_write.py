"""The cost of writing a run's bus logs and recording.mf4: asammdf alone against benchtwin's data blocks; the codecs.

Run ``benchtwin validate --out DIR`` on the paper campaign first, then::

    flock /tmp/benchtwin-heavy.lock nice -n 5 python benchmarks/bench_log_write.py DIR [--repeat 3] [--append 200000]

For each bus log of DIR (read once) and for ``recording.mf4`` (loaded whole once):

- *writers*: the file written by asammdf alone (``MDF.append``/``extend``, each block lz4'ed into its temporary file,
  then decompressed and compressed on ``save``: benchtwin's writer before) and by :mod:`benchtwin.mf4stream` (the data
  blocks made on worker threads as they come; the bus logs appended ``--append`` frames at a time, as the chain's
  chunks come): wall, CPU of the process and CPU of the calling thread (what the caller waits for when another
  thread has the second core), and whether the two files are equal but the history block's time;
- *codecs* (bus logs): the records of the whole log in 4 MiB blocks, compressed by libdeflate (asammdf's) and by
  stdlib zlib at levels 1 and 6, transposed (asammdf's compression 2) and not (1): size and CPU; and whether two
  threads compressing halves take half the wall (the codec releases the GIL).

Medians of ``--repeat``. Prints Markdown tables for benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def _timed(fn: Callable[[], Any], repeat: int) -> tuple[float, float, float]:
    """Median wall, process CPU and calling thread CPU seconds of ``fn``."""
    rows = []
    for _ in range(repeat):
        w, c, t = time.perf_counter(), time.process_time(), time.thread_time()
        fn()
        rows.append((time.perf_counter() - w, time.process_time() - c, time.thread_time() - t))
    return tuple(statistics.median(r[k] for r in rows) for k in range(3))  # type: ignore[return-value]


def _asammdf_bus_log(frames: np.ndarray, path: Path, step: int) -> None:
    """The bus log as benchtwin wrote it with asammdf alone (before benchtwin.mf4stream)."""
    from asammdf import MDF, Signal
    from asammdf.blocks.source_utils import Source

    from benchtwin.chain.buslog import DEFAULT_START, _mf4_records

    bus = path.stem
    mdf = MDF(version="4.10")
    mdf.header.start_time = DEFAULT_START
    mdf.header.comment = f"benchtwin bus log: bus {bus}, 500000 bit/s"
    src = Source(name=bus, path=bus, comment=f"CAN bus {bus}", source_type=Source.SOURCE_BUS,
                 bus_type=Source.BUS_TYPE_CAN)
    for k in range(0, max(len(frames), 1), step):
        part = frames[k:k + step]
        rec, ts = _mf4_records(part, 1), np.ascontiguousarray(part["timestamp"])
        if k == 0:
            mdf.append(Signal(name="CAN_DataFrame", samples=rec, timestamps=ts, source=src), acq_name=bus,
                       comment=f"CAN bus {bus}")
        else:
            mdf.extend(0, [(ts, None), (rec, None)])
    mdf.save(path, overwrite=True, compression=2)
    mdf.close()


def _streamed_bus_log(frames: np.ndarray, path: Path, step: int) -> None:
    from benchtwin.chain.buslog import BusLogWriter

    with BusLogWriter(path, path.stem, 500_000) as w:
        for k in range(0, len(frames), step):
            w.append(frames[k:k + step])


def _asammdf_recording(rec: Any, path: Path) -> None:
    import json

    from asammdf import MDF

    from benchtwin.mdf import write_channel_groups
    from benchtwin.recording import FLAG_CONVERSION
    from benchtwin.segments import segments_to_json

    mdf = MDF(version="4.10")
    write_channel_groups(mdf, rec.channels.values(), FLAG_CONVERSION, lambda names: None)
    if rec.start_time is not None:
        mdf.header.start_time = rec.start_time
    mdf.header.comment = json.dumps({"benchtwin": {"meta": rec.meta, "segments": json.loads(
        segments_to_json(rec.segments)), "channels": list(rec.channels)}}, default=str)
    mdf.save(path, overwrite=True, compression=2)
    mdf.close()


def _same_but_history_time(a: Path, b: Path) -> bool:
    from benchtwin.mf4stream import without_history_time

    return without_history_time(a.read_bytes()) == without_history_time(b.read_bytes())


def _codec_rows(name: str, frames: np.ndarray, repeat: int) -> list[str]:
    import deflate

    from benchtwin.chain.buslog import MF4_BLOCK_FRAMES, _mf4_block

    plain = [_mf4_block(frames[k:k + MF4_BLOCK_FRAMES], 1, False) for k in range(0, len(frames), MF4_BLOCK_FRAMES)]
    trans = [_mf4_block(frames[k:k + MF4_BLOCK_FRAMES], 1, True) for k in range(0, len(frames), MF4_BLOCK_FRAMES)]
    rows = []
    codecs = {"libdeflate": deflate.zlib_compress, "zlib": zlib.compress}
    for layout, blocks in (("transposed", trans), ("records", plain)):
        for codec, fn in codecs.items():
            for level in (1, 6):
                size = sum(len(fn(b, level)) for b in blocks)
                wall, cpu, _ = _timed(lambda fn=fn, level=level, blocks=blocks: [fn(b, level) for b in blocks], repeat)
                rows.append(f"| {name} | {layout} | {codec} {level} | {size / 1e6:.1f} | {wall:.2f} | {cpu:.2f} |")
    for codec, fn in codecs.items():
        def two(fn: Callable[..., bytes] = fn) -> None:
            ts = [threading.Thread(target=lambda part: [fn(b, 1) for b in part], args=(trans[i::2],)) for i in (0, 1)]
            for t in ts:
                t.start()
            for t in ts:
                t.join()

        one = _timed(lambda fn=fn: [fn(b, 1) for b in trans], repeat)[0]
        both = _timed(two, repeat)[0]
        rows.append(f"| {name} | transposed, two threads | {codec} 1 | | {both:.2f} (one thread {one:.2f}) | |")
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; print the tables."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", type=Path, help="a `benchtwin validate --out` folder of the paper campaign")
    ap.add_argument("--repeat", type=int, default=3, help="runs per measurement (medians)")
    ap.add_argument("--append", type=int, default=200_000, help="frames appended at a time (the chain's chunks)")
    ap.add_argument("--no-codecs", action="store_true", help="only the writers")
    ap.add_argument("--tmp", type=Path, default=None, help="where the files are written (default: a temp folder)")
    args = ap.parse_args(argv)

    import tempfile

    from benchtwin.chain.buslog import read_mf4
    from benchtwin.recording import Recording

    tmp = args.tmp or Path(tempfile.mkdtemp(prefix="bench_log_write_"))
    tmp.mkdir(parents=True, exist_ok=True)
    writers = ["| file | writer | size (MB) | wall (s) | CPU (s) | calling thread CPU (s) | same file |",
               "|---" * 7 + "|"]
    codecs = ["| log | layout | codec, level | size (MB) | wall (s) | CPU (s) |", "|---" * 6 + "|"]
    for log in sorted(args.dir.glob("*.mf4")):
        if log.name == "recording.mf4":
            continue
        frames = read_mf4(log).frames
        a, b = tmp / f"{log.stem}.mf4", tmp / "streamed" / f"{log.stem}.mf4"
        b.parent.mkdir(exist_ok=True)
        ta = _timed(lambda frames=frames, a=a: _asammdf_bus_log(frames, a, args.append), args.repeat)
        tb = _timed(lambda frames=frames, b=b: _streamed_bus_log(frames, b, args.append), args.repeat)
        same = "yes" if _same_but_history_time(a, b) else "NO"
        for label, t, p in (("asammdf alone", ta, a), ("mf4stream", tb, b)):
            writers.append(f"| {log.name} ({len(frames):,} frames) | {label} | {p.stat().st_size / 1e6:.1f} | "
                           f"{t[0]:.2f} | {t[1]:.2f} | {t[2]:.2f} | {same} |")
        if not args.no_codecs:
            codecs += _codec_rows(log.name, frames, args.repeat)
        del frames
    rec_path = args.dir / "recording.mf4"
    if rec_path.exists():
        rec = Recording.load(rec_path)
        for ch in rec.channels.values():
            ch.values  # noqa: B018  (read now: the writers are timed, not the reading)
        a, b = tmp / "recording.mf4", tmp / "streamed" / "recording.mf4"
        ta = _timed(lambda: _asammdf_recording(rec, a), args.repeat)
        tb = _timed(lambda: rec.save(b), args.repeat)
        same = "yes" if _same_but_history_time(a, b) else "NO"
        for label, t, p in (("asammdf alone", ta, a), ("mf4stream, 2 workers", tb, b)):
            writers.append(f"| recording.mf4 ({len(rec.channels)} channels) | {label} | {p.stat().st_size / 1e6:.1f} | "
                           f"{t[0]:.2f} | {t[1]:.2f} | {t[2]:.2f} | {same} |")
    print("\n".join(writers))
    if not args.no_codecs:
        print()
        print("\n".join(codecs))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
