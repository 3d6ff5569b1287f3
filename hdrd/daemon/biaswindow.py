"""The baselines' bias learning from GPS, pure: over windows of straight driving the gyro's
yaw change with only the static bias removed is compared with the GPS course's change; the
difference over the window's length is the static bias's error (deg/s, paper Eq. 2), of which
``bias_gain`` (at most ``max_bias_step_dps``) is returned for the pipeline to add to the
static bias (docs/gps-aiding.md). Learning eps0 rather than correcting HDR's output leaves the
I-controller to do its job through outages with the best static bias known.
"""

from __future__ import annotations

from typing import Protocol

from hdrd.core.angles import wrap180

__all__ = ["StepLike", "StraightWindows", "WindowSettings"]


class WindowSettings(Protocol):
    """What the learning reads of the aiding's settings (:class:`~hdrd.daemon.aiding.AidingConfig`)."""

    @property
    def step_s(self) -> float: ...
    @property
    def straight_max_dps(self) -> float: ...
    @property
    def max_course_step_deg(self) -> float: ...
    @property
    def bias_window_s(self) -> float: ...
    @property
    def max_residual_dps(self) -> float: ...
    @property
    def max_bias_step_dps(self) -> float: ...
    @property
    def bias_gain(self) -> float: ...


class StepLike(Protocol):
    """What the learning reads of a step (:class:`~hdrd.daemon.aiding.StepView`)."""

    @property
    def t(self) -> float: ...
    @property
    def omega_dps(self) -> float: ...
    @property
    def raw_dps(self) -> float: ...
    @property
    def bias_dps(self) -> float: ...
    @property
    def gap(self) -> bool: ...


class StraightWindows:
    """Windows of straight driving, one step at a time (:meth:`learn`)."""

    def __init__(self) -> None:
        self.windows = 0
        """Windows completed (applied or discarded)."""
        self.discarded = 0
        """Windows whose estimate was too large, or whose course turned on the whole."""
        self.learned_dps = 0.0
        """Sum of the corrections returned so far, deg/s."""
        self._prev_t: float | None = None
        self._prev_course: float | None = None
        self._win_dt = 0.0
        self._win_yaw = 0.0  # gyro yaw change, static bias removed, deg CCW
        self._win_course = 0.0  # GPS course change, unwrapped, deg CW

    def _restart(self, t: float | None, course: float | None) -> None:
        self._prev_t, self._prev_course = t, course
        self._win_dt = self._win_yaw = self._win_course = 0.0

    def learn(self, view: StepLike, course: float | None, c: WindowSettings) -> float:
        """The static bias error a window of straight driving shows, times ``bias_gain``
        (deg/s; 0.0 until a window completes). ``course``: the step's trusted GPS course
        (compass deg; None: none); a step after a gap, or not straight, starts anew."""
        t = view.t
        if course is None or view.gap:
            self._restart(None, None)
            return 0.0
        if self._prev_t is None or self._prev_course is None:
            self._restart(t, course)
            return 0.0
        dt = t - self._prev_t
        dcourse = wrap180(course - self._prev_course)
        straight = (
            abs(view.omega_dps) <= c.straight_max_dps and abs(dcourse) <= c.max_course_step_deg
        )
        if not (abs(dt - c.step_s) <= 0.5 * c.step_s and straight):
            self._restart(t, course)
            return 0.0
        self._prev_t, self._prev_course = t, course
        self._win_dt += dt
        self._win_yaw += (view.raw_dps - view.bias_dps) * dt
        self._win_course += dcourse
        if self._win_dt < c.bias_window_s - 1e-9:
            return 0.0
        # gyro yaw change (CCW) minus the true one (-course change): the static bias error
        window_s, course_rate = self._win_dt, self._win_course / self._win_dt
        residual = (self._win_yaw + self._win_course) / window_s
        self._restart(t, course)
        self.windows += 1
        if abs(residual) > c.max_residual_dps or abs(course_rate) > c.straight_max_dps:
            self.discarded += 1
            return 0.0
        delta = float(max(-c.max_bias_step_dps, min(c.max_bias_step_dps, c.bias_gain * residual)))
        self.learned_dps += delta
        return delta
