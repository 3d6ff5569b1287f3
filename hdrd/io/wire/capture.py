"""Whole captures: the vectorised decoder of a capture file's bytes (``hdrd replay``,
``hdrd convert``, the benches) and encoder of frames (:func:`encode_array`).

Pure. :func:`decode_capture` gives exactly the frames and counters of a
:class:`hdrd.io.wire.parser.Parser` fed the same bytes and flushed, plus for each frame the bad frames
that came before it (:class:`CaptureStats`), as a numpy structured array
(:data:`hdrd.io.wire.codec.FRAME_DTYPE`): hdr-bin without a Python loop per frame, in slices of
bounded memory (the CRCs table-driven, two bytes per step), by the parser's rule (the rare
overlapping candidates through its own :func:`hdrd.io.wire.parser.displaced`); hdr-text through the
push parser. Both judge the frames' sequence and clock with
:class:`hdrd.io.wire.tracker.FrameTracker`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from hdrd.io.wire.codec import (
    FRAME_DTYPE,
    Frame,
    array_to_frames,
    check_protocol,
    encode_text,
    frames_to_array,
)
from hdrd.io.wire.parser import Parser, displaced
from hdrd.io.wire.protocol import BIN_CRC_AT, BIN_FRAME_LEN, BIN_PAYLOAD_AT, BIN_PAYLOAD_LEN, SYNC
from hdrd.io.wire.tracker import FrameTracker, ParserStats

__all__ = [
    "CRC_TABLE",
    "CaptureStats",
    "crc16_ccitt_false_rows",
    "crc_ok_at",
    "decode_capture",
    "decode_frames",
    "encode_array",
]


# --------------------------------------------------------------------------- vectorised CRC


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


_PAYLOAD_WORDS = slice(BIN_PAYLOAD_AT // 2, BIN_CRC_AT // 2)
_CRC_WORD = BIN_CRC_AT // 2


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
    words = rows.view("<u2")  # (k, 8): sync, the payload's words, crc
    stored = words[:, _CRC_WORD]
    return _crc_words_le(words[:, _PAYLOAD_WORDS]) == ((stored >> 8) | (stored << 8))


def encode_array(arr: npt.NDArray[np.void], protocol: str = "hdr-bin") -> bytes:
    """A whole :data:`FRAME_DTYPE` array encoded back to back (vectorised for hdr-bin)."""
    check_protocol(protocol)
    arr = np.ascontiguousarray(arr, dtype=FRAME_DTYPE)
    if protocol == "hdr-text":
        return b"".join(encode_text(f) for f in array_to_frames(arr))
    k = arr.shape[0]
    out = np.empty((k, BIN_FRAME_LEN), np.uint8)
    out[:, :BIN_PAYLOAD_AT] = np.frombuffer(SYNC, np.uint8)
    out[:, BIN_PAYLOAD_AT:BIN_CRC_AT] = arr.view(np.uint8).reshape(k, BIN_PAYLOAD_LEN)
    crc = crc16_ccitt_false_rows(out[:, BIN_PAYLOAD_AT:BIN_CRC_AT])
    out[:, BIN_CRC_AT] = crc & 0xFF
    out[:, BIN_CRC_AT + 1] = crc >> 8
    return out.tobytes()


# --------------------------------------------------------------------------- decoding


@dataclass(slots=True, eq=False)
class CaptureStats(ParserStats):
    """:class:`ParserStats` of a whole capture (equal to a ParserStats with the same counters),
    plus ``bad_before[i]``: the bad frames that came before good frame i in the byte stream
    (what a live source reports as ``stats.bad_frames`` when it hands out frame i)."""

    bad_before: npt.NDArray[np.int64] = field(
        default_factory=lambda: np.zeros(0, np.int64), repr=False
    )


def _greedy_accept(v: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
    """Which CRC-valid frame starts the left-to-right scan takes: a start is taken if it is
    not inside an already taken frame. Python loops only over the (rare) overlaps."""
    accepted = np.ones(v.shape[0], bool)
    if v.shape[0] < 2:
        return accepted
    close = np.flatnonzero(np.diff(v) < BIN_FRAME_LEN) + 1
    if close.size == 0:
        return accepted
    ks = close.tolist()
    vk = v[close].tolist()
    vprev = v[close - 1].tolist()
    last = -BIN_FRAME_LEN
    prev_k = -2
    for k, x, xp in zip(ks, vk, vprev):
        if k - 1 != prev_k:
            last = xp  # start of a chain: its first member was taken
        if x >= last + BIN_FRAME_LEN:
            last = x
        else:
            accepted[k] = False
        prev_k = k
    return accepted


def _drop_displaced(a: npt.NDArray[np.uint8], v: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
    """Which CRC-valid candidates ``v`` (sorted positions) survive the push parser's
    :func:`hdrd.io.wire.parser.displaced` rule at the end of input; only a candidate with another
    within 14 bytes can be a coincidence, so Python loops only over those (rare)."""
    keep = np.ones(v.shape[0], bool)
    if v.shape[0] < 2:
        return keep
    for k in np.flatnonzero(np.diff(v) <= BIN_FRAME_LEN - 2).tolist():
        x = int(v[k])
        keep[k] = not displaced(a[x : x + 2 * BIN_FRAME_LEN].tobytes(), 0, True)
    return keep


_SCAN_BYTES = 1 << 20
"""decode_capture looks for frames in slices of this many bytes: its working memory is a
few times this, whatever the capture holds (20 MB of ``A5 5A`` is 10 million candidates)."""


_KEEP_FAILED = 1 << 20
"""decode_capture keeps the positions of up to this many failed candidates from its first
pass (8 MiB); beyond, a second pass finds them again, slice by slice."""


def _count_bad(
    inv: npt.NDArray[np.int64], acc: npt.NDArray[np.int64], counts: npt.NDArray[np.int64]
) -> None:
    """Add to ``counts[i]`` the failed candidates ``inv`` (sorted) that lie between accepted
    frame i - 1 and frame i, leaving out those inside an accepted frame."""
    if acc.shape[0] and inv.shape[0]:
        j = np.searchsorted(acc, inv, side="right") - 1
        inside = (j >= 0) & (inv < acc[np.maximum(j, 0)] + BIN_FRAME_LEN)
        inv = inv[~inside]
    if inv.shape[0]:
        at = np.searchsorted(acc, inv)
        first = int(at[0])  # sorted: this adds to counts[first .. at[-1]] only
        add = np.bincount(at - first)
        counts[first : first + add.shape[0]] += add


def _candidates(a: npt.NDArray[np.uint8], lo: int, hi: int) -> npt.NDArray[np.int64]:
    """Positions i in [lo, hi) where a sync pattern starts (hi <= len(a) - 15: room for a
    whole frame)."""
    seg = a[lo : hi + 1]
    cand = np.flatnonzero((seg[:-1] == SYNC[0]) & (seg[1:] == SYNC[1])).astype(np.int64, copy=False)
    if lo:
        cand += lo
    return cand


def _payload(a: npt.NDArray[np.uint8], acc: npt.NDArray[np.int64]) -> npt.NDArray[np.void]:
    """The :data:`FRAME_DTYPE` array of the frames starting at ``acc`` (their payloads)."""
    k = acc.shape[0]
    out = np.empty(k, FRAME_DTYPE)
    view = out.view(np.uint8).reshape(k, BIN_PAYLOAD_LEN)
    windows = np.lib.stride_tricks.sliding_window_view(a, BIN_FRAME_LEN)
    step = max(1, _SCAN_BYTES // BIN_FRAME_LEN)
    for lo in range(0, k, step):  # gathered in slices: 16 bytes a frame at a time, not all
        view[lo : lo + step] = windows[acc[lo : lo + step], BIN_PAYLOAD_AT:BIN_CRC_AT]
    return out


def _decode_text(
    data: bytes | bytearray | memoryview, st: CaptureStats
) -> tuple[npt.NDArray[np.void], CaptureStats]:
    """:func:`decode_capture` for hdr-text: the push parser, fed in slices (any split gives
    the same frames), each slice's frames packed into an array at once: no list of every
    Frame of the capture."""
    p = Parser("hdr-text")
    arrays: list[npt.NDArray[np.void]] = []
    bad: list[npt.NDArray[np.int64]] = []
    view = memoryview(data).cast("B")
    for lo in range(0, len(view), _SCAN_BYTES):
        frames = p.feed(view[lo : lo + _SCAN_BYTES])
        arrays.append(frames_to_array(frames))
        bad.append(np.asarray(p.bad_before, np.int64))
    p.flush()  # hdr-text holds no complete line back: it only counts the leftover
    for name, value in p.stats.as_dict().items():
        setattr(st, name, value)
    st.bad_before = np.concatenate(bad) if bad else np.empty(0, np.int64)
    return (np.concatenate(arrays) if arrays else np.empty(0, FRAME_DTYPE)), st


def _crc_valid(
    a: npt.NDArray[np.uint8], slices: list[tuple[int, int]]
) -> tuple[npt.NDArray[np.int64], list[npt.NDArray[np.int64]] | None, int]:
    """Pass 1, slice by slice: the positions of CRC-valid frames (at most the frames), those
    of the failed candidates while they are few (None past :data:`_KEEP_FAILED`: pass 2
    finds them again) and how many failed."""
    parts: list[npt.NDArray[np.int64]] = []
    failed_parts: list[npt.NDArray[np.int64]] | None = []
    failed = 0
    for lo, hi in slices:
        cand = _candidates(a, lo, hi)
        ok = crc_ok_at(a, cand)
        parts.append(cand[ok])
        if not ok.all():
            failed_here = cand[~ok]
            failed += failed_here.shape[0]
            if failed_parts is not None:
                failed_parts.append(failed_here)
                if failed > _KEEP_FAILED:
                    failed_parts = None
    valid = np.concatenate(parts) if parts else np.empty(0, np.int64)
    return valid, failed_parts, failed


def _count_bad_again(
    a: npt.NDArray[np.uint8],
    slices: list[tuple[int, int]],
    v: npt.NDArray[np.int64],
    acc: npt.NDArray[np.int64],
    counts: npt.NDArray[np.int64],
) -> None:
    """Pass 2, slice by slice: the failed candidates are those not in ``v``."""
    for lo, hi in slices:
        inv = _candidates(a, lo, hi)
        if v.shape[0]:
            at_v = np.minimum(np.searchsorted(v, inv), v.shape[0] - 1)
            inv = inv[v[at_v] != inv]
        _count_bad(inv, acc, counts)


def decode_capture(
    data: bytes | bytearray | memoryview, protocol: str = "hdr-bin"
) -> tuple[npt.NDArray[np.void], CaptureStats]:
    """Decode a whole capture to a :data:`FRAME_DTYPE` array and the parser's counters.

    Gives exactly the frames and counters of a :class:`Parser` fed the same bytes (in any
    chunking) and then flushed, plus ``bad_before`` per frame (:class:`CaptureStats`).
    hdr-bin is vectorised: every sync candidate's CRC is computed at once (table-driven, two
    payload bytes per step); Python loops only over overlapping candidates. hdr-text uses the
    push parser.
    """
    check_protocol(protocol)
    st = CaptureStats()
    if protocol == "hdr-text":
        return _decode_text(data, st)
    a = np.frombuffer(data, dtype=np.uint8)
    n = a.shape[0]
    if n < BIN_FRAME_LEN:
        st.garbage_bytes = n
        return np.empty(0, FRAME_DTYPE), st
    top = n - BIN_FRAME_LEN + 1  # a frame can start at 0 .. n - 16
    slices = [(lo, min(lo + _SCAN_BYTES, top)) for lo in range(0, top, _SCAN_BYTES)]
    valid, failed_parts, failed = _crc_valid(a, slices)
    keep = _drop_displaced(a, valid)
    v = valid if keep.all() else valid[keep]
    acc = v[_greedy_accept(v)]
    if failed == 0 and v.shape[0] == valid.shape[0]:
        st.bad_before = np.zeros(acc.shape[0], np.int64)
    else:
        # A candidate that failed (CRC, or a coincidence dropped above) counts as a bad
        # frame unless it lies inside a frame that was taken; bad_before[i] = bad positions
        # before acc[i].
        counts = np.zeros(acc.shape[0] + 1, np.int64)
        if failed_parts is not None:
            inv = np.sort(np.concatenate([*failed_parts, valid[~keep]]))
            _count_bad(inv, acc, counts)
        else:
            _count_bad_again(a, slices, v, acc, counts)
        st.bad_frames = int(counts.sum())
        st.bad_before = np.cumsum(counts[: acc.shape[0]], dtype=np.int64)
    arr = _payload(a, acc)
    st.garbage_bytes = n - BIN_FRAME_LEN * int(arr.shape[0])
    tracker = FrameTracker(st)
    kept = tracker.run_array(arr)
    tracker.flush()
    if kept.shape[0] < arr.shape[0]:
        arr, st.bad_before = arr[kept], st.bad_before[kept]
    st.frames = int(arr.shape[0])
    return arr, st


def decode_frames(data: bytes, protocol: str = "hdr-bin") -> list[Frame]:
    """All good frames of a capture as Frame objects (convenience over decode_capture)."""
    return array_to_frames(decode_capture(data, protocol)[0])
