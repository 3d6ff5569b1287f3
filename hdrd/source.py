"""Inputs of the daemon's pipeline: the serial gyro, or a simulated one.

Every source is shaped like python-can's bus: ``recv(timeout) -> Frame | SourceEvent | None``,
a context manager, an idempotent ``close()``, and ``stats`` (:class:`hdrd.frames.ParserStats`).

``recv`` returns

- a :class:`~hdrd.frames.Frame`;
- ``None``: nothing within ``timeout`` seconds ("no data yet" — never the end of the stream);
- :class:`DeviceLost` (once, when the device goes away: unplugged, EOF on a pty, I/O error),
  then, after the source has reopened the same path by itself, :class:`DeviceBack`;
- :class:`EndOfInput` once at the end of a simulated drive, then ``None``.

I/O trouble never raises out of ``recv``. ``stats.bad_frames`` is the count of bad frames
that came before the last frame ``recv`` returned (all of them after a ``None`` or an event),
exactly what :class:`hdrd.capture.CaptureStats` ``.bad_before`` gives for a whole capture,
so a live run and a replay of the same bytes publish the same counts (``hdrd replay`` decodes
a capture whole, :mod:`hdrd.capture`, instead of reading it as a source).

The serial byte reader with its reconnect loop, :class:`SerialReader`, lives in
:mod:`hdrd.serialport` (shared with ``hdrd record``); its link events are re-exported here,
the clocks are in :mod:`hdrd.clocks`.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from hdrd.clocks import Clock, RealClock
from hdrd.drivelog import DriveLog
from hdrd.frames import Frame, Parser, ParserStats, array_to_frames
from hdrd.sensor import SensorModel
from hdrd.serialport import DeviceBack, DeviceLost, LinkStats, SerialReader

if TYPE_CHECKING:
    from hdrd.config import Config

__all__ = [
    "DeviceBack",
    "DeviceLost",
    "EndOfInput",
    "LinkStats",
    "SerialReader",
    "SerialSource",
    "SimulatedSource",
    "Source",
    "SourceEvent",
    "open_source",
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


class _SourceBase:
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


class _ParsedSource(_SourceBase):
    """A source whose bytes go through a :class:`hdrd.frames.Parser` (the serial port): frames
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

    ``recv`` parses what the port delivers with :class:`hdrd.frames.Parser`; on a loss the
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


class SimulatedSource(_SourceBase):
    """Frames of a simulated gyro, paced in (optionally accelerated) real time.

    The drive is ``profile`` if given (any :class:`hdrd.drivelog.DriveLog`, e.g. from
    ``hdrd.sim.simulate_drive``; its raw ``omega`` becomes ADC counts through ``sensor``),
    else :func:`hdrd.sim.profiles.load_profile` (drive, minutes, seed, hz, rate_dps, grade).
    Frame k is handed out at ``start + (t_k - t_0) / speedup`` on ``clock``; ``speedup`` 0 =
    as fast as possible. Ends with one :class:`EndOfInput`, then None.
    """

    _BATCH = 512

    def __init__(
        self,
        drive: str = "standstill",
        *,
        minutes: float = 20.0,
        seed: int = 1,
        hz: float = 10.0,
        rate_dps: float = 0.0,
        speedup: float = 1.0,
        sensor: SensorModel | None = None,
        supply_v: float | None = None,
        t0_us: int = 0,
        seq0: int = 0,
        profile: DriveLog | None = None,
        clock: Clock | None = None,
        grade: str | None = None,
    ) -> None:
        if not (speedup >= 0 and math.isfinite(speedup)):
            raise ValueError(
                f"speedup must be a finite number >= 0 (0 = as fast as possible), got {speedup!r}"
            )
        from hdrd.sim.profiles import load_profile, profile_frames  # the simulator: only here

        self.profile = (
            profile
            if profile is not None
            else load_profile(drive, minutes, seed, hz, rate_dps, grade)
        )
        self.frames = profile_frames(self.profile, sensor, supply_v, t0_us, seq0)
        self.speedup = speedup
        self.clock: Clock = clock or RealClock()
        self._t = np.asarray(self.profile.t, np.float64)
        self._i = 0
        self._batch: deque[Frame] = deque()
        self._wall0: float | None = None
        self._ended = False
        self._stats = ParserStats()

    @property
    def stats(self) -> ParserStats:
        return dataclasses.replace(self._stats)

    @property
    def bad_frames(self) -> int:
        return self._stats.bad_frames

    def recv(self, timeout: float | None = None) -> Frame | SourceEvent | None:
        if self._closed or self._ended:
            return None
        n = self.frames.shape[0]
        if self._i >= n:
            self._ended = True
            return EndOfInput()
        if self.speedup > 0:
            now = self.clock.monotonic()
            if self._wall0 is None:
                self._wall0 = now
            due = self._wall0 + (self._t[self._i] - self._t[0]) / self.speedup
            wait = due - now
            if wait > 0:
                if timeout is not None and wait > timeout:
                    self.clock.sleep(timeout)
                    return None
                self.clock.sleep(wait)
        if not self._batch:
            self._batch.extend(array_to_frames(self.frames[self._i : self._i + self._BATCH]))
        self._i += 1
        self._stats.frames += 1
        return self._batch.popleft()


# --------------------------------------------------------------------------- from a configuration


def open_source(cfg: Config, simulate: bool) -> Source:
    """The configured input (``hdrd run``, ``hdrd calibrate``): the serial device
    (``device.*``), or the built-in simulated gyro (``simulate.*``)."""
    if simulate:
        s = cfg.simulate
        return SimulatedSource(
            drive=s.drive,
            seed=s.seed,
            hz=s.rate_hz,
            speedup=s.speedup,
            sensor=cfg.sensor,
            grade=s.grade,
        )
    d = cfg.device
    return SerialSource(
        d.port,
        protocol=d.protocol,
        baud=d.baud,
        reconnect_min_s=d.reconnect_min_s,
        reconnect_max_s=d.reconnect_max_s,
    )
