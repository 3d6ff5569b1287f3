"""hdr-bin and hdr-text: one frame <-> its bytes, and frames <-> a numpy array (docs/protocol.md).

Pure: no port, no clock. :func:`encode_bin` / :func:`decode_bin`, :func:`encode_text` /
:func:`decode_text` (a bad frame raises :class:`FrameError`); :data:`FRAME_DTYPE`, the array
form of frames the vectorised decoder (:mod:`hdrd.io.wire.capture`) and the simulator use. hdr-bin's
struct formats and the dtype are made from the field table :data:`hdrd.io.wire.protocol.BIN_FIELDS`.
The stream's parts: which frames are new (:mod:`hdrd.io.wire.tracker`), bytes to frames
(:mod:`hdrd.io.wire.parser`).

**hdr-bin**, 16 bytes, little-endian: sync ``A5 5A``, seq u16, t_us u32, rate u16, ref u16,
temp i16 (0.01 degC, -32768 = not fitted), CRC-16/CCITT-FALSE u16 over bytes 2..13.

**hdr-text**: ``$HDRG,<seq>,<t_us>,<rate>,<ref>,<temp_c>*HH\\r\\n``; ref and temp_c may be
empty (absent); HH is the XOR of the bytes between ``$`` and ``*``, two hex digits.
"""

from __future__ import annotations

import re
import struct
from binascii import crc_hqx
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.errors import HdrdError
from hdrd.io.wire.protocol import (
    BIN_CRC_AT,
    BIN_FIELDS,
    BIN_FRAME_LEN,
    BIN_PAYLOAD_AT,
    PROTOCOLS,
    SYNC,
    TEMP_NOT_FITTED,
    TEXT_SYNC,
    WIRE_TYPES,
)

__all__ = [
    "BIN_BODY",
    "FRAME_DTYPE",
    "Frame",
    "FrameError",
    "array_to_frames",
    "check_protocol",
    "crc16_ccitt_false",
    "decode_bin",
    "decode_text",
    "encode",
    "encode_bin",
    "encode_text",
    "fast_frame",
    "frames_to_array",
]

_CODES = "".join(WIRE_TYPES[f.type].struct for f in BIN_FIELDS)
_PAYLOAD = struct.Struct("<" + _CODES)  # the fields, the CRC's input
BIN_BODY = struct.Struct("<" + _CODES + "H")
"""An hdr-bin frame after its sync bytes: the fields of :data:`BIN_FIELDS`, then the CRC."""
_U16 = 0xFFFF
_U32 = 0xFFFFFFFF

FRAME_DTYPE = np.dtype([(f.name, WIRE_TYPES[f.type].numpy) for f in BIN_FIELDS])
"""One frame in a numpy structured array: exactly the payload of an hdr-bin frame (bytes
2..13, packed). ``temp`` is in 0.01 degC with -32768 = not fitted; ``ref`` 0 = not wired."""


class FrameError(HdrdError, ValueError):
    """Bytes that are not a valid frame (bad sync, length, CRC, checksum or field)."""


@dataclass(frozen=True, slots=True)
class Frame:
    """One ADC sample as sent by the device.

    seq: frame counter, +1 per frame, wraps at 2**16. t_us: device clock, microseconds,
    wraps at 2**32. rate: ADC counts of the gyro output. ref: ADC counts of the supply
    monitor, 0 = not wired. temp_cc: board temperature in 0.01 degC, None = not fitted.
    """

    seq: int
    t_us: int
    rate: int
    ref: int
    temp_cc: int | None

    @property
    def temp_c(self) -> float | None:
        """Board temperature, degC (None = not fitted)."""
        return None if self.temp_cc is None else self.temp_cc / 100.0


# Building a Frame through its slot descriptors has the same effect as Frame(...) (the frozen
# dataclass __init__ sets the same slots through object.__setattr__) at a fraction of the cost:
# the parser's hot path.
_new = object.__new__
_SLOTS: Any = vars(Frame)  # the slot descriptors (typing sees instance attributes only)
_SET_SEQ = _SLOTS["seq"].__set__
_SET_T = _SLOTS["t_us"].__set__
_SET_RATE = _SLOTS["rate"].__set__
_SET_REF = _SLOTS["ref"].__set__
_SET_TEMP = _SLOTS["temp_cc"].__set__


def fast_frame(seq: int, t_us: int, rate: int, ref: int, temp_cc: int | None) -> Frame:
    """``Frame(seq, t_us, rate, ref, temp_cc)``, without the frozen dataclass's cost (for the
    decoders, whose fields are in range by construction)."""
    f = _new(Frame)
    _SET_SEQ(f, seq)
    _SET_T(f, t_us)
    _SET_RATE(f, rate)
    _SET_REF(f, ref)
    _SET_TEMP(f, temp_cc)
    return f


# --------------------------------------------------------------------------- CRC


def crc16_ccitt_false(data: bytes) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final xor.

    ``binascii.crc_hqx`` is this CRC (MSB first, poly 0x1021) with the init passed in.
    Check value: ``crc16_ccitt_false(b"123456789") == 0x29B1``.
    """
    return crc_hqx(data, 0xFFFF)


# --------------------------------------------------------------------------- codecs


def _check_fields(f: Frame) -> None:
    if not (
        0 <= f.seq <= _U16 and 0 <= f.t_us <= _U32 and 0 <= f.rate <= _U16 and 0 <= f.ref <= _U16
    ):
        raise FrameError(
            f"field out of range in {f!r} (seq, rate, ref: 0..65535; t_us: 0..2**32-1)"
        )
    if f.temp_cc is not None and not -32767 <= f.temp_cc <= 32767:
        raise FrameError(
            f"temp_cc {f.temp_cc!r} out of range -32767..32767 (0.01 degC; None = not fitted)"
        )


def encode_bin(f: Frame) -> bytes:
    """The 16-byte hdr-bin frame of ``f``."""
    _check_fields(f)
    temp = TEMP_NOT_FITTED if f.temp_cc is None else f.temp_cc
    payload = _PAYLOAD.pack(f.seq, f.t_us, f.rate, f.ref, temp)
    return SYNC + payload + struct.pack("<H", crc_hqx(payload, 0xFFFF))


def decode_bin(b: bytes) -> Frame:
    """The frame in exactly 16 hdr-bin bytes; FrameError on bad length, sync or CRC."""
    if len(b) != BIN_FRAME_LEN:
        raise FrameError(f"hdr-bin frame is {BIN_FRAME_LEN} bytes, got {len(b)}")
    if b[:2] != SYNC:
        raise FrameError(f"bad sync {bytes(b[:2]).hex()} (expected a55a)")
    seq, t_us, rate, ref, temp, crc = BIN_BODY.unpack_from(b, BIN_PAYLOAD_AT)
    calc = crc_hqx(b[BIN_PAYLOAD_AT:BIN_CRC_AT], 0xFFFF)
    if calc != crc:
        raise FrameError(f"CRC mismatch: frame says {crc:04x}, bytes give {calc:04x}")
    return fast_frame(seq, t_us, rate, ref, None if temp == TEMP_NOT_FITTED else temp)


def _xor(data: bytes) -> int:
    x = 0
    for c in data:
        x ^= c
    return x


def _fmt_temp(temp_cc: int) -> str:
    sign = "-" if temp_cc < 0 else ""
    a = abs(temp_cc)
    return f"{sign}{a // 100}.{a % 100:02d}"


def encode_text(f: Frame) -> bytes:
    """The hdr-text line of ``f``, ``\\r\\n`` included. ref 0 (not wired) and temp None (not
    fitted) are sent as empty fields; temperature in degC with two decimals."""
    _check_fields(f)
    ref = str(f.ref) if f.ref else ""
    temp = "" if f.temp_cc is None else _fmt_temp(f.temp_cc)
    body = f"HDRG,{f.seq},{f.t_us},{f.rate},{ref},{temp}".encode("ascii")
    return b"$" + body + b"*%02X\r\n" % _xor(body)


_TEMP_RE = re.compile(rb"[-+]?[0-9]{1,6}(?:\.[0-9]{1,6})?")


def _uint(s: bytes, name: str, top: int) -> int:
    if not (0 < len(s) <= 10 and s.isdigit()):
        raise FrameError(f"hdr-text {name} {s!r} is not a decimal integer")
    v = int(s)
    if v > top:
        raise FrameError(f"hdr-text {name} {v} out of range 0..{top}")
    return v


def _text_body(line: bytes) -> bytes:
    """The bytes between ``$`` and ``*`` of an hdr-text line whose checksum they match."""
    s = bytes(line)
    if s.endswith(b"\n"):
        s = s[:-1]
    if s.endswith(b"\r"):
        s = s[:-1]
    if not s.startswith(TEXT_SYNC):
        raise FrameError(f"hdr-text line must start with $HDRG, : {s[:16]!r}")
    star = s.rfind(b"*")
    if star < 0 or len(s) - star != 3:
        raise FrameError("hdr-text line must end with *HH (two hex digits)")
    hh = s[star + 1 :]
    try:
        want = int(hh, 16)
    except ValueError:
        raise FrameError(f"hdr-text checksum {hh!r} is not two hex digits") from None
    body = s[1:star]
    got = _xor(body)
    if got != want:
        raise FrameError(f"hdr-text checksum mismatch: line says {want:02X}, bytes give {got:02X}")
    return body


def decode_text(line: bytes) -> Frame:
    """The frame in one hdr-text line (with or without the trailing ``\\r\\n``); FrameError
    on a bad line or checksum. Empty ref -> 0, empty temp -> None; temp rounded to 0.01 degC."""
    parts = _text_body(line).split(b",")
    if len(parts) != 6:
        raise FrameError(f"hdr-text line has {len(parts) - 1} fields, expected 5")
    seq = _uint(parts[1], "seq", _U16)
    t_us = _uint(parts[2], "t_us", _U32)
    rate = _uint(parts[3], "rate", _U16)
    ref = _uint(parts[4], "ref", _U16) if parts[4] else 0
    temp_cc: int | None = None
    if parts[5]:
        if not _TEMP_RE.fullmatch(parts[5]):
            raise FrameError(f"hdr-text temp_c {parts[5]!r} is not a decimal number")
        temp_cc = round(float(parts[5]) * 100)
        if not -32767 <= temp_cc <= 32767:
            raise FrameError(f"hdr-text temp_c {parts[5]!r} out of range -327.67..327.67")
    return fast_frame(seq, t_us, rate, ref, temp_cc)


def check_protocol(protocol: str) -> None:
    """ValueError unless ``protocol`` is one of :data:`hdrd.io.wire.protocol.PROTOCOLS`."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r} (expected one of {', '.join(PROTOCOLS)})")


def encode(f: Frame, protocol: str = "hdr-bin") -> bytes:
    """``f`` in the given protocol (one of :data:`PROTOCOLS`)."""
    check_protocol(protocol)
    return encode_bin(f) if protocol == "hdr-bin" else encode_text(f)


# --------------------------------------------------------------------------- arrays


def frames_to_array(frames: Iterable[Frame]) -> npt.NDArray[np.void]:
    """Frames -> a :data:`FRAME_DTYPE` array (temp None -> -32768)."""
    rows = [
        (f.seq, f.t_us, f.rate, f.ref, TEMP_NOT_FITTED if f.temp_cc is None else f.temp_cc)
        for f in frames
    ]
    return np.array(rows, dtype=FRAME_DTYPE)


def array_to_frames(arr: npt.NDArray[np.void]) -> list[Frame]:
    """A :data:`FRAME_DTYPE` array -> frames (temp -32768 -> None)."""
    temps = [None if t == TEMP_NOT_FITTED else t for t in arr["temp"].tolist()]
    return [
        fast_frame(*row)
        for row in zip(
            arr["seq"].tolist(),
            arr["t_us"].tolist(),
            arr["rate"].tolist(),
            arr["ref"].tolist(),
            temps,
        )
    ]
