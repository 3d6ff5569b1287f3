"""The push parser: bytes in any split -> frames (docs/protocol.md, "Resynchronisation").

Pure. :class:`Parser`, ``feed(chunk) -> frames`` in the manner of pyserial's threaded
``Packetizer``: partial frames wait for the next chunk, bad frames and garbage are counted, the
good frames go to its :class:`hdrd.io.wire.tracker.FrameTracker`. The vectorised decoder of a
whole capture (:mod:`hdrd.io.wire.capture`) gives exactly its frames and counters.

The resynchronisation rule (both formats): the scan stops at each sync pattern (``A5 5A``,
resp. ``$HDRG,``); if the frame there is good it is taken whole and the scan continues after
it, otherwise it is counted in ``bad_frames`` and the scan moves on by ONE byte, so a sync
pattern inside a payload or in garbage never costs the next good frame. A CRC-valid hdr-bin
candidate that hides a real frame is not good (:func:`displaced`).
"""

from __future__ import annotations

from binascii import crc_hqx

from hdrd.io.wire.codec import (
    BIN_BODY,
    Frame,
    FrameError,
    check_protocol,
    decode_text,
    fast_frame,
)
from hdrd.io.wire.protocol import (
    BIN_CRC_AT,
    BIN_FRAME_LEN,
    BIN_PAYLOAD_AT,
    SYNC,
    TEMP_NOT_FITTED,
    TEXT_MAX_LINE,
    TEXT_SYNC,
)
from hdrd.io.wire.tracker import FrameTracker, ParserStats

__all__ = ["Parser", "displaced"]


def _sync_at(buf: bytes, k: int) -> bool | None:
    """Whether a sync pattern starts at ``buf[k]``; None if those bytes are not there yet."""
    if k + 2 > len(buf):
        return None
    return buf[k] == SYNC[0] and buf[k + 1] == SYNC[1]


def _crc_ok(buf: bytes, i: int) -> bool:
    """Whether the hdr-bin candidate at ``buf[i]`` (whole) carries a matching CRC."""
    crc = crc_hqx(buf[i + BIN_PAYLOAD_AT : i + BIN_CRC_AT], 0xFFFF)
    return crc == buf[i + BIN_CRC_AT] | (buf[i + BIN_CRC_AT + 1] << 8)


def displaced(buf: bytes, i: int, final: bool) -> bool | None:
    """Is the CRC-valid candidate at ``buf[i]`` a coincidence hiding a real frame?

    It is when a sync pattern inside it, at j (i + 2 <= j <= i + 14), starts another
    CRC-valid candidate that is followed by a sync pattern at j + 16 while the one at i is
    not followed by one at i + 16: typically a truncated frame whose first bytes and the
    next frame's bytes pass the 16-bit CRC by chance (1 in 65536). None: undecided until
    more bytes arrive (with ``final``, missing bytes count as no sync pattern and no frame).
    The bytes it reads: ``buf[i : i + 32]``.
    """
    n = BIN_FRAME_LEN
    here = _sync_at(buf, i + n)
    if here is None and not final:
        return None
    if here:
        return False
    j = buf.find(SYNC, i + 2, i + n)
    while j >= 0:
        if j + n > len(buf):
            return None if not final else False
        if _crc_ok(buf, j):
            after = _sync_at(buf, j + n)
            if after is None and not final:
                return None
            if after:
                return True
        j = buf.find(SYNC, j + 1, i + n)
    return False


_Scan = tuple[list[Frame], list[int], int, int]  # frames, bad before each, bad, kept from


def _scan_bin(buf: bytes, bad: int, final: bool) -> _Scan:
    """Long because it is the binary parser's hot path: one loop with its names bound to
    locals. The frames in ``buf`` by the resynchronisation rule (module doc)."""
    n = len(buf)
    find = buf.find
    unpack = BIN_BODY.unpack_from
    size, at, crc_at, absent = BIN_FRAME_LEN, BIN_PAYLOAD_AT, BIN_CRC_AT, TEMP_NOT_FITTED
    frames: list[Frame] = []
    bads: list[int] = []
    add_f, add_b = frames.append, bads.append
    p = 0
    nxt = -2  # the first sync pattern at or after p when known (-1: none), else -2
    while True:
        i = find(SYNC, p) if nxt == -2 else nxt
        if i < 0:
            return frames, bads, bad, n - 1 if n > p and buf[n - 1] == SYNC[0] else n
        if i + size > n:
            return frames, bads, bad, i
        seq, t_us, rate, ref, temp, crc = unpack(buf, i + at)
        nxt = -2
        if crc_hqx(buf[i + at : i + crc_at], 0xFFFF) != crc:
            bad += 1
            p = i + 1
            continue
        # The next sync pattern after this one's: beyond the frame, the next scan starts
        # there; inside it (rare), is this frame a CRC coincidence? (:func:`displaced`)
        nxt = find(SYNC, i + 2)
        if 0 <= nxt < i + size:
            nxt = -2
            verdict = displaced(buf, i, final)
            if verdict is None:  # the bytes that decide have not arrived yet
                return frames, bads, bad, i
            if verdict:
                bad += 1
                p = i + 1
                continue
        p = i + size
        add_f(fast_frame(seq, t_us, rate, ref, None if temp == absent else temp))
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
        coincidence from a real frame are missing, see :func:`displaced`; at the end they
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
        st.garbage_bytes += keep - BIN_FRAME_LEN * len(frames)
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
