"""Standstill detection and bias refinement (zero-rate updates), pure.

Two pieces that HDR+ (:mod:`hdrd.hdrplus`) combines, usable on their own:

- :func:`standstill_candidate`: does one step T look like standstill? With a speed (m/s, e.g.
  from gpsd or the CAN bus) a step is a candidate when the speed is at or below
  ``speed_mps`` *and* the gyro agrees (a car cannot rotate on the spot, so a block that
  rotates means the speed is stale). Without a speed, only the gyro's statistics are left:
  the spread of the raw samples within the step and the level of the bias-corrected block
  mean must both be small, and :class:`StandstillParams` asks for more consecutive steps
  (``steps_gyro``) than with a speed (``steps_speed``). A gyro alone cannot tell a stop from a
  perfectly straight, smooth stretch of road; that is why speed is preferred.
- :class:`BiasState` with :func:`predict` and :func:`update`: a two-state Kalman filter of
  the gyro's bias relative to the start-up static bias eps0 (paper Eq. 2),
  ``bias(temp) = b + k * (temp - t_ref)``: b in deg/s, k the temperature coefficient in
  deg/s/degC, t_ref the first temperature seen. Each standstill step is a measurement of the
  bias (the true rate is zero) whose variance is the block's sample variance divided by the
  number of samples, so a stop contributes in proportion to how long and how quietly the
  vehicle stood (inverse-variance weighting). Between measurements the bias variance grows by
  a random walk (``q`` in (deg/s)^2/s), so old measurements count less.

Units: rates deg/s, + = counter-clockwise seen from above; temperature degC; time s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

__all__ = [
    "INITIAL_BIAS",
    "BiasState",
    "StandstillParams",
    "block_mean_variance",
    "correction",
    "init_bias",
    "predict",
    "standstill_candidate",
    "update",
]


@dataclass(frozen=True, slots=True)
class StandstillParams:
    """When a step counts as standstill (see :func:`standstill_candidate`)."""

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
    level_dps: float, spread_dps: float, speed_mps: float, params: StandstillParams
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


def block_mean_variance(spread_dps: float, params: StandstillParams) -> float:
    """Variance of a block mean, (deg/s)^2: (spread^2 + floor^2) / samples per step.

    An unknown spread (NaN) counts as the largest one a standstill step may have.
    """
    s = params.spread_dps if math.isnan(spread_dps) else spread_dps
    return (s * s + params.noise_floor_dps * params.noise_floor_dps) / params.samples_per_step


class BiasState(NamedTuple):
    """The bias model relative to eps0: bias(temp) = b + k * (temp - t_ref). Immutable.

    b: deg/s. k: deg/s/degC. p_bb, p_bk, p_kk: covariance of (b, k), in (deg/s)^2,
    (deg/s)^2/degC, (deg/s/degC)^2; NaN until :func:`init_bias` sets the prior. t_ref: the
    reference temperature, degC (NaN until a temperature is seen).
    """

    b: float = 0.0
    k: float = 0.0
    p_bb: float = math.nan
    p_bk: float = 0.0
    p_kk: float = math.nan
    t_ref: float = math.nan


INITIAL_BIAS = BiasState()


def init_bias(state: BiasState, p0: float, k_sd: float) -> BiasState:
    """Set the prior variances if not yet set: var(b) = p0 (deg/s)^2, sd(k) = k_sd deg/s/degC."""
    if not math.isnan(state.p_bb):
        return state
    return state._replace(p_bb=p0, p_kk=k_sd * k_sd)


def correction(state: BiasState, dT: float) -> float:
    """The modelled bias change since eps0 at a temperature dT above t_ref, deg/s."""
    return state.b + state.k * dT


def predict(state: BiasState, q: float, T: float) -> BiasState:
    """Let T seconds pass: the bias performs a random walk of q (deg/s)^2 per second."""
    return state._replace(p_bb=state.p_bb + q * T)


def update(state: BiasState, z: float, r: float, dT: float) -> BiasState:
    """Kalman update with a measurement z (deg/s) of the bias at dT (degC above t_ref) whose
    variance is r ((deg/s)^2): measurement row h = [1, dT]. With dT = 0 only b moves."""
    b, k, p_bb, p_bk, p_kk = state.b, state.k, state.p_bb, state.p_bk, state.p_kk
    ph0 = p_bb + dT * p_bk  # (P h)_0
    ph1 = p_bk + dT * p_kk  # (P h)_1
    s = ph0 + dT * ph1 + r
    k0 = ph0 / s
    k1 = ph1 / s
    innov = z - (b + k * dT)
    # P <- P - K (P h)^T, written out for the symmetric 2x2 case.
    return state._replace(
        b=b + k0 * innov,
        k=k + k1 * innov,
        p_bb=p_bb - k0 * ph0,
        p_bk=p_bk - k0 * ph1,
        p_kk=p_kk - k1 * ph1,
    )
