"""Synthetic stand-ins for real gyro logs at rest, built to the properties measured on real
devices (docs/model-gap.md, "Real-data cases"), for the model-gap tests and bench/gap_real.py.

Each builder returns a :class:`~hdrd.io.files.drivelog.DriveLog` *as a writer would have stored it* (values
rounded to the CSV's decimals) and the hidden truth. Rates deg/s, + = CCW; t s; temp degC.

- :func:`imu_log`: an IMU at rest for hours while its temperature goes 5 -> 24 -> 21 degC; the
  rate follows the temperature at 0.026 deg/s/degC (the bias following the die temperature
  with a short thermal lag; the temperature column read by a noisy sensor), a slow random walk,
  white noise, every value on a 0.0305 deg/s ADC step (1/32.8: a +/-1000 deg/s 16-bit MEMS),
  written with 6 decimals.
- :func:`phone_log`: a phone at rest for hours: white noise seen through a ~0.2 Hz low-pass
  (neighbouring samples at 10 Hz correlate at ~0.88), a Gauss-Markov bias (Allan floor ~0.004
  deg/s) and a rate random walk ~1.5e-4 deg/s/sqrt(s); a battery temperature that drifts by a
  degree or two and has nothing to do with the gyro; float output (no ADC lattice); optionally
  white noise after the low-pass (the output stage's).
- :func:`phone50_log`: a phone at rest for 6 h at 50 Hz whose filter has two sections (-3 dB at
  0.2 Hz) after its ADC (1/16.4 deg/s, dithered by the sensor's own noise: float output), a
  bias of an Allan floor of 0.0055 deg/s and tau_c 36 s, a random walk of 1.5e-4
  deg/s/sqrt(s): a real phone's Allan analysis; read with a one-section low-pass, hdrd gap
  named only the low-pass and stopped at a large gap.
- :func:`with_handling`: the same log with periods where someone picked the device up (large
  rates), marked ``valid`` = 0, or with those rows dropped.
- :func:`span_drive`: a drive, not a rest: a MEMS unit in 0.01 rad/s codes beside an INS that
  gives its rate only while moving, reading a motion offset while driving (or not: its twin).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from hdrd.io.files.drivelog import DriveLog
from hdrd.sim.drive import simulate_drive
from hdrd.sim.effects import MotionOffset, Quantization, StaticBias, WhiteNoise, ar1
from hdrd.sim.gyro import GyroModel

FloatArray = npt.NDArray[np.float64]

MPU_STEP_DPS = 1.0 / 32.8
"""A +/-1000 deg/s 16-bit MEMS gyro's step: 0.030488 deg/s."""


@dataclass(frozen=True)
class Hidden:
    """What went into a stand-in log."""

    temp_coeff_dps_per_c: float = 0.0
    step_dps: float = 0.0
    white_dps_per_rthz: float = 0.0
    rrw_dps_per_sqrt_s: float = 0.0
    gm_sigma_dps: float = 0.0
    gm_tau_s: float = 0.0
    cutoff_hz: float = 0.0
    filter_order: int = 0
    output_sd_dps: float = 0.0


def _lowpass(x: FloatArray, a: float, order: int) -> FloatArray:
    """``order`` cascaded first-order low-passes y[k] = a y[k-1] + (1 - a) x[k], settled."""
    for _ in range(order):
        n = x.shape[0]
        x = ar1(np.full(n, -math.log(a)), (1.0 - a) * x, float(x[0]))
    return x


def imu_temperature_profile(t: FloatArray, rng: np.random.Generator) -> FloatArray:
    """5 -> 24 -> 21 degC over the log: the device warms from a cold start towards the room,
    then the room cools in the evening; small cycles of a heating system, degC."""
    d = float(t[-1] - t[0]) or 1.0
    u = (t - t[0]) / d
    warm = 5.0 + 19.5 * (1.0 - np.exp(-u / 0.12))
    cool = -3.5 / (1.0 + np.exp(-(u - 0.7) / 0.05))
    cycles = 0.25 * np.sin(2.0 * math.pi * (t - t[0]) / 2700.0 + rng.uniform(0, 2 * math.pi))
    return np.asarray(warm + cool + cycles)


def imu_log(
    seed: int = 0,
    hours: float = 23.0,
    hz: float = 1.0,
    coeff_dps_per_c: float = 0.026,
    white_dps_per_rthz: float = 0.012,
    rrw_dps_per_sqrt_s: float = 8e-5,
    thermal_lag_s: float = 240.0,
    temp_noise_c: float = 0.03,
    bias_dps: float = -0.61,
    step_dps: float = MPU_STEP_DPS,
    decimals: int = 6,
) -> tuple[DriveLog, Hidden]:
    """The IMU at rest (see the module docstring)."""
    rng = np.random.default_rng([seed, 23])
    n = int(hours * 3600.0 * hz)
    t = np.arange(n) / hz
    temp = imu_temperature_profile(t, rng)
    die = _lowpass(temp, math.exp(-1.0 / (hz * thermal_lag_s)), 1) if thermal_lag_s else temp
    rw = np.cumsum(rrw_dps_per_sqrt_s * math.sqrt(1.0 / hz) * rng.standard_normal(n))
    rw -= rw[0]
    white = white_dps_per_rthz * math.sqrt(hz) * rng.standard_normal(n)
    rate = bias_dps + coeff_dps_per_c * (die - 20.0) + rw + white
    omega = step_dps * np.round(rate / step_dps)
    temp_read = temp + temp_noise_c * rng.standard_normal(n)
    log = DriveLog(
        t=np.round(t, 4),
        omega=np.round(omega, decimals),
        temp_c=np.round(temp_read, 2),
        name=f"imu{seed}",
    )
    return log, Hidden(
        temp_coeff_dps_per_c=coeff_dps_per_c,
        step_dps=step_dps,
        white_dps_per_rthz=white_dps_per_rthz,
        rrw_dps_per_sqrt_s=rrw_dps_per_sqrt_s,
    )


def phone_log(
    seed: int = 0,
    hours: float = 6.0,
    hz: float = 10.0,
    neighbour_r: float = 0.88,
    filter_order: int = 1,
    white_dps_per_rthz: float = 0.015,
    gm_sigma_dps: float = 0.006,
    gm_tau_s: float = 300.0,
    rrw_dps_per_sqrt_s: float = 1.5e-4,
    bias_dps: float = 0.21,
    output_sd_dps: float = 0.0,
    cutoff_hz: float = 0.0,
    step_dps: float = 0.0,
    adc_first: bool = False,
) -> tuple[DriveLog, Hidden]:
    """The phone at rest (see the module docstring). The low-pass is ``filter_order`` cascaded
    first-order sections, tuned so that neighbouring samples correlate at ``neighbour_r``
    (without the output noise), or, given ``cutoff_hz``, with the cascade's -3 dB there; ``output_sd_dps``: white noise after it, sd per sample (the output
    stage's own: the shortest tau reads more than the low-passed noise alone); ``step_dps``:
    every value rounded to that ADC step (0: float output), or with ``adc_first`` the sensor's
    rate rounded before the low-pass (a filter after the ADC: float output)."""
    rng = np.random.default_rng([seed, 6])
    n = int(hours * 3600.0 * hz)
    t = np.arange(n) / hz
    # Pole a of each section: first order: rho1 = a; two equal poles: rho1 = 2a / (1 + a**2).
    if cutoff_hz > 0.0:  # each section's cutoff puts the cascade's -3 dB at cutoff_hz
        section = cutoff_hz / math.sqrt(2.0 ** (1.0 / filter_order) - 1.0)
        a = math.exp(-2.0 * math.pi * section / hz)
    elif filter_order == 1:
        a = neighbour_r
    elif filter_order == 2:
        a = (1.0 - math.sqrt(1.0 - neighbour_r**2)) / neighbour_r
    else:
        raise ValueError("filter_order must be 1 or 2")
    # The whole filter's -3 dB (each section's for one section).
    cutoff = -math.log(a) * hz / (2.0 * math.pi) * math.sqrt(2.0 ** (1.0 / filter_order) - 1.0)
    white = white_dps_per_rthz * math.sqrt(hz) * rng.standard_normal(n)
    ag = math.exp(-1.0 / (hz * gm_tau_s))
    gm = ar1(
        np.full(n, 1.0 / (hz * gm_tau_s)),
        gm_sigma_dps * math.sqrt(1.0 - ag * ag) * rng.standard_normal(n),
        gm_sigma_dps * float(rng.standard_normal()),
    )
    rw = np.cumsum(rrw_dps_per_sqrt_s * math.sqrt(1.0 / hz) * rng.standard_normal(n))
    rw -= rw[0]
    rate = bias_dps + gm + rw + white
    if step_dps > 0.0 and adc_first:
        rate = step_dps * np.round(rate / step_dps)
    omega = _lowpass(rate, a, filter_order)
    if output_sd_dps > 0:
        omega = omega + output_sd_dps * np.random.default_rng([seed, 7]).standard_normal(n)
    if step_dps > 0.0 and not adc_first:
        omega = step_dps * np.round(omega / step_dps)
    u = t / t[-1]
    temp = 27.0 + 1.6 * (1.0 - np.exp(-u / 0.15)) - 0.6 * u + 0.1 * rng.standard_normal(n)
    log = DriveLog(t=np.round(t, 4), omega=omega, temp_c=np.round(temp, 1), name=f"phone{seed}")
    return log, Hidden(
        white_dps_per_rthz=white_dps_per_rthz,
        rrw_dps_per_sqrt_s=rrw_dps_per_sqrt_s,
        gm_sigma_dps=gm_sigma_dps,
        gm_tau_s=gm_tau_s,
        cutoff_hz=cutoff,
        filter_order=filter_order,
        output_sd_dps=output_sd_dps,
        step_dps=step_dps,
    )


PHONE_STEP_DPS = 1.0 / 16.4
"""A +/-2000 deg/s 16-bit MEMS gyro's step (a phone's): 0.061 deg/s."""


def phone50_log(
    seed: int = 0, hours: float = 6.0, adc_first: bool = True
) -> tuple[DriveLog, Hidden]:
    """The phone at rest at 50 Hz (see the module docstring): white noise 0.015
    deg/s/sqrt(Hz) through two low-pass sections, -3 dB at 0.2 Hz; a Gauss-Markov bias of
    sigma 0.0055 / 0.62 deg/s (an Allan floor of 0.0055) and tau_c 36 s; a random walk of
    1.5e-4 deg/s/sqrt(s); the ADC's 1/16.4 deg/s step before the filter (``adc_first``; else
    after it, where the filtered noise, a fifth of a step, does not dither it)."""
    return phone_log(
        seed,
        hours=hours,
        hz=50.0,
        filter_order=2,
        cutoff_hz=0.2,
        gm_sigma_dps=0.0055 / 0.62,
        gm_tau_s=36.0,
        step_dps=PHONE_STEP_DPS,
        adc_first=adc_first,
    )


def handling_periods(t: FloatArray, count: int, seed: int) -> list[tuple[float, float]]:
    """``count`` periods of 20-90 s spread over the log (s, in the log's own t)."""
    rng = np.random.default_rng([seed, 77])
    d = float(t[-1] - t[0])
    starts = np.sort(rng.uniform(0.05 * d, 0.95 * d, count))
    return [(float(t[0] + s), float(t[0] + s + rng.uniform(20.0, 90.0))) for s in starts]


def with_handling(
    log: DriveLog, periods: list[tuple[float, float]], seed: int, how: str = "valid"
) -> DriveLog:
    """The log with someone handling the device in ``periods``: rates of tens of deg/s (turning
    it over, putting it back). ``how``: "valid" marks those rows valid = 0; "drop" removes
    them (time gaps); "none" leaves them unmarked."""
    rng = np.random.default_rng([seed, 78])
    inside = np.zeros(len(log), dtype=bool)
    omega = log.omega.copy()
    for a, b in periods:
        sel = (log.t >= a) & (log.t <= b)
        inside |= sel
        k = int(sel.sum())
        omega[sel] += np.cumsum(rng.normal(0.0, 3.0, k)) + 40.0 * np.sin(
            np.linspace(0.0, 3.0 * math.pi, k)
        )
    codes = log.omega / MPU_STEP_DPS
    if np.allclose(codes, np.round(codes), atol=1e-4):  # on the ADC's lattice: stay on it
        omega = np.round(np.round(omega / MPU_STEP_DPS) * MPU_STEP_DPS, 6)
    out = replace(log, omega=omega)
    if how == "valid":
        return replace(out, valid=np.where(inside, 0.0, 1.0))
    if how == "drop":
        keep = ~inside
        return replace(
            out,
            t=out.t[keep],
            omega=out.omega[keep],
            temp_c=None if out.temp_c is None else out.temp_c[keep],
        )
    return out


RAD_CODE_DPS = 0.5729577951308232
"""0.01 rad/s in deg/s: the code of the log that motivated the twin drives below."""


def span_drive(seed: int, offset_dps: float) -> DriveLog:
    """A MEMS unit beside an INS that gives its rate only while moving (written with 9
    decimals, the gyro with 7): 0.01 rad/s codes, a bias of 0.05 deg/s and a noise of 0.23 deg/s
    per 10 Hz sample that leave ~78 % of the rows at rest exactly 0; ``offset_dps`` while
    driving (the unit) or none (its twin). 15 minutes of city driving at 10 Hz."""
    model = GyroModel((StaticBias(0.05), WhiteNoise(0.073), Quantization(step_dps=RAD_CODE_DPS)))
    if offset_dps:
        model = model.with_effect(MotionOffset(offset_dps=offset_dps))
    log = simulate_drive("city", 15.0, seed, hz=10.0, model=model)
    assert log.omega_truth is not None and log.speed is not None
    ins = np.where(log.speed > 0.5, np.round(log.omega_truth, 9) + 1e-9 * np.pi, np.nan)
    return replace(
        log, omega=np.round(log.omega, 7), omega_truth=ins, heading_truth=None, temp_c=None
    )


def least_squares_slope(log: DriveLog) -> float:
    """OLS slope of omega on temp_c with a constant, deg/s/degC (what a user computes)."""
    assert log.temp_c is not None
    a = np.vstack([log.temp_c, np.ones(len(log))]).T
    coef, *_ = np.linalg.lstsq(a, log.omega, rcond=None)
    return float(coef[0])


def neighbour_correlation(x: FloatArray) -> float:
    """Correlation of neighbouring samples after removing a 601-sample running mean (the slow
    drifts would dominate otherwise)."""
    y = x - np.convolve(x, np.ones(601) / 601, mode="same")
    y = y[300:-300]
    return float(np.corrcoef(y[1:], y[:-1])[0, 1])
