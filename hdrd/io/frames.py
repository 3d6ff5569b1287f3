"""The wire protocol of the gyro's USB ADC: hdr-bin and hdr-text frames (docs/protocol.md).

Pure: no port, no clock. Two layers here, in the manner of pyubx2 and pyserial's threaded
protocols, and a third beside it:

- codecs: :func:`encode_bin` / :func:`decode_bin`, :func:`encode_text` / :func:`decode_text`
  (one frame <-> its bytes; a bad frame raises :class:`FrameError`);
- :class:`Parser`: a push parser, ``feed(chunk) -> frames``, that keeps partial frames across
  chunks, resynchronises after garbage, drops and counts bad frames and reports sequence gaps
  and device-clock wraps in :class:`ParserStats`;
- :func:`hdrd.io.capture.decode_capture`: a vectorised decoder of a whole capture into a numpy
  structured array (:data:`FRAME_DTYPE`), giving exactly the frames and counters of the push
  parser.

The layout's constants (sync bytes, frame length, "no temperature", the device clock's wrap)
are in :mod:`hdrd.io.protocol`.

**hdr-bin**, 16 bytes, little-endian: sync ``A5 5A``, seq u16, t_us u32, rate u16, ref u16,
temp i16 (0.01 degC, -32768 = not fitted), CRC-16/CCITT-FALSE u16 over bytes 2..13.

**hdr-text**: ``$HDRG,<seq>,<t_us>,<rate>,<ref>,<temp_c>*HH\\r\\n``; ref and temp_c may be
empty (absent); HH is the XOR of the bytes between ``$`` and ``*``, two hex digits.

The resynchronisation rule (both formats): the scan stops at each sync pattern (``A5 5A``,
resp. ``$HDRG,``); if the frame there is good it is taken whole and the scan continues after
it, otherwise it is counted in ``bad_frames`` and the scan moves on by ONE byte, so a sync
pattern inside a payload or in garbage never costs the next good frame.
"""

from __future__ import annotations

import re
import struct
from binascii import crc_hqx
from collections.abc import Iterable
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.errors import HdrdError
from hdrd.io.protocol import (
    BIN_FRAME_LEN,
    CLOCK_WRAP_US,
    PROTOCOLS,
    RESET_THRESHOLD_US,
    SEQ_REORDER_WINDOW,
    SYNC,
    TEMP_NOT_FITTED,
    TEXT_MAX_LINE,
    TEXT_SYNC,
)

__all__ = [
    "CRC_TABLE",
    "FRAME_DTYPE",
    "Frame",
    "FrameError",
    "Parser",
    "ParserStats",
    "array_to_frames",
    "check_protocol",
    "crc_ok_at",
    "crc16_ccitt_false",
    "crc16_ccitt_false_rows",
    "decode_bin",
    "decode_text",
    "encode",
    "encode_array",
    "encode_bin",
    "encode_text",
    "frames_to_array",
    "sequence_stats",
]

_BODY = struct.Struct("<HIHHhH")  # seq, t_us, rate, ref, temp, crc: bytes 2..15
_PAYLOAD = struct.Struct("<HIHHh")  # bytes 2..13, the CRC's input
_U16 = 0xFFFF
_U32 = 0xFFFFFFFF

FRAME_DTYPE = np.dtype(
    [("seq", "<u2"), ("t_us", "<u4"), ("rate", "<u2"), ("ref", "<u2"), ("temp", "<i2")]
)
"""One frame in a numpy structured array: exactly bytes 2..13 of an hdr-bin frame (packed,
12 bytes). ``temp`` is in 0.01 degC with -32768 = not fitted; ``ref`` 0 = not wired."""


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


def _frame(seq: int, t_us: int, rate: int, ref: int, temp_cc: int | None) -> Frame:
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


def _crc_table() -> npt.NDArray[np.uint16]:
    table = np.empty(256, np.uint16)
    for b in range(256):
        c = b << 8
        for _ in range(8):
            c = ((c << 1) ^ 0x1021) if c & 0x8000 else (c << 1)
        table[b] = c & 0xFFFF
    return table


CRC_TABLE = _crc_table()
"""The table-driven CRC-16/CCITT-FALSE: crc' = (crc << 8) ^ TABLE[(crc >> 8) ^ byte]."""


def _crc_table16_le() -> npt.NDArray[np.uint16]:
    # Two bytes at a time: a 16-bit register shifts out whole, so crc' = T16[crc ^ w], w the
    # next two bytes big-endian, T16[w] the register after feeding w from 0. Keeping the
    # register byte-swapped (c = swap(crc)) lets the words be read little-endian in place:
    # c' = TLE[c ^ w_le] with TLE[x] = swap(T16[swap(x)]).
    x = np.arange(65536, dtype=np.uint16)
    hi = CRC_TABLE[x >> 8]
    t16 = (hi << 8) ^ CRC_TABLE[(hi >> 8) ^ (x & 0xFF)]
    swap = (x >> 8) | (x << 8)
    t = t16[swap]
    return (t >> 8) | (t << 8)


_CRC_TABLE16_LE = _crc_table16_le()


def _crc_words_le(words: npt.NDArray[np.uint16]) -> npt.NDArray[np.uint16]:
    """CRC-16/CCITT-FALSE of each row of (k, m) uint16 words read little-endian from the
    bytes, returned byte-swapped (``swap(crc)``)."""
    c = np.full(words.shape[0], 0xFFFF, np.uint16)
    for j in range(words.shape[1]):
        c = _CRC_TABLE16_LE[c ^ words[:, j]]
    return c


def crc16_ccitt_false_rows(rows: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint16]:
    """CRC-16/CCITT-FALSE of every row of a (k, m) uint8 array at once (table-driven)."""
    rows = np.asarray(rows, dtype=np.uint8)
    k, m = rows.shape
    if m % 2 == 0:
        c = _crc_words_le(np.ascontiguousarray(rows).view("<u2"))
        return ((c >> 8) | (c << 8)).astype(np.uint16, copy=False)
    crc = np.full(k, 0xFFFF, np.uint16)
    for j in range(m):
        crc = (crc << 8) ^ CRC_TABLE[(crc >> 8) ^ rows[:, j]]
    return crc


def crc_ok_at(a: npt.NDArray[np.uint8], cand: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
    """Whether the hdr-bin frame starting at each position ``cand`` (sorted, each with room
    for a whole frame) of the bytes ``a`` carries a matching CRC."""
    k = cand.shape[0]
    if k == 0:
        return np.zeros(0, bool)
    if cand[-1] - cand[0] == BIN_FRAME_LEN * (k - 1) and np.all(np.diff(cand) == BIN_FRAME_LEN):
        # A clean run of frames with no stray sync pattern: a view, no gather.
        rows = a[cand[0] : cand[0] + BIN_FRAME_LEN * k].reshape(k, BIN_FRAME_LEN)
    else:
        rows = np.lib.stride_tricks.sliding_window_view(a, BIN_FRAME_LEN)[cand]
    words = rows.view("<u2")  # (k, 8): sync, seq, t_us (2 words), rate, ref, temp, crc
    stored = words[:, 7]
    return _crc_words_le(words[:, 1:7]) == ((stored >> 8) | (stored << 8))


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
    seq, t_us, rate, ref, temp, crc = _BODY.unpack_from(b, 2)
    calc = crc_hqx(b[2:14], 0xFFFF)
    if calc != crc:
        raise FrameError(f"CRC mismatch: frame says {crc:04x}, bytes give {calc:04x}")
    return _frame(seq, t_us, rate, ref, None if temp == TEMP_NOT_FITTED else temp)


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


def decode_text(line: bytes) -> Frame:
    """The frame in one hdr-text line (with or without the trailing ``\\r\\n``); FrameError
    on a bad line or checksum. Empty ref -> 0, empty temp -> None; temp rounded to 0.01 degC."""
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
    parts = body.split(b",")
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
    return _frame(seq, t_us, rate, ref, temp_cc)


def encode(f: Frame, protocol: str = "hdr-bin") -> bytes:
    """``f`` in the given protocol (one of :data:`PROTOCOLS`)."""
    if protocol == "hdr-bin":
        return encode_bin(f)
    if protocol == "hdr-text":
        return encode_text(f)
    raise ValueError(f"unknown protocol {protocol!r} (expected one of {', '.join(PROTOCOLS)})")


def check_protocol(protocol: str) -> None:
    """ValueError unless ``protocol`` is one of :data:`hdrd.io.protocol.PROTOCOLS`."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r} (expected one of {', '.join(PROTOCOLS)})")


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
        _frame(*row)
        for row in zip(
            arr["seq"].tolist(),
            arr["t_us"].tolist(),
            arr["rate"].tolist(),
            arr["ref"].tolist(),
            temps,
        )
    ]


def encode_array(arr: npt.NDArray[np.void], protocol: str = "hdr-bin") -> bytes:
    """A whole :data:`FRAME_DTYPE` array encoded back to back (vectorised for hdr-bin)."""
    check_protocol(protocol)
    arr = np.ascontiguousarray(arr, dtype=FRAME_DTYPE)
    if protocol == "hdr-text":
        return b"".join(encode_text(f) for f in array_to_frames(arr))
    k = arr.shape[0]
    out = np.empty((k, BIN_FRAME_LEN), np.uint8)
    out[:, 0] = 0xA5
    out[:, 1] = 0x5A
    out[:, 2:14] = arr.view(np.uint8).reshape(k, 12)
    crc = crc16_ccitt_false_rows(out[:, 2:14])
    out[:, 14] = crc & 0xFF
    out[:, 15] = crc >> 8
    return out.tobytes()


# --------------------------------------------------------------------------- push parser


@dataclass(slots=True, eq=False)
class ParserStats:
    """Counters of a parser (or a source). All counts since the parser was made.

    frames: good frames returned. bad_frames: frames that started with a sync pattern but
    failed their CRC, checksum or syntax. garbage_bytes: bytes not part of a good frame
    (bad frames' bytes included; bytes still buffered are not counted until ``flush``).
    seq_gaps: jumps forward of the sequence number by more than 1 (events); lost_frames: the
    sum of the sequence numbers skipped. seq_repeats: frames whose sequence number repeats or
    is at most :data:`SEQ_REORDER_WINDOW` behind the last (kept, but the counter is not moved
    back). seq_resets: larger backward jumps (a device restart). clock_wraps: device-clock
    wraps at 2**32 us. clock_back: device-clock steps that did not go forward (a step back of
    more than 1 s resets the reference, like :class:`hdrd.io.clocks.DeviceClock`).
    """

    frames: int = 0
    bad_frames: int = 0
    garbage_bytes: int = 0
    seq_gaps: int = 0
    lost_frames: int = 0
    seq_repeats: int = 0
    seq_resets: int = 0
    clock_wraps: int = 0
    clock_back: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters by name."""
        return {f: getattr(self, f) for f in _COUNTERS}

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ParserStats):
            return NotImplemented
        return self.as_dict() == other.as_dict()


_COUNTERS = tuple(f.name for f in fields(ParserStats))


_SEQ_BACK = 0x10000 - SEQ_REORDER_WINDOW  # d >= this: at most SEQ_REORDER_WINDOW behind
_HALF_WRAP = CLOCK_WRAP_US >> 1


def _sync_at(buf: bytes, k: int) -> bool | None:
    """Whether a sync pattern starts at ``buf[k]``; None if those bytes are not there yet."""
    if k + 2 > len(buf):
        return None
    return buf[k] == 0xA5 and buf[k + 1] == 0x5A


def _displaced(buf: bytes, i: int, final: bool) -> bool | None:
    """Is the CRC-valid candidate at ``buf[i]`` a coincidence hiding a real frame?

    It is when a sync pattern inside it, at j (i + 2 <= j <= i + 14), starts another
    CRC-valid candidate that is followed by a sync pattern at j + 16 while the one at i is
    not followed by one at i + 16: typically a truncated frame whose first bytes and the
    next frame's bytes pass the 16-bit CRC by chance (1 in 65536). None: undecided until
    more bytes arrive (with ``final``, missing bytes count as no sync pattern and no frame).
    """
    here = _sync_at(buf, i + 16)
    if here is None and not final:
        return None
    if here:
        return False
    j = buf.find(SYNC, i + 2, i + 16)
    while j >= 0:
        if j + 16 > len(buf):
            return None if not final else False
        if crc_hqx(buf[j + 2 : j + 14], 0xFFFF) == buf[j + 14] | (buf[j + 15] << 8):
            after = _sync_at(buf, j + 16)
            if after is None and not final:
                return None
            if after:
                return True
        j = buf.find(SYNC, j + 1, i + 16)
    return False


class Parser:
    """Push parser: ``feed(chunk) -> list[Frame]`` (pyserial ``threaded.Packetizer`` style).

    Any bytes are accepted and nothing raises: partial frames wait for the next chunk, bad
    frames and garbage are counted in :attr:`stats`. Feeding a stream in any split gives
    the same frames and counters. ``flush()`` at end of input counts the leftover bytes.
    """

    __slots__ = ("_buf", "_feed", "_last_seq", "_last_t", "bad_before", "protocol", "stats")

    def __init__(self, protocol: str = "hdr-bin") -> None:
        check_protocol(protocol)
        self.protocol = protocol
        self.stats = ParserStats()
        self.bad_before: list[int] = []
        """For each frame the last ``feed`` returned: ``stats.bad_frames`` just before it."""
        self._buf = b""
        self._last_seq: int | None = None
        self._last_t: int | None = None
        self._feed = self._feed_bin if protocol == "hdr-bin" else self._feed_text

    @property
    def pending(self) -> int:
        """Bytes buffered for a frame not yet complete."""
        return len(self._buf)

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[Frame]:
        """Parse more bytes; return the good frames they complete, in order."""
        if not chunk:
            self.bad_before = []
            return []
        return self._feed(chunk if type(chunk) is bytes else bytes(chunk))

    def flush(self) -> list[Frame]:
        """End of input (or a link reset): the frames still held back are decided and
        returned (hdr-bin: a complete frame waits only while the bytes that tell a CRC
        coincidence from a real frame are missing, see :func:`_displaced`; at the end they
        never come), then the leftover bytes are dropped and counted as garbage.

        The sequence and clock references are kept, so a gap across a reconnection is
        still reported. :attr:`bad_before` describes the returned frames."""
        out: list[Frame] = []
        if self._buf and self.protocol == "hdr-bin":
            out = self._feed_bin(b"", final=True)
        else:
            self.bad_before = []
        self.stats.garbage_bytes += len(self._buf)
        self._buf = b""
        return out

    def _track(self, seq: int, t_us: int) -> None:
        """Sequence and clock bookkeeping for one good frame (the push path's rule, shared by
        the text parser and the vectorised decoder's slow path)."""
        st = self.stats
        last = self._last_seq
        if last is None:
            self._last_seq = seq
        else:
            d = (seq - last) & _U16
            if d == 1:
                self._last_seq = seq
            elif d == 0 or d >= _SEQ_BACK:
                st.seq_repeats += 1
            elif d < 0x8000:
                st.seq_gaps += 1
                st.lost_frames += d - 1
                self._last_seq = seq
            else:
                st.seq_resets += 1
                self._last_seq = seq
        lt = self._last_t
        if lt is None:
            self._last_t = t_us
        else:
            d = (t_us - lt) & _U32
            if 0 < d < _HALF_WRAP:
                if t_us < lt:
                    st.clock_wraps += 1
                self._last_t = t_us
            else:
                st.clock_back += 1
                if (CLOCK_WRAP_US - d) & _U32 > RESET_THRESHOLD_US:
                    self._last_t = t_us

    def _feed_bin(self, chunk: bytes, final: bool = False) -> list[Frame]:
        """Long because and Complex because it is the binary parser's hot path: one loop over
        the buffer with its names bound to locals and :meth:`_track` copied inline, as a call
        per frame would cost."""
        buf = self._buf + chunk if self._buf else chunk
        n = len(buf)
        find = buf.find
        unpack = _BODY.unpack_from
        crc16 = crc_hqx
        new, set_seq, set_t, set_rate, set_ref, set_temp = (
            _new,
            _SET_SEQ,
            _SET_T,
            _SET_RATE,
            _SET_REF,
            _SET_TEMP,
        )
        out: list[Frame] = []
        append = out.append
        bad = self.stats.bad_frames
        bad_before: list[int] = []
        bb_append = bad_before.append
        p = 0
        nxt = -2  # the first sync pattern at or after p when known (-1: none), else -2
        last_seq = self._last_seq
        last_t = self._last_t
        st = self.stats
        while True:
            i = find(SYNC, p) if nxt == -2 else nxt
            if i < 0:
                keep = n - 1 if n > p and buf[n - 1] == 0xA5 else n
                break
            if i + 16 > n:
                keep = i
                break
            seq, t_us, rate, ref, temp, crc = unpack(buf, i + 2)
            if crc16(buf[i + 2 : i + 14], 0xFFFF) != crc:
                bad += 1
                p = i + 1
                nxt = -2
                continue
            # The next sync pattern after this one's: beyond the frame, the next scan starts
            # there; inside it (rare), is this frame a CRC coincidence? (:func:`_displaced`)
            nxt = find(SYNC, i + 2)
            if 0 <= nxt < i + 16:
                verdict = _displaced(buf, i, final)
                if verdict is None:  # the bytes that decide have not arrived yet
                    keep = i
                    break
                if verdict:
                    bad += 1
                    p = i + 1
                    nxt = -2
                    continue
                nxt = -2
            p = i + 16
            # Inline copy of _track (the hot path); keep the two in step.
            if last_seq is None or seq == (last_seq + 1) & 0xFFFF:
                last_seq = seq
            else:
                d = (seq - last_seq) & _U16
                if d == 0 or d >= _SEQ_BACK:
                    st.seq_repeats += 1
                elif d < 0x8000:
                    st.seq_gaps += 1
                    st.lost_frames += d - 1
                    last_seq = seq
                else:
                    st.seq_resets += 1
                    last_seq = seq
            if last_t is None:
                last_t = t_us
            else:
                d = (t_us - last_t) & 0xFFFFFFFF
                if 0 < d < 0x80000000:  # forward by less than half the wrap
                    if t_us < last_t:
                        st.clock_wraps += 1
                    last_t = t_us
                else:
                    st.clock_back += 1
                    if (CLOCK_WRAP_US - d) & _U32 > RESET_THRESHOLD_US:
                        last_t = t_us
            f = new(Frame)
            set_seq(f, seq)
            set_t(f, t_us)
            set_rate(f, rate)
            set_ref(f, ref)
            set_temp(f, None if temp == -32768 else temp)
            append(f)
            bb_append(bad)
        self._last_seq = last_seq
        self._last_t = last_t
        self._buf = buf[keep:] if keep < n else b""
        nf = len(out)
        st.frames += nf
        st.bad_frames = bad
        self.bad_before = bad_before
        st.garbage_bytes += keep - 16 * nf
        return out

    def _feed_text(self, chunk: bytes) -> list[Frame]:
        buf = self._buf + chunk if self._buf else chunk
        n = len(buf)
        out: list[Frame] = []
        bad_before: list[int] = []
        st = self.stats
        p = 0
        good_bytes = 0
        while True:
            i = buf.find(TEXT_SYNC, p)
            if i < 0:
                # Keep a tail that may be the start of a sync pattern.
                keep = n
                j = buf.rfind(b"$", max(p, n - len(TEXT_SYNC) + 1))
                if j >= 0 and TEXT_SYNC.startswith(buf[j:]):
                    keep = j
                break
            e = buf.find(b"\n", i + len(TEXT_SYNC), i + TEXT_MAX_LINE)
            if e < 0:
                if n - i < TEXT_MAX_LINE:
                    keep = i  # the line may still be arriving
                    break
                st.bad_frames += 1  # no line end where one must be
                p = i + 1
                continue
            try:
                f = decode_text(buf[i : e + 1])
            except FrameError:
                st.bad_frames += 1
                p = i + 1
                continue
            self._track(f.seq, f.t_us)
            out.append(f)
            bad_before.append(st.bad_frames)
            good_bytes += e + 1 - i
            p = e + 1
        self._buf = buf[keep:] if keep < n else b""
        st.frames += len(out)
        st.garbage_bytes += keep - good_bytes
        self.bad_before = bad_before
        return out


def sequence_stats(arr: npt.NDArray[np.void], st: ParserStats) -> None:
    """Add the sequence/clock counters of the frames ``arr`` (a :data:`FRAME_DTYPE` array, in
    stream order) to ``st`` as the push parser counts them, vectorised in the common case (all
    steps forward), else through the push parser's own rule."""
    if arr.shape[0] < 2:
        return
    seq = arr["seq"].astype(np.int64)
    t = arr["t_us"].astype(np.int64)
    ds = np.diff(seq) & _U16
    dt = np.diff(t) & _U32
    seq_fast = bool(np.all((ds >= 1) & (ds < 0x8000)))
    clock_fast = bool(np.all((dt > 0) & (dt < _HALF_WRAP)))
    if seq_fast and clock_fast:
        jumps = ds[ds > 1]
        st.seq_gaps += int(jumps.size)
        st.lost_frames += int((jumps - 1).sum())
        st.clock_wraps += int(np.count_nonzero(t[1:] < t[:-1]))
        return
    p = Parser()
    for s, tu in zip(seq.tolist(), t.tolist()):
        p._track(s, tu)
    ps = p.stats
    st.seq_gaps += ps.seq_gaps
    st.lost_frames += ps.lost_frames
    st.seq_repeats += ps.seq_repeats
    st.seq_resets += ps.seq_resets
    st.clock_wraps += ps.clock_wraps
    st.clock_back += ps.clock_back
