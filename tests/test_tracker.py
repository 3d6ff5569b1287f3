"""hdrd.io.wire.tracker: which frames are new, by their sequence number and device clock (docs/protocol.md,
"Sequence and clock"): the rule itself, and each case through the push parser, byte by byte,
and the vectorised decoder alike."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdrd.io.wire.capture import decode_capture
from hdrd.io.wire.codec import (
    Frame,
    array_to_frames,
    encode,
)
from hdrd.io.wire.protocol import PROTOCOLS
from hdrd.io.wire.tracker import ParserStats, keeps
from tests.test_parser import I, run

# --------------------------------------------------------------------------- sequence and clock


def seq_stream(
    pairs: list[tuple[int, int]], protocol: str = "hdr-bin"
) -> tuple[list[int], ParserStats]:
    """Frames with these (seq, t_us) through the push parser (whole, and byte by byte) and the
    vectorised decoder: the indices of the frames kept, and the counters (all alike)."""
    sent = [Frame(s, t, k, 0, None) for k, (s, t) in enumerate(pairs)]  # rate = index
    data = b"".join(encode(f, protocol) for f in sent)
    frames, stats = run(protocol, data)
    assert run(protocol, data, list(range(len(data)))) == (frames, stats)
    arr, vstats = decode_capture(data, protocol)
    assert array_to_frames(arr) == frames and vstats == stats
    assert stats.frames == len(frames)
    return [f.rate for f in frames], stats


def counts(s: ParserStats) -> tuple[int, ...]:
    return (s.seq_gaps, s.lost_frames, s.seq_repeats, s.seq_resets, s.seq_clock_mismatch)


S = 1000
HEALTHY = [(S + k, k * I) for k in range(3)]  # the stream before each case below


@pytest.mark.parametrize("protocol", PROTOCOLS)
@pytest.mark.parametrize(
    "tail, kept, want",
    [
        # the last frame repeated: not new
        ([(S + 2, 2 * I), (S + 2, 2 * I), (S + 3, 3 * I)], [0, 1, 2, 5], (0, 0, 2, 0, 0)),
        # the sequence advancing with a frozen clock, then a frame at the right time
        (
            [(S + 3, 2 * I), (S + 4, 2 * I), (S + 5, 2 * I), (S + 6, 6 * I)],
            [0, 1, 2, 6],
            (1, 3, 0, 0, 3),
        ),
        # a clock 100x slow, then 100x fast: never integrated, each held and dropped
        ([(S + 3 + k, 2 * I + (k + 1) * I // 100) for k in range(5)], [0, 1, 2], (0, 0, 0, 0, 5)),
        ([(S + 3 + k, 2 * I + (k + 1) * I * 100) for k in range(5)], [0, 1, 2], (0, 0, 0, 0, 5)),
        # a random frame that passed the CRC, between good ones
        ([(31337, 123_456_789), (S + 3, 3 * I)], [0, 1, 2, 4], (0, 0, 0, 0, 1)),
        # reordered: one ahead (a gap), the one behind it (not new)
        ([(S + 4, 4 * I), (S + 3, 3 * I), (S + 5, 5 * I)], [0, 1, 2, 3, 5], (1, 1, 1, 0, 0)),
        # a device restart: held until three continue one another, then all kept
        ([(0, 5), (1, 5 + I), (2, 5 + 2 * I), (3, 5 + 3 * I)], list(range(7)), (0, 0, 0, 1, 0)),
        # a restart not confirmed: the input ends two frames after it
        ([(0, 5), (1, 5 + I)], [0, 1, 2], (0, 0, 0, 0, 2)),
        # the clock jumped on once and runs at the interval since: believed after three
        (
            [(S + 3, 10**9), (S + 4, 10**9 + I), (S + 5, 10**9 + 2 * I)],
            list(range(6)),
            (0, 0, 0, 0, 0),
        ),
        # a gap the clock agrees with, and a gap it does not (held, then dropped)
        ([(S + 6, 6 * I), (S + 9, 7 * I), (S + 7, 7 * I)], [0, 1, 2, 3, 5], (1, 3, 0, 0, 1)),
    ],
)
def test_frames_not_new_or_with_a_clock_that_disagrees_are_dropped(
    protocol: str, tail: list[tuple[int, int]], kept: list[int], want: tuple[int, ...]
) -> None:
    got, s = seq_stream(HEALTHY + tail, protocol)
    assert got == kept and counts(s) == want


@given(
    st.lists(
        st.tuples(
            st.integers(0, 0xFFFF),
            st.integers(0, 0xFFFFFFFF),
            st.integers(0, 0xFFFFFFFF),
            st.sampled_from([0, 1, 2, 7]),
        ),
        min_size=1,
        max_size=20,
    )
)
def test_the_keep_rule_is_one_rule_for_ints_and_arrays(
    steps: list[tuple[int, int, int, int]],
) -> None:
    """docs/protocol.md's rule, spelled out here: kept when 0 < k <= 64 sequence steps, the
    clock forward by less than half its wrap, and d / k within a factor 2 of the interval
    d0 / k0 (any, before there is one); the numpy form the decoder uses says the same."""
    for k, d, d0, k0 in steps:
        near = k0 == 0 or (d * k0 <= 2 * d0 * k and d0 * k <= 2 * d * k0)
        assert keeps(k, d, d0, k0) == (0 < k <= 64 and 0 < d < 2**31 and near)
    ks, ds, d0s = (np.array([s[i] for s in steps], np.int64) for i in range(3))
    for k0 in (0, 1, 2, 7):
        assert keeps(ks, ds, d0s, k0).tolist() == [keeps(*s[:3], k0) for s in steps]


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_sequence_wrap_is_not_a_gap(protocol: str) -> None:
    got, s = seq_stream([(65534, 0), (65535, 100), (0, 200), (1, 300)], protocol)
    assert got == [0, 1, 2, 3] and counts(s) == (0, 0, 0, 0, 0)


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_clock_wraps(protocol: str) -> None:
    top = 2**32
    got, s = seq_stream(
        [(0, top - 2 * I), (1, top - I), (2, 0), (3, I), (4, 2 * I), (5, top - 50), (6, 50)],
        protocol,
    )
    # frame 5 is 2**32 - 50 - 2 I on: far ahead of its one step, held; 6 is back, dropped
    assert got == [0, 1, 2, 3, 4] and s.clock_wraps == 1 and s.seq_clock_mismatch == 2


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_the_interval_follows_a_slow_drift_but_not_a_jump(protocol: str) -> None:
    # Each step 1.5x the one before is kept (within SEQ_CLOCK_RATIO of the step before);
    # 2.5x is not.
    t, pairs = 0, []
    for k, step in enumerate([I, I, int(1.5 * I), int(2.25 * I), int(2.25 * 2.5 * I)]):
        t += step
        pairs.append((k, t))
    got, s = seq_stream(pairs, protocol)
    assert got == [0, 1, 2, 3] and s.seq_clock_mismatch == 1


# -- the sequence and clock limits, push parser and vectorised decoder alike ---------------------


@pytest.mark.parametrize(
    "step, kept, want",
    [
        (1, 5, (0, 0, 0, 0, 0)),
        (0x7FFF, 5, (1, 0x7FFE, 0, 0, 0)),  # the largest gap
        (0x8000, 5, (0, 0, 0, 1, 0)),  # half the sequence: a restart
        (0x10000 - 65, 5, (0, 0, 0, 1, 0)),  # 65 back: a restart
        (0x10000 - 64, 2, (0, 0, 3, 0, 0)),  # 64 back (SEQ_REORDER_WINDOW): not new
        (0, 4, (0, 0, 1, 0, 0)),  # the same number and time: not new
    ],
)
@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_sequence_steps_at_their_limits(
    step: int, kept: int, want: tuple[int, ...], protocol: str
) -> None:
    # 10 us a step, so that the largest gap stays forward on the clock; a step back goes back.
    s2 = (1001 + step) & 0xFFFF
    back = step >= 0x8000
    t2 = 30 + (step - 0x10000 if back else step) * 10
    pairs = [(1000, 20), (1001, 30), (s2, t2 % 2**32), (s2 + 1, (t2 + 10) % 2**32)]
    pairs.append((s2 + 2, (t2 + 20) % 2**32))
    got, st_ = seq_stream([(s & 0xFFFF, t) for s, t in pairs], protocol)
    assert len(got) == kept and counts(st_) == want
