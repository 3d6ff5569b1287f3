"""GPS aiding of the HDR heading, pure: mode, heading alignment and bias learning.

hdrd's heading is dead reckoning: heading = (heading0 - yaw) mod 360, yaw the integral of the
drift-reduced rate (paper Eq. 3). With a GPS (through gpsd, :mod:`hdrd.gpsd`) the course over
ground is an absolute heading whenever the vehicle moves fast enough for it to mean
something. :class:`GpsAiding` uses it two ways, and says which mode it is in:

``"aided"`` while the latest fix is good: 2D/3D (``mode >= 2``), a course and a speed of at
least ``min_speed_mps``, a course error estimate (``epd``, when sent) within
``max_epd_deg``, and fresh (received within ``max_fix_age_s``). Then

- **alignment**: the published heading is the HDR heading plus an offset, compass degrees,
  ``heading = (heading_hdr + offset) mod 360``. The first good fix sets the offset at once;
  afterwards each step moves it by ``align_gain`` times the heading error (wrapped to
  [-180, 180)), and only while the rate is below ``align_max_rate_dps`` (in a turn the
  fix's course lags by its latency). The course is carried forward to the step by the
  gyro over the fix's age: ``course - omega * age`` (omega + CCW turns the compass
  course down).
- **bias learning**: over windows of ``bias_window_s`` of straight driving (|omega| at
  each step and the window's mean GPS course rate within ``straight_max_dps``, no course
  jump over ``max_course_step_deg``), the gyro's yaw change with only
  the static bias removed, ``sum((omega_raw - bias) * dt)`` (deg, CCW), is compared with
  the GPS's, ``-(course change)`` (compass course is CW): the difference over the window's
  length is the error of the static bias eps0 (deg/s, paper Eq. 2). ``bias_gain`` times it
  (at most ``max_bias_step_dps``) is returned for ``Pipeline.adjust_bias(delta, "gps")``;
  a window whose estimate exceeds ``max_residual_dps`` is discarded (a GPS glitch, a skid).
  Learning eps0 rather than correcting HDR's output leaves the I-controller (Eqs. 4, 9) to
  do its job during outages with the best static bias known; HDR's I then relaxes to 0.

``"dead-reckoning"`` otherwise (no fix, a tunnel, standing at a light, gpsd gone): the
heading continues from the last alignment, carried by the HDR yaw, and nothing is learned.

Messages are the pipeline's dicts (docs/protocol.md); keys are only added or, for
``heading``, replaced by the aligned value: ``mode``; ``heading_offset`` (deg, once
aligned); ``gps_course`` (deg, while aided) and ``gps_speed`` (m/s, with a fresh fix).
A message without a heading (calibrating) passes unchanged. Time ``now`` is any monotonic
clock in seconds, passed in by the caller; fixes are stamped with it when received.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

__all__ = ["AIDED", "DEAD_RECKONING", "AidingConfig", "FixLike", "GpsAiding", "wrap180"]

AIDED = "aided"
DEAD_RECKONING = "dead-reckoning"


def wrap180(deg: float) -> float:
    """An angle difference wrapped to [-180, 180), deg."""
    return (deg + 180.0) % 360.0 - 180.0


def _compass(deg: float) -> float:
    h = deg % 360.0
    return 0.0 if h >= 360.0 else h


class FixLike(Protocol):
    """What aiding reads from a gpsd fix (:class:`hdrd.gpsd.Fix`)."""

    @property
    def mode(self) -> int: ...
    @property
    def track_deg(self) -> float | None: ...
    @property
    def speed_mps(self) -> float | None: ...
    @property
    def epd(self) -> float | None: ...


@dataclass(frozen=True, slots=True)
class AidingConfig:
    """Thresholds and gains of :class:`GpsAiding` (units in the names)."""

    min_speed_mps: float = 5.0
    """GPS course is trusted at or above this ground speed (config ``gpsd.min_speed_mps``)."""
    max_fix_age_s: float = 2.5
    """A fix older than this (since received) is stale: two missed 1 Hz fixes."""
    max_epd_deg: float = 15.0
    """Course error estimate (gpsd ``epd``, 95 %) above which the course is not used."""
    step_s: float = 1.0
    """HDR step period T, s (paper: 1 s); a step interval off by more than half of it
    (a gap) restarts the bias window."""
    align_gain: float = 0.2
    """Fraction of the heading error removed per step while aided (time constant ~5 steps)."""
    align_max_rate_dps: float = 3.0
    """No alignment update while |omega| exceeds this (the fix's latency matters in turns)."""
    bias_window_s: float = 20.0
    """Straight-driving window over which one bias estimate is made, s."""
    bias_gain: float = 0.3
    """Fraction of a window's bias estimate applied."""
    straight_max_dps: float = 1.0
    """Straight: |omega| at every step, and the GPS course change over the window divided
    by its length, at most this, deg/s."""
    max_course_step_deg: float = 3.0
    """A larger GPS course change from one step to the next restarts the window (a jump)."""
    max_residual_dps: float = 1.0
    """A window estimate beyond this is discarded as a glitch, deg/s."""
    max_bias_step_dps: float = 0.1
    """Largest correction applied at once, deg/s."""

    def __post_init__(self) -> None:
        for name in (
            "min_speed_mps",
            "max_fix_age_s",
            "max_epd_deg",
            "step_s",
            "bias_window_s",
            "straight_max_dps",
            "max_residual_dps",
            "max_bias_step_dps",
            "align_max_rate_dps",
            "max_course_step_deg",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0) or (
                name in ("step_s", "max_fix_age_s", "bias_window_s") and v == 0
            ):
                raise ValueError(
                    f"AidingConfig.{name} must be a finite number >= 0 (> 0 for step_s, max_fix_age_s, bias_window_s), got {v!r}"
                )
        for name in ("align_gain", "bias_gain"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"AidingConfig.{name} must be in [0, 1], got {v!r}")


class GpsAiding:
    """Turns the pipeline's messages into GPS-aided ones (see the module doc). Pure.

    ``on_fix(fix, now)`` for each fix received; ``on_message(msg, now) -> (msg, delta)`` for
    each message before publishing, delta (deg/s) to add to the static bias (0.0: none);
    ``speed(now)`` the fresh GPS ground speed for ``Pipeline.set_speed``.
    """

    def __init__(self, config: AidingConfig = AidingConfig()) -> None:
        self.config = config
        self._fix: FixLike | None = None  # the latest TPV: fix or no fix
        self._fix_at = -math.inf
        self._course_fix: FixLike | None = None  # the latest 2D/3D TPV with course and speed
        self._course_at = -math.inf
        self._speed: float | None = None  # the latest 2D/3D TPV's speed
        self._speed_at = -math.inf
        self.offset_deg: float | None = None
        """Added to the HDR heading (compass deg), None until the first alignment."""
        self.mode = DEAD_RECKONING
        self.bias_learned_dps = 0.0
        """Sum of the corrections returned so far, deg/s."""
        self.windows = 0
        """Bias windows completed (applied or discarded)."""
        self.windows_discarded = 0
        self._prev_t: float | None = None
        self._prev_course: float | None = None
        self._win_dt = 0.0
        self._win_yaw = 0.0  # gyro yaw change, static bias removed, deg CCW
        self._win_course = 0.0  # GPS course change, unwrapped, deg CW

    # -- inputs --
    def on_fix(self, fix: FixLike, now: float) -> None:
        """A TPV report received at ``now`` (s, the caller's monotonic clock).

        A TPV without a course (gpsd reports one per sentence until it has found the
        receiver's cycle end, e.g. after a GGA and again after the RMC) does not hide the
        course of an earlier fix that is still fresh; a TPV without a fix (mode < 2) ends
        aiding at once. A negative or non-finite speed is treated as no speed (the fix
        gives neither a speed nor a course).
        """
        self._fix, self._fix_at = fix, now
        spd = fix.speed_mps
        # A ground speed is a magnitude: a negative (or non-finite) one is no speed at all,
        # never a standstill (it would let a zero-rate update fire while the car moves).
        if fix.mode >= 2 and spd is not None and math.isfinite(spd) and spd >= 0.0:
            self._speed, self._speed_at = fix.speed_mps, now
            if fix.track_deg is not None and math.isfinite(fix.track_deg):
                self._course_fix, self._course_at = fix, now

    def _has_fix(self, now: float) -> bool:
        f = self._fix
        return f is not None and f.mode >= 2 and now - self._fix_at <= self.config.max_fix_age_s

    def good_fix(self, now: float) -> FixLike | None:
        """The fix to align to, if good enough (see the module doc), else None."""
        c = self.config
        f = self._course_fix
        if f is None or not self._has_fix(now) or now - self._course_at > c.max_fix_age_s:
            return None
        assert f.speed_mps is not None
        if f.speed_mps < c.min_speed_mps or (f.epd is not None and f.epd > c.max_epd_deg):
            return None
        return f

    def speed(self, now: float) -> float | None:
        """Ground speed of a fresh 2D/3D fix, m/s; None when unknown."""
        if not self._has_fix(now) or now - self._speed_at > self.config.max_fix_age_s:
            return None
        return self._speed

    # -- per message --
    def on_message(self, msg: dict[str, Any], now: float) -> tuple[dict[str, Any], float]:
        """The message as published (a new dict) and the bias correction to apply, deg/s."""
        if "heading" not in msg:
            return msg, 0.0
        out = dict(msg)
        h_hdr = float(msg["heading"])
        is_step = "omega" in msg
        omega = float(msg["omega"]) if is_step else 0.0
        fix = self.good_fix(now)
        course: float | None = None
        if fix is not None:
            assert fix.track_deg is not None
            age = max(0.0, now - self._course_at)
            course = _compass(fix.track_deg - omega * age)
            if self.offset_deg is None:
                self.offset_deg = wrap180(course - h_hdr)
            elif is_step and abs(omega) <= self.config.align_max_rate_dps:
                err = wrap180(course - (h_hdr + self.offset_deg))
                self.offset_deg = wrap180(self.offset_deg + self.config.align_gain * err)
            self.mode = AIDED
        else:
            self.mode = DEAD_RECKONING
        if self.offset_deg is not None:
            out["heading"] = _compass(h_hdr + self.offset_deg)
            out["heading_offset"] = self.offset_deg
        out["mode"] = self.mode
        if fix is not None:
            out["gps_course"] = fix.track_deg
        spd = self.speed(now)
        if spd is not None:
            out["gps_speed"] = spd
        delta = self._learn(msg, course) if is_step else 0.0
        return out, delta

    # -- bias learning --
    def _restart_window(self, t: float | None, course: float | None) -> None:
        self._prev_t, self._prev_course = t, course
        self._win_dt = self._win_yaw = self._win_course = 0.0

    def _learn(self, msg: dict[str, Any], course: float | None) -> float:
        c = self.config
        t = msg.get("t")
        raw, bias = msg.get("omega_raw"), msg.get("bias")
        if course is None or t is None or raw is None or bias is None or "gap_s" in msg:
            self._restart_window(None, None)
            return 0.0
        t = float(t)
        if self._prev_t is None or self._prev_course is None:
            self._restart_window(t, course)
            return 0.0
        dt = t - self._prev_t
        dcourse = wrap180(course - self._prev_course)
        straight = (
            abs(float(msg["omega"])) <= c.straight_max_dps and abs(dcourse) <= c.max_course_step_deg
        )
        if not (abs(dt - c.step_s) <= 0.5 * c.step_s and straight):
            self._restart_window(t, course)
            return 0.0
        self._prev_t, self._prev_course = t, course
        self._win_dt += dt
        self._win_yaw += (float(raw) - float(bias)) * dt
        self._win_course += dcourse
        if self._win_dt < c.bias_window_s - 1e-9:
            return 0.0
        # gyro yaw change (CCW) minus the true one (-course change): the static bias error
        window_s, course_rate = self._win_dt, self._win_course / self._win_dt
        residual = (self._win_yaw + self._win_course) / window_s
        self._restart_window(t, course)
        self.windows += 1
        if abs(residual) > c.max_residual_dps or abs(course_rate) > c.straight_max_dps:
            self.windows_discarded += 1
            return 0.0
        delta = float(max(-c.max_bias_step_dps, min(c.max_bias_step_dps, c.bias_gain * residual)))
        self.bias_learned_dps += delta
        return delta
