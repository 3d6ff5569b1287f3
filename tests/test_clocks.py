"""hdrd.io.wire.clocks: the 32-bit microsecond device clock unwrapped (one sample at a time and a
whole array at once, which agree in every output and counter), the calibration window's
glitch-proof :class:`SampleClock`, a capture's device seconds, the host clocks a source
sleeps on, and :class:`WallClockCheck`, the device clock against the host's. Pure apart from
:class:`RealClock`.

The device clock's use by the resampler (blocks across a wrap, a reset mid-drive):
test_resample.py; the calibration window that SampleClock measures: test_calibrate.py.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.io.wire.clocks import (
    Clock,
    DeviceClock,
    ManualClock,
    RealClock,
    SampleClock,
    WallClockCheck,
    device_seconds,
    unwrap_us,
)
from hdrd.io.wire.protocol import CLOCK_WRAP_US


def test_device_clock_unwraps_monotonically_across_wraps() -> None:
    clock = DeviceClock()
    t = CLOCK_WRAP_US - 10
    assert clock.unwrap(t) == t
    assert clock.unwrap(5) == CLOCK_WRAP_US + 5
    # Forward jumps of less than half the wrap period (35.8 min) are time passing.
    assert clock.unwrap((1 << 31) - 1) == CLOCK_WRAP_US + (1 << 31) - 1
    assert clock.unwrap(CLOCK_WRAP_US - 2) == 2 * CLOCK_WRAP_US - 2
    assert clock.unwrap(3) == 2 * CLOCK_WRAP_US + 3
    assert clock.wraps == 2
    # 2**32 - 6 us "forward" is 6 us back: a reordered sample, rejected.
    assert clock.unwrap(CLOCK_WRAP_US - 3) is None


@pytest.mark.parametrize("back_us", [0, 1, 50_000, 1_000_000])
def test_repeated_and_out_of_order_timestamps_are_rejected(back_us: int) -> None:
    clock = DeviceClock()
    assert clock.unwrap(2_000_000) == 2_000_000
    assert clock.unwrap(2_100_000) == 2_100_000
    assert clock.unwrap(2_100_000 - back_us) is None
    assert clock.rejected == 1 and clock.resets == 0
    assert clock.unwrap(2_200_000) == 2_200_000  # resumes as if the bad one never came


def test_rejected_sample_across_the_wrap() -> None:
    clock = DeviceClock()
    clock.unwrap(10)
    assert clock.unwrap(CLOCK_WRAP_US - 100) is None  # 110 us back, across the wrap
    assert clock.unwrap(20) == 20


def test_device_reset_resumes_after_the_last_sample() -> None:
    clock = DeviceClock()
    assert clock.unwrap(50_000_000) == 50_000_000
    assert clock.unwrap(50_100_000) == 50_100_000
    # The device rebooted: its clock starts again near 0 (more than 1 s back).
    assert clock.unwrap(1_000) == 50_100_001
    assert clock.resets == 1 and clock.rejected == 0
    assert clock.unwrap(101_000) == 50_200_001  # then time passes normally


def test_unwrap_us_empty_and_fast_path() -> None:
    t, ok = unwrap_us([])
    assert t.shape == (0,) and ok.shape == (0,)
    raw = np.array([CLOCK_WRAP_US - 5, 2, 10])
    t, ok = unwrap_us(raw)
    assert ok.all() and t.tolist() == [CLOCK_WRAP_US - 5, CLOCK_WRAP_US + 2, CLOCK_WRAP_US + 10]


@given(
    st.integers(0, 2**32 - 1),
    st.lists(st.integers(1, 3_000_000), min_size=1, max_size=300),
    st.integers(0, 300),
)
def test_unwrap_many_continues_the_clock_like_unwrap(t0, steps, cut):
    raw = (t0 + np.cumsum([0, *steps])) % 2**32
    a, b = DeviceClock(), DeviceClock()
    stream = [a.unwrap(int(t)) for t in raw]
    cut = min(cut, len(raw))
    first, _ = b.unwrap_many(raw[:cut])
    second, _ = b.unwrap_many(raw[cut:])
    assert [*first.tolist(), *second.tolist()] == stream
    assert (b.wraps, b._last, b._last_raw) == (a.wraps, a._last, a._last_raw)


_CLOCK_STEP = st.one_of(
    st.integers(1, 300_000),
    st.integers(1, 300_000),
    st.integers(300_000, (1 << 31) - 1),
    st.sampled_from([0, 1 << 31, (1 << 31) - 1, (1 << 31) + 1]),
    st.sampled_from([-1, -1_000_000, -1_000_001]),
    st.integers(-1_000_000, -1),
    st.integers(-(1 << 31), -1_000_001),
)


@st.composite
def raw_clock(draw: st.DrawFn) -> list[int]:
    """32-bit device times with every kind of step: forward (to just under half the wrap),
    across the wrap, repeated, a little back (<= 1 s: rejected), far back (a reset), and
    exactly at the limits (half the wrap forward, 1 s and 1 s + 1 us back)."""
    t = draw(st.integers(0, CLOCK_WRAP_US - 1))
    out = [t]
    for step in draw(st.lists(_CLOCK_STEP, max_size=60)):
        t = (t + step) % CLOCK_WRAP_US
        out.append(t)
    return out


@settings(deadline=None)
@given(raw=raw_clock(), cuts=st.lists(st.integers(0, 61), max_size=3))
def test_unwrap_many_is_unwrap_in_everything(raw: list[int], cuts: list[int]) -> None:
    ref, sub = DeviceClock(), DeviceClock()
    want = [ref.unwrap(x) for x in raw]
    got: list[int | None] = []
    edges = [0, *sorted(min(c, len(raw)) for c in cuts), len(raw)]
    for lo, hi in zip(edges, edges[1:]):
        t, ok = sub.unwrap_many(np.array(raw[lo:hi], np.int64))
        assert ok.tolist() == [x >= 0 for x in t.tolist()]
        got += [int(x) if k else None for x, k in zip(t.tolist(), ok.tolist())]
        assert (sub.last_us, sub.wraps, sub.rejected, sub.resets) == (DeviceClock_after(raw[:hi]))
    assert got == want
    assert (sub.last_us, sub.wraps, sub.rejected, sub.resets) == (
        ref.last_us, ref.wraps, ref.rejected, ref.resets,
    )  # fmt: skip
    # The function form is a fresh clock over the whole array.
    t, ok = unwrap_us(np.array(raw, np.int64))
    assert [int(x) if k else None for x, k in zip(t.tolist(), ok.tolist())] == want


def DeviceClock_after(raw: list[int]) -> tuple[int | None, int, int, int]:  # noqa: N802
    c = DeviceClock()
    for x in raw:
        c.unwrap(x)
    return c.last_us, c.wraps, c.rejected, c.resets


def test_clock_limits_exactly() -> None:
    c = DeviceClock()
    assert c.last_us is None
    assert c.unwrap(5_000_000) == 5_000_000 and c.last_us == 5_000_000
    # half the wrap forward is as far back: more than 1 s back, a reset (time moves 1 us)
    assert c.unwrap(5_000_000 + (1 << 31)) == 5_000_001 and c.resets == 1
    # just under half the wrap forward is time passing, here across 2**32
    assert c.unwrap(5_000_000 - 1) == 5_000_001 + (1 << 31) - 1
    assert c.wraps == 1  # that last step crossed 2**32
    base, raw = 5_000_001 + (1 << 31) - 1, 5_000_000 - 1
    assert c.last_us == base
    # exactly 1 s back: a reordered sample, rejected; 1 s + 1 us back: a reset
    assert c.unwrap((raw - 1_000_000) % CLOCK_WRAP_US) is None and c.rejected == 1
    assert c.unwrap((raw - 1_000_001) % CLOCK_WRAP_US) == base + 1 and c.resets == 2
    # the same time twice: the second is rejected
    assert c.unwrap((raw - 1_000_001) % CLOCK_WRAP_US) is None and c.rejected == 2
    assert (c.wraps, c.rejected, c.resets) == (1, 2, 2)


@pytest.mark.parametrize(
    "raw",
    [
        [10, 10, 20],  # a repeat: d == 0
        [10, 10 + (1 << 31), 20],  # d == half the wrap
        [10, 10 + (1 << 31) - 1, 20 + (1 << 31)],  # just under half: the fast path
        [CLOCK_WRAP_US - 1, 0, 1],  # across the wrap, 1 us steps
    ],
)
def test_array_clock_forms_at_their_fast_path_limits(raw: list[int]) -> None:
    c = DeviceClock()
    want = [c.unwrap(x) for x in raw]
    t, ok = unwrap_us(np.array(raw, np.int64))
    assert [int(x) if k else None for x, k in zip(t.tolist(), ok.tolist())] == want
    d = DeviceClock()
    d.unwrap(raw[0])
    t, ok = d.unwrap_many(np.array(raw[1:], np.int64))
    assert [int(x) if k else None for x, k in zip(t.tolist(), ok.tolist())] == want[1:]
    assert (d.wraps, d.rejected, d.resets, d.last_us) == (c.wraps, c.rejected, c.resets, c.last_us)


def test_array_forms_take_the_frames_uint32_clock_and_give_int64() -> None:
    # frames["t_us"] is uint32: arithmetic on it in uint32 would overflow at the wrap.
    raw = [CLOCK_WRAP_US - 300_000, CLOCK_WRAP_US - 100_000, 100_000, 300_000, 500_000]
    c = DeviceClock()
    want = [c.unwrap(x) for x in raw]
    for dtype in (np.uint32, np.int64):
        t, ok = unwrap_us(np.array(raw, dtype))
        assert t.dtype == np.int64 and ok.all() and t.tolist() == want
        d = DeviceClock()
        t, ok = d.unwrap_many(np.array(raw, dtype))
        assert t.dtype == np.int64 and ok.all() and t.tolist() == want
        assert (d.wraps, d.last_us) == (1, want[-1])
    # the slow path (a repeat) and the empty array are int64 too
    t, ok = DeviceClock().unwrap_many(np.array([5, 5, 7], np.uint32))
    assert t.dtype == np.int64 and t.tolist() == [5, -1, 7] and ok.tolist() == [True, False, True]
    for t, ok in (DeviceClock().unwrap_many([]), unwrap_us([])):
        assert t.dtype == np.int64 and ok.dtype == bool and t.shape == (0,)


def test_unwrap_many_counts_one_wrap_with_samples_after_it() -> None:
    # Every step forward (the numpy path), the wrap in the middle, three samples after it.
    raw = [CLOCK_WRAP_US - 250_000, CLOCK_WRAP_US - 150_000, CLOCK_WRAP_US - 50_000,
           50_000, 150_000, 250_000]  # fmt: skip
    for head in (0, 1, 2):
        c = DeviceClock()
        for x in raw[:head]:
            c.unwrap(x)
        c.unwrap_many(np.array(raw[head:], np.int64))
        assert c.wraps == 1 and c.last_us == CLOCK_WRAP_US + 250_000


def test_sample_clock_sets_a_glitch_aside() -> None:
    c = SampleClock()
    t = [k * 100_000 for k in range(50)]
    t[20] += 1_800_000_000  # one frame 30 min ahead
    kept = [c.accept(x) for x in t]
    assert kept.count(False) == 1 and not kept[20] and c.glitches == 1
    assert c.elapsed_us == 4_900_000  # the 49 steps of the good frames only


def test_sample_clock_repeats_steps_back_and_the_wrap() -> None:
    c = SampleClock()
    base = 2**32 - 250_000  # wraps after two frames
    seq = [base, base + 100_000, base + 100_000, base + 50_000, (base + 200_000) % 2**32,
           (base + 300_000) % 2**32]  # fmt: skip
    assert [c.accept(x) for x in seq] == [True, True, False, False, True, True]
    assert c.elapsed_us == 300_000 and c.glitches == 2


def test_sample_clock_follows_a_real_jump() -> None:
    # The device clock jumps for good (a reset, or frames lost for a while): after a few
    # frames that step normally among themselves, the clock follows them; the jump itself
    # is not counted as time at standstill.
    c = SampleClock(confirm=3)
    before = [k * 100_000 for k in range(10)]
    after = [50_000_000 + k * 100_000 for k in range(10)]
    kept = [c.accept(x) for x in before + after]
    assert kept[:10] == [True] * 10 and kept[10:13] == [False] * 3 and all(kept[13:])
    assert c.elapsed_us == 900_000 + 7 * 100_000  # from the third frame after the jump


def test_sample_clock_limits_exactly() -> None:
    c = SampleClock(max_step_us=1_000_000, confirm=2)
    assert c.accept(0) and c.accept(1_000_000)  # a step of exactly the largest counts
    assert not c.accept(2_000_001) and c.glitches == 1  # one microsecond more does not
    assert c.elapsed_us == 1_000_000
    # two set-aside samples that step normally among themselves: the clock follows them
    assert not c.accept(2_100_000) and c.glitches == 2
    assert c.accept(2_200_000) and c.elapsed_us == 1_100_000
    # set-aside samples that do not step normally among themselves start over each time
    d = SampleClock(max_step_us=1_000_000, confirm=3)
    d.accept(0)
    assert [d.accept(x) for x in (5_000_000, 9_000_000, 13_000_000, 13_100_000)] == [False] * 4
    assert d.accept(13_200_000) is False and d.accept(13_300_000) is True
    assert d.elapsed_us == 100_000


def test_sample_clock_default_largest_step_is_2_s() -> None:
    c = SampleClock()
    assert c.accept(0) and c.accept(2_000_000) and not c.accept(4_000_001)
    assert c.elapsed_us == 2_000_000 and c.glitches == 1


# -- a capture's device seconds ------------------------------------------------------------


def test_device_seconds_unwraps_and_counts_a_step_back_as_no_time() -> None:
    raw = np.array(
        [CLOCK_WRAP_US - 200_000, CLOCK_WRAP_US - 100_000, 0, 100_000, 50_000, 150_000],
        np.uint32,
    )
    # across the wrap: time goes on; 100_000 -> 50_000 is a step back: no time passes
    assert device_seconds(raw).tolist() == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.3, 0.4])
    assert device_seconds(np.zeros(0, np.uint32)).shape == (0,)
    assert device_seconds(np.array([7], np.uint32)).tolist() == [0.0]


@settings(max_examples=50)
@given(st.integers(0, CLOCK_WRAP_US - 1), st.lists(st.integers(0, (1 << 31) - 1), max_size=50))
def test_device_seconds_is_the_unwrapped_clock_when_time_only_goes_forward(
    t0: int, steps: list[int]
) -> None:
    raw = (t0 + np.cumsum([0, *steps])) % CLOCK_WRAP_US
    t, _ = unwrap_us(raw)
    # the unwrapped clock rejects repeats (steps of 0) and device_seconds keeps them: compare
    # the elapsed time only, which a repeat does not change
    assert device_seconds(raw.astype(np.uint32))[-1] == pytest.approx((t.max() - t[0]) / 1e6)


# -- the host's clocks ---------------------------------------------------------------------


def test_manual_clock_moves_only_when_slept_on() -> None:
    c: Clock = ManualClock(start=10.0)
    assert c.monotonic() == 10.0 == c.monotonic()
    c.sleep(0.5)
    c.sleep(0.0)
    c.sleep(-1.0)  # a negative sleep is recorded and moves nothing
    assert c.monotonic() == 10.5
    assert isinstance(c, ManualClock) and c.slept == [0.5, 0.0, -1.0]


def test_real_clock_is_the_hosts_monotonic_clock() -> None:
    c: Clock = RealClock()
    a = time.monotonic()
    b = c.monotonic()
    c.sleep(0.01)
    c.sleep(0.0)
    c.sleep(-1.0)  # never an error (time.sleep would raise on a negative)
    assert a <= b and c.monotonic() - b >= 0.01


# -- the device clock against the host's ------------------------------------------------------

AGREES, DISAGREES, JUMPED = WallClockCheck.AGREES, WallClockCheck.DISAGREES, WallClockCheck.JUMPED


def verdicts(
    check: WallClockCheck,
    n: int,
    dev_step_us: int,
    host_step_s: float,
    t0: int = 0,
    at: float = 0.0,
) -> list[int]:
    """``n`` frames ``dev_step_us`` apart on the device clock, ``host_step_s`` apart in hand."""
    return [check.check((t0 + k * dev_step_us) % 2**32, at + k * host_step_s) for k in range(n)]


def test_a_device_clock_at_the_host_rate_agrees_late_frames_and_a_wrap_included() -> None:
    c = WallClockCheck()
    assert set(verdicts(c, 500, 100_000, 0.1, t0=2**32 - 10_000_000)) == {AGREES}  # wraps
    # a burst read 3 s late (a stalled reader), then frames in time again: all agree
    t = (2**32 - 10_000_000 + 500 * 100_000) % 2**32
    assert {c.check((t + k * 100_000) % 2**32, 50.0 + 3.0) for k in range(30)} == {AGREES}
    assert set(verdicts(c, 30, 100_000, 0.1, t0=t + 30 * 100_000, at=53.0)) == {AGREES}
    assert c.mismatches == 0 and c.jumps == 0


@pytest.mark.parametrize("factor", [100.0, 0.01, 3.0, 0.3])
def test_a_device_clock_too_fast_or_too_slow_disagrees_and_is_never_followed(factor: float) -> None:
    c = WallClockCheck(tolerance_s=5.0, reanchor_s=5.0)
    assert set(verdicts(c, 50, 100_000, 0.1)) == {AGREES}
    t0 = 49 * 100_000
    # 20 s: 100x fast, 2,000 s of device time, short of half the 32-bit clock's wrap (a step
    # beyond it reads as a step back, a restart, which only FrameTracker in front can judge)
    got = [c.check(int(t0 + k * 100_000 * factor) % 2**32, 4.9 + k * 0.1) for k in range(1, 200)]
    assert JUMPED not in got  # never re-anchored
    first = got.index(DISAGREES)
    assert set(got[:first]) <= {AGREES}  # within 5 s of the host clock before that
    assert set(got[first:]) == {DISAGREES}


def test_a_jump_of_the_device_clock_is_followed_after_reanchor_s() -> None:
    c = WallClockCheck(tolerance_s=5.0, reanchor_s=5.0)
    verdicts(c, 50, 100_000, 0.1)
    got = verdicts(c, 200, 100_000, 0.1, t0=368_000_000, at=5.0)  # 368 s on, then at the rate
    jumped = got.index(JUMPED)
    assert got[:jumped] == [DISAGREES] * jumped and set(got[jumped + 1 :]) == {AGREES}
    assert 50 <= jumped <= 51 and c.jumps == 1  # 5 s of frames 0.1 s apart
    # a device restart (its clock back to 0): a jump at once, then the frames agree
    got = verdicts(c, 20, 100_000, 0.1, t0=0, at=25.0)
    assert got[0] == JUMPED and set(got[1:]) == {AGREES} and c.jumps == 2


def test_clock_rate_scales_the_device_clock_and_0_turns_the_check_off() -> None:
    fast = WallClockCheck(rate=4.0)
    assert set(verdicts(fast, 400, 100_000, 0.025)) == {AGREES}  # a feed 4x real time
    assert DISAGREES in verdicts(WallClockCheck(), 400, 100_000, 0.025)
    off = WallClockCheck(rate=0.0)
    assert set(verdicts(off, 400, 10**9, 0.001)) == {AGREES} and off.mismatches == 0
    with pytest.raises(ValueError):
        WallClockCheck(rate=-1.0)


def test_reset_starts_a_new_reference() -> None:
    c = WallClockCheck()
    verdicts(c, 10, 100_000, 0.1)
    c.reset()  # a new connection: whatever its device time, the first frame is the reference
    assert set(verdicts(c, 10, 100_000, 0.1, t0=123_456_789, at=500.0)) == {AGREES}
