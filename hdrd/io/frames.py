"""The wire protocol of the gyro's USB ADC: hdr-bin and hdr-text frames (docs/protocol.md).

Pure: no port, no clock. Three layers here, in the manner of pyubx2 and pyserial's threaded
protocols, and a fourth beside it:

- codecs: :func:`encode_bin` / :func:`decode_bin`, :func:`encode_text` / :func:`decode_text`
  (one frame <-> its bytes; a bad frame raises :class:`FrameError`);
- :class:`FrameTracker`: the sequence number and device clock of a stream, the one place that
  decides which frames are new and whose clock agrees with their sequence, and counts the
  rest (:class:`ParserStats`);
- :class:`Parser`: a push parser, ``feed(chunk) -> frames``, that keeps partial frames across
  chunks, resynchronises after garbage, drops and counts bad frames, and hands its good ones
  to its tracker;
- :func:`hdrd.io.capture.decode_capture`: a vectorised decoder of a whole capture into a numpy
  structured array (:data:`FRAME_DTYPE`), giving exactly the frames and counters of the push
  parser. The layout's constants are in :mod:`hdrd.io.protocol`.

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

import collections
import itertools
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
    BREAK_CONFIRM_FRAMES,
    BREAK_REBASE_FRAMES,
    CLOCK_WRAP_US,
    PROTOCOLS,
    REBASE_RATIO,
    SEQ_CLOCK_RATIO,
    SEQ_GAP_WINDOW,
    SEQ_REORDER_WINDOW,
    SYNC,
    TEMP_NOT_FITTED,
    TEXT_MAX_LINE,
    TEXT_SYNC,
)

__all__ = [
    "FRAME_DTYPE",
    "Frame",
    "FrameError",
    "FrameTracker",
    "Parser",
    "ParserStats",
    "array_to_frames",
    "check_protocol",
    "crc16_ccitt_false",
    "decode_bin",
    "decode_text",
    "encode",
    "encode_bin",
    "encode_text",
    "frames_to_array",
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


# --------------------------------------------------------------------------- sequence and clock


@dataclass(slots=True, eq=False)
class ParserStats:
    """Counters of a parser (or a source), since it was made. frames: good frames returned.
    bad_frames: frames that started with a sync pattern but failed their CRC, checksum or
    syntax. garbage_bytes: bytes not part of a good frame (bad frames' included; bytes still
    buffered count at ``flush``). Of the sequence and the clock (:class:`FrameTracker`):
    seq_gaps, lost_frames (events of frames lost, and how many); seq_resets (a device
    restart); clock_wraps (of the device clock at 2**32 us); and the good frames dropped:
    seq_repeats (not new), seq_clock_mismatch (the clock disagrees with the sequence).
    """

    frames: int = 0
    bad_frames: int = 0
    garbage_bytes: int = 0
    seq_gaps: int = 0
    lost_frames: int = 0
    seq_repeats: int = 0
    seq_resets: int = 0
    clock_wraps: int = 0
    seq_clock_mismatch: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters by name."""
        return {f: getattr(self, f) for f in _COUNTERS}

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ParserStats):
            return NotImplemented
        return self.as_dict() == other.as_dict()


_COUNTERS = tuple(f.name for f in fields(ParserStats))


_SEQ_BACK = 0x10000 - SEQ_REORDER_WINDOW  # k >= this: at most SEQ_REORDER_WINDOW behind
_HALF_WRAP = CLOCK_WRAP_US >> 1
_R = SEQ_CLOCK_RATIO
_GAP = SEQ_GAP_WINDOW


def _agrees(d: int, k: int, d0: int, k0: int, r: int = _R) -> bool:
    """Whether d us over k sequence steps keep to the interval d0 us per k0 steps (within a
    factor r, :data:`SEQ_CLOCK_RATIO`); any step does when there is no interval yet (k0 = 0)."""
    return k0 == 0 or (r * d * k0 >= d0 * k and d * k0 <= r * d0 * k)


_At = collections.namedtuple("_At", "seq t_us i")  # a frame of an array, for run: its place i


class FrameTracker:
    """The sequence number and device clock of a stream of frames, in one place: which frames
    are kept, and the sequence/clock counters of :class:`ParserStats`. Pure. The rule
    (docs/protocol.md, "Sequence and clock"), for a frame k sequence steps and d us after the
    last frame kept: **kept** if 0 < k <= :data:`SEQ_GAP_WINDOW`, d forward and d / k within
    :data:`SEQ_CLOCK_RATIO` of the interval (the last single step's d; any before it);
    **dropped, not new** (``seq_repeats``) if k = 0 or at most :data:`SEQ_REORDER_WINDOW`
    behind, d not forward; else a **break**: held with the frames after it that continue it
    by their own clock, released when :data:`BREAK_CONFIRM_FRAMES` do at the interval agreed on
    (or none was) or :data:`BREAK_REBASE_FRAMES` at their own within :data:`REBASE_RATIO`
    of it (a restart: ``seq_resets``; a
    jump: a gap), dropped by a frame kept or a break that does not continue them
    (``seq_clock_mismatch``). :meth:`run` (a batch of frames) and :meth:`run_array` (a whole
    capture, numpy where each step agrees) decide alike; :meth:`flush` drops what is held.
    """

    __slots__ = ("_agreed", "_d", "_held", "_held_off", "_k", "_kept_run", "_seq", "_t", "stats")

    def __init__(self, stats: ParserStats | None = None) -> None:
        self.stats = ParserStats() if stats is None else stats
        self._seq: int | None = None  # the last frame kept: its sequence number, device time
        self._t = 0
        self._d = 0  # the interval: device us over _k sequence steps (0: none yet)
        self._k = 0
        self._agreed = 0  # steps kept since the start or the last break
        self._kept_run = 0  # frames kept by the rule in a row, to the last one judged
        self._held: list[tuple[Any, int, int, int]] = []  # (item, seq, t_us, bad) after a break
        self._held_off = False  # a held step off the interval agreed on

    def run(self, items: list[Any], bads: list[int]) -> tuple[list[Any], list[int]]:
        """Judge frames (each with ``seq`` and ``t_us``; ``bads``: bad frames before each): those
        kept, in order, with their bads (held ones released now first). :meth:`_run_all`
        takes over from the first frame that the common case does not keep."""
        seq0, t0, d0, k0 = self._seq, self._t, self._d, self._k
        if seq0 is None or self._held:
            return self._run_all(items, bads, 0)
        st = self.stats
        j = 0
        for f in items:
            s, t = f.seq, f.t_us
            k = (s - seq0) & 0xFFFF
            d = (t - t0) & 0xFFFFFFFF
            if not (
                0 < k <= _GAP
                and 0 < d < 0x80000000
                and (k0 == 0 or (_R * d * k0 >= d0 * k and d * k0 <= _R * d0 * k))
            ):
                break
            if k > 1:
                st.seq_gaps += 1
                st.lost_frames += k - 1
            if t < t0:
                st.clock_wraps += 1
            seq0, t0 = s, t
            if k == 1:  # the interval: a single step's (a gap's average may hide a skip)
                d0, k0 = d, 1
            j += 1
        self._seq, self._t, self._d, self._k = seq0, t0, d0, k0
        self._agreed += j
        self._kept_run += j
        if j == len(items):
            return items, bads
        out, out_bad = self._run_all(items, bads, j)
        return items[:j] + out, bads[:j] + out_bad

    def _run_all(
        self, items: list[Any], bads: list[int], start: int
    ) -> tuple[list[Any], list[int]]:
        """:meth:`run` from ``items[start]`` on, breaks and repeats included."""
        out: list[Any] = []
        out_bad: list[int] = []
        st = self.stats
        for j in range(start, len(items)):
            f, b = items[j], bads[j]
            seq0 = self._seq
            if seq0 is None:  # the first frame: nothing to judge it by
                self._seq, self._t, self._kept_run = f.seq, f.t_us, 1
                out.append(f)
                out_bad.append(b)
                continue
            k = (f.seq - seq0) & 0xFFFF
            d = (f.t_us - self._t) & 0xFFFFFFFF
            fwd = 0 < d < _HALF_WRAP
            if 0 < k <= _GAP and fwd and _agrees(d, k, self._d, self._k):
                self._gap(k)
                if f.t_us < self._t:
                    st.clock_wraps += 1
                self._seq, self._t = f.seq, f.t_us
                if k == 1:
                    self._d, self._k = d, 1
                self._agreed += 1
                self._kept_run += 1
                self._drop_held()
                out.append(f)
                out_bad.append(b)
                continue
            self._kept_run = 0
            if (k == 0 or k >= _SEQ_BACK) and not fwd and not self._continues_held(f.seq, f.t_us):
                st.seq_repeats += 1
                continue
            for it, bb in self._on_break(f, f.seq, f.t_us, b):
                out.append(it)
                out_bad.append(bb)
        return out, out_bad

    def _continues_held(self, s: int, t: int) -> bool:
        """Whether a frame continues the held ones (by their own clock: class doc)."""
        held = self._held
        if not held:
            return False
        _, ps, pt, _ = held[-1]
        d0 = k0 = 0
        if len(held) >= 2:
            d0, k0 = (pt - held[-2][2]) & 0xFFFFFFFF, (ps - held[-2][1]) & 0xFFFF
        k, d = (s - ps) & 0xFFFF, (t - pt) & 0xFFFFFFFF
        return 0 < k <= _GAP and 0 < d < _HALF_WRAP and _agrees(d, k, d0, k0)

    def _on_break(self, item: Any, s: int, t: int, b: int) -> list[tuple[Any, int]]:
        """A frame that breaks the sequence or the clock: held (after what is held, if it
        continues it; else in its place); the held frames released once
        :data:`BREAK_CONFIRM_FRAMES` continue one another at the interval agreed on (or none
        was), or :data:`BREAK_REBASE_FRAMES` at one of their own near it."""
        if self._continues_held(s, t):
            _, ps, pt, _ = self._held[-1]
            self._held_off |= not _agrees(
                (t - pt) & 0xFFFFFFFF, (s - ps) & 0xFFFF, self._d, self._k
            )
        else:
            self._drop_held()
        self._held.append((item, s, t, b))
        n = len(self._held)
        if n >= BREAK_CONFIRM_FRAMES and (self._agreed < 2 or not self._held_off):
            return self._release()
        if n < BREAK_REBASE_FRAMES:
            return []
        (_, sa, ta, _), (_, sb, tb, _) = self._held[-2:]  # their interval: near the old one?
        if _agrees((tb - ta) & 0xFFFFFFFF, (sb - sa) & 0xFFFF, self._d, self._k, REBASE_RATIO):
            return self._release()
        self._held.pop(0)  # far from it: never taken, the oldest dropped as the next comes
        self.stats.seq_clock_mismatch += 1
        return []

    def _release(self) -> list[tuple[Any, int]]:
        """The held frames are kept; the interval agreed on stays if they kept to it."""
        held, st = self._held, self.stats
        assert self._seq is not None  # a break follows a kept frame
        k = (held[0][1] - self._seq) & 0xFFFF
        if k >= 0x8000:
            st.seq_resets += 1
        else:
            self._gap(k)
        keep_interval = self._agreed >= 2 and not self._held_off
        for (_, sa, ta, _), (_, sb, tb, _) in itertools.pairwise(held):
            kk = (sb - sa) & 0xFFFF
            self._gap(kk)
            if tb < ta:
                st.clock_wraps += 1
            self._seq, self._t = sb, tb
            if kk == 1 and not keep_interval:
                self._d, self._k = (tb - ta) & 0xFFFFFFFF, 1
        self._agreed = len(held) - 1
        out = [(it, bb) for it, _, _, bb in held]
        held.clear()
        self._held_off = False
        return out

    def _gap(self, k: int) -> None:
        if k > 1:
            self.stats.seq_gaps += 1
            self.stats.lost_frames += k - 1

    def _drop_held(self) -> None:
        self.stats.seq_clock_mismatch += len(self._held)
        self._held.clear()
        self._held_off = False

    def flush(self) -> None:
        """End of the input (or of a connection): the frames held after a break are dropped
        (never confirmed), the interval forgotten (another device may come); the last frame
        kept stays, so that a gap across a reconnection is still counted."""
        self._drop_held()
        self._kept_run = self._agreed = self._d = self._k = 0

    def run_array(self, arr: npt.NDArray[np.void]) -> npt.NDArray[np.int64]:
        """:meth:`run` over a :data:`FRAME_DTYPE` array (a whole capture): the positions of the
        frames kept. Numpy over the runs ``run`` would keep whole, ``run`` around the rest."""
        n = arr.shape[0]
        if n == 0 or (self._seq is None and n > 1 and self._all_kept(arr)):
            return np.arange(n, dtype=np.int64)
        seq = arr["seq"].astype(np.int64)
        t = arr["t_us"].astype(np.int64)
        k = np.zeros(n, np.int64)
        d = np.zeros(n, np.int64)
        np.bitwise_and(np.diff(seq), 0xFFFF, out=k[1:])
        np.bitwise_and(np.diff(t), 0xFFFFFFFF, out=d[1:])
        # The interval for each step: the last single step's before it (as run has it when
        # it kept that step; a run through numpy starts only there).
        one = np.maximum.accumulate(np.where(k == 1, np.arange(n), -1))
        prev = np.empty(n, np.int64)
        prev[0], prev[1:] = -1, one[:-1]
        d_i = d[np.maximum(prev, 0)]
        good = (prev >= 0) & (k > 0) & (k <= _GAP) & (d > 0) & (d < _HALF_WRAP)
        good &= (_R * d >= d_i * k) & (d <= _R * d_i * k)
        breaks = np.flatnonzero(~good)
        w = 2 * BREAK_CONFIRM_FRAMES + 2  # after this many good steps the tracker is at rest
        calm = np.empty(0, np.int64)
        if n >= w:
            calm = np.flatnonzero(np.lib.stride_tricks.sliding_window_view(good, w).all(axis=1))
        kept: list[npt.NDArray[np.int64]] = []
        i = 0
        while i < n:
            if i and self._kept_run >= 2 and k[i - 1] == 1 and good[i]:  # i - 2, i - 1 kept
                j = int(breaks[np.searchsorted(breaks, i)]) if breaks[-1] >= i else n
                self._numpy_run(k[i:j], t[i - 1 : j])
                self._seq, self._t = int(seq[j - 1]), int(t[j - 1])
                self._d, self._k = int(d[one[j - 1]]), 1
                kept.append(np.arange(i, j, dtype=np.int64))
                i = j
                continue
            at = int(np.searchsorted(calm, i))  # run to the end of the next calm stretch
            hi = max(min(n, int(calm[at]) + w) if at < calm.shape[0] else n, i + 1)
            kept.append(self._run_slice(seq, t, i, hi))
            i = hi
        return np.concatenate(kept) if kept else np.empty(0, np.int64)

    def _run_slice(
        self, seq: npt.NDArray[np.int64], t: npt.NDArray[np.int64], lo: int, hi: int
    ) -> npt.NDArray[np.int64]:
        """:meth:`run` over frames lo .. hi - 1 of an array: the positions kept."""
        rows = [_At(*x) for x in zip(seq[lo:hi].tolist(), t[lo:hi].tolist(), range(lo, hi))]
        got, _ = self.run(rows, [0] * len(rows))
        return np.fromiter((r.i for r in got), np.int64, len(got))

    def _all_kept(self, arr: npt.NDArray[np.void]) -> bool:
        """A whole capture kept whole by a new tracker, cheaply told: every step forward, and
        every step's d / k within 1.99 of every other's (whatever the rounding)."""
        seq, t = arr["seq"], arr["t_us"]
        k = np.diff(seq)  # uint16 and uint32: the differences wrap as the wire's counters do
        d = np.diff(t)
        if not (np.all(k - np.uint16(1) < _GAP) and np.all(d.view(np.int32) > 0)):
            return False
        per = d / k
        if not per.max() <= 1.99 * per.min():
            return False
        self._seq, self._t = int(seq[0]), int(t[0])
        self._numpy_run(k, t)
        self._seq, self._t = int(seq[-1]), int(t[-1])
        single = np.flatnonzero(k == 1)
        if single.shape[0]:
            self._d, self._k = int(d[single[-1]]), 1
        self._kept_run += 1
        return True

    def _numpy_run(self, k: npt.NDArray[np.int64], t: npt.NDArray[np.int64]) -> None:
        """Count the steps ``k`` (into the frames at ``t[1:]``) of a run kept whole."""
        st = self.stats
        jumps = k[k > 1]
        st.seq_gaps += int(jumps.size)
        st.lost_frames += int((jumps - 1).sum())
        st.clock_wraps += int(np.count_nonzero(t[1:] < t[:-1]))
        self._agreed += int(k.size)
        self._kept_run += int(k.size)


# --------------------------------------------------------------------------- push parser


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


_Scan = tuple[list[Frame], list[int], int, int]  # frames, bad before each, bad, kept from


def _scan_bin(buf: bytes, bad: int, final: bool) -> _Scan:
    """Long because it is the binary parser's hot path: one loop with its names bound to
    locals. The frames in ``buf`` by the resynchronisation rule (module doc)."""
    n = len(buf)
    find = buf.find
    unpack = _BODY.unpack_from
    frames: list[Frame] = []
    bads: list[int] = []
    add_f, add_b = frames.append, bads.append
    p = 0
    nxt = -2  # the first sync pattern at or after p when known (-1: none), else -2
    while True:
        i = find(SYNC, p) if nxt == -2 else nxt
        if i < 0:
            return frames, bads, bad, n - 1 if n > p and buf[n - 1] == 0xA5 else n
        if i + 16 > n:
            return frames, bads, bad, i
        seq, t_us, rate, ref, temp, crc = unpack(buf, i + 2)
        nxt = -2
        if crc_hqx(buf[i + 2 : i + 14], 0xFFFF) != crc:
            bad += 1
            p = i + 1
            continue
        # The next sync pattern after this one's: beyond the frame, the next scan starts
        # there; inside it (rare), is this frame a CRC coincidence? (:func:`_displaced`)
        nxt = find(SYNC, i + 2)
        if 0 <= nxt < i + 16:
            nxt = -2
            verdict = _displaced(buf, i, final)
            if verdict is None:  # the bytes that decide have not arrived yet
                return frames, bads, bad, i
            if verdict:
                bad += 1
                p = i + 1
                continue
        p = i + 16
        add_f(_frame(seq, t_us, rate, ref, None if temp == -32768 else temp))
        add_b(bad)


class Parser:
    """Push parser: ``feed(chunk) -> list[Frame]`` (pyserial ``threaded.Packetizer`` style).

    Any bytes are accepted and nothing raises: partial frames wait for the next chunk, bad
    frames and garbage are counted in :attr:`stats`; good frames are judged by their sequence
    number and device clock (:class:`FrameTracker`): those not new or whose clock disagrees
    with their sequence are dropped and counted. Feeding a stream in any split gives the same
    frames and counters. ``flush()`` at end of input counts the leftover bytes.
    """

    __slots__ = ("_buf", "_feed", "bad_before", "protocol", "stats", "tracker")

    def __init__(self, protocol: str = "hdr-bin") -> None:
        check_protocol(protocol)
        self.protocol = protocol
        self.stats = ParserStats()
        self.tracker = FrameTracker(self.stats)
        self.bad_before: list[int] = []
        """For each frame the last ``feed`` returned: ``stats.bad_frames`` just before it."""
        self._buf = b""
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
        never come), then the leftover bytes are dropped and counted as garbage, and the
        tracker flushed (:meth:`FrameTracker.flush`: a gap across a reconnection is still
        counted). :attr:`bad_before` describes the returned frames."""
        out: list[Frame] = []
        if self._buf and self.protocol == "hdr-bin":
            out = self._feed_bin(b"", final=True)
        else:
            self.bad_before = []
        self.stats.garbage_bytes += len(self._buf)
        self._buf = b""
        self.tracker.flush()
        return out

    def _feed_bin(self, chunk: bytes, final: bool = False) -> list[Frame]:
        buf = self._buf + chunk if self._buf else chunk
        st = self.stats
        frames, bads, st.bad_frames, keep = _scan_bin(buf, st.bad_frames, final)
        self._buf = buf[keep:] if keep < len(buf) else b""
        st.garbage_bytes += keep - 16 * len(frames)
        out, self.bad_before = self.tracker.run(frames, bads)
        st.frames += len(out)
        return out

    def _feed_text(self, chunk: bytes) -> list[Frame]:
        buf = self._buf + chunk if self._buf else chunk
        n = len(buf)
        found: list[Frame] = []
        bads: list[int] = []
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
            found.append(f)
            bads.append(st.bad_frames)
            good_bytes += e + 1 - i
            p = e + 1
        self._buf = buf[keep:] if keep < n else b""
        st.garbage_bytes += keep - good_bytes
        out, self.bad_before = self.tracker.run(found, bads)
        st.frames += len(out)
        return out
