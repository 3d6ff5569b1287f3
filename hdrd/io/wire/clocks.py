"""Clocks: the host's (real, or a test's manual one) and the device's (the ADC's ``t_us``).

- :class:`Clock`, :class:`RealClock`, :class:`ManualClock`: where a source or the serial link
  gets the host's monotonic time and sleeps (a test passes a :class:`ManualClock`);
- :class:`DeviceClock` (and :func:`unwrap_us` for a whole capture): the 32-bit microsecond
  device clock unwrapped into a monotonic integer, with repeats rejected and resets followed;
  the pipeline cuts its blocks of T on it;
- :class:`SampleClock`: how much device time a calibration window spans, robust to one frame
  with a glitched timestamp (``hdrd calibrate``);
- :class:`WallClockCheck`: whether the device clock agrees with the host's (``hdrd run``: a
  frame whose clock does not is dropped, not integrated);
- :func:`device_seconds`: a capture's device time since its first frame, s (pacing a replay).

The device clock's constants (wrap at 2**32 us, a reset is a step back of more than 1 s) are
the wire protocol's: :mod:`hdrd.io.wire.protocol`. Pure apart from :class:`RealClock`.
"""

from __future__ import annotations

import time
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from hdrd.io.wire.protocol import CLOCK_WRAP_US, RESET_THRESHOLD_US

__all__ = [
    "Clock",
    "DeviceClock",
    "ManualClock",
    "RealClock",
    "SampleClock",
    "WallClockCheck",
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
    """A whole capture's device times through a new :class:`DeviceClock`: (unwrapped times,
    accepted mask; rejected samples get time -1)."""
    return DeviceClock().unwrap_many(t_us)


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


# -- the device's clock against the host's --------------------------------------------------


class WallClockCheck:
    """Whether each frame's device time agrees with the host's monotonic clock. Pure: the
    caller passes the times (``hdrd run``: when the frame was in hand).

    A frame's offset, o = (host time in hand) - (device seconds since the first frame) /
    ``rate``, is its delay in reaching the host plus a constant, while the device clock runs
    at ``rate`` device seconds per host second (1: a gyro; N: a feed N times real time). The
    reference A starts at the first frame's offset and follows the frames kept by at most
    ``drift`` seconds per second either way (a crystal is off by 1e-4 at most). :meth:`check`
    says:

    - :data:`AGREES` when |o - A| <= ``tolerance_s`` (a frame late by a stalled reader, a burst
      of USB frames, the device's crystal: all well inside). Frames more than half the
      tolerance off that run at the rate among themselves for ``reanchor_s`` (the device clock
      fell behind once, in a stall) move A to them at once;
    - :data:`DISAGREES` otherwise (counted in ``mismatches``): a device clock running fast,
      slow or stopped, or one that jumped; the frame is not to be integrated;
    - :data:`JUMPED` when the frames have disagreed for ``reanchor_s`` of host time while
      running at the rate among themselves (device time and host time since the first of them
      within :attr:`RUN_TOLERANCE` of ``tolerance_s``: the device clock jumped once, or
      restarted after a silence, and runs at the rate since): A is set to this frame's offset
      and the frame kept (counted in ``jumps``); the caller takes the device time since the
      last frame kept as unknown (the daemon counts the steps on by the host's clock).

    A device clock that goes back (a restart of the device, which
    :class:`hdrd.io.wire.tracker.FrameTracker` has confirmed; or one that jumped half its wrap on,
    which no one can tell from it) is :data:`JUMPED` at once, the reference following it: the
    caller counts the time since the last frame kept by its own clock. ``rate`` 0 turns the
    check off: every frame agrees.
    """

    AGREES = 0
    DISAGREES = 1
    JUMPED = 2
    RUN_TOLERANCE = 0.05
    """Frames off centre run at the rate among themselves when their device time and host
    time since the first of them differ by at most this share of ``tolerance_s``."""

    __slots__ = (
        "_a",
        "_at",
        "_last_raw",
        "_run_at",
        "_run_raw",
        "_tau",
        "drift",
        "jumps",
        "mismatches",
        "rate",
        "reanchor_s",
        "tolerance_s",
    )

    def __init__(
        self,
        rate: float = 1.0,
        tolerance_s: float = 5.0,
        drift: float = 1e-3,
        reanchor_s: float = 5.0,
    ) -> None:
        if not (rate >= 0 and tolerance_s > 0 and drift >= 0 and reanchor_s >= 0):
            raise ValueError("need rate >= 0, tolerance_s > 0, drift >= 0, reanchor_s >= 0")
        self.rate = rate
        self.tolerance_s = tolerance_s
        self.drift = drift
        self.reanchor_s = reanchor_s
        self.mismatches = 0
        self.jumps = 0
        self.reset()

    def reset(self) -> None:
        """A new connection: the next frame starts a new reference."""
        self._last_raw: int | None = None
        self._tau = 0.0  # device seconds of the last frame kept, since the first
        self._a = 0.0  # the reference offset, s
        self._at = 0.0  # host time of the last frame kept
        self._run_raw: int | None = None  # the first of a run of frames off centre: its
        self._run_at = 0.0  # device time, and when it was in hand

    def check(self, t_us: int, now: float) -> int:
        """The verdict on a frame with raw device time ``t_us`` in hand at host time ``now``
        (s): :data:`AGREES`, :data:`DISAGREES` or :data:`JUMPED` (see the class doc)."""
        last = self._last_raw
        if last is None or self.rate == 0:
            if self.rate:
                self._keep(t_us, 0.0, now, now)
            return self.AGREES
        d = (t_us - last) & 0xFFFFFFFF
        if d >= _HALF_WRAP:  # back (a restart FrameTracker confirmed), or 2**31 us on: unknown
            self.jumps += 1
            self._run_raw = None
            self._keep(t_us, self._tau, now - self._tau / self.rate, now)
            return self.JUMPED
        tau = self._tau + d / 1e6
        o = now - tau / self.rate
        off = o - self._a
        step = self.drift * (now - self._at)
        if step < 0.0:
            step = 0.0
        if -self.tolerance_s / 2 <= off <= self.tolerance_s / 2:  # the common case
            self._run_raw = None
            self._last_raw, self._tau, self._at = t_us, tau, now
            self._a += off if -step <= off <= step else (step if off > 0 else -step)
            return self.AGREES
        lasted = self._run(t_us, now)  # off centre: how long at the rate since the first such
        if abs(off) <= self.tolerance_s:
            # agreeing, but off centre for reanchor_s at the rate: the centre follows at once
            moved = lasted >= self.reanchor_s
            self._keep(t_us, tau, o if moved else self._a + min(max(off, -step), step), now)
            if moved:
                self._run_raw = None
            return self.AGREES
        if lasted < self.reanchor_s:
            self.mismatches += 1
            return self.DISAGREES
        self.jumps += 1
        self._run_raw = None
        self._keep(t_us, tau, o, now)
        return self.JUMPED

    def _run(self, t_us: int, now: float) -> float:
        """Host seconds since the first of the frames off centre in a row that run at the rate
        among themselves (device time and host time since it within :attr:`RUN_TOLERANCE` of
        ``tolerance_s``); a frame that does not starts a new run (0)."""
        if self._run_raw is not None:
            d = (t_us - self._run_raw) % CLOCK_WRAP_US
            host = now - self._run_at
            if (
                d < _HALF_WRAP
                and abs(d / 1e6 / self.rate - host) <= self.RUN_TOLERANCE * self.tolerance_s
            ):
                return host
        self._run_raw, self._run_at = t_us, now
        return 0.0

    def _keep(self, t_us: int, tau: float, a: float, now: float) -> None:
        self._last_raw, self._tau, self._a, self._at = t_us, tau, a, now
