"""Profiles of the real recordings' sensors: a grade preset plus what ``hdrd gap`` measured on
the recording's *tuning* drives where the preset missed it (docs/model-gap.md, "The
simulated-versus-real gap on the shared drives"; bench/gap_real.py measures every value and
is their user).

A recording profile says how a log of that recording is made: the gyro (a grade of
:mod:`hdrd.core.grades` with some values replaced and effects added), how the log samples it
(point samples of a sensor running faster than the log), and its GPS course (a latency). Plain
data with a source per value, like :data:`hdrd.core.grades.GRADE_TABLE`; the table is the one
place to change a profile.

Parameters of a profile (rates deg/s, + = counter-clockwise; times s):

==================== ============== ==========================================================
grade                -              the grade preset the gyro starts from
log_hz               Hz             the log's sample rate
sensor_hz            Hz             the rate the gyro runs at; the log keeps point samples
white_dps_per_rthz   deg/s/sqrt(Hz) white noise density as installed (at the sensor's
                                    bandwidth), replacing the grade's
quant_step_dps       deg/s          the log's output step, replacing the grade's
rrw_dps_per_sqrt_s   deg/s/sqrt(s)  rate random walk (the bias's wander while driving),
                                    replacing the grade's
gps_latency_s        s              the GPS course's latency (:class:`hdrd.sim.gps.GpsModel`)
gps_course_sd_deg    deg            the GPS course's noise at speed (its ``floor_deg``)
==================== ============== ==========================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from hdrd.core.grades import Grade
from hdrd.io.files.drivelog import DriveLog
from hdrd.sim.drive import simulate_drive
from hdrd.sim.effects import Bandwidth, Quantization, RateRandomWalk, TimeOffset, WhiteNoise
from hdrd.sim.gps import GpsModel
from hdrd.sim.grades import grade_model
from hdrd.sim.gyro import GyroModel

RECORDING_TABLE: dict[str, dict[str, Any]] = {
    "driveplotr": {
        "description": "DrivePlotR's naturalistic-driving logger: a phone-class gyro read "
        "once a second (point samples, 1/16 deg/s steps) and a phone GPS course at 1 Hz",
        "grade": "phone",
        "log_hz": 1.0,
        "sensor_hz": 100.0,
        "white_dps_per_rthz": 0.0142,
        "quant_step_dps": 0.0625,
        "rrw_dps_per_sqrt_s": 0.0108,
        "gps_latency_s": 0.98,
        "gps_course_sd_deg": 4.77,
        "sources": {
            "log_hz, sensor_hz": "../shared/data/driveplotr_nds/README.txt: 1 Hz point "
            "samples of a faster sensor; 100 Hz is the phone grade's rate (assumed)",
            "white_dps_per_rthz": "the tuning drives' stops: 0.126 deg/s per 1 Hz sample "
            "(median of hdrd gap's reading inside stops, bench/gap_real.py), as a 100 Hz sensor "
            "of the phone grade's 32 Hz bandwidth gives it point-sampled (the BMI160 "
            "datasheet's 0.007 gives 0.061: the rest is the idling car's vibration)",
            "quant_step_dps": "hdrd gap's lattice on every tuning drive: 0.0625 deg/s",
            "rrw_dps_per_sqrt_s": "the rate random walk hdrd gap names on the tuning drives "
            "long enough to show it (median of the significant ones; bench/gap_real.py)",
            "gps_latency_s": "hdrd gap's time_offset on the tuning drives, their stops "
            "truth too (median, sign turned: the course lags the gyro; bench/gap_real.py)",
            "gps_course_sd_deg": "the heading noise at the fixes hdrd gap fits on the tuning "
            "drives with this profile, their stops truth too (median; bench/gap_real.py)",
        },
    },
}
"""Every recording profile by name: its values and, per value, where it comes from."""

RECORDINGS: tuple[str, ...] = tuple(RECORDING_TABLE)


@dataclass(frozen=True)
class Recording:
    """One row of :data:`RECORDING_TABLE`, typed (units in the module docstring)."""

    name: str
    description: str
    grade: str
    log_hz: float
    sensor_hz: float
    white_dps_per_rthz: float
    quant_step_dps: float
    rrw_dps_per_sqrt_s: float
    gps_latency_s: float
    gps_course_sd_deg: float
    sources: dict[str, str]

    @classmethod
    def from_table(cls, name: str) -> Recording:
        """The profile ``name``; ValueError naming the known ones."""
        if name not in RECORDING_TABLE:
            raise ValueError(f"unknown recording {name!r} (known: {', '.join(RECORDINGS)})")
        row = RECORDING_TABLE[name]
        return cls(name=name, **{k: row[k] for k in cls.__dataclass_fields__ if k != "name"})


def point_sampled_sd(density_dps_per_rthz: float, bandwidth_hz: float, sensor_hz: float) -> float:
    """The sd per sample (deg/s) of a point sample of a sensor's white noise of this density
    seen through its first-order low-pass at ``sensor_hz``, as the simulator makes it
    (:class:`hdrd.sim.gyro.WhiteNoise` then :class:`hdrd.sim.gyro.Bandwidth`): N sqrt(fs)
    sqrt((1 - a) / (1 + a)), a = exp(-2 pi f_c / fs); whatever rate the log keeps."""
    a = math.exp(-2.0 * math.pi * bandwidth_hz / sensor_hz)
    return density_dps_per_rthz * math.sqrt(sensor_hz) * math.sqrt((1.0 - a) / (1.0 + a))


def recording_model(name: str, seed: int = 0) -> GyroModel:
    """The recording's gyro at its sensor's rate (for :func:`hdrd.sim.drive.simulate_legs`
    with ``sensor_hz``): the grade's model (its turn-on bias drawn from ``seed``) with the
    profile's white noise, output step and random walk."""
    r = Recording.from_table(name)
    return (
        grade_model(r.grade, seed)
        .with_effect(WhiteNoise(density_dps_per_rthz=r.white_dps_per_rthz))
        .with_effect(Quantization(step_dps=r.quant_step_dps))
        .with_effect(RateRandomWalk(k_dps_per_sqrt_s=r.rrw_dps_per_sqrt_s))
    )


def recording_gps(name: str) -> GpsModel:
    """The recording's GPS course: the simulator's default receiver with the profile's latency
    and course noise."""
    r = Recording.from_table(name)
    return replace(GpsModel(), latency_s=r.gps_latency_s, floor_deg=r.gps_course_sd_deg)


def log_rate_model(name: str, seed: int = 0) -> GyroModel:
    """The recording's gyro as its log sees it at ``log_hz`` (for ``hdrd gap --model``, which
    simulates a model at the log's own sample times): the point-sampled sensor noise as a white
    noise of the same sd per log sample, the low-pass left out (it acts within a sensor
    sample), and the GPS course's latency as a ``time_offset`` of -latency (the gyro leads the
    course). Without a temperature in the log, the grade's temperature effect is left out."""
    r = Recording.from_table(name)
    g = Grade.from_table(r.grade)
    sd = point_sampled_sd(r.white_dps_per_rthz, g.bandwidth_hz, r.sensor_hz)
    m = recording_model(name, seed).without("bandwidth").without("temperature_bias")
    m = m.with_effect(WhiteNoise(density_dps_per_rthz=sd / math.sqrt(r.log_hz)))
    if r.gps_latency_s > 0:
        m = m.with_effect(TimeOffset(delay_s=-r.gps_latency_s))
    assert not isinstance(m.get("bandwidth"), Bandwidth)
    return m


def simulate_recording(name: str, drive: str, minutes: float, seed: int) -> DriveLog:
    """A drive of ``drive`` type logged as the recording ``name`` logs: its gyro point-sampled
    at ``log_hz`` from ``sensor_hz``, its GPS course with the latency. Deterministic for a
    seed."""
    r = Recording.from_table(name)
    return simulate_drive(
        drive,
        minutes,
        seed,
        hz=r.log_hz,
        model=recording_model(name, seed),
        gps=recording_gps(name),
        sensor_hz=r.sensor_hz,
    )
