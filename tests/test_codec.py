"""hdrd.io.wire.codec: the CRC, one frame <-> its bytes in both formats, frames <-> arrays, and what a
bad frame's error says (docs/protocol.md is the contract: its worked examples byte for byte)."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdrd.io.wire.capture import crc16_ccitt_false_rows, decode_capture, decode_frames, encode_array
from hdrd.io.wire.codec import (
    FRAME_DTYPE,
    Frame,
    FrameError,
    array_to_frames,
    crc16_ccitt_false,
    decode_bin,
    decode_text,
    encode,
    encode_bin,
    encode_text,
    frames_to_array,
)
from hdrd.io.wire.parser import Parser
from hdrd.io.wire.protocol import PROTOCOLS, SYNC
from hdrd.io.wire.tracker import FrameTracker
from tests.test_rel_bytes import as_stream, frames_st


def crc_bitwise(data: bytes) -> int:
    """Reference CRC-16/CCITT-FALSE, bit by bit from the definition (poly 0x1021, init 0xFFFF,
    no reflection, no final xor): independent of the implementation under test."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def kept_by_tracker(frames: list[Frame]) -> list[Frame]:
    """The frames a new :class:`FrameTracker` keeps of ``frames`` (the input ends after them)."""
    tr = FrameTracker()
    kept, _ = tr.run(frames, [0] * len(frames))
    tr.flush()
    return kept


# --------------------------------------------------------------------------- CRC and codecs


def test_crc_check_value() -> None:
    # The catalogue check value of CRC-16/CCITT-FALSE.
    assert crc16_ccitt_false(b"123456789") == 0x29B1 == crc_bitwise(b"123456789")


@given(st.binary(max_size=40))
def test_crc_matches_definition(data: bytes) -> None:
    assert crc16_ccitt_false(data) == crc_bitwise(data)


@given(st.integers(0, 30), st.integers(0, 17), st.integers(0, 2**32 - 1))
def test_crc_rows_matches_scalar(k: int, m: int, seed: int) -> None:
    rows = np.random.default_rng(seed).integers(0, 256, (k, m), dtype=np.uint8)
    assert crc16_ccitt_false_rows(rows).tolist() == [crc_bitwise(r.tobytes()) for r in rows]


def test_worked_example_of_docs() -> None:
    """The example frame of docs/protocol.md, byte for byte."""
    f = Frame(seq=258, t_us=1_000_000, rate=33554, ref=32768, temp_cc=2512)
    wire = bytes.fromhex("a5 5a 02 01 40 42 0f 00 12 83 00 80 d0 09 ae 8a")
    assert crc_bitwise(wire[2:14]) == 0x8AAE
    assert encode_bin(f) == wire
    assert decode_bin(wire) == f
    assert f.temp_c == pytest.approx(25.12)
    assert encode_text(f) == b"$HDRG,258,1000000,33554,32768,25.12*1D\r\n"
    absent = Frame(seq=259, t_us=1_100_000, rate=31982, ref=0, temp_cc=None)
    assert encode_text(absent) == b"$HDRG,259,1100000,31982,,*0A\r\n"
    wire2 = bytes.fromhex("a5 5a 03 01 e0 c8 10 00 ee 7c 00 00 00 80 92 0e")
    assert crc_bitwise(wire2[2:14]) == 0x0E92 and encode_bin(absent) == wire2
    assert absent.temp_c is None


def test_bin_layout_follows_the_table() -> None:
    f = Frame(seq=0x1234, t_us=0x89ABCDEF, rate=0xFFFE, ref=1, temp_cc=-2)
    b = encode_bin(f)
    assert b[:2] == SYNC and len(b) == 16
    assert struct.unpack("<HIHHhH", b[2:]) == (
        0x1234,
        0x89ABCDEF,
        0xFFFE,
        1,
        -2,
        crc_bitwise(b[2:14]),
    )
    assert struct.unpack("<h", encode_bin(Frame(0, 0, 0, 0, None))[12:14]) == (-32768,)


@given(frames_st)
def test_bin_round_trip(f: Frame) -> None:
    assert decode_bin(encode_bin(f)) == f
    assert encode(f, "hdr-bin") == encode_bin(f)


@given(frames_st)
def test_text_round_trip(f: Frame) -> None:
    line = encode_text(f)
    assert decode_text(line) == f
    assert decode_text(line.rstrip(b"\r\n")) == f  # the line end is optional for one line
    assert encode(f, "hdr-text") == line
    body, _, hh = line[1:-2].partition(b"*")
    x = 0
    for c in body:
        x ^= c
    assert hh == b"%02X" % x  # two uppercase hex digits


def test_text_fields() -> None:
    assert encode_text(Frame(1, 2, 3, 0, -5)).startswith(b"$HDRG,1,2,3,,-0.05*")
    assert encode_text(Frame(1, 2, 3, 7, 0)).startswith(b"$HDRG,1,2,3,7,0.00*")
    assert encode_text(Frame(1, 2, 3, 7, -32767)).startswith(b"$HDRG,1,2,3,7,-327.67*")

    def line(body: bytes, hh: str | None = None) -> bytes:
        x = 0
        for c in body:
            x ^= c
        return b"$" + body + b"*" + (hh or f"{x:02X}").encode() + b"\r\n"

    # Lenient input: other decimals, lowercase checksum, LF only.
    assert decode_text(line(b"HDRG,1,2,3,4,25")).temp_cc == 2500
    assert decode_text(line(b"HDRG,1,2,3,4,-1.5")).temp_cc == -150
    assert decode_text(line(b"HDRG,1,2,3,4,+0.014")).temp_cc == 1
    assert decode_text(line(b"HDRG,1,2,3,0,")) == Frame(1, 2, 3, 0, None)
    body = b"HDRG,259,1100000,31982,,"  # checksum 0A: lowercase hex is accepted too
    assert decode_text(line(body, "0a")) == decode_text(line(body, "0A"))
    assert decode_text(line(b"HDRG,1,2,3,,")[:-2] + b"\n") == Frame(1, 2, 3, 0, None)
    bad = [
        line(b"HDRG,1,2,3,4,5", "00"),  # checksum
        line(b"HDRG,1,2,3,4"),  # too few fields
        line(b"HDRG,1,2,3,4,5,6"),  # too many
        line(b"HDRG,65536,2,3,4,5"),  # seq range
        line(b"HDRG,1,4294967296,3,4,5"),  # t_us range
        line(b"HDRG,1,2,65536,4,5"),
        line(b"HDRG,1,2,3,-4,5"),  # sign on an unsigned field
        line(b"HDRG,1,2,3,4,327.68"),  # temp range
        line(b"HDRG,1,2,3,4,1e3"),
        line(b"HDRG,,2,3,4,5"),  # seq is required
        line(b"HDRX,1,2,3,4,5"),
        b"$HDRG,1,2,3,4,5*4\r\n",
        b"$HDRG,1,2,3,4,5*ZZ\r\n",
        b"$HDRG,1,2,3,4,5\r\n",
        b"HDRG,1,2,3,4,5*00\r\n",
        b"",
    ]
    for b in bad:
        with pytest.raises(FrameError):
            decode_text(b)


def test_decode_bin_errors() -> None:
    good = encode_bin(Frame(1, 2, 3, 4, 5))
    for b in (
        good[:15],
        good + b"\0",
        b"",
        b"\xa5\x5b" + good[2:],
        good[:14] + bytes([good[14] ^ 1, good[15]]),
    ):
        with pytest.raises(FrameError):
            decode_bin(b)


@pytest.mark.parametrize(
    "f",
    [
        Frame(-1, 0, 0, 0, None),
        Frame(0, 2**32, 0, 0, None),
        Frame(0, 0, 65536, 0, None),
        Frame(0, 0, 0, 65536, None),
        Frame(0, 0, 0, 0, -32768),
        Frame(0, 0, 0, 0, 32768),
    ],
)
def test_encode_rejects_out_of_range(f: Frame) -> None:
    for protocol in PROTOCOLS:
        with pytest.raises(FrameError):
            encode(f, protocol)


def test_unknown_protocol() -> None:
    with pytest.raises(ValueError, match="unknown protocol"):
        Parser("nmea")
    with pytest.raises(ValueError, match="unknown protocol"):
        encode(Frame(0, 0, 0, 0, None), "bin")
    with pytest.raises(ValueError, match="unknown protocol"):
        decode_capture(b"", "x")


@given(st.lists(frames_st, max_size=30))
def test_array_helpers_round_trip(frames: list[Frame]) -> None:
    arr = frames_to_array(frames)
    assert arr.dtype == FRAME_DTYPE
    assert array_to_frames(arr) == frames
    for protocol in PROTOCOLS:
        data = encode_array(arr, protocol)
        assert data == b"".join(encode(f, protocol) for f in frames)
        assert decode_frames(data, protocol) == kept_by_tracker(frames)
        healthy = as_stream(frames)
        assert decode_frames(encode_array(frames_to_array(healthy), protocol), protocol) == healthy


# -- what the errors say ------------------------------------------------------------------------


def test_each_codec_error_says_what_is_wrong() -> None:
    good = encode_bin(Frame(seq=1, t_us=2, rate=3, ref=4, temp_cc=5))
    with pytest.raises(FrameError, match=r"^bad sync 0000 \(expected a55a\)$"):
        decode_bin(b"\x00\x00" + good[2:])
    text = encode_text(Frame(seq=1, t_us=2, rate=3, ref=4, temp_cc=250)).rstrip(b"\r\n")
    body = text[: text.index(b"*")]
    cases = {
        body: "hdr-text line must end with *HH (two hex digits)",
        b"$HDRG,1,2,3": "hdr-text line has 3 fields, expected 5",
        b"$HDRG,1,x,3,4,": "hdr-text t_us b'x' is not a decimal integer",
        b"$HDRG,1,2,3,y,": "hdr-text ref b'y' is not a decimal integer",
        b"$HDRG,1,2,3,4,2.5.0": "hdr-text temp_c b'2.5.0' is not a decimal number",
    }
    from hdrd.io.wire.codec import _xor

    for line, message in cases.items():
        if line is not body:  # a valid checksum: the error is the field's
            line = line + b"*%02X" % _xor(line[1:])
        with pytest.raises(FrameError) as e:
            decode_text(line)
        assert str(e.value) == message, (line, str(e.value))
    with pytest.raises(
        ValueError, match=r"unknown protocol 'x' \(expected one of hdr-bin, hdr-text\)"
    ):
        encode(Frame(seq=1, t_us=2, rate=3, ref=4, temp_cc=5), "x")
