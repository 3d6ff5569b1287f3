"""The values' lattice: the ADC codes a log's omega sits on, and the log's recording resolution.

Rates deg/s. Pure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["LATTICE_MIN_FRACTION", "Lattice", "decimal_resolution", "detect_lattice", "on_lattice"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

LATTICE_MIN_FRACTION = 0.999  # share of omega samples on a lattice for it to count as an ADC's


@dataclass(frozen=True)
class Lattice:
    """The values' lattice: omega = offset + k * step_dps for all but a few samples."""

    step_dps: float
    offset_dps: float
    fraction: float
    """Share of samples on the lattice."""


def decimal_resolution(x: npt.ArrayLike) -> float:
    """The log's recording resolution, deg/s: the coarsest 10**-k (k = 0..9) of which every
    value is a multiple; 1e-9 for binary floating-point data that fit none."""
    v = np.asarray(x, dtype=np.float64)
    v = v[np.isfinite(v)]
    for k in range(10):
        s = v * 10.0**k
        if np.all(np.abs(s - np.round(s)) <= 1e-6 * np.maximum(1.0, np.abs(s)) * 1e-3 + 1e-6):
            return 10.0**-k
    return 1e-9


def on_lattice(v: FloatArray, step: float, offset: float, resolution: float) -> BoolArray:
    frac = (v - offset) / step
    tol = (0.5 * resolution + 1e-12 * np.max(np.abs(v), initial=1.0)) / step + 1e-6
    return np.asarray(np.abs(frac - np.round(frac)) <= tol)


def detect_lattice(x: npt.ArrayLike, resolution: float) -> Lattice | None:
    """The coarsest value lattice (ADC codes) of the samples, if one at least 3x coarser than
    the recording ``resolution`` holds :data:`LATTICE_MIN_FRACTION` of them; else None.

    The step is guessed from the spacing of neighbouring distinct values (5th percentile),
    its offset from the circular mean phase, then the step is refined by least squares on the
    code numbers (a step read off one spacing is only good to the resolution)."""
    v = np.asarray(x, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.shape[0] < 20:
        return None
    u = np.unique(v)
    if u.shape[0] < 3:
        return None
    d = np.diff(u)
    d = d[d > 0.5 * resolution]
    if d.shape[0] == 0:
        return None
    step = float(np.percentile(d, 5))
    if not step > 3.0 * resolution:
        return None
    for _ in range(3):
        phase = np.angle(np.mean(np.exp(2j * np.pi * v / step)))
        offset = float(phase * step / (2.0 * np.pi))
        k = np.round((v - offset) / step)
        on = on_lattice(v, step, offset, resolution)
        if on.sum() < 10 or np.all(k[on] == k[on][0]):
            return None
        kk, vv = k[on], v[on]
        # v = offset + k * step: least squares on the samples on the lattice.
        a = np.vstack([np.ones_like(kk), kk]).T
        (offset, step), *_ = np.linalg.lstsq(a, vv, rcond=None)
        step = float(abs(step))
        if not step > 3.0 * resolution:
            return None
    on = on_lattice(v, step, float(offset), resolution)
    fraction = float(on.mean())
    if fraction < LATTICE_MIN_FRACTION:
        return None
    return Lattice(step_dps=step, offset_dps=float(offset), fraction=fraction)
