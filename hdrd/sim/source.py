"""The built-in simulated gyro as a frame source (``hdrd run --simulate``, ``hdrd calibrate
--simulate``, ``hdrd fakegyro``'s drives): a drive's raw rate as ADC frames, paced in
(optionally accelerated) real time on a clock (:class:`hdrd.io.wire.sources.Source`)."""

from __future__ import annotations

import dataclasses
import math
from collections import deque

import numpy as np

from hdrd.core.sensor import SensorModel
from hdrd.io.files.drivelog import DriveLog
from hdrd.io.wire.clocks import Clock, RealClock
from hdrd.io.wire.codec import Frame, array_to_frames
from hdrd.io.wire.sources import EndOfInput, SourceBase, SourceEvent
from hdrd.io.wire.tracker import ParserStats
from hdrd.sim.profiles import load_profile, profile_frames

__all__ = ["SimulatedSource"]


class SimulatedSource(SourceBase):
    """Frames of a simulated gyro, paced in (optionally accelerated) real time.

    The drive is ``profile`` if given (any :class:`hdrd.io.files.drivelog.DriveLog`, e.g. from
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
