"""Simulated vehicle motion: true yaw rate, speed and cabin temperature of a drive.

Pure and seeded. A drive is a sequence of legs, each on one road type (:class:`RoadProfile`),
built from the paper's kinds of motion (Sec. 4.1, Fig. 2):

- straight stretches with *swaying* (small steering corrections: a smooth heading wiggle of a
  fraction of a degree that returns to the road's direction, so it adds no net heading);
- *curving*: long arcs (clothoid entry and exit, constant radius in between);
- *turning*: ~90 deg corners at low speed, and roundabouts (veer right, circle counter-clockwise,
  veer right: right-hand traffic);
- stops (traffic lights, stop signs) and lane changes (highway);
- speed changes with raised-cosine profiles (finite acceleration and jerk).

Every rate event is a raised-cosine trapezoid in time, so the yaw rate is continuous with a
finite yaw acceleration; its samples are scaled so that the event's heading change is exact.
Units: yaw rate deg/s, + = counter-clockwise (left turn); speed m/s; time s; temperature degC.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from hdrd.sim.effects import ar1

__all__ = [
    "DRIVE_TYPES",
    "PROFILES",
    "CabinTemperature",
    "Motion",
    "RoadProfile",
    "count_turns",
    "generate_motion",
]

FloatArray = npt.NDArray[np.float64]
Range = tuple[float, float]

EVENTS = ("turn", "stop", "curve", "roundabout", "lane_change", "none")


@dataclass(frozen=True)
class RoadProfile:
    """How a road type drives. Ranges are (low, high), drawn uniformly per event."""

    name: str
    cruise_mps: Range
    """Cruising speed between events, m/s."""
    straight_m: Range
    """Length of a straight stretch before the next event, m."""
    weights: Mapping[str, float]
    """Relative frequency of the event ending a stretch: turn, stop, curve, roundabout,
    lane_change, none (just carry on)."""
    turn_speed_mps: Range = (4.0, 6.5)
    """Speed through a 90 deg corner, m/s."""
    turn_radius_m: Range = (9.0, 16.0)
    """Corner radius, m (peak yaw rate = speed / radius)."""
    stop_before_turn: float = 0.3
    """Probability of stopping (stop sign, red light) before a corner."""
    stop_s: Range = (5.0, 40.0)
    """Standstill time at a stop, s."""
    curve_deg: Range = (15.0, 60.0)
    """Heading change of a curve, deg (sign random)."""
    curve_radius_m: Range = (200.0, 600.0)
    """Curve radius, m (yaw rate = speed / radius)."""
    curve_ramp_s: Range = (3.0, 8.0)
    """Clothoid entry/exit time of a curve, s."""
    sway_deg: float = 0.4
    """Standard deviation of the swaying heading wiggle, deg."""
    sway_tau_s: float = 2.5
    """Correlation time of the swaying wiggle, s."""
    accel_mps2: float = 1.2
    """Mean acceleration/deceleration of speed changes, m/s^2."""

    def __post_init__(self) -> None:
        unknown = set(self.weights) - set(EVENTS)
        if unknown:
            raise ValueError(
                f"profile {self.name}: unknown event(s) {sorted(unknown)} (known: {EVENTS})"
            )
        if sum(self.weights.values()) <= 0:
            raise ValueError(f"profile {self.name}: event weights must not all be zero")


PROFILES: dict[str, RoadProfile] = {
    # Downtown grid: short blocks, corners and traffic lights.
    "city": RoadProfile(
        "city",
        cruise_mps=(10.0, 15.0),
        straight_m=(100.0, 300.0),
        weights={"turn": 0.3, "stop": 0.15, "curve": 0.1, "roundabout": 0.02, "none": 0.43},
        stop_before_turn=0.25,
        curve_deg=(10.0, 35.0),
        curve_radius_m=(60.0, 200.0),
        curve_ramp_s=(2.0, 4.0),
        stop_s=(5.0, 30.0),
        sway_deg=0.5,
        sway_tau_s=2.0,
    ),
    # Subdivision streets: mostly curving, short straights, some stop-sign corners.
    "suburbs": RoadProfile(
        "suburbs",
        cruise_mps=(10.0, 15.0),
        straight_m=(20.0, 120.0),
        weights={"curve": 0.75, "turn": 0.12, "stop": 0.06, "roundabout": 0.02, "none": 0.05},
        curve_deg=(25.0, 110.0),
        curve_radius_m=(60.0, 250.0),
        curve_ramp_s=(2.0, 5.0),
        stop_before_turn=0.6,
        stop_s=(2.0, 10.0),
        sway_deg=0.5,
        sway_tau_s=2.0,
    ),
    # Country roads: long straights, some curves, an occasional junction.
    "rural": RoadProfile(
        "rural",
        cruise_mps=(19.0, 25.0),
        straight_m=(400.0, 2500.0),
        weights={"curve": 0.55, "turn": 0.12, "stop": 0.05, "roundabout": 0.03, "none": 0.25},
        turn_speed_mps=(5.0, 8.0),
        turn_radius_m=(12.0, 25.0),
        curve_deg=(10.0, 50.0),
        curve_radius_m=(250.0, 800.0),
        curve_ramp_s=(3.0, 8.0),
        stop_before_turn=0.5,
        stop_s=(3.0, 20.0),
        sway_deg=0.35,
        sway_tau_s=3.0,
    ),
    # Motorway: long straights, gentle curves, lane changes, no stops.
    "highway": RoadProfile(
        "highway",
        cruise_mps=(27.0, 33.0),
        straight_m=(1000.0, 5000.0),
        weights={"curve": 0.45, "lane_change": 0.35, "none": 0.2},
        curve_deg=(8.0, 40.0),
        curve_radius_m=(800.0, 3000.0),
        curve_ramp_s=(5.0, 12.0),
        sway_deg=0.25,
        sway_tau_s=4.0,
    ),
}
"""The built-in road types."""

DRIVE_TYPES: dict[str, tuple[tuple[str, float], ...]] = {
    "city": (("city", 1.0),),
    "suburbs": (("suburbs", 1.0),),
    "rural": (("rural", 1.0),),
    "highway": (("highway", 1.0),),
    # The paper's Mixed Drive (Sec. 5.1): rural roads, then highway, then city streets.
    "mixed": (("rural", 0.33), ("highway", 0.33), ("city", 0.34)),
    "standstill": (),
}
"""Drive types of ``hdrd simulate --drive``: legs as (road type, fraction of the time)."""


@dataclass(frozen=True)
class CabinTemperature:
    """Board/cabin temperature over a drive, degC (the paper's Sec. 5 discussion: the car leaves
    a cold garage, the heater brings the cabin to room temperature)::

        T(t) = start_c + self_heat_c (1 - exp(-t / self_heat_tau_s))            (board warm-up)
                       + (end_c - start_c) (1 - exp(-(t - on_s) / tau_s))  for t > on_s (heater)

    t is time since power-on; on_s is when the heater starts (the end of the standstill lead-in
    by default); noise_c is the sensor's white noise, degC.
    """

    start_c: float = 15.0
    end_c: float = 21.0
    tau_s: float = 600.0
    on_s: float | None = None
    self_heat_c: float = 1.0
    self_heat_tau_s: float = 300.0
    noise_c: float = 0.02

    def profile(self, t_s: FloatArray, on_s: float, rng: np.random.Generator) -> FloatArray:
        """Temperature at times t_s (s since power-on); on_s used when self.on_s is None."""
        on = self.on_s if self.on_s is not None else on_s
        t = np.asarray(t_s, dtype=np.float64)
        heat = np.where(t > on, 1.0 - np.exp(-np.maximum(t - on, 0.0) / self.tau_s), 0.0)
        board = self.self_heat_c * (1.0 - np.exp(-t / self.self_heat_tau_s))
        noise = self.noise_c * rng.standard_normal((t.shape[0],))
        return self.start_c + board + (self.end_c - self.start_c) * heat + noise

    @staticmethod
    def random(rng: np.random.Generator) -> CabinTemperature:
        """A plausible day: start 2..25 degC, heater/AC to 20..23 degC over 5..15 min."""
        return CabinTemperature(
            start_c=float(rng.uniform(2.0, 25.0)),
            end_c=float(rng.uniform(20.0, 23.0)),
            tau_s=float(rng.uniform(300.0, 900.0)),
        )


@dataclass(frozen=True)
class Motion:
    """True motion sampled at the gyro rate: yaw rate deg/s (+ = CCW), speed m/s, and the
    events that made it (kind, start s, end s, heading change deg) for tests and plots."""

    t: FloatArray
    omega: FloatArray
    speed: FloatArray
    events: list[tuple[str, float, float, float]] = field(default_factory=list)


class _Builder:
    """Appends pieces of motion sample by sample, keeping speed continuous."""

    def __init__(self, hz: float, rng: np.random.Generator) -> None:
        self.hz = hz
        self.dt = 1.0 / hz
        self.rng = rng
        self.speed: list[FloatArray] = []
        self.omega: list[FloatArray] = []
        self.sway: list[FloatArray] = []
        self.n = 0
        self.v = 0.0
        self.events: list[tuple[str, float, float, float]] = []
        self.profile: RoadProfile | None = None

    @property
    def elapsed(self) -> float:
        return self.n * self.dt

    def _append(self, speed: FloatArray, omega: FloatArray) -> None:
        assert self.profile is not None
        self.speed.append(speed)
        self.omega.append(omega)
        self.sway.append(np.full(speed.shape[0], self.profile.sway_deg))
        self.n += speed.shape[0]

    def _samples(self, seconds: float) -> int:
        return max(round(seconds * self.hz), 1)

    def u(self, r: Range) -> float:
        return float(self.rng.uniform(r[0], r[1]))

    def hold(self, seconds: float) -> None:
        """Constant speed, no yaw (apart from the swaying added later)."""
        n = self._samples(seconds)
        self._append(np.full(n, self.v), np.zeros(n))

    def speed_to(self, v1: float) -> None:
        """Raised-cosine speed change to v1, m/s."""
        assert self.profile is not None
        dv = v1 - self.v
        if abs(dv) < 1e-9:
            return
        n = self._samples(abs(dv) / self.profile.accel_mps2)
        k = np.arange(n) / n
        self._append(self.v + dv * 0.5 * (1.0 - np.cos(math.pi * k)), np.zeros(n))
        self.v = v1

    def rate_event(self, kind: str, angle_deg: float, rate_dps: float, ramp_s: float) -> None:
        """A heading change of angle_deg at constant speed: raised-cosine ramps of ramp_s up to
        |rate_dps|, a plateau, and back down; samples scaled so the heading change is exact."""
        rate = abs(rate_dps)
        plateau = abs(angle_deg) / rate - ramp_s
        if plateau < 0:  # too short for a plateau: a bell of the same peak rate
            ramp_s = abs(angle_deg) / rate
            plateau = 0.0
        total = 2 * ramp_s + plateau
        n = max(self._samples(total), 3)
        tt = np.arange(n) * (total / n)
        up = np.clip(tt / ramp_s, 0.0, 1.0)
        down = np.clip((total - tt) / ramp_s, 0.0, 1.0)
        shape = 0.5 * (1.0 - np.cos(math.pi * np.minimum(up, down)))
        omega = shape * (angle_deg / (shape.sum() * self.dt))
        start = self.elapsed
        self._append(np.full(n, self.v), omega)
        self.events.append((kind, start, self.elapsed, angle_deg))

    def sine_event(self, kind: str, peak_dps: float, period_s: float) -> None:
        """One full sine period of yaw rate: a lane change, no net heading change."""
        n = self._samples(period_s)
        omega = peak_dps * np.sin(2 * math.pi * np.arange(n) / n)
        start = self.elapsed
        self._append(np.full(n, self.v), omega)
        self.events.append((kind, start, self.elapsed, 0.0))

    def stop(self, seconds: float) -> None:
        start = self.elapsed
        self.speed_to(0.0)
        self.hold(seconds)
        self.events.append(("stop", start, self.elapsed, 0.0))

    # -- events ----------------------------------------------------------------------------

    def stretch(self, until_s: float) -> None:
        p = self.profile
        assert p is not None
        v1 = self.u(p.cruise_mps)
        self.speed_to(v1)
        # A stretch never runs far past the leg's end, so legs keep their share of the time.
        self.hold(min(self.u(p.straight_m) / v1, max(until_s - self.elapsed, 1.0)))

    def turn(self) -> None:
        p = self.profile
        assert p is not None
        if self.rng.random() < p.stop_before_turn:
            self.stop(self.u(p.stop_s))
        self.speed_to(self.u(p.turn_speed_mps))
        angle = float(np.clip(90.0 + 3.0 * self.rng.standard_normal(), 80.0, 100.0))
        angle *= 1.0 if self.rng.random() < 0.5 else -1.0
        rate = math.degrees(self.v / self.u(p.turn_radius_m))
        self.rate_event("turn", angle, rate, self.u((1.0, 2.0)))

    def curve(self) -> None:
        p = self.profile
        assert p is not None
        if self.v < 1.0:
            self.speed_to(self.u(p.cruise_mps))
        angle = self.u(p.curve_deg) * (1.0 if self.rng.random() < 0.5 else -1.0)
        rate = math.degrees(self.v / self.u(p.curve_radius_m))
        self.rate_event("curve", angle, rate, self.u(p.curve_ramp_s))

    def roundabout(self) -> None:
        # Right-hand traffic: the circle is driven counter-clockwise (+ yaw rate).
        self.speed_to(self.u((5.0, 7.0)))
        exit_deg = float(self.rng.choice([-90.0, 0.0, 90.0, 180.0]))
        veer = self.u((40.0, 55.0))
        radius = self.u((10.0, 20.0))
        circle_rate = math.degrees(self.v / radius)
        start = self.elapsed
        self.rate_event("roundabout_in", -veer, circle_rate * 0.7, 1.0)
        self.rate_event("roundabout_circle", max(exit_deg + 2 * veer, 30.0), circle_rate, 1.0)
        self.rate_event("roundabout_out", -veer, circle_rate * 0.7, 1.0)
        self.events.append(("roundabout", start, self.elapsed, exit_deg))

    def lane_change(self) -> None:
        # Lateral 3.5 m in period D: peak rate = 2 pi * 3.5 / (v D^2) rad/s.
        period = self.u((4.0, 7.0))
        v = max(self.v, 5.0)
        peak = math.degrees(2 * math.pi * 3.5 / (v * period * period))
        self.sine_event("lane_change", peak * (1.0 if self.rng.random() < 0.5 else -1.0), period)

    def leg(self, profile: RoadProfile, until_s: float) -> None:
        self.profile = profile
        kinds = list(profile.weights)
        w = np.array([profile.weights[k] for k in kinds], dtype=np.float64)
        w /= w.sum()
        while self.elapsed < until_s:
            self.stretch(until_s)
            kind = kinds[int(self.rng.choice(len(kinds), p=w))]
            if kind == "turn":
                self.turn()
            elif kind == "stop":
                self.stop(self.u(profile.stop_s))
            elif kind == "curve":
                self.curve()
            elif kind == "roundabout":
                self.roundabout()
            elif kind == "lane_change":
                self.lane_change()


def _smooth(x: FloatArray, n: int) -> FloatArray:
    """Centred moving average over n samples (edges use what exists)."""
    if n <= 1 or x.shape[0] == 0:
        return x
    c = np.concatenate(([0.0], np.cumsum(x)))
    idx = np.arange(x.shape[0])
    lo = np.clip(idx - n // 2, 0, x.shape[0])
    hi = np.clip(idx + n // 2 + 1, 0, x.shape[0])
    return (c[hi] - c[lo]) / (hi - lo)


def _sway(
    t: FloatArray, speed: FloatArray, amp_deg: FloatArray, tau_s: float, rng: np.random.Generator
) -> FloatArray:
    """Swaying yaw rate, deg/s: the time derivative of a smooth heading wiggle (two cascaded
    first-order lags of white noise, unit variance, scaled by amp_deg and faded out at low
    speed), so it is continuous and integrates back to zero whenever the car stops."""
    n = t.shape[0]
    if n < 3:
        return np.zeros(n)
    dt = np.diff(t, prepend=t[0] - (t[1] - t[0]))
    decay = dt / tau_s
    a = np.exp(-decay)
    w = rng.standard_normal((n,))
    s1 = ar1(decay, np.sqrt(1 - a * a) * w, float(w[0]))
    s2 = ar1(decay, (1 - a) * s1, 0.0)
    s2 /= max(float(np.std(s2)), 1e-12)
    x = np.clip(speed / 5.0, 0.0, 1.0)
    fade = x * x * (3.0 - 2.0 * x)  # smoothstep: no corrections when parked, C1 in speed
    wiggle = amp_deg * fade * s2
    return np.gradient(wiggle, t)


def generate_motion(
    legs: Sequence[tuple[RoadProfile, float]],
    drive_s: float,
    hz: float,
    rng: np.random.Generator,
    lead_in_s: float = 30.0,
) -> Motion:
    """True yaw rate and speed at ``hz`` for a standstill lead-in of ``lead_in_s`` followed by
    ``drive_s`` seconds of driving through ``legs`` (road profile, fraction of the drive time;
    an empty sequence = standstill throughout). Sample k is at t = k / hz, t = 0 at power-on."""
    if not (hz > 0 and math.isfinite(hz)):
        raise ValueError(f"hz must be a positive number, got {hz!r}")
    if drive_s < 0 or lead_in_s < 0:
        raise ValueError("drive and lead-in durations must be >= 0")
    n_lead = round(lead_in_s * hz)
    n_drive = round(drive_s * hz)
    n = n_lead + n_drive
    t = np.arange(n) / hz
    speed = np.zeros(n)
    omega = np.zeros(n)
    amp = np.zeros(n)
    events: list[tuple[str, float, float, float]] = []
    if legs and n_drive > 0:
        total = sum(f for _, f in legs)
        b = _Builder(hz, rng)
        until = 0.0
        for profile, frac in legs:
            until += drive_s * frac / total
            b.leg(profile, until)
        sp = np.concatenate(b.speed)[:n_drive]
        om = np.concatenate(b.omega)[:n_drive]
        sw = np.concatenate(b.sway)[:n_drive]
        speed[n_lead:] = sp
        omega[n_lead:] = om
        # Sway amplitude changes between legs: smooth it over 10 s so its derivative is finite.
        amp[n_lead:] = _smooth(sw, int(10 * hz))
        sway_tau = float(np.mean([p.sway_tau_s for p, _ in legs]))
        omega += _sway(t, speed, amp, sway_tau, rng)
        end = n / hz
        events = [
            (k, s + lead_in_s, e + lead_in_s, a) for k, s, e, a in b.events if s + lead_in_s < end
        ]
    return Motion(t=t, omega=omega, speed=speed, events=events)


def _trapz(y: FloatArray, x: FloatArray) -> float:
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(x))) if y.shape[0] > 1 else 0.0


def count_turns(
    t: npt.ArrayLike,
    omega_dps: npt.ArrayLike,
    threshold_dps: float = 4.0,
    min_deg: float = 70.0,
    max_deg: float = 110.0,
) -> int:
    """Number of ~90 deg turns in a yaw-rate trace (deg/s): stretches between sign changes of
    omega whose peak |omega| exceeds threshold_dps and whose heading change (trapezoid
    integral, deg) lies in [min_deg, max_deg]."""
    tt = np.asarray(t, dtype=np.float64)
    w = np.asarray(omega_dps, dtype=np.float64)
    if w.shape[0] < 2:
        return 0
    s = np.sign(w)
    cuts = np.concatenate(([0], np.flatnonzero(np.diff(s) != 0) + 1, [w.shape[0]]))
    count = 0
    for a, b in itertools.pairwise(cuts):
        if s[a] == 0 or np.max(np.abs(w[a:b])) <= threshold_dps:
            continue
        seg = slice(max(a - 1, 0), min(b + 1, w.shape[0]))
        if min_deg <= abs(_trapz(w[seg], tt[seg])) <= max_deg:
            count += 1
    return count
