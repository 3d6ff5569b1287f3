"""Inputs of the daemon's pipeline: the serial gyro, or a simulated one.

Every source is shaped like python-can's bus: ``recv(timeout) -> Frame | SourceEvent | None``,
a context manager, an idempotent ``close()``, and ``stats`` (:class:`hdrd.io.wire.tracker.ParserStats`).

``recv`` returns

- a :class:`~hdrd.io.wire.codec.Frame`;
- ``None``: nothing within ``timeout`` seconds ("no data yet" — never the end of the stream);
- :class:`DeviceLost` (once, when the device goes away: unplugged, EOF on a pty, I/O error),
  then, after the source has reopened the same path by itself, :class:`DeviceBack`;
- :class:`EndOfInput` once at the end of a simulated drive, then ``None``.

I/O trouble never raises out of ``recv``. ``stats.bad_frames`` is the count of bad frames
that came before the last frame ``recv`` returned (all of them after a ``None`` or an event),
exactly what :class:`hdrd.io.wire.capture.CaptureStats` ``.bad_before`` gives for a whole capture,
so a live run and a replay of the same bytes publish the same counts (``hdrd replay`` decodes
a capture whole, :mod:`hdrd.io.wire.capture`, instead of reading it as a source).

The serial byte reader with its reconnect loop, :class:`SerialReader`, lives in
:mod:`hdrd.io.wire.serialport` (shared with ``hdrd record``); its link events are re-exported here,
the clocks are in :mod:`hdrd.io.wire.clocks`.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from dataclasses import dataclass
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from hdrd.io.wire.clocks import Clock
from hdrd.io.wire.codec import Frame
from hdrd.io.wire.parser import Parser
from hdrd.io.wire.serialport import DeviceBack, DeviceLost, LinkStats, SerialReader
from hdrd.io.wire.tracker import ParserStats

if TYPE_CHECKING:
    pass

__all__ = [
    "DeviceBack",
    "DeviceLost",
    "EndOfInput",
    "LinkStats",
    "SerialReader",
    "SerialSource",
    "Source",
    "SourceEvent",
]


# --------------------------------------------------------------------------- events


@dataclass(frozen=True, slots=True)
class EndOfInput:
    """A simulated drive has ended; ``recv`` returns None from now on."""


SourceEvent = DeviceLost | DeviceBack | EndOfInput


@runtime_checkable
class Source(Protocol):
    """What the daemon reads from (python-can ``BusABC``-like)."""

    @property
    def stats(self) -> ParserStats: ...

    @property
    def bad_frames(self) -> int:
        """``stats.bad_frames`` without copying the counters (read once per frame)."""
        ...

    def recv(self, timeout: float | None = None) -> Frame | SourceEvent | None: ...

    def close(self) -> None: ...

    def __enter__(self) -> Source: ...

    def __exit__(
        self, typ: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None: ...


class SourceBase:
    """Context manager and idempotent close for the sources below."""

    _closed = False

    def __enter__(self) -> Any:
        return self

    def __exit__(
        self, typ: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._close()

    @property
    def closed(self) -> bool:
        return self._closed

    def _close(self) -> None:
        pass


class _FrameQueue:
    """Frames parsed but not handed out yet, each with the bad-frame count before it."""

    __slots__ = ("bad", "frames")

    def __init__(self) -> None:
        self.frames: deque[Frame] = deque()
        self.bad: deque[int] = deque()

    def extend(self, frames: list[Frame], bad_before: list[int]) -> None:
        self.frames.extend(frames)
        self.bad.extend(bad_before)

    def __bool__(self) -> bool:
        return bool(self.frames)

    def __len__(self) -> int:
        return len(self.frames)

    def pop(self) -> tuple[Frame, int]:
        return self.frames.popleft(), self.bad.popleft()


class _ParsedSource(SourceBase):
    """A source whose bytes go through a :class:`hdrd.io.wire.parser.Parser` (the serial port): frames
    parsed but not handed out wait in a queue with the bad-frame count before each."""

    def __init__(self, protocol: str) -> None:
        self.parser = Parser(protocol)
        self._queue = _FrameQueue()
        self._bad_seen = 0

    @property
    def stats(self) -> ParserStats:
        return dataclasses.replace(self.parser.stats, bad_frames=self._bad_seen)

    @property
    def bad_frames(self) -> int:
        return self._bad_seen

    def end_input(self) -> bool:
        """The input ends here (end of a capture, a lost device, shutdown): frames the parser
        still holds back for a look past their end are decided as at the end of a capture
        and queued for ``recv``. True if any were."""
        held = self.parser.flush()
        self._queue.extend(held, self.parser.bad_before)
        return bool(held)


class SerialSource(_ParsedSource):
    """Frames from a serial port (any pyserial URL), reopened by itself when lost.

    ``recv`` parses what the port delivers with :class:`hdrd.io.wire.parser.Parser`; on a loss the
    partial frame is dropped (counted as garbage) and the parser's sequence/clock references
    are kept, so the frames lost across the gap show in ``stats.lost_frames``.
    """

    def __init__(
        self,
        url: str,
        protocol: str = "hdr-bin",
        baud: int = 115200,
        reconnect_min_s: float = 0.5,
        reconnect_max_s: float = 10.0,
        clock: Clock | None = None,
    ) -> None:
        super().__init__(protocol)
        self.reader = SerialReader(url, baud, reconnect_min_s, reconnect_max_s, clock)
        self.clock = self.reader.clock
        self._lost: SourceEvent | None = None  # a loss to report once the queue is empty

    @property
    def url(self) -> str:
        return self.reader.url

    @property
    def port(self) -> Any:
        """The open pyserial object (None while lost); tests write to ``loop://`` through it."""
        return self.reader.port

    @property
    def link(self) -> LinkStats:
        return self.reader.stats

    @property
    def pending(self) -> int:
        """Frames read and parsed but not handed out by ``recv`` yet."""
        return len(self._queue)

    def recv(self, timeout: float | None = None) -> Frame | SourceEvent | None:
        if self._queue:
            frame, self._bad_seen = self._queue.pop()
            return frame
        if self._lost is not None:  # the frames the parser still held came first
            lost, self._lost = self._lost, None
            self._bad_seen = self.parser.stats.bad_frames
            return lost
        if self._closed:
            return None
        deadline = None if timeout is None else self.clock.monotonic() + timeout
        while True:
            left = None if deadline is None else max(0.0, deadline - self.clock.monotonic())
            item = self.reader.read(left)
            if isinstance(item, bytes):
                frames = self.parser.feed(item)
                if frames:
                    bad = self.parser.bad_before
                    self._queue.extend(frames[1:], bad[1:])
                    self._bad_seen = bad[0]
                    return frames[0]
                if deadline is not None and self.clock.monotonic() >= deadline:
                    self._bad_seen = self.parser.stats.bad_frames
                    return None
                continue
            if isinstance(item, DeviceLost) and self.end_input():
                self._lost = item  # reported once the frames the parser held are out
                frame, self._bad_seen = self._queue.pop()
                return frame
            self._bad_seen = self.parser.stats.bad_frames
            return item

    def _close(self) -> None:
        self.reader.close()


# --------------------------------------------------------------------------- simulated
