"""Block averaging by device time (hdrd/core/resample.py; paper Eq. 11, HDR-NOTES "Conventions").

Step i averages the samples whose device time is in [t0 + iT, t0 + (i+1)T); a dropped frame
shortens a block, an empty block is Missing (never a zero rate), the 32-bit microsecond clock
wraps every 2**32 us.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.core.resample import Block, BlockAverager, Missing
from hdrd.io.wire.clocks import DeviceClock, unwrap_us
from hdrd.io.wire.protocol import CLOCK_WRAP_US

S = 1_000_000  # us per s


def run_stream(
    raw_us: list[int], values: list[float], T_s: float = 1.0, flush: bool = True
) -> tuple[list[Block | Missing], DeviceClock, BlockAverager]:
    clock, avg = DeviceClock(), BlockAverager(T_s)
    out: list[Block | Missing] = []
    for t, v in zip(raw_us, values):
        u = clock.unwrap(t)
        if u is not None:
            out += avg.feed(u, v)
    if flush:
        out += avg.flush()
    return out, clock, avg


def blocks(items: list[Block | Missing]) -> list[Block]:
    return [b for b in items if isinstance(b, Block)]


def test_ten_hz_into_one_hz_eq_11() -> None:
    t = [5_000 + k * 100_000 for k in range(30)]  # 10 Hz for 3 s
    v = [float(k) for k in range(30)]
    out, _, _ = run_stream(t, v)
    assert out == [
        Block(0, 0.0, 1.0, sum(range(10)) / 10, 10),
        Block(1, 1.0, 2.0, sum(range(10, 20)) / 10, 10),
        Block(2, 2.0, 3.0, sum(range(20, 30)) / 10, 10),
    ]


def test_block_edges_are_half_open() -> None:
    # A sample exactly at t0 + 1 s belongs to step 1, not step 0.
    out, _, _ = run_stream([0, 999_999, 1_000_000], [1.0, 3.0, 7.0])
    assert [(b.index, b.mean, b.n) for b in blocks(out)] == [(0, 2.0, 2), (1, 7.0, 1)]


def test_a_block_closes_when_the_next_one_starts() -> None:
    avg = BlockAverager()
    assert avg.feed(0, 1.0) == []
    assert avg.feed(900_000, 2.0) == []
    closed = avg.feed(1_000_000, 5.0)
    assert closed == [Block(0, 0.0, 1.0, 1.5, 2)]


def test_dropped_frames_shorten_a_block() -> None:
    t = [k * 100_000 for k in range(20)]
    v = [float(k % 10) for k in range(20)]
    keep = [k for k in range(20) if k not in (3, 4, 15)]
    out, _, _ = run_stream([t[k] for k in keep], [v[k] for k in keep])
    b0, b1 = blocks(out)
    assert (b0.n, b1.n) == (8, 9)
    assert b0.mean == (0 + 1 + 2 + 5 + 6 + 7 + 8 + 9) / 8  # not divided by 10
    assert b1.mean == (0 + 1 + 2 + 3 + 4 + 6 + 7 + 8 + 9) / 9
    assert not any(isinstance(x, Missing) for x in out)


def test_an_empty_block_is_missing_never_zero() -> None:
    # 10 Hz, then nothing from 1.0 s to 4.3 s, then 10 Hz again.
    t = [k * 100_000 for k in range(10)] + [4_300_000 + k * 100_000 for k in range(7)]
    v = [0.5] * 10 + [0.7] * 7
    out, _, _ = run_stream(t, v)
    assert out == [
        Block(0, 0.0, 1.0, 0.5, 10),
        Missing(first=1, count=3, t_start=1.0, t_end=4.0),
        Block(4, 4.0, 5.0, pytest.approx(0.7), 7),  # type: ignore[arg-type]
    ]
    assert all(b.mean != 0.0 for b in blocks(out))


def test_one_missing_step_between_two_blocks() -> None:
    out, _, _ = run_stream([0, 2_500_000], [1.0, 2.0])
    assert out[1] == Missing(1, 1, 1.0, 2.0)
    assert [b.index for b in blocks(out)] == [0, 2]


def test_clock_wrap_in_the_middle_of_a_block() -> None:
    start = CLOCK_WRAP_US - 450_000  # wraps 0.45 s into the first block
    raw = [(start + k * 100_000) % CLOCK_WRAP_US for k in range(25)]
    assert raw[4] > raw[5]  # the raw counter did wrap inside block 0
    out, clock, _ = run_stream(raw, [1.0] * 10 + [2.0] * 10 + [3.0] * 5)
    assert clock.wraps == 1 and clock.rejected == 0 and clock.resets == 0
    assert [(b.index, b.mean, b.n) for b in blocks(out)] == [
        (0, 1.0, 10),
        (1, 2.0, 10),
        (2, 3.0, 5),
    ]
    assert not any(isinstance(x, Missing) for x in out)


def test_device_reset_in_the_resampler() -> None:
    raw = [k * 100_000 for k in range(15)] + [500 + k * 100_000 for k in range(10)]
    out, clock, _ = run_stream(raw, [1.0] * 15 + [2.0] * 10)
    assert clock.resets == 1
    # Time resumed 1 us after the last sample (1.4 s): the ten samples after the reset land at
    # 1.400001 .. 2.300001 s, six in step 1 and four in step 2; no step invented or missing.
    got = [(b.index, b.n) for b in blocks(out)]
    assert got == [(0, 10), (1, 5 + 6), (2, 4)]
    assert blocks(out)[1].mean == pytest.approx((5 * 1.0 + 6 * 2.0) / 11)
    assert not any(isinstance(x, Missing) for x in out)


def test_flush() -> None:
    avg = BlockAverager()
    assert avg.flush() == []  # nothing fed
    avg.feed(0, 1.0)
    avg.feed(300_000, 2.0, temp_c=20.0, saturated=True)  # counted, not averaged
    avg.feed(600_000, 4.0, temp_c=22.0)
    assert avg.flush() == [Block(0, 0.0, 1.0, 5.0 / 2, 2, 22.0, 1)]
    assert avg.flush() == []  # idempotent


def test_feeding_after_flush_neither_repeats_nor_invents() -> None:
    avg = BlockAverager()
    avg.feed(0, 1.0)
    (b,) = avg.flush()
    assert isinstance(b, Block) and b.index == 0
    # A late sample in the flushed step cannot change what was already published.
    assert avg.feed(500_000, 9.0) == [] and avg.late == 1
    # The next step continues normally ...
    assert avg.feed(1_200_000, 2.0) == []
    # ... and a gap after a flush reports only the steps really missed.
    avg2 = BlockAverager()
    avg2.feed(0, 1.0)
    avg2.flush()
    assert avg2.feed(3_100_000, 2.0) == [Missing(1, 2, 1.0, 3.0)]
    assert avg2.flush() == [Block(3, 3.0, 4.0, 2.0, 1)]


def test_temperature_and_saturation_are_aggregated() -> None:
    avg = BlockAverager()
    avg.feed(0, 0.0, temp_c=None)
    avg.feed(50_000, 0.0, temp_c=20.0)
    avg.feed(100_000, 0.0, temp_c=30.0, saturated=True)
    avg.feed(200_000, 0.0, temp_c=40.0, saturated=True)
    (b,) = avg.feed(1_000_000, 0.0)
    assert isinstance(b, Block)
    assert (b.temp_c, b.saturated, b.n) == (20.0, 2, 2)  # what was averaged only
    (b,) = avg.flush()
    assert isinstance(b, Block)
    assert b.temp_c is None and b.saturated == 0


def test_other_step_periods() -> None:
    t = [k * 100_000 for k in range(10)]
    out, _, _ = run_stream(t, [float(k) for k in range(10)], T_s=0.5)
    assert [(b.index, b.t_start, b.t_end, b.mean) for b in blocks(out)] == [
        (0, 0.0, 0.5, 2.0),
        (1, 0.5, 1.0, 7.0),
    ]
    with pytest.raises(ValueError, match="T must be > 0"):
        BlockAverager(0.0)
    with pytest.raises(ValueError):
        BlockAverager(float("nan"))


# -- the vectorised forms agree bit for bit with the streaming ones ------------------------------


@st.composite
def capture(draw: st.DrawFn) -> tuple[list[int], list[float]]:
    """A raw 32-bit device-time sequence with jitter, drops, gaps, wraps, repeats, reorders,
    resets; and sample values."""
    t = draw(st.sampled_from([0, 123_456, CLOCK_WRAP_US - 2_000_000, CLOCK_WRAP_US - 1]))
    n = draw(st.integers(0, 150))
    events = st.sampled_from(["ok"] * 12 + ["drop", "gap", "repeat", "back", "reset"])
    raw: list[int] = []
    for _ in range(n):
        ev = draw(events)
        if ev == "ok":
            t += 100_000 + draw(st.integers(-3_000, 3_000))
        elif ev == "drop":
            t += 200_000
        elif ev == "gap":
            t += draw(st.integers(1_000_000, 20_000_000))
        elif ev == "back":
            t -= draw(st.integers(1, 1_000_000))
        elif ev == "reset":
            t = draw(st.integers(0, 5_000))
        # "repeat": same t
        raw.append(t % CLOCK_WRAP_US)
    values = draw(
        st.lists(
            st.floats(-300, 300, allow_nan=False, allow_infinity=False),
            min_size=n, max_size=n,
        )
    )  # fmt: skip
    return raw, values


@settings(deadline=None)
@given(cap=capture(), T_s=st.sampled_from([1.0, 0.5, 2.0, 0.1]))
def test_vectorised_equals_streaming(cap: tuple[list[int], list[float]], T_s: float) -> None:
    raw, values = cap
    # unwrap_us == DeviceClock, sample by sample
    clock = DeviceClock()
    stream_t = [clock.unwrap(x) for x in raw]
    t_us, ok = unwrap_us(np.array(raw, dtype=np.int64))
    assert ok.tolist() == [x is not None for x in stream_t]
    assert t_us[ok].tolist() == [x for x in stream_t if x is not None]
    if len(raw):
        assert np.all(np.diff(t_us[ok]) > 0)
    # feed_many (+ flush) == feed (+ flush), bit for bit
    out, _, _ = run_stream(raw, values, T_s)
    many = BlockAverager(T_s)
    got = [b for _, b in many.feed_many(t_us[ok], np.array(values, dtype=np.float64)[ok])]
    bs = blocks(out)
    assert blocks(got + many.flush()) == bs  # exact float equality
    # Missing runs cover exactly the empty steps between the blocks.
    covered = sorted(
        [b.index for b in bs]
        + [m.first + k for m in out if isinstance(m, Missing) for k in range(m.count)]
    )
    assert covered == list(range(len(covered)))


def test_block_spread_streaming_equals_vectorised_and_numpy():
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.integers(5_000, 150_000, 2000)).astype(np.int64)
    v = rng.normal(0.5, 2.0, 2000)
    a = BlockAverager(1.0)
    stream = [b for i in range(2000) for b in a.feed(int(t[i]), float(v[i]))] + a.flush()
    b = BlockAverager(1.0)
    fast = [blk for _, blk in b.feed_many(t, v)] + b.flush()
    sb = [x for x in stream if isinstance(x, Block)]
    fb = [x for x in fast if isinstance(x, Block)]
    assert [x.sumsq for x in sb] == [x.sumsq for x in fb]
    idx = (t - t[0]) // 1_000_000
    for blk in sb:
        np.testing.assert_allclose(blk.std, np.std(v[idx == blk.index]), rtol=1e-9, atol=1e-12)


def test_memory_follows_the_samples_not_the_device_time_they_span() -> None:
    # Samples 3,000 years of device time apart (a clock that jumps, a hostile capture): the
    # vectorised forms take one bin per non-empty block, not one per step in between (which
    # would be 10**11 bins here), and agree with the streaming form bit for bit.
    t = np.array([0, 5, 10**17, 10**17 + 1, 10**17 + 2_000_000], np.int64)
    v = np.array([1.0, 0.25, 2.0, 4.0, -1.5])
    stream = BlockAverager(1.0)
    want = [b for i in range(len(t)) for b in stream.feed(int(t[i]), float(v[i]))]
    want += stream.flush()
    many = BlockAverager(1.0)
    got = [b for _, b in many.feed_many(t, v)] + many.flush()
    assert got == want
    assert [b for b in got if isinstance(b, Missing)] == [
        Missing(1, 10**11 - 1, 1.0, 1e11),
        Missing(10**11 + 1, 1, 1e11 + 1, 1e11 + 2),
    ]


# -- the array forms against their scalar twins: every output, every counter, both paths --------


def block_tuple(item: Block | Missing) -> tuple[object, ...]:
    """Everything a block says, its sum of squares included (Block's == leaves it out)."""
    if isinstance(item, Missing):
        return ("missing", item.first, item.count, item.t_start, item.t_end)
    return (
        "block", item.index, item.t_start, item.t_end, item.mean, item.n, item.temp_c,
        item.saturated, item.sumsq, item.faults, item.fault_lo, item.fault_hi,
    )  # fmt: skip


def same(a: object, b: object) -> bool:
    """Equal, NaN equal to NaN (a block's mean and fault readings when it has none), -0.0
    not equal to 0.0: bit for bit as far as floats go."""
    if isinstance(a, float) and isinstance(b, float):
        return (a != a and b != b) or (a == b and math.copysign(1, a) == math.copysign(1, b))
    if isinstance(a, (tuple, list)) and isinstance(b, (tuple, list)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


def averager_state(a: BlockAverager) -> tuple[object, ...]:
    return (a.t0_us, a.open_block, a.late)


_STEP = st.one_of(
    st.integers(1, 400_000),  # time passing within a block or to the next
    st.integers(1, 400_000),
    st.integers(1_000_000, 6_000_000),  # a gap of a few steps
    st.just(0),  # the same time again
    st.integers(-2_500_000, -1),  # back (after a flush, or a hostile array)
)
_SAMPLE = st.tuples(
    _STEP,
    st.floats(-300, 300, allow_nan=False, allow_infinity=False),
    st.one_of(st.none(), st.floats(-40, 85, allow_nan=False)),
    st.booleans(),
    st.one_of(st.none(), st.none(), st.floats(0.0, 10.0)),  # a fault's reading
)


@st.composite
def sample_chunks(draw: st.DrawFn) -> tuple[float, list[tuple[str, bool, list[tuple]]]]:
    """Samples (unwrapped us, value, temperature or None, saturated, the reading of a fault
    or None) in chunks, each fed
    either through feed_many or one by one, some followed by a flush. Times mostly go
    forward by up to 0.4 s; sometimes they jump a few steps ahead, repeat, or go back (as
    after a flush, or in a hostile array: the slow path)."""
    T_s = draw(st.sampled_from([1.0, 0.5, 0.1]))
    t = draw(st.integers(0, 3_000_000))
    chunks = []
    for how, flush, drawn in draw(
        st.lists(
            st.tuples(
                st.sampled_from(["many", "one"]), st.booleans(), st.lists(_SAMPLE, max_size=30)
            ),
            min_size=1,
            max_size=4,
        )
    ):
        samples = []
        for step, value, temp, sat, fault in drawn:
            t = max(0, t + step)
            samples.append((t, value, temp, sat, fault))
        chunks.append((how, flush, samples))
    return T_s, chunks


@settings(deadline=None)
@given(case=sample_chunks())
def test_feed_many_is_feed_in_everything(
    case: tuple[float, list[tuple[str, bool, list[tuple]]]],
) -> None:
    T_s, chunks = case
    ref, sub = BlockAverager(T_s), BlockAverager(T_s)
    for how, flush, samples in chunks:
        want = [
            (i, block_tuple(b))
            for i, (t, v, tc, sat, f) in enumerate(samples)
            for b in ref.feed(t, v, tc, sat, f)
        ]
        if how == "many":
            got = [
                (i, block_tuple(b))
                for i, b in sub.feed_many(
                    np.array([s[0] for s in samples], np.int64),
                    np.array([s[1] for s in samples], np.float64),
                    np.array([np.nan if s[2] is None else s[2] for s in samples], np.float64),
                    np.array([s[3] for s in samples], bool),
                    np.array([np.nan if s[4] is None else s[4] for s in samples], np.float64),
                )
            ]
        else:
            got = [
                (i, block_tuple(b))
                for i, (t, v, tc, sat, f) in enumerate(samples)
                for b in sub.feed(t, v, tc, sat, f)
            ]
        assert same(got, want)
        assert averager_state(sub) == averager_state(ref)
        if flush:
            assert same(
                [block_tuple(b) for b in sub.flush()], [block_tuple(b) for b in ref.flush()]
            )
    assert same([block_tuple(b) for b in sub.flush()], [block_tuple(b) for b in ref.flush()])


def test_feed_many_with_a_time_that_goes_back_reports_every_block() -> None:
    # Not what a DeviceClock gives (its times only go forward), but an array can hold it:
    # block 0, its closing sample (1.0 s), one late sample back in block 0, then block 1.
    # The sample that closes block 0 comes before the first one that a binary search puts
    # beyond the open block: block 0 used to be closed there and never reported.
    t = np.array([0, 1, 2, 3, 4, 10, 9, 11, 12, 13, 14, 15], np.int64) * 100_000
    v = np.arange(12, dtype=np.float64)
    ref = BlockAverager()
    want = [(i, block_tuple(b)) for i in range(12) for b in ref.feed(int(t[i]), float(v[i]))]
    assert same(want, [(5, ("block", 0, 0.0, 1.0, 2.0, 5, None, 0, 30.0, 0, math.nan, math.nan))])
    assert ref.late == 1
    sub = BlockAverager()
    assert same([(i, block_tuple(b)) for i, b in sub.feed_many(t, v)], want)
    assert averager_state(sub) == averager_state(ref)


def test_feed_many_without_temperatures_or_flags_is_feed_without_them() -> None:
    t = np.array([0, 400_000, 1_100_000, 1_200_000, 3_500_000, 3_600_000], np.int64)
    v = np.array([1.0, 2.0, 4.0, 8.0, 16.0, 32.0])
    ref = BlockAverager()
    want = [(i, block_tuple(b)) for i in range(6) for b in ref.feed(int(t[i]), float(v[i]))]
    sub = BlockAverager()
    assert same([(i, block_tuple(b)) for i, b in sub.feed_many(t, v)], want)
    nan = math.nan
    assert same(
        want,
        [
            (2, ("block", 0, 0.0, 1.0, 1.5, 2, None, 0, 5.0, 0, nan, nan)),
            (4, ("block", 1, 1.0, 2.0, 6.0, 2, None, 0, 80.0, 0, nan, nan)),
            (4, ("missing", 2, 1, 2.0, 3.0)),
        ],
    )
    assert averager_state(sub) == averager_state(ref) == (0, (3_000_000, 4_000_000, 2), 0)
    assert sub.feed_many(np.empty(0, np.int64), np.empty(0)) == []


def test_feed_many_closes_each_block_at_the_sample_that_ends_it() -> None:
    # Blocks 0..3 in one array: each is reported at the position of the first sample of the
    # next non-empty block (its arrival is when the step can be published), with the
    # temperatures and saturation flags of its own samples only.
    t = np.array([0, 500_000, 1_000_000, 1_500_000, 2_000_000, 4_200_000, 4_300_000], np.int64)
    v = np.array([1.0, 3.0, 10.0, 20.0, -5.0, 7.0, 9.0])
    temp = np.array([20.0, 22.0, 30.0, np.nan, 41.0, np.nan, 50.0])
    sat = np.array([False, True, True, True, False, False, True])
    a = BlockAverager()
    got = [(i, block_tuple(b)) for i, b in a.feed_many(t, v, temp, sat)]
    nan = math.nan
    want = [
        (2, ("block", 0, 0.0, 1.0, 1.0, 1, 20.0, 1, 1.0, 0, nan, nan)),
        (4, ("block", 1, 1.0, 2.0, nan, 0, None, 2, 0.0, 0, nan, nan)),  # nothing averaged
        (5, ("block", 2, 2.0, 3.0, -5.0, 1, 41.0, 0, 25.0, 0, nan, nan)),
        (5, ("missing", 3, 1, 3.0, 4.0)),
    ]
    assert same(got, want)
    flushed = [block_tuple(b) for b in a.flush()]
    assert same(flushed, [("block", 4, 4.0, 5.0, 7.0, 1, None, 1, 49.0, 0, nan, nan)])


def test_flush_of_a_later_block_and_what_follows_it() -> None:
    a = BlockAverager(0.5)
    for k in range(7):  # 0 .. 0.6 s in steps of 0.1 s: blocks 0 (5 samples) and 1 (open)
        a.feed(k * 100_000, float(k), temp_c=10.0 + k, saturated=k == 6)
    (b,) = a.flush()
    assert same(
        block_tuple(b), ("block", 1, 0.5, 1.0, 5.0, 1, 15.0, 1, 25.0, 0, math.nan, math.nan)
    )
    assert a.open_block == (1_000_000, 1_500_000, 0)
    assert a.flush() == []
    # The flushed step is final: a late sample in it is counted, not added.
    assert a.feed(900_000, 99.0) == [] and a.late == 1
    assert a.feed(700_000, 99.0) == [] and a.late == 2
    # The step after the flushed one is open and empty: a sample two steps on reports one
    # missing step (1.0 .. 1.5 s), not the flushed one again.
    assert [block_tuple(x) for x in a.feed(1_600_000, 3.0)] == [("missing", 2, 1, 1.0, 1.5)]
    assert same(
        [block_tuple(x) for x in a.flush()],
        [("block", 3, 1.5, 2.0, 3.0, 1, None, 0, 9.0, 0, math.nan, math.nan)],
    )


def test_temperatures_and_flags_do_not_leak_into_the_next_block() -> None:
    a = BlockAverager()
    a.feed(0, 1.0, temp_c=20.0, saturated=True)
    a.feed(500_000, 1.0, temp_c=30.0, saturated=True)
    (b0,) = a.feed(1_000_000, 2.0, temp_c=40.0)
    a.feed(1_500_000, 2.0, temp_c=None, saturated=True)
    (b1,) = a.feed(2_000_000, 3.0)
    (b2,) = a.flush()
    assert isinstance(b0, Block) and isinstance(b1, Block) and isinstance(b2, Block)
    assert [(b.temp_c, b.saturated) for b in (b0, b1, b2)] == [(None, 2), (40.0, 1), (None, 0)]
    assert [(b.n, b.sumsq) for b in (b0, b1, b2)] == [(0, 0.0), (1, 4.0), (1, 9.0)]


def test_block_std_is_never_nan_for_equal_samples() -> None:
    # sumsq / n - mean**2 rounds below zero for these: the spread is 0, not NaN.
    v = [0.1, 0.1, 0.1]
    a = BlockAverager()
    for k, x in enumerate(v):
        a.feed(k * 100_000, x)
    (b,) = a.flush()
    assert isinstance(b, Block)
    assert b.sumsq / b.n - b.mean * b.mean < 0.0
    assert b.std == 0.0
    assert Block(0, 0.0, 1.0, 2.0, 4, sumsq=20.0).std == 1.0


def test_faulty_samples_are_counted_with_their_readings_and_never_averaged() -> None:
    """A block of faulty samples only is still a block (n = 0, no mean), never Missing: its
    time passed and the step says why nothing was averaged."""
    a = BlockAverager()
    a.feed(0, 1.0, 20.0)
    a.feed(300_000, -125.0, 20.0, fault=10.0)
    a.feed(600_000, 3.0, 20.0, fault=4.0)
    (b0,) = a.feed(1_000_000, 9.0, fault=0.1)
    (b1,) = a.feed(2_100_000, 2.0)
    assert isinstance(b0, Block) and isinstance(b1, Block)
    assert (b0.n, b0.mean, b0.faults, b0.fault_lo, b0.fault_hi) == (1, 1.0, 2, 4.0, 10.0)
    assert (b1.n, b1.faults, b1.fault_lo, b1.fault_hi, b1.temp_c) == (0, 1, 0.1, 0.1, None)
    assert math.isnan(b1.mean) and math.isnan(b1.std)
