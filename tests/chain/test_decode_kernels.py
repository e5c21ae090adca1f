"""The decoding's numba kernels against the numpy paths they replaced, value for value.

``MessageCodec.unpack_words`` (``codec._unpack_kernel`` vs ``codec._unpack_numpy``), ``quality.counter_flags``
(``_counter_flags_kernel`` vs ``_counter_flags_numpy``), ``quality.split_bad`` (``_split_bad_kernel`` vs
``_split_bad_numpy``), ``streams.hold_cut`` (vs the loop the acquisition ran before it) and the IVT's status
flags (``ivt._status_flags`` vs ``ivt._status_flags_numpy``) on random and edge inputs: empty, one frame, every bit
pattern of a word's edges, wrapped, repeated and reordered counters, ties and times going back. The expected flags
of a few hand-made counter sequences come from the rule (a gap is a loss unless it is the "skip one, back one" of
a reorder), not from either implementation.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchtwin.chain.streams import hold_cut
from benchtwin.sensors.ivt import _status_flags, _status_flags_numpy, result_codecs
from benchtwin.sensors.vehicle import message_codecs
from benchtwin.wire.codec import SignalLayout, _unpack_kernel, _unpack_numpy
from benchtwin.wire.quality import (
    FLAG,
    _counter_flags_kernel,
    _counter_flags_numpy,
    _split_bad_numpy,
    counter_flags,
    split_bad,
)

LOST, DUP, OOO, PE = FLAG["LOST_FRAME"], FLAG["DUPLICATE"], FLAG["OUT_OF_ORDER"], FLAG["PROTOCOL_ERROR"]

EDGE_WORDS = [0, 2**64 - 1, 2**63, 1, 2**63 - 1, 0x8000000000000001, 0xFF, 0xFF00000000000000,
              0x0123456789ABCDEF, 0xFEDCBA9876543210, 0x00000000FFFFFFFF, 0xFFFFFFFF00000000]


def _words(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    w = rng.integers(0, 2**64, size=n, dtype=np.uint64)
    w[:min(n, len(EDGE_WORDS))] = np.array(EDGE_WORDS, dtype=np.uint64)[:min(n, len(EDGE_WORDS))]
    return w


def _layouts() -> list[SignalLayout]:
    out = []
    for length in (1, 2, 3, 4, 7, 8, 12, 16, 31, 32, 33, 63, 64):
        for shift in sorted({0, 1, 64 - length, (64 - length) // 2}):
            for little in (True, False):
                for signed in (True, False):
                    out.append(SignalLayout(f"s{len(out)}", shift, length, little, signed, 1.0, 0.0, ""))
    return out


def _plan(sigs: list[SignalLayout]) -> tuple[np.ndarray, ...]:
    return (np.array([s.shift for s in sigs], np.uint64), np.array([int(s.mask) for s in sigs], np.uint64),
            np.array([s.little_endian for s in sigs], np.bool_),
            np.array([s.length if s.signed else 0 for s in sigs], np.int64))


@pytest.mark.parametrize("n", [0, 1, 2, 12, 5000])
def test_unpack_kernel_matches_numpy_on_every_layout(n: int) -> None:
    sigs = _layouts()
    w = _words(n, seed=n)
    got = _unpack_kernel(w, *_plan(sigs))
    ref = _unpack_numpy(sigs, w)
    assert got.shape == (len(sigs), n) and got.dtype == np.int64
    for sig, a, b in zip(sigs, got, ref):
        assert np.array_equal(a, b), sig


def test_unpack_kernel_sign_extends_from_the_top_bit() -> None:
    """Independent of both paths: a 4-bit signed field at bit 8 of 0x0F00 is -1, unsigned it is 15."""
    w = np.array([0x0F00, 0x0700, 0x0800], np.uint64)
    signed = SignalLayout("s", 8, 4, True, True, 1.0, 0.0, "")
    unsigned = SignalLayout("u", 8, 4, True, False, 1.0, 0.0, "")
    got = _unpack_kernel(w, *_plan([signed, unsigned]))
    assert got[0].tolist() == [-1, 7, -8] and got[1].tolist() == [15, 7, 8]
    # big-endian: the first data byte is the top byte of the big-endian word (bits 56..63)
    be = SignalLayout("b", 56, 8, False, False, 1.0, 0.0, "")
    assert _unpack_kernel(np.array([0xAB], np.uint64), *_plan([be]))[0].tolist() == [0xAB]


def test_message_codecs_unpack_as_before() -> None:
    """The IVT's (big-endian, signed value) and the vehicle's codecs: all signals, a subset, 2-D words."""
    w = _words(3000, seed=7)
    codecs = list(result_codecs(0x521, "IVT_test")) + list(message_codecs("vehicle"))
    for codec in codecs:
        names = list(codec.signals)
        got = codec.unpack_words(w)
        ref = _unpack_numpy([codec.signals[n] for n in names], w)
        assert list(got) == names
        for n, b in zip(names, ref):
            assert np.array_equal(got[n], b), (codec.name, n)
        sub = names[::-1][:2]
        got = codec.unpack_words(w[:5], sub)
        assert list(got) == sub and all(np.array_equal(got[n], codec.unpack_words(w[:5])[n]) for n in sub)
        two = codec.unpack_words(w[:6].reshape(2, 3))
        assert all(np.array_equal(two[n].reshape(-1), codec.unpack_words(w[:6])[n]) for n in names)
        assert all(v.shape == (0,) for v in codec.unpack_words(w[:0]).values())


@pytest.mark.parametrize(("counter", "bits", "expected"), [
    ([14, 15, 0, 1], 4, [0, 0, 0, 0]),  # the wrap is a step of one
    ([1, 2, 4, 5], 4, [0, 0, LOST, 0]),  # one lost
    ([1, 2, 2, 3], 4, [0, 0, DUP, 0]),  # one doubled
    ([1, 3, 2, 4], 4, [0, OOO, OOO, 0]),  # two swapped: skip one, back one, skip one: no loss
    ([255, 1], 8, [0, LOST]),  # 0 lost across the wrap of an 8-bit counter
    ([0, 1, 0], 1, [0, 0, 0]),  # a 1-bit counter toggles
    ([7], 4, [0]),
    ([], 4, []),
])
def test_counter_flags_by_the_rule(counter: list[int], bits: int, expected: list[int]) -> None:
    c = np.array(counter, np.int64)
    assert counter_flags(c, bits).tolist() == expected
    assert _counter_flags_numpy(c, bits).tolist() == expected


def test_counter_kernel_matches_numpy_on_random_streams() -> None:
    rng = np.random.default_rng(3)
    for trial in range(4000):
        bits = int(rng.integers(1, 9))
        n = int(rng.integers(0, 60))
        if trial % 3 == 0:
            c = rng.integers(-2**40, 2**40, size=n)  # any values: only the low bits count
        else:
            c = np.cumsum(rng.choice([0, 1, 1, 1, 1, 2, 3, -1, 5, 2**bits + 1], size=n)) + int(rng.integers(-99, 99))
        c = c.astype(np.int64)
        got = _counter_flags_kernel(c, bits, LOST, DUP, OOO)
        ref = _counter_flags_numpy(c, bits)
        assert got.dtype == ref.dtype == np.uint16
        assert np.array_equal(got, ref), (bits, c.tolist())


def test_counter_flags_other_dtypes_take_the_numpy_path() -> None:
    c = np.array([1, 2, 2, 5, 4, 6], np.int16)
    assert np.array_equal(counter_flags(c, 4), _counter_flags_numpy(c, 4))
    assert np.array_equal(counter_flags(c, 4), counter_flags(c.astype(np.int64), 4))


@pytest.mark.parametrize("n", [0, 1, 1000])
def test_ivt_status_flags_match_numpy(n: int) -> None:
    rng = np.random.default_rng(n)
    status = rng.integers(0, 16, size=n).astype(np.int64)
    flags = rng.integers(0, 2**12, size=n).astype(np.uint16)
    rf, ef = FLAG["OUT_OF_RANGE"] | FLAG["SATURATED"], FLAG["STATUS_ERROR"]
    a, b = flags.copy(), flags.copy()
    assert _status_flags(a, status, rf, ef) == _status_flags_numpy(b, status, rf, ef)
    assert np.array_equal(a, b)
    if n:  # by the nibble: bit 0 OCS (counted), bit 1 out of range, bits 2-3 errors
        assert _status_flags(np.zeros(4, np.uint16), np.array([1, 1, 0, 8], np.int64), rf, ef) == 2



@pytest.mark.parametrize(("dlc", "length", "extra", "good", "proto", "nbad"), [
    ([8, 8, 8], 8, None, [1, 1, 1], [0, 0, 0], 0),
    ([8, 5, 8, 8], 8, None, [1, 0, 1, 1], [0, PE, 0], 1),  # the good frame after it
    ([5, 5, 8, 3], 8, None, [0, 0, 1, 0], [PE], 3),  # two bad before one good: one flag
    ([3, 4, 8], 0, None, [1, 1, 1], [0, 0, 0], 0),  # length 0: any length is good
    ([6, 6, 6, 6], 6, [0, 1, 0, 0], [1, 0, 1, 1], [0, PE, 0], 1),  # bad for another reason
    ([], 8, None, [], [], 0),
    ([7], 8, None, [0], [], 1),
])
def test_split_bad_by_the_rule(dlc: list[int], length: int, extra: list[int] | None, good: list[int],
                               proto: list[int], nbad: int) -> None:
    d = np.array(dlc, np.uint8)
    e = None if extra is None else np.array(extra, bool)
    for fn in (split_bad, _split_bad_numpy):
        g, p, n = fn(d, length, e)
        assert g.tolist() == [bool(x) for x in good] and p.tolist() == proto and n == nbad
        assert g.dtype == np.bool_ and p.dtype == np.uint16 and isinstance(n, int)


def test_split_bad_kernel_matches_numpy_on_random_streams() -> None:
    rng = np.random.default_rng(5)
    for trial in range(3000):
        n = int(rng.integers(0, 50))
        d = rng.choice(np.array([8, 8, 8, 8, 6, 0, 3], np.uint8), size=n)
        length = int(rng.choice([8, 6, 0]))
        e = rng.random(n) < 0.2 if trial % 2 else None
        got, ref = split_bad(d, length, e), _split_bad_numpy(d, length, e)
        assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1]) and got[2] == ref[2], trial
    d16 = np.array([8, 5, 8], np.int16)  # another dtype: the numpy path
    assert split_bad(d16, 8)[1].tolist() == [0, FLAG["PROTOCOL_ERROR"]]


def _hold_cut_before(t: np.ndarray, hold: int) -> int:
    """What ``Acquisition._decode_stream`` computed before ``hold_cut`` (-1: times go back)."""
    n = t.shape[0]
    if n > 1 and bool(np.any(t[1:] < t[:-1])):
        return -1
    j = n - hold
    while j > 0 and t[j] == t[j - 1]:
        j -= 1
    return max(j, 0)


def test_hold_cut_matches_the_loop_it_replaced() -> None:
    rng = np.random.default_rng(11)
    for trial in range(3000):
        n = int(rng.integers(0, 30))
        t = np.cumsum(rng.choice([0.0, 0.0, 0.01, 0.02], size=n))  # ties: several frames at one time
        if trial % 5 == 0 and n > 1:
            i = int(rng.integers(1, n))
            t[i] = t[i - 1] - 0.001  # back in time
        hold = int(rng.integers(1, 10))
        assert hold_cut(t, hold) == _hold_cut_before(t, hold), (t.tolist(), hold)
    assert hold_cut(np.array([0.0, 1.0, 2.0, 2.0, 2.0, 3.0]), 2) == 2  # t[4] shares its time: back to the first 2.0
    assert hold_cut(np.array([0.0, 1.0]), 8) == 0 and hold_cut(np.array([1.0, 0.5, 2.0]), 1) == -1
    assert hold_cut(np.array([0.0, np.nan, 1.0]), 1) == 2  # NaN compares false, as before
    with pytest.raises(ValueError):
        hold_cut(np.zeros(3), 0)


def test_a_short_column_is_unpacked_without_the_kernel_and_the_same(monkeypatch: pytest.MonkeyPatch) -> None:
    """A live device's frame or two never waits for the kernel (its first call compiles where no cached copy
    exists); the values are the kernel's all the same, and a long column still takes the kernel."""
    from benchtwin.wire import codec as codec_mod

    codec = result_codecs(0x521, "IVT_test")[0]
    names = list(codec.signals)
    w = _words(codec_mod.KERNEL_MIN_WORDS, seed=11)
    short = w[:codec_mod.KERNEL_MIN_WORDS - 1]
    kernel = _unpack_kernel(np.ascontiguousarray(short), *_plan([codec.signals[n] for n in names]))

    def refused(*args: object) -> None:
        raise AssertionError("the kernel was called for a short column")

    monkeypatch.setattr(codec_mod, "_unpack_kernel", refused)
    got = codec.unpack_words(short)
    assert all(np.array_equal(got[n], k) and got[n].dtype == k.dtype for n, k in zip(names, kernel, strict=True))
    assert codec.unpack_words(w[:1])[names[0]].shape == (1,)
    with pytest.raises(AssertionError, match="kernel was called"):
        codec.unpack_words(w)  # KERNEL_MIN_WORDS words: the kernel's
