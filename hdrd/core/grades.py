"""Gyro grades: named presets of a gyro's error model from datasheets (docs/gyro-model.md,
"Grades"); data the product uses (``gyro.grade``: HDR+'s error model) and the simulator too.

A grade is plain data (:data:`GRADE_TABLE`: one mapping per grade, each value with its source
in ``sources``). :func:`hdrd.core.gyronoise.grade_noise` gives it as HDR+'s error model
(:class:`hdrd.core.gyronoise.GyroNoise`); :func:`hdrd.sim.grades.grade_model` builds the
simulator's gyro from it. The table is the one place to add or change a grade.

Parameters of a grade (rates deg/s, + = counter-clockwise; times s; temperatures degC):
==================== ============== ==========================================================
white_dps_per_rthz   deg/s/sqrt(Hz) white rate noise density N (angle random walk)
bias_instability_dps deg/s          B, the floor of the Allan deviation ("in-run bias
                                    stability"); simulated as a Gauss-Markov bias of sigma
                                    B / 0.62 (its Allan deviation peaks at 0.62 sigma)
bias_tau_s           s              the Gauss-Markov correlation time (the floor near 1.9 tau)
rrw_dps_per_sqrt_s   deg/s/sqrt(s)  rate random walk K
temp_coeff_dps_per_c deg/s/degC     bias temperature coefficient (of the cabin temperature)
quant_step_dps       deg/s          output resolution (one LSB of the reading hdrd gets)
bandwidth_hz         Hz             first-order output low-pass, -3 dB
startup_bias_dps     deg/s          mean turn-on bias (the null offset before calibration)
startup_bias_sd_dps  deg/s          spread of the turn-on bias, drawn per drive from its seed
scale_error          -              scale-factor error
range_dps            deg/s          measurement range (saturation)
rate_hz              Hz             the sample rate hdrd reads it at (``hdrd simulate`` default)
==================== ============== ==========================================================

The CRS03-04 grade is today's default model (:func:`hdrd.sim.gyro.crs03_default_model`)
exactly, so the paper-like benchmark is unchanged by it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

__all__ = [
    "DEFAULT_GRADE",
    "GM_PEAK",
    "GRADES",
    "GRADE_TABLE",
    "Grade",
]

GM_PEAK = 0.62
"""Peak of a Gauss-Markov bias's Allan deviation, in units of its sigma (docs/gyro-model.md)."""

DEG_PER_HOUR = 1.0 / 3600.0
"""deg/s per deg/h."""
ARW_DEG_PER_RTH = 1.0 / 60.0
"""deg/s/sqrt(Hz) per deg/sqrt(h) (angle random walk)."""

GRADE_TABLE: dict[str, dict[str, Any]] = {
    "crs03": {
        "description": "Silicon Sensing CRS03-04 on a 16-bit 5 V ADC (the paper's gyro; "
        "today's default model)",
        "white_dps_per_rthz": 0.05,
        "bias_instability_dps": GM_PEAK * 0.01,
        "bias_tau_s": 300.0,
        "rrw_dps_per_sqrt_s": 3e-4,
        "temp_coeff_dps_per_c": 0.008,
        "quant_step_dps": 5.0 / 2**16 / 0.010,
        "bandwidth_hz": 10.0,
        "startup_bias_dps": 1.0,
        "startup_bias_sd_dps": 0.0,
        "scale_error": 0.005,
        "range_dps": 200.0,
        "rate_hz": 10.0,
        "sources": {
            "range_dps, bandwidth_hz": "CRS03 datasheet (Silicon Sensing), as quoted in "
            "../shared/paper/HDR-NOTES.md: +-200 deg/s, 10 Hz bandwidth",
            "bias_instability_dps, bias_tau_s, rrw_dps_per_sqrt_s": "chosen inside the datasheet's bias "
            "drift < 1.1 deg/min (0.018 deg/s); hdrd's default model",
            "temp_coeff_dps_per_c": "chosen so that a 5 -> 21 degC cabin moves the bias "
            "~0.17 deg/s (the paper's Sec. 5); within the datasheet's +-3 deg/s over "
            "-40..85 degC; plus -1e-4 deg/s/degC^2 and a 0.02 deg/s warm-up transient",
            "white_dps_per_rthz": "hdrd's default model (0.16 deg/s rms at 10 Hz)",
            "quant_step_dps": "10 mV/(deg/s) on a 16-bit ADC over 5 V (hdrd.core.sensor)",
            "startup_bias_dps, startup_bias_sd_dps": "the paper measured eps0 = 1.432 deg/s on its unit; no spread, "
            "so the benchmark is today's",
            "scale_error": "hdrd's default model",
            "rate_hz": "the paper: 10 Hz",
        },
    },
    "phone": {
        "description": "consumer phone MEMS gyro (Bosch BMI160-like), +-2000 deg/s range, 100 Hz",
        "white_dps_per_rthz": 0.007,
        "bias_instability_dps": 10.0 * DEG_PER_HOUR,
        "bias_tau_s": 100.0,
        "rrw_dps_per_sqrt_s": 1e-4,
        "temp_coeff_dps_per_c": 0.02,
        "quant_step_dps": 1.0 / 16.4,
        "bandwidth_hz": 32.0,
        "startup_bias_dps": 0.0,
        "startup_bias_sd_dps": 1.0,
        "scale_error": 0.01,
        "range_dps": 2000.0,
        "rate_hz": 100.0,
        "sources": {
            "white_dps_per_rthz": "BMI160 datasheet (BST-BMI160-DS000-07, 2015): output "
            "noise 0.007 deg/s/sqrt(Hz)",
            "quant_step_dps, range_dps": "BMI160 datasheet: 16.4 LSB/(deg/s) at +-2000 deg/s "
            "(the DrivePlotR phone log's 1/16 deg/s steps are this range)",
            "temp_coeff_dps_per_c": "BMI160 datasheet: zero-rate offset drift +-0.05 "
            "deg/s/K (a bound); 0.02 taken as a typical part (assumed)",
            "startup_bias_dps, startup_bias_sd_dps": "BMI160 datasheet: zero-rate offset +-3 deg/s; the "
            "comma2k19 phone reads 3.9 deg/s raw; 1 deg/s taken as the spread (assumed)",
            "bandwidth_hz": "BMI160 datasheet: ~32 Hz at 100 Hz output data rate, normal "
            "filter mode",
            "bias_instability_dps, bias_tau_s, rrw_dps_per_sqrt_s": "not specified in the "
            "datasheet; 10 deg/h, the best of the 'rate grade' class (10-1000 deg/h; "
            "Norouzpour-Shirazi, IEEE Sensors 2013 tutorial), assumed",
            "scale_error": "BMI160 datasheet: sensitivity tolerance +-1 %",
            "rate_hz": "a common phone sensor rate (comma2k19: 104 Hz)",
        },
    },
    "automotive": {
        "description": "automotive MEMS yaw-rate sensor of an ESC system, read from the "
        "vehicle's CAN bus (0.244 deg/s signal resolution)",
        "white_dps_per_rthz": 0.01,
        "bias_instability_dps": 20.0 * DEG_PER_HOUR,
        "bias_tau_s": 100.0,
        "rrw_dps_per_sqrt_s": 1e-4,
        "temp_coeff_dps_per_c": 0.005,
        "quant_step_dps": 0.244,
        "bandwidth_hz": 60.0,
        "startup_bias_dps": 0.0,
        "startup_bias_sd_dps": 1.0,
        "scale_error": 0.005,
        "range_dps": 111.0,
        "rate_hz": 80.0,
        "sources": {
            "range_dps, bandwidth_hz": "Hyundai/Kia ESP yaw-rate & lateral-G sensor "
            "specification (2011 shop manual): range typ. 111 deg/s, upper cut-off typ. 60 Hz",
            "startup_bias_dps, startup_bias_sd_dps": "same: offset 3.75 deg/s within life and "
            "temperature (a bound); mean 0, 1 deg/s spread assumed",
            "scale_error": "same: non-linearity +-1 %; 0.5 % assumed",
            "quant_step_dps, rate_hz": "Toyota KINEMATICS CAN message (opendbc, via the "
            "comma2k19 README in ../shared/data): YAW_RATE in 0.244 deg/s steps at ~83 Hz",
            "white_dps_per_rthz": "automotive gyros typically 0.004-0.02 deg/s/sqrt(Hz) "
            "(Ersa automotive gyroscope selection guide, 2025); 0.01 assumed",
            "bias_instability_dps, bias_tau_s, rrw_dps_per_sqrt_s, temp_coeff_dps_per_c": "not "
            "in the specification; 20 deg/h (rate grade) and 0.005 deg/s/degC assumed",
        },
    },
    "tactical": {
        "description": "tactical-grade MEMS IMU (Analog Devices ADIS16465-1-like), "
        "factory temperature-compensated, 100 Hz",
        "white_dps_per_rthz": 0.15 * ARW_DEG_PER_RTH,
        "bias_instability_dps": 2.0 * DEG_PER_HOUR,
        "bias_tau_s": 100.0,
        "rrw_dps_per_sqrt_s": 3.8e-5,
        "temp_coeff_dps_per_c": 5e-4,
        "quant_step_dps": 1.0 / 160.0,
        "bandwidth_hz": 550.0,
        "startup_bias_dps": 0.0,
        "startup_bias_sd_dps": 0.2,
        "scale_error": 0.001,
        "range_dps": 125.0,
        "rate_hz": 100.0,
        "sources": {
            "white_dps_per_rthz": "ADIS16465 datasheet (Analog Devices): angular random walk "
            "0.15 deg/sqrt(h) (-1 and -2 models)",
            "bias_instability_dps": "ADIS16465 datasheet: in-run bias stability 2 deg/h "
            "(ADIS16465-1)",
            "quant_step_dps, range_dps": "ADIS16465 datasheet: +-125 deg/s (-1 model), "
            "160 LSB/(deg/s) in 16-bit output",
            "bandwidth_hz": "ADIS16465 datasheet: 550 Hz -3 dB bandwidth",
            "rrw_dps_per_sqrt_s": "the rtklib drive 0708 source project's filter setting "
            "for this IMU (drive_config.py gyro_bias_PSD, 3.8e-5 deg/s/sqrt(s))",
            "temp_coeff_dps_per_c": "factory temperature calibration over -40..85 degC; the "
            "residual 5e-4 deg/s/degC is assumed",
            "startup_bias_dps, startup_bias_sd_dps": "assumed (mean 0, spread 0.2 deg/s); the "
            "rtklib unit reads 0.17 deg/s at standstill",
            "scale_error": "assumed (factory-calibrated sensitivity)",
            "bias_tau_s": "assumed",
            "rate_hz": "the rtklib drive 0708 recording: 100 Hz",
        },
    },
}
"""Every grade by name: its parameters and, per parameter, where the value comes from."""

DEFAULT_GRADE = "crs03"


@dataclass(frozen=True)
class Grade:
    """One row of :data:`GRADE_TABLE`, typed (units in the module docstring)."""

    name: str
    description: str
    white_dps_per_rthz: float
    bias_instability_dps: float
    bias_tau_s: float
    rrw_dps_per_sqrt_s: float
    temp_coeff_dps_per_c: float
    quant_step_dps: float
    bandwidth_hz: float
    startup_bias_dps: float
    startup_bias_sd_dps: float
    scale_error: float
    range_dps: float
    rate_hz: float
    sources: dict[str, str]

    @classmethod
    def from_table(cls, name: str) -> Grade:
        """The grade ``name``; ValueError naming the known grades."""
        if name not in GRADE_TABLE:
            raise ValueError(f"unknown gyro grade {name!r} (known: {', '.join(GRADE_TABLE)})")
        row = GRADE_TABLE[name]
        kw = {f.name: row[f.name] for f in fields(cls) if f.name != "name"}
        for k, v in kw.items():
            if k in ("description", "sources"):
                continue
            ok = isinstance(v, (int, float)) and math.isfinite(v)
            if not ok or (v < 0.0 and k != "startup_bias_dps"):
                raise ValueError(f"grade {name}: {k} = {v!r} must be a finite number >= 0")
        return cls(name=name, **kw)


GRADES: tuple[str, ...] = tuple(GRADE_TABLE)
"""Grade names, in the table's order (roughly worst to best)."""
