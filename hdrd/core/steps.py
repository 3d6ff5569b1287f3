"""What a drift reducer sees of a step: one step's input, and a drive's steps as arrays. Pure.

Every method (:mod:`hdrd.core.methods`) takes the same input, of which it reads what it uses: the
paper's HDR only ``u``; HDR+ also the spread, the speed and the temperature. Units: rates
deg/s, + = counter-clockwise seen from above (a left turn); speed m/s; temperature degC;
time s. NaN marks an unknown value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

__all__ = ["StepInput", "StepInputs", "per_step"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


class StepInput(NamedTuple):
    """One step's input. NaN marks an unknown spread, speed or temperature."""

    u: float
    """Block mean raw rate minus the start-up static bias eps0 (paper Eqs. 2, 11), deg/s CCW."""
    spread_dps: float
    """Standard deviation of the raw samples within the block, deg/s."""
    speed_mps: float
    """Vehicle speed, m/s."""
    temp_c: float
    """Board temperature, degC."""
    T: float
    """Step length, s."""
    heading_err_deg: float = math.nan
    """A GPS course's measurement of the heading error at the end of the step before: the
    heading published then minus the course carried to that time, compass deg wrapped to
    [-180, 180) (+: the heading reads clockwise of the truth); NaN: no measurement. Only a
    method that owns the heading reads it (HDR+; the aiding stage makes it)."""
    heading_err_var: float = math.nan
    """Its variance, deg^2."""
    heading_reset: bool = False
    """The heading was (re)aligned to a course before this step: what the method knew of
    its heading error starts again (with ``heading_err_var`` as its variance)."""


@dataclass(frozen=True)
class StepInputs:
    """A drive's steps as arrays, one element per step taken (a step without samples is not
    a step: it has no element, and the yaw holds across it).

    u: block mean of the raw rate minus the static bias, deg/s CCW (Eqs. 2, 11). t_end: end
    of each step, s since the drive log's first sample. T: step period, s. bias_dps: the static
    bias removed, deg/s. n_samples: samples averaged in each step. speed: mean speed in each
    step, m/s (NaN where unknown), None if the log has none. temp_c: mean temperature in each
    step, deg C (NaN where unknown), or None. omega_std: standard deviation of the raw samples
    within each step, deg/s (0 for a single sample). bias_var: variance of the static bias
    estimate, (deg/s)^2 (sample variance / samples of the calibration window; NaN if the bias
    was given).
    """

    u: FloatArray
    t_end: FloatArray
    T: float
    bias_dps: float
    n_samples: IntArray
    speed: FloatArray | None = None
    temp_c: FloatArray | None = None
    omega_std: FloatArray | None = None
    bias_var: float = math.nan

    def input(self, i: int) -> StepInput:
        """Step i as the daemon's pipeline hands it to a method's ``step``."""

        def at(a: FloatArray | None) -> float:
            return math.nan if a is None else float(a[i])

        return StepInput(
            float(self.u[i]), at(self.omega_std), at(self.speed), at(self.temp_c), self.T
        )


def per_step(v: npt.ArrayLike | None, n: int, name: str) -> list[float]:
    """An input of n steps as a list of floats: None is unknown (NaN) throughout, a scalar the
    same at every step, else one value per step (ValueError naming ``name`` otherwise)."""
    if v is None:
        return [math.nan] * n
    a = np.asarray(v, dtype=np.float64)
    if a.ndim == 0:
        return [float(a)] * n
    if a.shape != (n,):
        raise ValueError(f"{name} must have one value per step ({a.shape} vs {n})")
    return a.tolist()
