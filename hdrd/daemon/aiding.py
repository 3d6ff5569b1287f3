"""GPS aiding of the heading, pure: the mode, the heading's alignment to the GPS course, and
the bias learned from it (docs/gps-aiding.md is the reference).

:class:`GpsAiding` is ``"aided"`` while the latest fix is good (2D/3D, fast enough, its
course error within bounds, fresh) and ``"dead-reckoning"`` otherwise. Aided, the published
heading is the method's plus an offset aligned to the course, and for ``none`` and paper
``hdr`` the static bias is learned over straight windows; a method that owns the heading
(HDR+) is instead handed each good course as a measurement (:class:`HeadingFix`). Every
course passes a gate around the heading the gyro predicts; rejections that agree, across
steps, realign; one receiver is followed. A stage of the pipeline
(:class:`hdrd.daemon.stepper.Stepper`): it sees each step as a :class:`StepView` and answers
with an :class:`Aid`. Time ``now`` is any monotonic clock (s) the caller passes; events for
the log go to :attr:`GpsAiding.events` for the caller to log and clear.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

from hdrd.core.angles import compass, wrap180
from hdrd.daemon.biaswindow import StraightWindows

__all__ = [
    "AIDED",
    "DEAD_RECKONING",
    "Aid",
    "AidingConfig",
    "FixLike",
    "GpsAiding",
    "HeadingFix",
    "StepView",
]

AIDED = "aided"
DEAD_RECKONING = "dead-reckoning"


@dataclass(frozen=True, slots=True)
class _NoFix:
    """A TPV refused as a fix: what aiding keeps of it (the receiver that sent it)."""

    device: str | None
    mode: int = 0
    track_deg: float | None = None
    speed_mps: float | None = None
    epd: float | None = None
    eps: float | None = None


class FixLike(Protocol):
    """What aiding reads from a gpsd fix (:class:`hdrd.io.net.gpsdjson.Fix`)."""

    @property
    def mode(self) -> int: ...
    @property
    def track_deg(self) -> float | None: ...
    @property
    def speed_mps(self) -> float | None: ...
    @property
    def epd(self) -> float | None: ...
    @property
    def eps(self) -> float | None: ...
    @property
    def device(self) -> str | None: ...


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
    default_course_err_deg: float = 5.0
    """A fix's course error (95 %, deg) when it gives neither ``epd`` nor ``eps``."""
    default_speed_err_mps: float = 0.5
    """A fix's ground-speed error (95 %, m/s) when it gives neither ``epd`` nor ``eps``, for
    the variance of its course as a measurement (:meth:`GpsAiding.course_var`)."""
    gate_min_deg: float = 5.0
    """The gate is never narrower than this, deg."""
    gate_max_deg: float = 30.0
    """The gate is never wider than this, deg. Once the drift allowance alone reaches it
    (``gate_max_deg / max_drift_dps`` without a course accepted: 300 s) the gap is long: a
    course is taken again only when ``realign_after`` in a row agree with one another."""
    max_drift_dps: float = 0.1
    """How fast the gyro heading may drift from the truth, deg/s: the gate widens by this
    times the time since the last course accepted (after a 2-minute outage, by 12 deg)."""
    latency_s: float = 0.5
    """A fix's latency that the gyro's carrying-forward may miss, s: the gate widens by
    ``|omega|`` times this in a turn."""
    realign_after: int = 3
    """Rejections in a row that agree with one another after which the offset is set to the
    GPS course (the gyro heading is what is wrong)."""
    device: str | None = None
    """The receiver to follow (gpsd's TPV ``device``, e.g. ``/dev/ttyUSB0``); None: the
    first that reports a fix."""
    device_timeout_s: float = 10.0
    """A followed receiver (not a configured one) without a fix for this long hands over to
    another that has one, s."""
    max_speed_mps: float = 150.0
    """A ground speed beyond this is no car's (540 km/h, beyond any road vehicle's top
    speed): the TPV is refused as a fix, m/s."""
    max_lateral_mps2: float = 10.0
    """The largest lateral acceleration a car turns with (about 1 g, the grip of a dry road),
    m/s^2: at ground speed v the course turns at most by this / v rad/s; two courses of one
    step further apart than that (and their errors) disagree."""

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
            "default_course_err_deg",
            "default_speed_err_mps",
            "gate_min_deg",
            "gate_max_deg",
            "max_drift_dps",
            "latency_s",
            "device_timeout_s",
            "max_speed_mps",
            "max_lateral_mps2",
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
        if self.gate_max_deg < self.gate_min_deg:
            raise ValueError(
                f"AidingConfig.gate_max_deg ({self.gate_max_deg!r}) must be >= gate_min_deg "
                f"({self.gate_min_deg!r})"
            )
        if isinstance(self.realign_after, bool) or not (
            isinstance(self.realign_after, int) and self.realign_after >= 1
        ):
            raise ValueError(
                f"AidingConfig.realign_after must be an integer >= 1, got {self.realign_after!r}"
            )


@dataclass(frozen=True, slots=True)
class StepView:
    """What the aiding sees of a step, before its message is built.

    t: device time at the step's end, s. omega_dps: the method's corrected rate, deg/s CCW (0
    for a report that is not a step). raw_dps: the step's raw block mean, deg/s CCW. bias_dps:
    the bias in force (the static bias and the method's correction), deg/s. heading_deg: the
    compass heading of the method's yaw, deg. gap: samples were missing before the step.
    step: a new step (False: a report of the held heading, e.g. while the gyro is silent).
    """

    t: float
    omega_dps: float
    raw_dps: float
    bias_dps: float
    heading_deg: float
    gap: bool = False
    step: bool = True


class HeadingFix(NamedTuple):
    """A GPS course's measurement for a method that owns the heading error (HDR+).

    err_deg: the published heading minus the course at the step's end, compass deg wrapped to
    [-180, 180). var_deg2: its variance. reset: the heading was aligned (anew) at this step:
    its error restarts at 0 with this variance.
    """

    err_deg: float
    var_deg2: float
    reset: bool


@dataclass(frozen=True, slots=True)
class Aid:
    """What the aiding says of a step (:meth:`GpsAiding.on_step`).

    mode: ``aided`` or ``dead-reckoning``. heading_deg: the heading to publish, compass deg
    (the method's plus the offset; None before the first alignment). offset_deg: the offset.
    course_deg: the course of the good fix in use (None while not aided). course_age_s: s since
    the last course was received (None before one). speed_mps: the ground speed of a fresh
    fix. bias_delta_dps: a correction to the static bias, deg/s, for a method that does not
    estimate the bias itself. fix: the measurement for one that does (None: none this step).
    """

    mode: str
    heading_deg: float | None
    offset_deg: float | None
    course_deg: float | None
    course_age_s: float | None
    speed_mps: float | None
    bias_delta_dps: float = 0.0
    fix: HeadingFix | None = None


class GpsAiding:
    """GPS aiding as a stage of the pipeline (see the module doc). Pure.

    ``on_fix(fix, now)`` for each fix received; ``on_step(view, now, owner) -> Aid`` for each
    step (and held-heading report) before its message is built; ``speed(now)`` the fresh GPS
    ground speed for the standstill detection.
    """

    def __init__(self, config: AidingConfig = AidingConfig()) -> None:
        self.config = config
        self._fix: FixLike | None = None  # the latest TPV: fix or no fix
        self._fix_at = -math.inf
        self._course_fix: FixLike | None = None  # the latest 2D/3D TPV with course and speed
        self._course_at = -math.inf
        self._course_seq = 0  # +1 per course received; the gate judges each once
        self._judged_seq = 0
        self._course_ok = False  # the gate's verdict on the latest course
        self._speed: float | None = None  # the latest 2D/3D TPV's speed
        self._speed_at = -math.inf
        self.offset_deg: float | None = None
        """Added to the HDR heading (compass deg), None until the first alignment."""
        self.mode = DEAD_RECKONING
        self.learning = StraightWindows()
        """The baselines' bias learning over windows of straight driving."""
        self.device: str | None = config.device
        """The receiver followed (TPV ``device``); None until one has reported a fix."""
        self._following = config.device is not None
        self._device_fix_at = -math.inf  # when the followed receiver last reported a fix
        self.fixes_ignored = 0
        """TPVs from receivers not followed."""
        self.courses_rejected = 0
        """Courses the gate rejected."""
        self.realignments = 0
        """Offsets set anew after ``realign_after`` agreeing rejections."""
        self.fixes_refused = 0
        """TPVs refused as fixes: a ground speed beyond ``max_speed_mps``."""
        self.courses_disagreeing = 0
        """Steps whose courses disagreed with one another (none of them used)."""
        self._step_course: tuple[FixLike, float] | None = None  # the last course this step
        self._disagree: tuple[float, float] | None = None  # this step's: (spread, allowed) deg
        self._accepted_at = -math.inf  # when the gate last accepted a course
        self._realigned = False  # the offset was set anew since the last step
        self._streak: list[float] = []  # the implied offsets of the rejections in a row
        self.events: list[tuple[str, dict[str, Any]]] = []
        """``(name, fields)`` for the log: gps_device, gps_course_rejected, gps_realigned."""

    # -- inputs --
    def _follows(self, fix: FixLike, now: float) -> bool:
        """Whether ``fix`` comes from the receiver followed (see the module doc); picks one
        when none is followed yet, or when the followed one has gone quiet."""
        dev = fix.device
        has_fix = fix.mode >= 2
        if self._following and dev == self.device:
            return True
        if self.config.device is not None:
            return False  # a configured receiver only
        quiet = now - self._device_fix_at > self.config.device_timeout_s
        if has_fix and (not self._following or quiet):
            was = self.device if self._following else None
            self.device, self._following = dev, True
            fields: dict[str, Any] = {"device": dev}
            if was is not None or dev is None:
                fields["previous"] = was
            self.events.append(("gps_device", fields))
            return True
        return not self._following  # no fix and nobody followed yet: harmless either way

    def on_fix(self, fix: FixLike, now: float) -> None:
        """A TPV report received at ``now`` (s, the caller's monotonic clock).

        A report from a receiver that is not followed is ignored (counted). A TPV without a
        course (gpsd reports one per sentence until it has found the receiver's cycle end,
        e.g. after a GGA and again after the RMC) does not hide the course of an earlier fix
        that is still fresh; a TPV without a fix (mode < 2) ends aiding at once. A negative
        or non-finite speed is treated as no speed (the fix gives neither a speed nor a
        course).
        """
        spd = fix.speed_mps
        if fix.mode >= 2 and spd is not None and spd > self.config.max_speed_mps:
            self.fixes_refused += 1
            self.events.append(
                (
                    "gps_fix_refused",
                    {
                        "speed_mps": spd,
                        "max_speed_mps": self.config.max_speed_mps,
                        "device": fix.device,
                    },
                )
            )
            fix = _NoFix(fix.device)  # no car goes so fast: not a fix, whatever else it says
        if not self._follows(fix, now):
            self.fixes_ignored += 1
            return
        self._fix, self._fix_at = fix, now
        if fix.mode >= 2:
            self._device_fix_at = now
        spd = fix.speed_mps
        # A ground speed is a magnitude: a negative (or non-finite) one is no speed at all,
        # never a standstill (it would let a zero-rate update fire while the car moves).
        if fix.mode >= 2 and spd is not None and math.isfinite(spd) and spd >= 0.0:
            self._speed, self._speed_at = fix.speed_mps, now
            if fix.track_deg is not None and math.isfinite(fix.track_deg):
                self._course_fix, self._course_at = fix, now
                self._course_seq += 1
                self._compare_in_step(fix, now)

    def _compare_in_step(self, fix: FixLike, now: float) -> None:
        """A course received at ``now`` against the one received before it in the same step:
        further apart than a car turns in between (``max_lateral_mps2`` at the lower of their
        speeds), plus twice their errors, and at least ``gate_max_deg``, they disagree."""
        prev, self._step_course = self._step_course, (fix, now)
        if prev is None:
            return
        pf, at = prev
        c = self.config
        assert pf.speed_mps is not None and fix.speed_mps is not None
        assert pf.track_deg is not None and fix.track_deg is not None
        v = min(pf.speed_mps, fix.speed_mps)
        if v <= 0.0 or v < c.min_speed_mps:
            return  # courses aiding does not use
        turn = math.degrees(c.max_lateral_mps2 / v) * max(0.0, now - at)
        err = self.course_err_deg(pf) + self.course_err_deg(fix)
        allowed = max(c.gate_max_deg, turn + 2.0 * err)
        spread = abs(wrap180(fix.track_deg - pf.track_deg))
        if spread > allowed and (self._disagree is None or spread > self._disagree[0]):
            self._disagree = (spread, allowed)

    def _has_fix(self, now: float) -> bool:
        f = self._fix
        return f is not None and f.mode >= 2 and now - self._fix_at <= self.config.max_fix_age_s

    def good_fix(self, now: float) -> FixLike | None:
        """The fix to align to, if good enough (see the module doc; the gate aside), else
        None."""
        c = self.config
        f = self._course_fix
        if f is None or not self._has_fix(now) or now - self._course_at > c.max_fix_age_s:
            return None
        assert f.speed_mps is not None
        if f.speed_mps < c.min_speed_mps or self.course_err_deg(f) > c.max_epd_deg:
            return None  # too slow, or a course error (however known) above max_epd_deg
        return f

    def course_err_deg(self, fix: FixLike) -> float:
        """The fix's course error, 95 %, deg: ``epd``; else from the speed error,
        ``atan(eps / speed)``; else ``default_course_err_deg``."""
        if fix.epd is not None and math.isfinite(fix.epd):
            return float(fix.epd)
        spd = fix.speed_mps
        if fix.eps is not None and math.isfinite(fix.eps) and spd is not None and spd > 0.0:
            return math.degrees(math.atan2(fix.eps, spd))
        return self.config.default_course_err_deg

    def gate_deg(self, fix: FixLike, omega_dps: float, now: float) -> float:
        """The largest innovation (deg) a course from ``fix`` may have at ``now``, the
        yaw rate being ``omega_dps`` (see the module doc)."""
        c = self.config
        width = (
            self.course_err_deg(fix)
            + c.max_drift_dps * self._since_accepted(now)
            + abs(omega_dps) * c.latency_s
        )
        return min(c.gate_max_deg, max(c.gate_min_deg, width))

    def _since_accepted(self, now: float) -> float:
        """Seconds since the gate last accepted a course (0 before the first)."""
        return max(0.0, now - self._accepted_at) if math.isfinite(self._accepted_at) else 0.0

    def long_gap(self, now: float) -> bool:
        """No course accepted for so long that the gate has stopped widening (the drift
        allowance alone has reached ``gate_max_deg``): one course is not enough to re-acquire."""
        c = self.config
        return c.max_drift_dps * self._since_accepted(now) >= c.gate_max_deg

    def _judge(self, fix: FixLike, course: float, h_hdr: float, omega: float, now: float) -> bool:
        """The gate's verdict on a new course (True: use it); a run of agreeing courses that
        the gate rejected, or any run after a long gap, sets the offset anew."""
        if self.offset_deg is None:  # nothing to test against yet: the first course aligns
            self._accept(now)
            return True
        innovation = wrap180(course - (h_hdr + self.offset_deg))
        gate = self.gate_deg(fix, omega, now)
        long_gap = self.long_gap(now)
        if abs(innovation) <= gate and not long_gap:
            self._accept(now)
            return True
        implied = wrap180(course - h_hdr)  # the offset this course asks for
        own = max(
            self.config.gate_min_deg, self.course_err_deg(fix) + abs(omega) * self.config.latency_s
        )
        if self._streak and abs(wrap180(implied - self._streak[-1])) > own:
            self._streak.clear()  # it disagrees with the courses before it: a new run
        self._streak.append(implied)
        self.courses_rejected += 1
        fields: dict[str, Any] = {
            "course": fix.track_deg,
            "innovation_deg": round(innovation, 2),
            "gate_deg": round(gate, 2),
            "in_a_row": len(self._streak),
        }
        if long_gap:
            fields["long_gap_s"] = round(self._since_accepted(now), 1)
        self.events.append(("gps_course_rejected", fields))
        if len(self._streak) < self.config.realign_after:
            return False
        old = self.offset_deg
        self.offset_deg = implied
        self._realigned = True
        self.realignments += 1
        self._accept(now)
        realigned: dict[str, Any] = {
            "offset_deg": round(implied, 2),
            "previous_offset_deg": round(old, 2),
        }
        if long_gap:
            realigned["reason"] = "re-acquired after a long gap"
        self.events.append(("gps_realigned", realigned))
        return True

    def _accept(self, now: float) -> None:
        self._accepted_at = now
        self._streak.clear()

    def speed(self, now: float) -> float | None:
        """Ground speed of a fresh 2D/3D fix, m/s; None when unknown."""
        if not self._has_fix(now) or now - self._speed_at > self.config.max_fix_age_s:
            return None
        return self._speed

    # -- per step --
    def on_step(self, view: StepView, now: float, owner: bool = False) -> Aid:
        """What the aiding says of a step (:class:`Aid`), before its message is built; ``now``
        the aiding's clock, s. owner: the method estimates the bias and the heading error
        itself (HDR+: the heading is aligned once, then each good course is a measurement
        for it, :class:`HeadingFix`); else (none, paper HDR) the offset follows the course
        and a learned bias correction is returned for the static bias (the baselines)."""
        h_hdr = view.heading_deg
        fix, course = self._trusted_course(h_hdr, view.omega_dps, now)
        reset, self._realigned = self._realigned, False  # the gate set the offset anew
        heading_fix: HeadingFix | None = None
        if fix is not None and course is not None:
            if self.offset_deg is None:
                self.offset_deg = wrap180(course - h_hdr)
                reset = True
            elif view.step and abs(view.omega_dps) <= self.config.align_max_rate_dps:
                err = wrap180(course - (h_hdr + self.offset_deg))
                if owner:
                    heading_fix = HeadingFix(-err, self.course_var(fix, view.omega_dps), False)
                else:
                    self.offset_deg = wrap180(self.offset_deg + self.config.align_gain * err)
            self.mode = AIDED
        else:
            self.mode = DEAD_RECKONING
        if reset and owner:  # the heading's error restarts, known to the course's
            var = self.course_var(fix, view.omega_dps) if fix is not None else math.nan
            heading_fix = HeadingFix(0.0, var, True)
        learn = view.step and not owner
        delta = self.learning.learn(view, course, self.config) if learn else 0.0
        return Aid(
            mode=self.mode,
            heading_deg=None if self.offset_deg is None else compass(h_hdr + self.offset_deg),
            offset_deg=self.offset_deg,
            course_deg=fix.track_deg if fix is not None else None,
            course_age_s=round(max(0.0, now - self._course_at), 3)
            if math.isfinite(self._course_at)
            else None,
            speed_mps=self.speed(now),
            bias_delta_dps=delta,
            fix=heading_fix,
        )

    def course_var(self, fix: FixLike, omega_dps: float) -> float:
        """A course's variance as a measurement of the heading, deg^2: its error (95 %, / 1.96:
        ``epd``; else from the speed error, ``atan(eps / speed)``, with ``eps`` at most
        ``default_speed_err_mps`` when the fix gives none: a course is better the faster the
        vehicle; at most ``default_course_err_deg``) and, in a turn, the latency the
        carrying-forward may miss (``|omega| x latency_s``)."""
        c = self.config
        err = self.course_err_deg(fix)
        spd = fix.speed_mps
        if fix.epd is None and fix.eps is None and spd is not None and spd > 0.0:
            err = min(err, math.degrees(math.atan2(c.default_speed_err_mps, spd)))
        sd = err / 1.96
        lag = abs(omega_dps) * self.config.latency_s
        return sd * sd + lag * lag

    def _trusted_course(
        self, h_hdr: float, omega: float, now: float
    ) -> tuple[FixLike | None, float | None]:
        """The good fix and its course carried forward to ``now`` with the yaw rate
        (compass deg), each new course judged once against HDR's heading; (None, None) when
        there is no good fix or its course was judged wrong."""
        if self._step_disagreed():
            return None, None
        fix = self.good_fix(now)
        course: float | None = None
        if fix is not None:
            assert fix.track_deg is not None
            age = max(0.0, now - self._course_at)
            course = compass(fix.track_deg - omega * age)
            if self._judged_seq != self._course_seq:
                self._judged_seq = self._course_seq
                self._course_ok = self._judge(fix, course, h_hdr, omega, now)
            if not self._course_ok:
                fix = course = None
        return fix, course

    def _step_disagreed(self) -> bool:
        """The courses received since the last step disagreed with one another: fixes faster
        than the step are not independent evidence, and ones that contradict each other are
        none at all. The step takes no course, the latest is not used, and a run of rejections
        that would realign starts again."""
        disagree, self._disagree = self._disagree, None
        self._step_course = None
        if disagree is None:
            return False
        self.courses_disagreeing += 1
        self._streak.clear()
        self._judged_seq, self._course_ok = self._course_seq, False
        spread, allowed = disagree
        self.events.append(
            (
                "gps_courses_disagree",
                {"spread_deg": round(spread, 2), "allowed_deg": round(allowed, 2)},
            )
        )
        return True

    # the bias learning's counters, read by tests and tools
    @property
    def windows(self) -> int:
        """Bias windows completed (applied or discarded)."""
        return self.learning.windows

    @property
    def windows_discarded(self) -> int:
        return self.learning.discarded

    @property
    def bias_learned_dps(self) -> float:
        """Sum of the corrections returned so far, deg/s."""
        return self.learning.learned_dps
