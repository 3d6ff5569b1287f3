"""Inputs of the pipeline: the serial gyro, a replayed capture, a simulated gyro.

Every source is shaped like python-can's bus: ``recv(timeout) -> Frame | SourceEvent | None``,
a context manager, an idempotent ``close()``, and ``stats`` (:class:`hdrd.frames.ParserStats`).

``recv`` returns

- a :class:`~hdrd.frames.Frame`;
- ``None``: nothing within ``timeout`` seconds ("no data yet" — never the end of the stream);
- :class:`DeviceLost` (once, when the device goes away: unplugged, EOF on a pty, I/O error),
  then, after the source has reopened the same path by itself, :class:`DeviceBack`;
- :class:`EndOfInput` once at the end of a capture or a simulated drive, then ``None``.

I/O trouble never raises out of ``recv``. ``stats.bad_frames`` is the count of bad frames
that came before the last frame ``recv`` returned (all of them after a ``None`` or an event),
exactly what :class:`hdrd.frames.CaptureStats` ``.bad_before`` gives for a whole capture,
so a live run and a replay of the same bytes publish the same counts.

The serial byte reader with its reconnect loop, :class:`SerialReader`, lives in
:mod:`hdrd.serialport` (shared with ``hdrd record``); its clocks and link events are
re-exported here.
"""

from __future__ import annotations

import dataclasses
import io
import math
import os
from collections import deque
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from hdrd.drivelog import DriveLog
from hdrd.frames import (
    FRAME_DTYPE,
    TEMP_NOT_FITTED,
    Frame,
    Parser,
    ParserStats,
    array_to_frames,
)
from hdrd.resample import CLOCK_WRAP_US
from hdrd.sensor import SensorModel
from hdrd.serialport import (
    Clock,
    DeviceBack,
    DeviceLost,
    LinkStats,
    ManualClock,
    RealClock,
    SerialReader,
)

__all__ = [
    "BUILTIN_DRIVES",
    "Clock",
    "DeviceBack",
    "DeviceLost",
    "EndOfInput",
    "LinkStats",
    "ManualClock",
    "ProfileError",
    "RealClock",
    "ReplaySource",
    "SerialReader",
    "SerialSource",
    "SimulatedSource",
    "Source",
    "SourceEvent",
    "builtin_profile",
    "load_profile",
    "profile_frames",
]


# --------------------------------------------------------------------------- events


@dataclass(frozen=True, slots=True)
class EndOfInput:
    """A capture or a simulated drive has ended; ``recv`` returns None from now on."""


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
    """A source whose bytes go through a :class:`hdrd.frames.Parser` (serial, replay): frames
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


# --------------------------------------------------------------------------- replay


class ReplaySource(_ParsedSource):
    """Frames of a capture file (or bytes), as fast as possible or paced by device time.

    The capture is read in chunks through the same :class:`hdrd.frames.Parser` as the live
    source. Paced (``paced=True``, ``speedup`` > 0): frame k is handed out at
    ``start + (t_k - t_0) / speedup`` on ``clock``, device time unwrapped across 2**32 us
    (a step backwards does not wait). Ends with one :class:`EndOfInput`, then None.
    """

    def __init__(
        self,
        path_or_bytes: str | os.PathLike[str] | bytes | bytearray | memoryview,
        protocol: str = "hdr-bin",
        paced: bool = False,
        speedup: float = 1.0,
        clock: Clock | None = None,
        chunk_size: int = 65536,
    ) -> None:
        if paced and not (speedup > 0 and math.isfinite(speedup)):
            raise ValueError(f"speedup must be a finite number > 0 when paced, got {speedup!r}")
        super().__init__(protocol)
        if isinstance(path_or_bytes, (bytes, bytearray, memoryview)):
            self._file: io.BufferedIOBase = io.BytesIO(bytes(path_or_bytes))
            self.name = "<bytes>"
        else:
            self._file = open(path_or_bytes, "rb")  # noqa: SIM115 - closed in close()
            self.name = os.fspath(path_or_bytes)
        self.paced = paced
        self.speedup = speedup
        self.clock: Clock = clock or RealClock()
        self.chunk_size = chunk_size
        self._eof = False
        self._ended = False
        self._wall0: float | None = None
        self._dev_us = 0  # unwrapped device time of the head frame since the first, us
        self._last_raw: int | None = None
        self._head_due: float | None = None

    def _fill(self) -> bool:
        while not self._queue and not self._eof:
            chunk = self._file.read(self.chunk_size)
            if not chunk:
                self._eof = True
                self.end_input()
                break
            frames = self.parser.feed(chunk)
            self._queue.extend(frames, self.parser.bad_before)
        return bool(self._queue)

    def _due(self, frame: Frame) -> float:
        if self._head_due is None:
            if self._last_raw is None or self._wall0 is None:
                self._wall0 = self.clock.monotonic()
            else:
                d = (frame.t_us - self._last_raw) % CLOCK_WRAP_US
                if d < CLOCK_WRAP_US // 2:
                    self._dev_us += d
            self._last_raw = frame.t_us
            self._head_due = self._wall0 + self._dev_us / 1e6 / self.speedup
        return self._head_due

    def recv(self, timeout: float | None = None) -> Frame | SourceEvent | None:
        if self._closed or self._ended:
            return None
        if not self._fill():
            self._ended = True
            self._bad_seen = self.parser.stats.bad_frames
            return EndOfInput()
        if self.paced:
            wait = self._due(self._queue.frames[0]) - self.clock.monotonic()
            if wait > 0:
                if timeout is not None and wait > timeout:
                    self.clock.sleep(timeout)
                    return None
                self.clock.sleep(wait)
            self._head_due = None
        frame, self._bad_seen = self._queue.pop()
        return frame

    def _close(self) -> None:
        self._file.close()


# --------------------------------------------------------------------------- simulated


BUILTIN_DRIVES = ("standstill", "constant")


class ProfileError(ValueError):
    """A drive profile that cannot be made (unknown drive, simulator missing, bad value)."""


def builtin_profile(
    drive: str = "standstill",
    minutes: float = 20.0,
    seed: int = 1,
    hz: float = 10.0,
    rate_dps: float = 0.0,
    bias_dps: float = 0.2,
    noise_dps: float = 0.05,
    temp_c: float = 25.0,
    lead_in_s: float = 30.0,
) -> DriveLog:
    """A simple drive with no simulator: ``lead_in_s`` of standstill, then ``minutes`` of
    standstill ("standstill") or of a constant true yaw rate ``rate_dps`` ("constant").

    Raw gyro ``omega`` = true rate + ``bias_dps`` + white noise of std ``noise_dps`` (deg/s,
    + = CCW, seeded); ``omega_truth`` the true rate; ``temp_c`` constant. Time from 0 s.
    """
    if drive not in BUILTIN_DRIVES:
        raise ProfileError(
            f"unknown built-in drive {drive!r} (built in: {', '.join(BUILTIN_DRIVES)})"
        )
    for name, v in (("minutes", minutes), ("hz", hz), ("lead_in_s", lead_in_s)):
        if not (math.isfinite(v) and v >= 0) or (name == "hz" and v == 0):
            raise ProfileError(
                f"{name} must be a finite number {'> 0' if name == 'hz' else '>= 0'}, got {v!r}"
            )
    for name, v in (
        ("rate_dps", rate_dps),
        ("bias_dps", bias_dps),
        ("noise_dps", noise_dps),
        ("temp_c", temp_c),
    ):
        if not math.isfinite(v):
            raise ProfileError(f"{name} must be a finite number, got {v!r}")
    n = _profile_samples(minutes, hz, lead_in_s)
    t = np.arange(n, dtype=np.float64) / hz
    truth = np.where(t >= lead_in_s, rate_dps if drive == "constant" else 0.0, 0.0)
    rng = np.random.default_rng(seed)
    omega = truth + bias_dps + rng.normal(0.0, noise_dps, n) if noise_dps > 0 else truth + bias_dps
    return DriveLog(
        t=t,
        omega=omega,
        temp_c=np.full(n, temp_c),
        omega_truth=truth,
        name=drive,
        meta={
            "drive": drive,
            "rate_dps": repr(rate_dps),
            "bias_dps": repr(bias_dps),
            "noise_dps": repr(noise_dps),
            "lead_in_s": repr(lead_in_s),
            "seed": str(seed),
        },
    )


MAX_PROFILE_SAMPLES = 50_000_000
"""Most samples a generated drive may have (each a few float64 columns: ~1 GB at most)."""


def _profile_samples(minutes: float, hz: float, lead_in_s: float = 0.0) -> int:
    """Samples of a drive of ``minutes`` after ``lead_in_s`` at ``hz``; ProfileError if it
    has none or more than MAX_PROFILE_SAMPLES (1e308 minutes used to overflow, 1e6 minutes
    to fill the memory)."""
    total = (lead_in_s + minutes * 60.0) * hz
    if not total <= MAX_PROFILE_SAMPLES:
        raise ProfileError(
            f"a drive of {minutes:g} min at {hz:g} Hz is {total:.3g} samples; "
            f"at most {MAX_PROFILE_SAMPLES:,} are made"
        )
    n = int(round(total))
    if n < 1:
        raise ProfileError(f"a drive of {minutes} min at {hz} Hz has no samples")
    return n


def load_profile(
    drive: str,
    minutes: float = 20.0,
    seed: int = 1,
    hz: float = 10.0,
    rate_dps: float = 0.0,
    grade: str | None = None,
) -> DriveLog:
    """A drive by name: "standstill" and "constant" are built in (:func:`builtin_profile`);
    any other name comes from the simulator, ``hdrd.sim.simulate_drive`` (imported lazily),
    with the gyro of ``grade`` (hdrd.sim.grades; None: the default CRS03-04 model)."""
    if drive in BUILTIN_DRIVES:
        return builtin_profile(drive, minutes, seed, hz, rate_dps)
    for name, v in (("minutes", minutes), ("hz", hz)):
        if not (math.isfinite(v) and v > 0):
            raise ProfileError(f"{name} must be a finite number > 0, got {v!r}")
    _profile_samples(minutes, hz)
    try:
        from hdrd.sim import simulate_drive
    except ImportError as e:
        raise ProfileError(
            f"drive {drive!r} needs the simulator (hdrd.sim), which cannot be imported ({e}); "
            f"built-in drives: {', '.join(BUILTIN_DRIVES)}"
        ) from None
    try:
        model = None
        if grade is not None:
            from hdrd.sim.grades import grade_model

            model = grade_model(grade, seed)
        return simulate_drive(drive, minutes, seed, hz=hz, model=model)
    except ValueError as e:
        raise ProfileError(str(e)) from None


def profile_frames(
    log: DriveLog,
    sensor: SensorModel | None = None,
    supply_v: float | None = None,
    t0_us: int = 0,
    seq0: int = 0,
) -> npt.NDArray[np.void]:
    """The frames the ADC sends for a drive: a :data:`hdrd.frames.FRAME_DTYPE` array.

    rate = ``sensor.to_counts(log.omega, supply_v)`` (rounded, clipped to the rails); ref =
    the supply monitor's counts for ``supply_v``, 0 (not wired) when None; temp from
    ``log.temp_c`` in 0.01 degC (NaN or no column: not fitted); t_us = t0_us + t * 1e6,
    wrapped at 2**32; seq from ``seq0``, wrapped at 2**16.
    """
    sensor = sensor or SensorModel()
    n = len(log)
    arr = np.zeros(n, FRAME_DTYPE)
    arr["seq"] = (seq0 + np.arange(n, dtype=np.int64)) & 0xFFFF
    arr["t_us"] = (
        t0_us + np.rint(np.asarray(log.t, np.float64) * 1e6).astype(np.int64)
    ) % CLOCK_WRAP_US
    arr["rate"] = sensor.to_counts(log.omega, supply_v)
    arr["ref"] = 0 if supply_v is None else sensor.ref_counts_for(supply_v)
    if log.temp_c is None:
        arr["temp"] = TEMP_NOT_FITTED
    else:
        cc = np.clip(np.rint(np.nan_to_num(log.temp_c, nan=0.0) * 100.0), -32767, 32767).astype(
            np.int64
        )
        arr["temp"] = np.where(np.isnan(log.temp_c), TEMP_NOT_FITTED, cc)
    return arr


class SimulatedSource(_SourceBase):
    """Frames of a simulated gyro, paced in (optionally accelerated) real time.

    The drive is ``profile`` if given (any :class:`hdrd.drivelog.DriveLog`, e.g. from
    ``hdrd.sim.simulate_drive``; its raw ``omega`` becomes ADC counts through ``sensor``),
    else :func:`load_profile` (drive, minutes, seed, hz, rate_dps, grade). Frame k is handed out at
    ``start + (t_k - t_0) / speedup`` on ``clock``; ``speedup`` 0 = as fast as possible.
    Ends with one :class:`EndOfInput`, then None.
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

    @classmethod
    def from_arrays(
        cls,
        t_s: npt.ArrayLike,
        omega_dps: npt.ArrayLike,
        temp_c: npt.ArrayLike | None = None,
        **kwargs: Any,
    ) -> SimulatedSource:
        """From raw arrays: time (s), raw gyro rate (deg/s, + = CCW), temperature (degC)."""
        t = np.asarray(t_s, np.float64)
        log = DriveLog(
            t=t,
            omega=np.asarray(omega_dps, np.float64),
            temp_c=None if temp_c is None else np.asarray(temp_c, np.float64),
            name="arrays",
        )
        return cls(profile=log, **kwargs)

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
