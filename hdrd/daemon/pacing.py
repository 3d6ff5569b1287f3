"""When the daemon may leave the serial port unread without delaying a step. Pure: the caller
passes the times.

Why pause at all: a read per frame costs a wake-up per frame (50-150 us of CPU each on a busy
2-core machine), most of ``hdrd run``'s cost at 1 kHz (bench/live.py). Pausing between reads
lets the frames gather in the kernel's tty buffer and come in one read; but the frame that
closes a step (the first of the next T-block) must be read as it arrives, because its arrival
is when the step can be published.

When can that frame arrive? Not before the block's end edge by the device clock (its device
time is at least that), plus the delay between a frame's device time and its arrival. That
delay is at least the smallest lag seen so far between a frame's device time and the moment
it was in hand (an upper bound of each frame's delay, so their minimum is close to the true
delay of a promptly read frame). Late or bursty delivery (a busy writer, USB latency timers)
only makes lags larger, so it never moves the estimate later. The estimate may creep later by
``drift`` seconds per second, so that a device clock slower than the host's is followed; a
faster one gives smaller lags at once.

:class:`ReadPacer` turns that into a pause: until ``guard_s`` before the earliest arrival of the
closing frame, never longer than ``max_pause_s``, and never longer than ``max_frames`` sample
intervals: at high frame rates a long pause would fill the tty layer's 4 KB buffer, which
blocks a pty's writer (and so delays the frames behind it) and risks overruns on a real port.
"""

from __future__ import annotations

import math

__all__ = ["ReadPacer"]


class ReadPacer:
    """Pauses between reads of the port (see the module doc). Times in seconds: ``now`` on
    the host's monotonic clock, device times unwrapped (:class:`hdrd.io.wire.clocks.DeviceClock`).

    max_pause_s: longest pause. guard_s: margin before the closing frame's earliest arrival.
    drift: how fast (s/s) the delay estimate may grow between observations. max_frames: most
    sample intervals in a pause (128 hdr-bin frames are 2 KB, half the tty buffer).
    """

    __slots__ = ("_lag", "_lag_at", "drift", "guard_s", "max_frames", "max_pause_s")

    def __init__(
        self,
        max_pause_s: float = 0.02,
        guard_s: float = 0.002,
        drift: float = 2e-4,
        max_frames: int = 128,
    ) -> None:
        if not (max_pause_s >= 0 and guard_s >= 0 and drift >= 0 and max_frames >= 0):
            raise ValueError("max_pause_s, guard_s, drift and max_frames must be >= 0")
        self.max_pause_s = max_pause_s
        self.guard_s = guard_s
        self.drift = drift
        self.max_frames = max_frames
        self._lag = math.inf
        self._lag_at = 0.0

    def reset(self) -> None:
        """The device clock started over (a reconnection): forget the delay."""
        self._lag = math.inf

    @property
    def lag_s(self) -> float:
        """The delay estimate: smallest (host time - device time) seen, s (inf: none yet)."""
        return self._lag

    def pause(
        self,
        in_hand_s: float,
        t_dev_s: float,
        until_step_s: float | None,
        now_s: float,
        interval_s: float | None = None,
    ) -> float:
        """Seconds to wait before reading again (0: read now).

        in_hand_s: host time at which the newest frame read was in hand; t_dev_s: its device
        time. until_step_s: :meth:`hdrd.daemon.pipeline.Pipeline.until_step_s` after it (device
        seconds from it to the earliest step-closing sample, or None: unknown). now_s: host
        time now. interval_s: the sample interval, device s
        (:meth:`hdrd.daemon.pipeline.Pipeline.sample_interval_s`; None: unknown, no frame limit).
        """
        lag = in_hand_s - t_dev_s
        grown = self._lag + self.drift * (in_hand_s - self._lag_at)
        self._lag = min(lag, grown)
        self._lag_at = in_hand_s
        if until_step_s is None:
            return 0.0
        due = t_dev_s + until_step_s + self._lag  # earliest arrival of the closing frame
        p = due - self.guard_s - now_s
        if interval_s is not None:
            p = min(p, self.max_frames * interval_s)
        if p <= 0.001:  # not worth a sleep
            return 0.0
        return min(p, self.max_pause_s)
