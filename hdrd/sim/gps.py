"""Simulated GPS ground truth: course over ground at 1 Hz, noisy, unusable at low speed.

Pure and seeded. The paper's truth is the heading from a GPS receiver at 1 Hz (Sec. 5.2). A GPS
course is the direction of the velocity vector, so its error grows as the speed falls: with a
velocity error of ``vel_noise_mps`` per axis, the course error is about atan(vel_noise / speed);
below ``min_speed_mps`` the course is meaningless and reported unknown (NaN). Outages (tunnels,
urban canyons) blank whole intervals.

Heading in compass degrees, clockwise from north, [0, 360).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["GpsModel", "gps_course", "heading_from_rate"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class GpsModel:
    """A GPS receiver's course output."""

    rate_hz: float = 1.0
    """Epoch rate, Hz (paper: 1 Hz)."""
    min_speed_mps: float = 2.0
    """Below this speed the course is unknown (NaN), m/s."""
    vel_noise_mps: float = 0.08
    """Velocity noise per horizontal axis, m/s: course noise ~ atan(vel_noise / speed)."""
    floor_deg: float = 0.15
    """Course noise that remains at high speed (antenna, multipath), deg."""
    outages_per_hour: float = 0.0
    """Mean number of outages per hour of driving."""
    outage_s: tuple[float, float] = (5.0, 40.0)
    """Outage length range, s."""
    latency_s: float = 0.0
    """The course is reported this late, s: the course at an epoch is the vehicle's heading
    (and the speed threshold its speed) that long before. A receiver's velocity filter and
    its output path delay the course; against a gyro sampled at the same epochs it is a time
    offset (``hdrd gap`` names it ``time_offset`` with delay -latency). 0: no latency."""

    def __post_init__(self) -> None:
        if not (self.rate_hz > 0 and self.min_speed_mps >= 0 and self.vel_noise_mps >= 0):
            raise ValueError("GpsModel: rate_hz must be > 0, min_speed_mps and vel_noise_mps >= 0")
        if not (math.isfinite(self.latency_s) and self.latency_s >= 0):
            raise ValueError(f"GpsModel: latency_s must be finite and >= 0, got {self.latency_s!r}")


def heading_from_rate(
    t_s: npt.ArrayLike, omega_dps: npt.ArrayLike, heading0_deg: float
) -> FloatArray:
    """Compass heading (deg, clockwise from north, [0, 360)) from a yaw rate (deg/s, + = CCW):
    heading = heading0 - integral(omega dt), trapezoid rule from t_s[0]. Yaw is counter-clockwise,
    compass heading clockwise, hence the minus sign."""
    t = np.asarray(t_s, dtype=np.float64)
    w = np.asarray(omega_dps, dtype=np.float64)
    yaw = np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))))
    return np.mod(heading0_deg - yaw, 360.0)


def gps_course(
    t_s: npt.ArrayLike,
    heading_deg: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    rng: np.random.Generator,
    model: GpsModel = GpsModel(),
) -> FloatArray:
    """GPS course per sample: NaN except at the sample nearest each GPS epoch (t_s[0] + j /
    rate_hz), where it is the true heading plus noise, unless the speed is below the threshold
    or an outage covers the epoch. With a ``latency_s`` the heading and speed are those of
    that long before (interpolated; held before the first sample). Compass degrees, [0, 360)."""
    t = np.asarray(t_s, dtype=np.float64)
    hdg = np.asarray(heading_deg, dtype=np.float64)
    v = np.asarray(speed_mps, dtype=np.float64)
    n = t.shape[0]
    out = np.full(n, np.nan)
    if n == 0:
        return out
    epochs = t[0] + np.arange(math.floor((t[-1] - t[0]) * model.rate_hz) + 1) / model.rate_hz
    idx = np.clip(np.searchsorted(t, epochs), 0, n - 1)
    prev = np.clip(idx - 1, 0, n - 1)
    idx = np.where(np.abs(t[prev] - epochs) < np.abs(t[idx] - epochs), prev, idx)
    idx = np.unique(idx)
    if model.latency_s > 0:
        then = t[idx] - model.latency_s
        speed = np.interp(then, t, v)
        hdg_then = np.interp(then, t, np.degrees(np.unwrap(np.radians(hdg))))
    else:
        speed = v[idx]
        hdg_then = hdg[idx]
    sd = np.hypot(
        model.floor_deg, np.degrees(np.arctan2(model.vel_noise_mps, np.maximum(speed, 1e-3)))
    )
    course = np.mod(hdg_then + sd * rng.standard_normal((idx.shape[0],)), 360.0)
    ok = speed >= model.min_speed_mps
    # Outages: a Poisson number over the drive, uniformly placed.
    hours = (t[-1] - t[0]) / 3600.0
    k = int(rng.poisson(model.outages_per_hour * hours)) if model.outages_per_hour > 0 else 0
    for _ in range(k):
        start = rng.uniform(t[0], t[-1])
        length = rng.uniform(*model.outage_s)
        ok &= ~((t[idx] >= start) & (t[idx] < start + length))
    out[idx[ok]] = course[ok]
    return out
