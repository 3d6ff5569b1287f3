"""hdrd.io.wire.capture: the vectorised decoder of a whole capture (``hdrd replay``), which must
give exactly what the push parser (hdrd.io.wire.parser) gives over the same bytes: the same frames,
counters and per-frame bad counts, however the capture is sliced for scanning and however
many bad candidates it holds.

The push parser's own rules, and the decoder beside it on small dirty streams:
test_parser.py; both on one realistic 10-minute capture: test_fastpaths.py.
"""

from __future__ import annotations

from unittest import mock

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from hdrd.io.wire import capture as capture_mod
from hdrd.io.wire.capture import decode_capture, encode_array
from hdrd.io.wire.codec import FRAME_DTYPE, Frame, array_to_frames, encode_bin
from hdrd.io.wire.parser import Parser
from hdrd.io.wire.protocol import PROTOCOLS, SYNC
from tests.test_parser import _NEAR, run
from tests.test_rel_bytes import frames_st


@given(
    st.lists(
        st.one_of(frames_st.map(encode_bin), _NEAR, st.just(SYNC), st.binary(max_size=24)),
        max_size=30,
    ),
    st.sampled_from([1, 2, 3, 5, 15, 16, 17, 31, 64]),
    st.sampled_from(PROTOCOLS),
)
def test_decode_in_slices_is_decode_whole(pieces: list[bytes], scan: int, protocol: str) -> None:
    """decode_capture scans a capture in slices of _SCAN_BYTES (its memory follows the slice,
    not the capture); a frame, a CRC coincidence or a bad frame across a slice boundary is
    decided exactly as by the push parser over the whole capture."""
    data = b"".join(p if protocol == "hdr-bin" else p.replace(b"\xa5", b"$HDRG,")
                    for p in pieces)  # fmt: skip
    bb: list[int] = []
    whole = run(protocol, data, None, bb)
    with mock.patch.object(capture_mod, "_SCAN_BYTES", scan):
        arr, vstats = decode_capture(data, protocol)
    assert (array_to_frames(arr), vstats) == whole and vstats.bad_before.tolist() == bb


def test_vectorised_slow_path_equals_push_on_messy_sequences() -> None:
    rng = np.random.default_rng(7)
    n = 3000
    arr = np.zeros(n, FRAME_DTYPE)
    arr["seq"] = (np.arange(n) + rng.choice([0, 0, 0, 1, -1, 5000, 40000], n).cumsum()) & 0xFFFF
    arr["t_us"] = (
        np.arange(n) * 3_000_000
        + rng.choice([0, 0, 0, 0, -3_000_000, -3_500_000, -10_000_000], n).cumsum()
    ) % 2**32
    arr["rate"] = rng.integers(0, 65536, n)
    arr["temp"] = rng.choice([-32768, 2500, -1], n)
    data = encode_array(arr)
    frames, stats = run("hdr-bin", data, list(rng.integers(0, len(data), 40)))
    got, vstats = decode_capture(data)
    assert array_to_frames(got) == frames and vstats == stats
    assert stats.seq_gaps and stats.seq_repeats and stats.seq_clock_mismatch
    assert stats.frames + stats.seq_repeats + stats.seq_clock_mismatch == n


def test_vectorised_on_a_large_dirty_capture() -> None:
    """Many frames, random garbage (with sync patterns), corrupted frames: identical results."""
    rng = np.random.default_rng(3)
    n = 20_000
    arr = np.zeros(n, FRAME_DTYPE)
    arr["seq"] = np.arange(n) & 0xFFFF
    arr["t_us"] = np.arange(n) * 100_000
    arr["rate"] = rng.integers(0, 65536, n)
    arr["ref"] = rng.integers(0, 65536, n)
    arr["temp"] = rng.integers(-32768, 32768, n)
    frames = bytearray(encode_array(arr))
    pieces = []
    for i in range(n):
        fr = bytearray(frames[16 * i : 16 * i + 16])
        r = rng.random()
        if r < 0.05:
            fr[rng.integers(2, 16)] ^= 1 << rng.integers(0, 8)
        elif r < 0.1:
            pieces.append(rng.integers(0, 256, rng.integers(1, 30), dtype=np.uint8).tobytes())
        elif r < 0.12:
            pieces.append(b"\xa5\x5a" + rng.integers(0, 256, 10, dtype=np.uint8).tobytes())
        pieces.append(bytes(fr))
    data = b"".join(pieces)
    got, vstats = decode_capture(data)
    p = Parser()
    out = []
    bb = []
    for i in range(0, len(data), 64):
        out += p.feed(data[i : i + 64])
        bb += p.bad_before
    out += p.flush()
    bb += p.bad_before
    assert array_to_frames(got) == out and vstats == p.stats and vstats.bad_before.tolist() == bb
    assert p.stats.bad_frames >= int(0.04 * n) and p.stats.frames >= int(0.9 * n)


@given(
    st.lists(
        st.one_of(frames_st.map(encode_bin), _NEAR, st.just(SYNC), st.binary(max_size=24)),
        max_size=30,
    ),
    st.sampled_from([3, 16, 17, 64, 1 << 20]),
    st.sampled_from([0, 1, 2, 5]),
)
def test_many_bad_candidates_are_counted_as_few_are(
    pieces: list[bytes], scan: int, keep_failed: int
) -> None:
    """Past _KEEP_FAILED failed candidates, decode_capture stops keeping their positions and
    finds them again in a second pass over the slices: the same frames, bad-frame count and
    bad_before as the push parser."""
    data = b"".join(pieces)
    bb: list[int] = []
    whole = run("hdr-bin", data, None, bb)
    with (
        mock.patch.object(capture_mod, "_SCAN_BYTES", scan),
        mock.patch.object(capture_mod, "_KEEP_FAILED", keep_failed),
    ):
        arr, vstats = decode_capture(data)
    assert (array_to_frames(arr), vstats) == whole and vstats.bad_before.tolist() == bb


def test_second_pass_on_a_known_capture() -> None:
    f = [Frame(seq=k, t_us=100_000 * k, rate=32768 + k, ref=0, temp_cc=None) for k in range(6)]
    bad = bytearray(encode_bin(f[2]))
    bad[9] ^= 0x10  # a CRC error
    data = encode_bin(f[0]) + SYNC + encode_bin(f[1]) + bytes(bad) + SYNC + SYNC
    data += b"".join(encode_bin(x) for x in f[3:])
    for keep in (0, 1 << 20):
        with mock.patch.object(capture_mod, "_KEEP_FAILED", keep):
            arr, st_ = decode_capture(data)
        assert array_to_frames(arr) == [f[0], f[1], f[3], f[4], f[5]]
        assert st_.bad_frames == 4 and st_.bad_before.tolist() == [0, 1, 4, 4, 4]
        assert st_.garbage_bytes == len(data) - 5 * 16
