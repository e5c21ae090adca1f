"""recording.mf4's writer holds one block of a channel group at a time, its size bounded in bytes (not growing with the
group's width or the recording's length)."""

from __future__ import annotations

import weakref

import numpy as np
import pytest

import benchtwin.mdf
from benchtwin.mdf import group_block_samples
from benchtwin.recording import Channel, LazyChannel, Recording

#: bytes per sample of one channel as the chunk files hold it: float64 time, float64 value, uint16 flags
_READ_BYTES = 8 + 8 + 2


class _Held:
    """Bytes of the arrays the block readers handed out that are still alive, and the most alive at once."""

    def __init__(self) -> None:
        self.now = 0
        self.most = 0
        self.widest = 0

    def hand_out(self, arrays: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
        for a in arrays:
            self.now += a.nbytes
            weakref.finalize(a, self._gone, a.nbytes)
        self.most = max(self.most, self.now)
        self.widest = max(self.widest, len(arrays[0]))
        return arrays

    def _gone(self, nbytes: int) -> None:
        self.now -= nbytes


def _wide_recording(n_channels: int, n: int, held: _Held) -> Recording:
    """``n_channels`` channels of one source on one time base, ``n`` samples, read only through block readers."""
    t = np.arange(n) * 0.01
    rec = Recording()
    for k in range(n_channels):
        v = np.sin(t * (k + 1))
        f = (np.arange(n) % 7 == k % 7).astype(np.uint16)

        def whole() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            raise AssertionError("read whole")

        def part(a: int, b: int, v: np.ndarray = v, f: np.ndarray = f) -> tuple[np.ndarray, ...]:
            return held.hand_out((t[a:b].copy(), v[a:b].copy(), f[a:b].copy()))

        rec.add(LazyChannel(f"c{k}", "V", "dev", n, whole, block_loader=part))
    return rec, t


def test_group_block_samples_bounds_the_columns_in_bytes() -> None:
    """A group's columns per block are 8 B of time and 10 B per channel (float64 value, uint16 flags) a sample."""
    assert group_block_samples(1, 1 << 20, 16 << 20) == (16 << 20) // 18  # the sample count would allow more
    assert group_block_samples(17, 1 << 20, 16 << 20) == (16 << 20) // 178
    assert group_block_samples(2, 1000, 16 << 20) == 1000  # the sample count bites first
    assert group_block_samples(10_000, 1000, 100) == 1  # never nothing
    with pytest.raises(ValueError, match="budget"):
        group_block_samples(3, 1000, 0)


@pytest.mark.parametrize("n", [3_000, 30_000])
def test_writer_holds_one_bounded_block_whatever_the_length(n: int, tmp_path, monkeypatch) -> None:
    """A 12-channel group written with a 20 kB budget: blocks of 20,000 // 128 = 156 samples, and the arrays the
    block readers handed out alive at once stay within one block's reads (plus one channel's read of the next block
    while it is gathered; or the two channels' blocks compared to group them) at 3,000 and at 30,000 samples; the
    file reads back equal."""
    monkeypatch.setattr(benchtwin.mdf, "WRITE_BLOCK_BYTES", 20_000)
    held = _Held()
    rec, t = _wide_recording(12, n, held)
    path = rec.save(tmp_path / "r.mf4")
    block = 20_000 // (8 + 12 * 10)
    compare = 20_000 // _READ_BYTES  # the time bases of two channels compared (to group them): a block of each
    assert held.widest == compare
    # a block of every channel (times too: the reader gives all three) and the first read of the next block, or the
    # two channels compared
    assert held.most <= max((12 + 1) * block * _READ_BYTES, 2 * compare * _READ_BYTES)
    back = Recording.load(path)
    for k in range(12):
        ch = back[f"c{k}"]
        assert np.array_equal(ch.timestamps, t)
        assert np.array_equal(ch.values, np.sin(t * (k + 1)))
        assert np.array_equal(ch.flags, (np.arange(n) % 7 == k % 7).astype(np.uint16))


def test_narrow_group_keeps_the_sample_count(tmp_path, monkeypatch) -> None:
    """A group of one channel is not cut finer than WRITE_BLOCK_SAMPLES when the byte budget allows more."""
    monkeypatch.setattr(benchtwin.mdf, "WRITE_BLOCK_SAMPLES", 500)
    held = _Held()
    rec, _ = _wide_recording(1, 2_000, held)
    rec.save(tmp_path / "r.mf4")
    assert held.widest == 500
    assert isinstance(rec["c0"], Channel)
