"""Standstill detection, and what a calibration window says about the gyro; pure.

Pieces that HDR+ (:mod:`hdrd.core.hdrplus`) combines, usable on their own:

- :func:`standstill_candidate`: does one step T look like standstill? With a speed (m/s, e.g.
  from gpsd or the CAN bus) a step is a candidate when the speed is at or below
  ``speed_mps`` *and* the gyro agrees (a car cannot rotate on the spot, so a block that
  rotates means the speed is stale). Without a speed, only the gyro's statistics are left:
  the spread of the raw samples within the step and the level of the bias-corrected block
  mean must both be small, and :class:`StopDetection` asks for more consecutive steps
  (``steps_gyro``) than with a speed (``steps_speed``). A gyro alone cannot tell a stop from a
  perfectly straight, smooth stretch of road; that is why speed is preferred.
- The estimator these stops feed (a zero-rate update of its bank) is :mod:`hdrd.core.hdrplus`.
- :class:`CalibrationNoise` and :func:`calibration_noise`: what a start-up calibration window
  says about the gyro's noise (the variance of eps0 and of one step's mean at standstill, the
  quantisation step, the samples per step), for HDR+'s settings (:meth:`hdrd.core.plusparams.
  PlusParams.fitted`).

Units: rates deg/s, + = counter-clockwise seen from above; temperature degC; time s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import numpy.typing as npt

__all__ = [
    "CalibrationNoise",
    "StopDetection",
    "block_mean_variance",
    "calibration_noise",
    "quantization_step",
    "standstill_candidate",
]


@dataclass(frozen=True, slots=True)
class StopDetection:
    """HDR+'s stop detection: when a step counts as standstill (see
    :func:`standstill_candidate`). Not the start-up calibration's test
    (:class:`hdrd.core.calibrate.CalibrationLimits`)."""

    enabled: bool = True
    """False: never standstill (no zero-rate update, no bias refinement at stops)."""
    speed_mps: float = 0.3
    """A step with a known speed at or below this, m/s, may be standstill (GPS speed at rest
    jitters by a few tenths of a m/s)."""
    spread_dps: float = 0.5
    """Largest standard deviation of the raw samples within a step, deg/s (a parked car with
    its engine running shows less; a step with a turn in it shows more)."""
    level_dps: float = 1.0
    """Largest |bias-corrected block mean rate|, deg/s, for a step with a known speed to count
    as standstill: far above any bias error, far below the rate of a turn seen with a stale
    speed."""
    steps_speed: int = 3
    """Consecutive candidate steps needed when the speed is known: the first steps of a stop
    are not used (the car still rocks and yaws as it brakes to a halt, and the speed's and
    the gyro's averaging windows are not aligned), nor a halt shorter than this."""
    gyro_only: bool = False
    """Detect standstill from the gyro alone when the speed is unknown (NaN)."""
    gyro_spread_dps: float = 0.3
    """Gyro-only detection: largest within-step spread, deg/s."""
    gyro_level_dps: float = 0.1
    """Gyro-only detection: largest |bias-corrected block mean rate|, deg/s."""
    steps_gyro: int = 10
    """Gyro-only detection: consecutive quiet steps needed before the first zero-rate update."""
    samples_per_step: float = 10.0
    """Samples averaged per step (paper: 10 Hz x 1 s), to turn the within-step variance into
    the variance of the block mean."""
    noise_floor_dps: float = 0.01
    """Added (in quadrature) to the spread: no block mean is trusted to better than this,
    deg/s per sample (quantisation, vibration that a spread of a few samples misses)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.type in ("bool", bool):
                object.__setattr__(self, f.name, bool(v))
            elif f.type in ("int", int):
                if int(v) < 1:
                    raise ValueError(f"standstill.{f.name} must be >= 1, got {v!r}")
                object.__setattr__(self, f.name, int(v))
            else:
                v = float(v)
                if not (math.isfinite(v) and v >= 0.0):
                    raise ValueError(f"standstill.{f.name} must be a number >= 0, got {v!r}")
                object.__setattr__(self, f.name, v)
        if self.samples_per_step <= 0.0:
            raise ValueError("standstill.samples_per_step must be > 0")


def standstill_candidate(
    level_dps: float, spread_dps: float, speed_mps: float, params: StopDetection
) -> tuple[bool, int]:
    """(is this step a standstill candidate, consecutive candidates needed).

    level_dps: the bias-corrected block mean rate, deg/s. spread_dps: standard deviation of
    the raw samples within the step, deg/s (NaN = unknown: not checked). speed_mps: vehicle
    speed, m/s (NaN = unknown: gyro-only detection if enabled, otherwise never standstill).
    """
    if not params.enabled:
        return False, params.steps_speed
    if not math.isnan(speed_mps):  # known speed
        ok = (
            speed_mps <= params.speed_mps
            and not spread_dps > params.spread_dps
            and abs(level_dps) <= params.level_dps
        )
        return ok, params.steps_speed
    if params.gyro_only and not math.isnan(spread_dps):
        ok = spread_dps <= params.gyro_spread_dps and abs(level_dps) <= params.gyro_level_dps
        return ok, params.steps_gyro
    return False, params.steps_gyro


def block_mean_variance(spread_dps: float, params: StopDetection) -> float:
    """Variance of a block mean, (deg/s)^2: (spread^2 + floor^2) / samples per step.

    An unknown spread (NaN) counts as the largest one a standstill step may have.
    """
    s = params.spread_dps if math.isnan(spread_dps) else spread_dps
    return (s * s + params.noise_floor_dps * params.noise_floor_dps) / params.samples_per_step


# -- what a calibration window says about the gyro's noise ------------------------------------


def quantization_step(values_dps: npt.ArrayLike) -> float:
    """The output step (LSB) of a quantised rate signal, deg/s; 0 when it cannot be seen.

    Over the central half of the values (between their quartiles, where a drive's rates are
    dense: far out, a turn's rates are sparse and skip codes), the mean of the gaps between
    neighbouring distinct values that are at most 1.5 times the smallest gap: the distinct
    values of a quantised signal sit on a lattice (a step printed to fewer digits than it has,
    e.g. 1/16 deg/s with two decimals, gives gaps of 0.06 and 0.07, whose mean is the step to
    a per cent). Fewer than 3 distinct values, or gaps mostly wider than that (an unquantised
    signal): 0.
    """
    w = np.asarray(values_dps, dtype=np.float64)
    w = w[np.isfinite(w)]
    if w.shape[0] < 3:
        return 0.0
    lo, hi = np.percentile(w, [25.0, 75.0])
    v = np.unique(w[(w >= lo) & (w <= hi)])
    if v.shape[0] < 3:
        v = np.unique(w)
    if v.shape[0] < 3:
        return 0.0
    gaps = np.diff(v)
    gaps = gaps[gaps > 1e-9]
    if gaps.shape[0] < 2:
        return 0.0
    small = gaps[gaps <= 1.5 * float(np.min(gaps))]
    if small.shape[0] < 0.5 * gaps.shape[0]:
        return 0.0
    return float(np.mean(small))


@dataclass(frozen=True, slots=True)
class CalibrationNoise:
    """What a start-up calibration window says about the gyro at standstill.

    bias_var: variance of its mean, eps0, (deg/s)^2 (sample variance / samples). block_var:
    variance of the mean of one step of T seconds at standstill, (deg/s)^2 (from the window's
    step means when it holds 3 or more steps, else sample variance / samples per step).
    quant_step_dps: the output step, deg/s (0 = not seen). samples_per_step: samples averaged
    per step (rate x T). codes: distinct output values in the window (1 or 2: the window sits
    on the lattice and cannot see the bias better than half a step).
    """

    bias_var: float
    block_var: float
    quant_step_dps: float
    samples_per_step: float
    codes: int = 0


def calibration_noise(
    omega_dps: npt.ArrayLike,
    t_s: npt.ArrayLike,
    T: float = 1.0,
    quant_step_dps: float | None = None,
) -> CalibrationNoise:
    """The :class:`CalibrationNoise` of raw standstill samples (deg/s) at times t_s (s).

    quant_step_dps: the output step when known (e.g. the ADC's LSB in deg/s); None estimates
    it from the samples (:func:`quantization_step`). ValueError for fewer than 2 samples.
    """
    w = np.asarray(omega_dps, dtype=np.float64)
    t = np.asarray(t_s, dtype=np.float64)
    n = int(w.shape[0])
    if n < 2 or t.shape != w.shape or not (np.all(np.isfinite(w)) and np.all(np.isfinite(t))):
        raise ValueError("calibration_noise needs 2 or more finite samples with one time each")
    var = float(np.var(w, ddof=1))
    span = float(t[-1] - t[0])
    per_step = max(1.0, (n - 1) / span * T) if span > 0 else 1.0
    idx = np.floor((t - t[0]) / T + 1e-9).astype(np.int64)
    counts = np.bincount(idx)
    full = np.flatnonzero(counts >= 0.5 * per_step)
    if full.shape[0] >= 3:
        means = np.bincount(idx, weights=w)[full] / counts[full]
        block_var = float(np.var(means, ddof=1))
    else:
        block_var = var / per_step
    q = quantization_step(w) if quant_step_dps is None else float(quant_step_dps)
    return CalibrationNoise(var / n, block_var, q, per_step, int(np.unique(w).shape[0]))
