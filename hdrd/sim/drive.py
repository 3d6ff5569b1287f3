"""A simulated drive log: vehicle motion + cabin temperature + gyro error model + GPS truth.

Pure and deterministic for a seed: the seed is split into independent streams for the route,
the temperature, the GPS and the gyro, so that changing the gyro model leaves the route and
the truth unchanged (and the reverse).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict

import numpy as np

from hdrd import __version__
from hdrd.io.files.drivelog import DriveLog
from hdrd.sim.gps import GpsModel, gps_course, heading_from_rate
from hdrd.sim.gyro import GyroModel, crs03_default_model
from hdrd.sim.vehicle import DRIVE_TYPES, PROFILES, CabinTemperature, RoadProfile, generate_motion

__all__ = ["MAX_SAMPLES", "simulate_drive", "simulate_legs", "too_big"]

DEFAULT_GPS = GpsModel()
"""1 Hz course, unusable below 2 m/s, no outages."""


def _streams(seed: int) -> list[np.random.Generator]:
    """Independent random streams of a seed: the route's, the temperature's, the GPS's and
    the gyro's."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4)]


def _sensor_step(minutes: float, lead_in_s: float, hz: float, sensor_hz: float | None) -> int:
    """The arguments of :func:`simulate_legs` checked; how many sensor samples a logged
    sample stands for (1: the gyro is simulated at ``hz``)."""
    if not (math.isfinite(minutes) and minutes >= 0):
        raise ValueError(f"minutes must be >= 0, got {minutes!r}")
    if not (math.isfinite(lead_in_s) and lead_in_s >= 0):
        raise ValueError(f"lead_in_s must be >= 0, got {lead_in_s!r}")
    if not (math.isfinite(hz) and hz > 0):
        raise ValueError(f"hz must be > 0, got {hz!r}")
    step = 1
    if sensor_hz is not None and sensor_hz != hz:
        ratio = sensor_hz / hz if math.isfinite(sensor_hz) else math.nan
        step = round(ratio) if math.isfinite(ratio) else 0
        if not (step >= 2 and abs(ratio - step) < 1e-9 * ratio):
            raise ValueError(
                f"sensor_hz must be a whole multiple of hz ({hz:g}), got {sensor_hz!r}"
            )
    return step


def _metadata(
    seed: int, minutes: float, lead_in_s: float, hz: float, step: int, heading0_deg: float
) -> dict[str, str]:
    """The metadata lines that say where the drive came from and how it was sampled."""
    return {
        "source": f"hdrd {__version__} simulate",
        "seed": str(seed),
        "minutes": f"{minutes:g}",
        "lead_in_s": f"{lead_in_s:g}",
        "hz": f"{hz:g}",
        **({"sensor_hz": f"{hz * step:g}"} if step > 1 else {}),
        "heading0_deg": f"{heading0_deg:.3f}",
    }


def _model_metadata(
    legs: Sequence[tuple[RoadProfile, float]],
    temperature: CabinTemperature,
    model: GyroModel,
    gps: GpsModel,
) -> dict[str, str]:
    """The metadata lines that say which route, cabin, gyro and GPS made the drive."""
    return {
        "legs": json.dumps([[p.name, f] for p, f in legs]),
        "temperature": json.dumps(asdict(temperature)),
        "gyro_model": json.dumps(model.to_dict()["effects"]),
        "heading_truth": "GPS course at 1 Hz epochs only, empty between epochs and below "
        f"{gps.min_speed_mps:g} m/s",
    }


def simulate_legs(
    legs: Sequence[tuple[RoadProfile, float]],
    minutes: float,
    seed: int,
    hz: float = 10.0,
    model: GyroModel | None = None,
    lead_in_s: float = 30.0,
    temperature: CabinTemperature | None = None,
    gps: GpsModel = DEFAULT_GPS,
    heading0_deg: float | None = None,
    name: str = "",
    meta: dict[str, str] | None = None,
    sensor_hz: float | None = None,
) -> DriveLog:
    """A drive through ``legs`` (road profile, fraction of the time) of ``minutes`` after a
    standstill lead-in of ``lead_in_s``; see :func:`simulate_drive` for the columns.

    temperature: the cabin profile (None: drawn from the seed); heading0_deg: compass heading
    at the start (None: drawn from the seed); meta: extra metadata lines for the log.

    sensor_hz: the rate the gyro itself runs at when the log only keeps *point samples* of it
    at ``hz`` (a logger reading a phone's 100 Hz gyro once a second): the motion, the
    temperature and the gyro are simulated at ``sensor_hz`` (a whole multiple of ``hz``) and
    every (sensor_hz / hz)-th sample is kept, so the sensor's noise over its own bandwidth,
    and any motion faster than ``hz`` / 2, alias into the log as they do in a real one. The
    true heading (and so the GPS course) integrates the full-rate motion. None (or ``hz``):
    the gyro is simulated at ``hz``, its samples standing for the whole sample period.
    """
    step = _sensor_step(minutes, lead_in_s, hz, sensor_hz)
    model = crs03_default_model() if model is None else model
    route_rng, temp_rng, gps_rng, gyro_rng = _streams(seed)
    if heading0_deg is None:
        heading0_deg = float(route_rng.uniform(0.0, 360.0))
    if temperature is None:
        temperature = CabinTemperature.random(temp_rng)
    motion = generate_motion(legs, 60.0 * minutes, hz * step, route_rng, lead_in_s)
    t = motion.t
    if t.shape[0] < 2 * step:
        raise ValueError("the drive is shorter than two samples")
    temp = temperature.profile(t, lead_in_s, temp_rng)
    heading = heading_from_rate(t, motion.omega, heading0_deg)
    omega = model.apply(t, motion.omega, temp, gyro_rng, motion.speed)
    omega_true, speed = motion.omega, motion.speed
    if step > 1:  # the log keeps point samples of the sensor's output
        kept = [a[::step] for a in (t, temp, heading, omega, omega_true, speed)]
        t, temp, heading, omega, omega_true, speed = kept
    truth = gps_course(t, heading, speed, gps_rng, gps)
    info = _metadata(seed, minutes, lead_in_s, hz, step, heading0_deg)
    info.update(_model_metadata(legs, temperature, model, gps))
    info.update(meta or {})
    return DriveLog(
        t=t,
        omega=omega,
        temp_c=temp,
        heading_truth=truth,
        omega_truth=omega_true,
        speed=speed,
        name=name,
        meta=info,
    )


def simulate_drive(
    drive: str,
    minutes: float,
    seed: int,
    hz: float = 10.0,
    model: GyroModel | None = None,
    lead_in_s: float = 30.0,
    temperature: CabinTemperature | None = None,
    gps: GpsModel = DEFAULT_GPS,
    sensor_hz: float | None = None,
) -> DriveLog:
    """A simulated drive of type city|suburbs|rural|highway|mixed|standstill.

    The log starts at power-on (t = 0) with ``lead_in_s`` of standstill (the paper's Tbias,
    so the static bias can be measured from the first seconds), then ``minutes`` of driving;
    one row per gyro sample at ``hz``. Columns: ``omega`` the raw gyro output (deg/s, + = CCW,
    bias NOT removed) from ``model`` (default :func:`crs03_default_model`); ``omega_truth`` the
    true yaw rate (deg/s, + = CCW); ``heading_truth`` the GPS course (compass deg, clockwise
    from north) at the 1 Hz epochs only, NaN between them and below 2 m/s; ``speed`` (m/s);
    ``temp_c`` the cabin/board temperature (deg C, warm-up profile). Deterministic for a seed.
    The true heading is heading0 - integral(omega_truth), trapezoid rule. ``sensor_hz``: the
    log keeps point samples of a gyro running at that rate (:func:`simulate_legs`).
    """
    if drive not in DRIVE_TYPES:
        raise ValueError(f"unknown drive type {drive!r} (known: {', '.join(DRIVE_TYPES)})")
    legs = [(PROFILES[p], f) for p, f in DRIVE_TYPES[drive]]
    return simulate_legs(
        legs,
        minutes,
        seed,
        hz=hz,
        model=model,
        lead_in_s=lead_in_s,
        temperature=temperature,
        gps=gps,
        name=drive,
        meta={"drive": drive},
        sensor_hz=sensor_hz,
    )


MAX_SAMPLES = 5_000_000
"""Most samples one simulated drive may have: a drive takes about 300 bytes of memory per
sample while it is made (1,000 min at 10 Hz, 600,300 samples: 220 MB peak), so at most
~1.5 GB; 8,300 minutes at 10 Hz."""
LEAD_IN_S = 30.0
"""The standstill before every drive (:func:`simulate_drive`'s lead_in_s)."""


def too_big(minutes: float, hz: float, what: str = "a drive") -> str | None:
    """Why a drive of ``minutes`` at ``hz`` cannot be made (more than :data:`MAX_SAMPLES`
    samples with its lead-in), or None (a bad number is said where it is checked)."""
    if not (math.isfinite(minutes) and minutes > 0):
        return None
    samples = (minutes * 60.0 + LEAD_IN_S) * hz
    if samples <= MAX_SAMPLES:
        return None
    return (
        f"{what} of {minutes:g} min at {hz:g} Hz is {samples:.3g} samples; at most "
        f"{MAX_SAMPLES:,} are simulated (about 300 bytes each in memory)"
    )
