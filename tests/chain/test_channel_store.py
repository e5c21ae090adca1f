"""The chunk store on disk: its open files give the chunks' samples back exactly, on threads and past the limit of
files it keeps open, and go with the store."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from benchtwin.chain import channel_store
from benchtwin.chain.channel_store import ChannelStore


def _chunks(seed: int, names: list[str], n_chunks: int) -> dict[str, list[tuple[np.ndarray, ...]]]:
    rng = np.random.default_rng(seed)
    out: dict[str, list[tuple[np.ndarray, ...]]] = {n: [] for n in names}
    for c in range(n_chunks):
        for n in names:
            m = int(rng.integers(0, 700))  # an empty chunk too, now and then
            t = c * 1000.0 + np.sort(rng.uniform(0, 999, m))
            out[n].append((t, rng.normal(size=m), rng.integers(0, 2**16, m).astype(np.uint16)))
    return out


def _whole(parts: list[tuple[np.ndarray, ...]]) -> tuple[np.ndarray, ...]:
    return tuple(np.concatenate([p[k] for p in parts]) for k in range(3))


@pytest.mark.parametrize("max_open", [512, 4, 0])
def test_the_store_gives_back_what_was_appended(tmp_path: Path, monkeypatch, max_open: int) -> None:
    # 512: every file kept open; 4: one channel's files and one more, the rest opened at each call; 0: none
    monkeypatch.setattr(channel_store, "MAX_OPEN_FILES", max_open)
    names = [f"ch{k}" for k in range(5)]
    chunks = _chunks(7, names, 6)
    store = ChannelStore(tmp_path)
    for c in range(6):
        for n in names:
            store.append(n, "V", "dev", None, (0,), *chunks[n][c])
            # reads between appends see everything appended so far (the appends are not buffered)
            whole = _whole(chunks[n][:c + 1])
            got = store.read_block(n, 0, store.length(n))
            for k in range(3):
                np.testing.assert_array_equal(got[k], whole[k])
    for n in names:
        whole = _whole(chunks[n])
        size = len(whole[0])
        ch = store.reader(n)
        np.testing.assert_array_equal(ch.timestamps, whole[0])
        np.testing.assert_array_equal(ch.values, whole[1])
        np.testing.assert_array_equal(ch.flags, whole[2])
        for a, b in ((0, 1), (size // 3, 2 * size // 3), (size - 5, size), (size - 5, size + 40), (size, size)):
            got = store.read_block(n, a, b)
            for k in range(3):  # a read past the end is short, as np.fromfile's
                np.testing.assert_array_equal(got[k], whole[k][a:b])
                assert got[k].dtype == whole[k].dtype and got[k].flags.writeable
    # flags written back in place are read back, by the open files and by the memory map alike
    f = np.arange(10, dtype=np.uint16) + 1000
    store.write_flags("ch2", 3, f)
    np.testing.assert_array_equal(store.read_block("ch2", 3, 13)[2], f)
    np.testing.assert_array_equal(store.channel("ch2").flags[3:13], f)
    store.cleanup()
    assert store.directory is not None and not store.directory.exists()


def test_reads_on_threads_are_the_samples_at_their_own_offsets(tmp_path: Path) -> None:
    # positional reads: one thread's read does not move another's (a shared file position would mix them up)
    names = ["a", "b"]
    chunks = _chunks(11, names, 30)
    store = ChannelStore(tmp_path)
    for c in range(30):
        for n in names:
            store.append(n, "", "", None, (0,), *chunks[n][c])
    wholes = {n: _whole(chunks[n]) for n in names}
    rng = np.random.default_rng(5)
    spans = [(n, int(a), int(a) + int(rng.integers(1, 500))) for n in names * 100
             for a in rng.integers(0, store.length(n) - 500, 1)]

    def check(span: tuple[str, int, int]) -> bool:
        n, a, b = span
        got = store.read_block(n, a, b)
        return all(np.array_equal(got[k], wholes[n][k][a:b]) for k in range(3))

    with ThreadPoolExecutor(4) as pool:
        assert all(pool.map(check, spans * 5))
    store.cleanup()


def test_cleanup_closes_the_files(tmp_path: Path) -> None:
    fd_dir = Path("/proc/self/fd")
    if not fd_dir.is_dir():
        pytest.skip("needs /proc/self/fd")
    before = len(os.listdir(fd_dir))
    store = ChannelStore(tmp_path)
    for n in ("x", "y", "z"):
        store.append(n, "", "", None, (0,), np.arange(3.0), np.ones(3), np.zeros(3, np.uint16))
        store.reader(n).values  # noqa: B018 - read once
    assert len(os.listdir(fd_dir)) == before + 9  # three files a channel, held open
    store.cleanup()
    assert len(os.listdir(fd_dir)) == before
    with pytest.raises(OSError):
        store.read_block("x", 0, 3)  # the files are gone


def test_the_limit_of_open_files_is_shared_by_the_stores(tmp_path: Path, monkeypatch) -> None:
    # the limit holds for every store of the process together: a second store opens what the first leaves
    monkeypatch.setattr(channel_store, "MAX_OPEN_FILES", channel_store._open_count + 4)
    one, two = ChannelStore(tmp_path), ChannelStore(tmp_path)
    for store in (one, two):
        for n in ("x", "y"):
            store.append(n, "", "", None, (0,), np.arange(3.0), np.ones(3), np.zeros(3, np.uint16))
    assert len(one._fds) == 4 and len(two._fds) == 0
    np.testing.assert_array_equal(two.read_block("y", 1, 3)[0], [1.0, 2.0])  # its files opened at each call
    one.cleanup()
    two.append("x", "", "", None, (0,), np.arange(2.0), np.ones(2), np.zeros(2, np.uint16))
    assert len(two._fds) == 3  # x's three files, now that the first store's are closed
    np.testing.assert_array_equal(two.reader("x").timestamps, [0.0, 1.0, 2.0, 0.0, 1.0])
    two.cleanup()
