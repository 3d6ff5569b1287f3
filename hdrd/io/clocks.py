"""Clocks: the host's (real, or a test's manual one) and the device's (the ADC's ``t_us``).

- :class:`Clock`, :class:`RealClock`, :class:`ManualClock`: where a source or the serial link
  gets the host's monotonic time and sleeps (a test passes a :class:`ManualClock`);
- :class:`DeviceClock` (and :func:`unwrap_us` for a whole capture): the 32-bit microsecond
  device clock unwrapped into a monotonic integer, with repeats rejected and resets followed;
  the pipeline cuts its blocks of T on it;
- :class:`SampleClock`: how much device time a calibration window spans, robust to one frame
  with a glitched timestamp (``hdrd calibrate``);
- :func:`device_seconds`: a capture's device time since its first frame, s (pacing a replay).

The device clock's constants (wrap at 2**32 us, a reset is a step back of more than 1 s) are
the wire protocol's: :mod:`hdrd.io.protocol`. Pure apart from :class:`RealClock`.
"""

from __future__ import annotations

import time
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from hdrd.io.protocol import CLOCK_WRAP_US, RESET_THRESHOLD_US

__all__ = [
    "Clock",
    "DeviceClock",
    "ManualClock",
    "RealClock",
    "SampleClock",
    "device_seconds",
    "unwrap_us",
]

# -- the host's clock ----------------------------------------------------------------------


class Clock(Protocol):
    """Where a source gets time from: real time, or a test's manual clock."""

    def monotonic(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class RealClock:
    """``time.monotonic`` and ``time.sleep``."""

    def monotonic(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class ManualClock:
    """A clock that only moves when slept on: for tests and offline pacing.
    ``slept`` lists every sleep, s."""

    def __init__(self, start: float = 0.0) -> None:
        self.now = start
        self.slept: list[float] = []

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        if seconds > 0:
            self.now += seconds


# -- the device's clock --------------------------------------------------------------------


_HALF_WRAP = CLOCK_WRAP_US >> 1


class DeviceClock:
    """Unwraps the 32-bit microsecond device clock into a monotonic integer (us).

    A forward step of less than half the wrap period is time passing (including across the
    wrap). A backward step of up to 1 s is a repeated or reordered sample: rejected
    (``unwrap`` returns None, counted in ``rejected``). A larger backward step is a device
    reset: time resumes 1 us after the last accepted sample (counted in ``resets``), because
    the real time elapsed across a reset cannot be known from the device clock.
    """

    __slots__ = ("_last", "_last_raw", "rejected", "resets", "wraps")

    def __init__(self) -> None:
        self._last_raw: int | None = None
        self._last = 0
        self.wraps = 0
        self.rejected = 0
        self.resets = 0

    @property
    def last_us(self) -> int | None:
        """The last accepted sample's unwrapped time, us (None before the first)."""
        return None if self._last_raw is None else self._last

    def unwrap(self, t_us: int) -> int | None:
        """Monotonic device time in us for a raw 32-bit timestamp, or None if rejected."""
        if self._last_raw is None:
            self._last_raw = t_us
            self._last = t_us
            return t_us
        d = (t_us - self._last_raw) % CLOCK_WRAP_US
        if d == 0 or d >= _HALF_WRAP:
            back = (CLOCK_WRAP_US - d) % CLOCK_WRAP_US
            if back <= RESET_THRESHOLD_US:
                self.rejected += 1
                return None
            self.resets += 1
            d = 1
        elif t_us < self._last_raw:
            self.wraps += 1
        self._last_raw = t_us
        self._last += d
        return self._last

    def unwrap_many(
        self, t_us: npt.ArrayLike
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
        """:meth:`unwrap` over an array, continuing this clock's state: (times, accepted).

        Identical to calling :meth:`unwrap` in order (rejected samples get time -1); numpy
        when every step is forward (the normal case), the scalar path otherwise.
        """
        raw = np.asarray(t_us, dtype=np.int64)
        n = raw.shape[0]
        if n == 0:
            return np.empty(0, np.int64), np.empty(0, bool)
        if self._last_raw is None:
            d = np.diff(raw) % CLOCK_WRAP_US
            start = int(raw[0])
            head = 1
        else:
            d = np.diff(raw, prepend=self._last_raw) % CLOCK_WRAP_US
            start = self._last
            head = 0
        if np.all((d > 0) & (d < _HALF_WRAP)):
            out = np.empty(n, np.int64)
            if head:
                out[0] = start
            np.cumsum(d, out=out[head:])
            out[head:] += start
            prev = np.empty(n, np.int64)  # each sample's predecessor; a wrap goes down
            prev[0] = raw[0] if self._last_raw is None else self._last_raw
            prev[1:] = raw[:-1]
            self.wraps += int(np.count_nonzero(raw < prev))
            self._last_raw = int(raw[-1])
            self._last = int(out[-1])
            return out, np.ones(n, bool)
        out = np.full(n, -1, np.int64)
        for i, t in enumerate(raw.tolist()):
            u = self.unwrap(t)
            if u is not None:
                out[i] = u
        return out, out >= 0


def unwrap_us(t_us: npt.ArrayLike) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
    """Vectorised :class:`DeviceClock`: (unwrapped times, accepted mask) for a whole capture.

    Identical to feeding ``DeviceClock.unwrap`` in order; rejected samples get time -1.
    """
    raw = np.asarray(t_us, dtype=np.int64)
    n = raw.shape[0]
    if n == 0:
        return np.empty(0, np.int64), np.empty(0, bool)
    d = np.diff(raw) % CLOCK_WRAP_US
    if np.all((d > 0) & (d < _HALF_WRAP)):
        out = np.empty(n, np.int64)
        out[0] = raw[0]
        np.cumsum(d, out=out[1:])
        out[1:] += raw[0]
        return out, np.ones(n, bool)
    # Rare: repeats, reordering or resets. Take the exact streaming path.
    clock = DeviceClock()
    out = np.full(n, -1, np.int64)
    for i, t in enumerate(raw.tolist()):
        u = clock.unwrap(t)
        if u is not None:
            out[i] = u
    return out, out >= 0


class SampleClock:
    """How much device time a calibration window spans, robust to a glitched timestamp.

    Pure. ``accept(t_us)`` takes each sample's raw 32-bit device time (us, wrapping at
    2**32) and says whether the sample counts. :attr:`elapsed_us` sums the forward steps
    between counted samples; a step is counted only if it is forward and at most
    ``max_step_us``. A sample whose step is not (one CRC-valid frame with a wild clock, a
    repeat, a step back) is set aside and counted in :attr:`glitches`, so one bad frame can
    neither end a 30 s window after 2 s nor stretch it. If ``confirm`` set-aside samples in
    a row step normally among themselves, the device clock really jumped (a reset, frames
    lost for a while): the clock continues from them, the jump itself not counted.
    """

    __slots__ = ("_cand", "_cand_n", "_last", "confirm", "elapsed_us", "glitches", "max_step_us")

    def __init__(self, max_step_us: int = 2_000_000, confirm: int = 3) -> None:
        self.max_step_us = max_step_us
        self.confirm = confirm
        self.elapsed_us = 0
        self.glitches = 0
        self._last: int | None = None
        self._cand: int | None = None  # the last set-aside sample, a possible new reference
        self._cand_n = 0  # set-aside samples in a row that step normally among themselves

    def _step_ok(self, prev: int, t_us: int) -> bool:
        return 0 < (t_us - prev) % CLOCK_WRAP_US <= self.max_step_us

    def accept(self, t_us: int) -> bool:
        """True if the sample at raw device time ``t_us`` counts (see the class doc)."""
        if self._last is None:
            self._last = t_us
            return True
        if self._step_ok(self._last, t_us):
            self.elapsed_us += (t_us - self._last) % CLOCK_WRAP_US
            self._last = t_us
            self._cand, self._cand_n = None, 0
            return True
        self.glitches += 1
        if self._cand is not None and self._step_ok(self._cand, t_us):
            self._cand_n += 1
        else:
            self._cand_n = 1
        self._cand = t_us
        if self._cand_n >= self.confirm:  # the device clock moved for good: follow it
            self._last = t_us
            self._cand, self._cand_n = None, 0
        return False


def device_seconds(t_us: npt.NDArray[np.integer[Any]]) -> npt.NDArray[np.float64]:
    """Device time of each frame since the first, s (unwrapped; a step back counts as 0)."""
    if t_us.shape[0] == 0:
        return np.zeros(0)
    d = np.mod(np.diff(t_us.astype(np.int64)), CLOCK_WRAP_US)
    d[d >= CLOCK_WRAP_US // 2] = 0
    return np.concatenate(([0.0], np.cumsum(d) / 1e6))
