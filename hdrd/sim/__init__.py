"""Seeded simulation of drives and of the gyro's errors (docs/gyro-model.md).

- :func:`simulate_drive`: a drive log (hdrd.io.files.drivelog) of a road type, with the raw gyro output
  from a :class:`GyroModel`, the true rate, 1 Hz GPS course, speed and cabin temperature.
- :mod:`hdrd.sim.gyro`: the error model of named effects (static_bias, white_noise, ...).
- :mod:`hdrd.sim.vehicle`: road types and the true motion; :mod:`hdrd.sim.gps`: GPS truth.
- :mod:`hdrd.sim.benchmark`: the paper-like nine training drives (Table II) and five tests.
- :mod:`hdrd.sim.profiles`: the drives ``hdrd fakegyro`` and ``hdrd run --simulate`` play
  (built-in standstill and constant-rate drives, or a road type) and their ADC frames.

Conventions: yaw rate deg/s, + = counter-clockwise (left turn); heading compass deg, clockwise
from north; time s since power-on; temperature deg C.
"""

from hdrd.sim.drive import simulate_drive, simulate_legs
from hdrd.sim.effects import (
    EFFECT_NAMES,
    EFFECTS,
    Bandwidth,
    BiasInstability,
    Effect,
    MotionOffset,
    Quantization,
    RateRandomWalk,
    Saturation,
    ScaleAsymmetry,
    ScaleFactor,
    StaticBias,
    TemperatureBias,
    TimeOffset,
    WarmupTransient,
    WhiteNoise,
    effect_from_dict,
)
from hdrd.sim.gps import GpsModel, gps_course, heading_from_rate
from hdrd.sim.gyro import (
    DEFAULT_START_MODEL,
    GyroModel,
    crs03_default_model,
    load_model,
    save_model,
)
from hdrd.sim.vehicle import DRIVE_TYPES, PROFILES, CabinTemperature, RoadProfile, count_turns

__all__ = [
    "DEFAULT_START_MODEL",
    "DRIVE_TYPES",
    "EFFECTS",
    "EFFECT_NAMES",
    "PROFILES",
    "Bandwidth",
    "BiasInstability",
    "CabinTemperature",
    "Effect",
    "GpsModel",
    "GyroModel",
    "MotionOffset",
    "Quantization",
    "RateRandomWalk",
    "RoadProfile",
    "Saturation",
    "ScaleAsymmetry",
    "ScaleFactor",
    "StaticBias",
    "TemperatureBias",
    "TimeOffset",
    "WarmupTransient",
    "WhiteNoise",
    "count_turns",
    "crs03_default_model",
    "effect_from_dict",
    "gps_course",
    "heading_from_rate",
    "load_model",
    "save_model",
    "simulate_drive",
    "simulate_legs",
]
