"""Models of the real recordings' sensors: a grade preset plus what ``hdrd gap`` measured on the
recording's *tuning* drives where the preset missed it (docs/model-gap.md, "The
simulated-versus-real gap on the shared drives"; bench/gap_real.py measures every value);
and the gyro errors ``hdrd gap`` fitted to a set of real drives as the distribution simulated
routes draw their gyro from (:func:`errors_from`, :class:`FittedErrors`; docs/model-gap.md,
"From real drives to training routes").

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

import json
import math
import os
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from hdrd.core.grades import Grade
from hdrd.errors import clipped
from hdrd.io.files.access import printable
from hdrd.io.files.drivelog import DriveLog
from hdrd.sim.drive import simulate_drive
from hdrd.sim.effects import Bandwidth, Quantization, RateRandomWalk, TimeOffset, WhiteNoise
from hdrd.sim.gps import GpsModel
from hdrd.sim.grades import grade_model
from hdrd.sim.gyro import GyroModel

__all__ = [
    "MAX_GAP_REPORT_BYTES",
    "NOT_THE_GYRO",
    "RECORDINGS",
    "RECORDING_TABLE",
    "FittedErrors",
    "Recording",
    "errors_from",
    "gyro_error_draws",
    "log_rate_model",
    "point_sampled_sd",
    "recording_gps",
    "recording_model",
    "simulate_recording",
]

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


# -- the errors real gyros showed, as the distribution simulated routes draw from ----------------

MAX_GAP_REPORT_BYTES = 64 << 20
"""Largest ``hdrd gap --report`` file read: 64 MiB (a fleet's reports run to 20-50 KB a drive:
1,300 to 3,000 drives)."""
MAX_GAP_REPORT_VALUES = 4_000_000
"""Most JSON values (objects, arrays, keys, numbers, strings) a report read may hold, counted
before any is built: a drive's report holds some 1,300 to 3,000 (18 bytes a value), but 64 MiB
of ``{},`` would be 22 million objects, 1.6 GB to build; 4 million of the smallest values take
some 300 MB."""

NOT_THE_GYRO = ("time_offset",)
"""Effects left out of a drive's draw when its truth was a heading (a GPS course): there a
``time_offset`` is the course's latency, not the gyro's."""


@dataclass(frozen=True)
class FittedErrors:
    """The gyro errors ``hdrd gap`` fitted to real drives: one model per drive (its report's
    ``final_params``), each drive equally likely. A simulated route draws the whole model of
    one drive (:meth:`draw`), so that the effects a real gyro showed together stay together
    (a random walk with the white noise it came with, a temperature slope with its bias).
    ``drives``: (name, model) in the report's order; ``source``: where they came from."""

    drives: tuple[tuple[str, GyroModel], ...]
    source: str = ""

    def draw(self, seed: int) -> tuple[str, GyroModel]:
        """The drive (name, model) route ``seed`` draws: uniform over the drives, from a
        stream of its own (the route, its temperature and its GPS keep theirs)."""
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0x676170])  # "gap"
        return self.drives[int(rng.integers(len(self.drives)))]


def _report_model(rep: Any, where: str) -> tuple[str, GyroModel]:
    """One drive's (name, fitted model) from its report; ValueError naming what is wrong."""
    if not isinstance(rep, dict) or not isinstance(rep.get("final_params"), list):
        raise ValueError(f"{where}: not an hdrd gap report (no final_params list)")
    log: dict[str, Any] = rep["log"] if isinstance(rep.get("log"), dict) else {}
    name = str(log.get("name") or where)
    try:
        model = GyroModel.from_dict({"effects": rep["final_params"]})
    except (ValueError, TypeError) as exc:
        drive = f" ({clipped(printable(name), 80)})" if name != where else ""
        raise ValueError(f"{where}{drive}: {exc}") from None
    if str(log.get("truth", "")).startswith("heading_truth"):
        for effect in NOT_THE_GYRO:
            model = model.without(effect)
    return name, model


def errors_from(source: str | os.PathLike[str] | dict[str, Any]) -> FittedErrors:
    """The gyro errors of an ``hdrd gap --report`` file (one drive's report, or a fleet's
    ``{"drives": [...], "skipped": [...]}``), or of that JSON already read. Raises ValueError
    naming the file and what is wrong (one line), OSError if it cannot be read."""
    from hdrd.io.files.access import InputFileError, read_limited, shown_path

    if isinstance(source, dict):
        doc: Any = source
        where = "the report"
    else:
        where = shown_path(source)
        try:
            doc = _report_json(read_limited(source, MAX_GAP_REPORT_BYTES), where)
        except InputFileError as e:
            raise ValueError(f"{where}: cannot be read: {e}") from None
    if not isinstance(doc, dict):
        raise ValueError(
            f"{where}: not an hdrd gap report (a JSON object: one drive's report, or "
            '{"drives": [report, ...]} of several)'
        )
    reports = doc.get("drives") if "drives" in doc else [doc]
    if not isinstance(reports, list) or not reports:
        raise ValueError(f"{where}: no drive's report in it")
    drives = tuple(
        _report_model(rep, f"{where}, drive {i + 1}" if len(reports) > 1 else where)
        for i, rep in enumerate(reports)
    )
    return FittedErrors(tuple((printable(n)[:100], m) for n, m in drives), where)


def _report_json(data: bytes, where: str) -> Any:
    """The JSON of a report's bytes, its values counted first (a comma, a colon or an opening
    bracket before each but the first, an empty pair once; those inside strings counted too) and
    refused beyond :data:`MAX_GAP_REPORT_VALUES` before any is built. ValueError naming
    ``where`` and what is wrong, in one line."""
    values = 1 + sum(data.count(c) for c in (b",", b":", b"[", b"{"))
    values -= data.count(b"{}") + data.count(b"[]")  # an empty one's comma counted it
    if values > MAX_GAP_REPORT_VALUES:
        raise ValueError(
            f"{where}: holds about {values:,} JSON values, more than the "
            f"{MAX_GAP_REPORT_VALUES:,} a report is read with (a drive's report: some 3,000)"
        )
    try:
        return json.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise ValueError(f"{where}: not JSON (not UTF-8 text)") from None
    except json.JSONDecodeError as e:
        raise ValueError(
            f"{where}: not JSON ({e.msg} at line {e.lineno}, column {e.colno})"
        ) from None
    except RecursionError:
        raise ValueError(f"{where}: not JSON this reads (nested too deep)") from None
    except ValueError as e:  # int() of more digits than Python converts
        digits = "more than 4300 digits" if "digits" in str(e) else type(e).__name__
        raise ValueError(f"{where}: not JSON (a number of {digits})") from None


def gyro_error_draws(
    source: str | os.PathLike[str] | dict[str, Any] | FittedErrors, seeds: Any
) -> list[GyroModel]:
    """The gyro model each route of ``seeds`` (an iterable of ints) draws from the errors of
    an ``hdrd gap`` report (:func:`errors_from`): for a drift reducer tuned on simulated routes
    whose gyros err as the real ones did."""
    errors = source if isinstance(source, FittedErrors) else errors_from(source)
    return [errors.draw(int(s))[1] for s in seeds]
