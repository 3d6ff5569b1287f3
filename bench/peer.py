"""The course-aided Kalman filter of heading and bias that bench/outages.py and bench/holds.py
set beside hdrd's methods through GNSS outages: the peer (Groves, Principles of GNSS, Inertial,
and Multisensor Integrated Navigation Systems, 2nd ed., ch. 14: loosely coupled, one axis).

States: heading psi (compass deg, clockwise) and gyro bias b (deg/s, CCW, a random walk).
Each step of T s it predicts psi <- psi - (omega - b) T from the step's mean raw rate omega,
with a heading process noise of the step's own gyro noise, (sd T)^2 / n for n samples of
spread sd, and of its turn, (scale_sd x the angle turned)^2; a step after a gap in the log
(no samples for more than 1.5 T) leaves the heading where it was and its variance at
:data:`LOST_VAR` (the heading is not known across a gap; the bias is). Measurements:

- a GPS course (the step's newest fix, at or above the aiding's ``min_speed_mps``): z = the
  course, H = [1, 0], R = :meth:`hdrd.daemon.aiding.GpsAiding.course_var` as the daemon's aiding
  computes it (the speed's error over the speed, and in a turn |omega| x the fix's latency);
  an innovation beyond ``gate_sigma`` sigma is not used, and ``realign_after`` such in a row
  set the heading to the course (the filter, not the GPS, has lost it);
- a stop (the daemon's test, :func:`hdrd.core.standstill.standstill_candidate` with its
  defaults: the speed at most 0.3 m/s and the gyro agreeing, |omega - b| <= 1 deg/s, for 3
  steps in a row; a logged speed lags a car that already turns). The speed is the log's
  ``speed``, as a receiver reports it with or without a course, outside the outages only
  (:func:`hdrd.analysis.outages.run_outages` gives the daemon's methods a speed only with a
  course, and none at rest where a log has no course below 2 m/s). The heading does not move
  (no prediction) and the step's mean rate measures the bias, z = omega, H = [0, 1], R = the
  calibration's spread^2 / n + ``stop_sd_dps``^2.

In an outage there is no fix and no GPS speed: it predicts only. The outage's own end takes no
fix either (a fix at that instant is the first after it). bench/outages.py's docstring says
why the peer had diverged and which data tuned which setting.

Also here: the outages the benchmarks judge on (:func:`outage_plan`: several phases of the
grid, a shorter period on long drives) and :func:`plan_errors`, each method and the peer
through all of them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from hdrd.analysis.outages import (
    LogFix,
    OutageResult,
    OutageSpec,
    drive_fixes,
    outage_windows,
    run_outages,
)
from hdrd.analysis.prepare import EvaluationError, PreparedDrive
from hdrd.core.angles import wrap180
from hdrd.core.methods import MethodSetup
from hdrd.core.standstill import StopDetection, standstill_candidate
from hdrd.daemon.aiding import AidingConfig, GpsAiding
from hdrd.io.files.drivelog import DriveLog

LOST_VAR = 90.0**2
"""The heading's variance after a gap in the log, deg^2: lost, so the next course sets it
(its gain ~1) without moving the bias."""


@dataclass(frozen=True)
class PeerParams:
    """The Kalman peer's settings (units in the names); the defaults are the tuned ones
    (bench/outages.py's docstring says which data tuned which)."""

    point_sd_dps: float = 1.0
    """The rate noise of a lone sample while driving, deg/s: the heading noise of a step of a
    point-sampled gyro (one sample per step: vibration and the yaw between samples are not
    averaged out) is (point_sd_dps x T)^2. A step of several samples uses their spread."""
    scale_sd: float = 0.02
    """Heading noise per degree turned (scale-factor error), 1 sigma, fraction."""
    bias_q: float = 3e-6
    """The bias's random walk, (deg/s)^2/s."""
    bias0_sd_dps: float = 0.02
    """The start-up calibration's bias uncertainty, deg/s (at least the sd of its mean)."""
    stop_sd_dps: float = 0.1
    """The yaw rate of a standing car (the engine rocking it, a logged speed that lags its
    start), 1 sigma, deg/s: a stop's noise as a measurement of the bias beside the gyro's own."""
    gate_sigma: float = 4.0
    """A course whose innovation is beyond this many sigma is not used ..."""
    realign_after: int = 5
    """... and after this many such in a row the heading is set to the course (its variance
    to the course's; the bias kept)."""


SWEEP: dict[str, tuple[float, ...]] = {
    "point_sd_dps": (0.5, 2.0),
    "scale_sd": (0.0, 0.05),
    "bias_q": (1e-6, 1e-5),
    "stop_sd_dps": (0.05, 0.2),
    "bias0_sd_dps": (0.01, 0.05, 0.1),
    "gate_sigma": (3.0, 5.0),
    "realign_after": (3, 10, 10**9),
}
"""What ``--tune-peer`` tries, one setting at a time, around :class:`PeerParams`."""


def _fix_of_step(fix_t: np.ndarray, t0: float, t1: float, j: int) -> tuple[int, int]:
    """(index of the last fix with t0 < time <= t1, or -1; the index of the first fix after
    t1): one course per step, the newest; older ones are stale by the step's end."""
    last = -1
    while j < fix_t.shape[0] and fix_t[j] <= t1:
        if fix_t[j] > t0:
            last = j
        j += 1
    return last, j


class _Filter:
    """The two-state filter: x = [psi deg, b deg/s], P its covariance."""

    def __init__(self, b0: float, b0_var: float, p: PeerParams) -> None:
        self.psi, self.b, self.p = math.nan, b0, p
        self.P = np.diag([LOST_VAR, b0_var])
        self.rejected = 0

    def predict(self, omega: float, T: float, heading_var: float) -> None:
        """A step of T s at the raw rate omega (deg/s CCW); heading_var: its gyro noise, deg^2."""
        turned = (omega - self.b) * T
        self.psi = (self.psi - turned) % 360.0
        F = np.array([[1.0, T], [0.0, 1.0]])  # d psi / d b = +T (psi clockwise, b CCW)
        q_psi = heading_var + (self.p.scale_sd * turned) ** 2
        self.P = F @ self.P @ F.T + np.diag([q_psi, self.p.bias_q * T])

    def hold(self, T: float, lost: bool = False) -> None:
        """A step where the heading does not move (a stop), or is lost (a gap)."""
        self.P[1, 1] += self.p.bias_q * T
        if lost:
            self.P[0, 0], self.P[0, 1], self.P[1, 0] = LOST_VAR, 0.0, 0.0

    def update(self, nu: float, H: np.ndarray, R: float) -> None:
        S = float(H @ self.P @ H) + R
        K = self.P @ H / S
        self.psi = (self.psi + K[0] * nu) % 360.0
        self.b += K[1] * nu
        self.P = self.P - np.outer(K, H @ self.P)

    def course(self, course_deg: float, R: float) -> None:
        """A GPS course (compass deg) of variance R (deg^2): gated, or the heading reset."""
        if not math.isfinite(self.psi):
            self.psi, self.P[0, 0], self.P[0, 1], self.P[1, 0] = course_deg, R, 0.0, 0.0
            return
        nu = wrap180(course_deg - self.psi)
        if nu * nu > self.p.gate_sigma**2 * (self.P[0, 0] + R):
            self.rejected += 1
            if self.rejected >= self.p.realign_after:
                self.rejected = 0
                self.psi, self.P[0, 0], self.P[0, 1], self.P[1, 0] = course_deg, R, 0.0, 0.0
            return
        self.rejected = 0
        self.update(nu, np.array([1.0, 0.0]), R)

    def zero_rate(self, omega: float, R: float) -> None:
        """A step at standstill: its mean raw rate omega (deg/s) measures the bias."""
        self.update(omega - self.b, np.array([0.0, 1.0]), R)


def _step_noise(prep: PreparedDrive, p: PeerParams) -> np.ndarray:
    """The heading variance each step's gyro noise adds, deg^2: (sd T)^2 / n with sd the
    step's sample spread, or ``point_sd_dps`` for a step of one sample."""
    s = prep.steps
    n = np.maximum(s.n_samples.astype(np.float64), 1.0)
    spread = np.zeros_like(n) if s.omega_std is None else np.nan_to_num(s.omega_std)
    sd = np.where(n > 1.0, spread, p.point_sd_dps)
    return (sd * s.T) ** 2 / n


def kalman_peer(
    prep: PreparedDrive,
    log: DriveLog,
    spec: OutageSpec,
    p: PeerParams = PeerParams(),
    phase_s: float = 0.0,
) -> np.ndarray:
    """The peer's heading error (deg, wrapped) at the end of each outage of ``spec`` starting
    ``phase_s`` later (:func:`hdrd.analysis.outages.outage_windows`; NaN where the truth or
    the peer's heading is unknown), with the settings ``p`` (module docstring)."""
    s = prep.steps
    fix_t, fixes = drive_fixes(log)
    windows = outage_windows(spec, prep.start_s, float(s.t_end[-1]), phase_s)
    heading = _run(prep, fix_t, fixes, windows, p)
    ends = [int(np.searchsorted(s.t_end, c, side="right")) - 1 for _, c in windows]
    out = np.full(len(windows), math.nan)
    for k, i in enumerate(ends):
        if i >= 0 and math.isfinite(prep.truth[i]) and math.isfinite(heading[i]):
            out[k] = wrap180(float(heading[i]) - float(prep.truth[i]))
    return out


def _run(
    prep: PreparedDrive,
    fix_t: np.ndarray,
    fixes: Sequence[LogFix],
    windows: list[tuple[float, float]],
    p: PeerParams,
) -> np.ndarray:
    """The peer's heading at each step end (compass deg, NaN before its first course)."""
    s = prep.steps
    T, n = s.T, s.u.shape[0]
    raw = s.u + s.bias_dps  # block means, deg/s CCW
    samples = np.maximum(s.n_samples.astype(np.float64), 1.0)
    rest_var = prep.bias_std_dps**2 if math.isfinite(prep.bias_std_dps) else 0.0
    b0_var = max(p.bias0_sd_dps**2, s.bias_var if math.isfinite(s.bias_var) else 0.0)
    noise = _step_noise(prep, p)
    aiding = GpsAiding(AidingConfig(step_s=T))
    stop = StopDetection()
    speed = s.speed if s.speed is not None else np.full(n, math.nan)
    spread_dps = s.omega_std if s.omega_std is not None else np.full(n, math.nan)
    f = _Filter(s.bias_dps, b0_var, p)
    heading = np.full(n, math.nan)
    j, still, t_prev = 0, 0, -math.inf
    for i in range(n):
        t = float(s.t_end[i])
        out = any(a <= t <= c for a, c in windows)
        level, spread = float(raw[i]) - f.b, float(spread_dps[i])
        v = math.nan if out else float(speed[i])  # no GPS speed in an outage
        candidate, needed = standstill_candidate(level, spread, v, stop)
        still = still + 1 if candidate else 0
        if t - t_prev > 1.5 * T and t_prev > -math.inf:
            f.hold(t - t_prev, lost=True)
        elif still >= needed:
            f.hold(T)
            f.zero_rate(float(raw[i]), rest_var / samples[i] + p.stop_sd_dps**2)
        elif math.isfinite(f.psi):
            f.predict(float(raw[i]), T, float(noise[i]))
        t_prev = t
        k, j = _fix_of_step(fix_t, t - T, t, j)
        track = _course(fixes, fix_t, k, windows, aiding.config.min_speed_mps)
        if track is not None:
            f.course(track, aiding.course_var(fixes[k], float(raw[i]) - f.b))
        heading[i] = f.psi
    return heading


def _course(
    fixes: Sequence[LogFix],
    fix_t: np.ndarray,
    k: int,
    windows: list[tuple[float, float]],
    min_speed_mps: float,
) -> float | None:
    """Fix ``k``'s course (compass deg) when it aids: a fix of the step (``k`` >= 0) with a
    course, fast enough, outside the outages; else None."""
    if k < 0:
        return None
    fix = fixes[k]
    if fix.track_deg is None or fix.speed_mps is None or not fix.speed_mps >= min_speed_mps:
        return None  # (a speed of NaN does not aid)
    if any(a <= fix_t[k] <= c for a, c in windows):
        return None
    return fix.track_deg


# -- the outages judged on ---------------------------------------------------------------------

SPEC = "120s/10min"
"""The outages: one of 120 s at the end of every 10 minutes of driving ..."""
LONG_SPEC = "120s/5min"
"""... every 5 minutes on a drive whose scored part (after its calibration) is longer than
:data:`LONG_MIN` ..."""
LONG_MIN = 30.0
PHASES = 4
"""... and the grid run this many times, each starting a further 1/PHASES of the period later
(10 minutes: 0, 150, 300, 450 s; 5 minutes: 0, 75, 150, 225 s): each run is the drive from its
start with other instants cut out, so that one drive gives outages everywhere on it."""


def outage_plan(duration_min: float) -> list[tuple[OutageSpec, float]]:
    """(spec, phase s) of each run of a drive whose scored part lasts ``duration_min`` (Td,
    min): :data:`SPEC` or, beyond :data:`LONG_MIN`, :data:`LONG_SPEC`, at :data:`PHASES`
    phases."""
    spec = OutageSpec.parse(LONG_SPEC if duration_min > LONG_MIN else SPEC)
    return [(spec, k * spec.period_s / PHASES) for k in range(PHASES)]


def plan_text() -> str:
    """The plan in words, for the reports."""
    ten, five = OutageSpec.parse(SPEC), OutageSpec.parse(LONG_SPEC)

    def phases(spec: OutageSpec) -> str:
        return ", ".join(f"{k * spec.period_s / PHASES:g}" for k in range(PHASES))

    return (
        f"outages of {ten.duration_s:g} s at the end of every {ten.period_s / 60:g} min (every "
        f"{five.period_s / 60:g} min on a drive whose scored part exceeds {LONG_MIN:g} min), the "
        f"grid run at {PHASES} phases ({phases(ten)} s; {phases(five)} s), each a run of its own"
    )


@dataclass
class PlanErrors:
    """One drive through every run of its plan: the (start, end) of each outage, s, the
    phase of its run, s, and per method (and ``peer``) the heading error at each outage's end,
    deg (NaN where unscored), in the same order."""

    windows: list[tuple[float, float]] = field(default_factory=list)
    phases: list[float] = field(default_factory=list)
    errors: dict[str, np.ndarray] = field(default_factory=dict)
    sd: np.ndarray = field(default_factory=lambda: np.empty(0))
    """HDR+'s published heading sd at each outage's end, deg (NaN: not run)."""

    def add(
        self,
        errors: dict[str, np.ndarray],
        windows: Sequence[tuple[float, float]],
        phase: float,
        sd: np.ndarray | None = None,
    ) -> None:
        self.windows.extend(windows)
        self.phases.extend([phase] * len(windows))
        for m, e in errors.items():
            self.errors[m] = np.concatenate([self.errors.get(m, np.empty(0)), e])
        more = np.full(len(windows), np.nan) if sd is None else sd
        self.sd = np.concatenate([self.sd, more])


def _sd_at_ends(prep: PreparedDrive, r: OutageResult) -> np.ndarray | None:
    """HDR+'s heading sd at each outage's last step (the step the error is scored at), deg."""
    if r.trace is None or "heading_sd_hdr+" not in r.trace:
        return None
    sd = r.trace["heading_sd_hdr+"]
    ends = [int(np.searchsorted(prep.steps.t_end, b, side="right")) - 1 for _, b in r.windows]
    return np.array([sd[i] if i >= 0 else np.nan for i in ends])


def plan_errors(
    prep: PreparedDrive,
    log: DriveLog,
    methods: Sequence[str],
    setup: MethodSetup,
    peer: str | None = "kalman peer",
    params: PeerParams = PeerParams(),
) -> PlanErrors:
    """Each method (:func:`hdrd.analysis.outages.run_outages`) and, named ``peer`` (None: not
    run), the Kalman peer through every run of the drive's :func:`outage_plan`. A run without
    an outage is left out; EvaluationError when none has one, or the drive no fix."""
    out = PlanErrors()
    why = ""
    for spec, phase in outage_plan(prep.duration_min):
        try:
            r = run_outages(prep, log, spec, methods, setup=setup, phase_s=phase)
        except EvaluationError as e:
            why = why or str(e)
            continue
        errors = dict(r.errors)
        if peer is not None:
            errors[peer] = kalman_peer(prep, log, spec, params, phase)
        out.add(errors, r.windows, phase, _sd_at_ends(prep, r))
    if not out.windows:
        raise EvaluationError(why)
    return out
