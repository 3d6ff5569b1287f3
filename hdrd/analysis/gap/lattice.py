"""The values' lattice: the ADC codes a log's omega sits on, and the log's recording resolution.

Rates deg/s. Pure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = [
    "LATTICE_MIN_FRACTION",
    "Lattice",
    "decimal_resolution",
    "detect_lattice",
    "lattice_tolerance",
    "on_lattice",
]

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


def lattice_tolerance(step: float, resolution: float, scale: float = 1.0) -> float:
    """How far (deg/s) a recorded value may sit from a lattice point and still be on it: the
    recording's rounding (half its resolution) with as much again for the fitted lattice's own
    error, plus binary round-off relative to the values' size. A continuous signal puts only
    2 * resolution / step of its values that close, at most 2/3 for the coarsest step allowed
    (3 resolutions)."""
    return resolution + 1e-12 * scale + 1e-9 * step


def on_lattice(v: FloatArray, step: float, offset: float, resolution: float) -> BoolArray:
    """Which values lie on the lattice offset + k * step within the recording's rounding."""
    frac = (v - offset) / step
    tol = lattice_tolerance(step, resolution, float(np.max(np.abs(v), initial=1.0))) / step
    return np.asarray(np.abs(frac - np.round(frac)) <= tol)


def _fit_codes(
    u: FloatArray, w: FloatArray, ref: float, step: float, tol: float
) -> tuple[float, float, BoolArray]:
    """Least squares of u = offset + k * step (weights w) over the values within ``tol`` of
    the lattice through ``ref``; returns (offset, step, which values were used)."""
    k = np.round((u - ref) / step)
    on = np.abs(u - ref - k * step) <= tol
    if on.sum() < 2 or np.all(k[on] == k[on][0]):
        return ref, step, on
    kk, uu, ww = k[on], u[on], np.sqrt(w[on])
    a = np.vstack([np.ones_like(kk), kk]).T * ww[:, None]
    (off, st), *_ = np.linalg.lstsq(a, uu * ww, rcond=None)
    return float(off), float(abs(st)), on


def detect_lattice(x: npt.ArrayLike, resolution: float) -> Lattice | None:
    """The coarsest value lattice (ADC codes) of the samples, if one at least 3x coarser than
    the recording ``resolution`` holds :data:`LATTICE_MIN_FRACTION` of them; else None.

    A value counts as on the lattice when it lies within the recording's rounding of a lattice
    point (:func:`lattice_tolerance`): a step that is no round decimal (0.0305 deg/s written
    with 6 decimals) is found as well as a round one. The step is first read off the smallest
    spacings of neighbouring distinct values (each good only to the resolution), then refined
    by least squares on the code numbers over a window of codes around the most common value
    that widens fourfold at each pass (so that a step still a little off never assigns a value
    to the wrong code), and finally over all values."""
    v = np.asarray(x, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.shape[0] < 20:
        return None
    u, counts = np.unique(v, return_counts=True)
    if u.shape[0] < 3:
        return None
    w = counts.astype(np.float64)
    d = np.diff(u)
    d = d[d > 0.5 * resolution]
    if d.shape[0] == 0:
        return None
    p5 = float(np.percentile(d, 5))
    if not p5 > 2.0 * resolution:
        return None
    step = float(np.median(d[d <= 1.5 * p5]))
    ref = float(u[int(np.argmax(counts))])
    span = float(np.max(np.abs(u - ref)))
    width = 4.0 * step
    while True:
        near = np.abs(u - ref) <= width
        off, st, on = _fit_codes(u[near], w[near], ref, step, 0.25 * step)
        if on.sum() < 2:
            return None
        ref, step = off, st  # a lattice point (offset) and the refined step
        if width >= span + step:
            break
        width *= 4.0
    if not step > 3.0 * resolution:
        return None
    tol = lattice_tolerance(step, resolution, float(np.max(np.abs(u))))
    off, st, _ = _fit_codes(u, w, ref, step, max(tol, 2.0 * resolution))
    offset = off - st * round(off / st)  # the lattice point nearest zero
    on = on_lattice(v, st, offset, resolution)
    fraction = float(on.mean())
    if fraction < LATTICE_MIN_FRACTION or not st > 3.0 * resolution:
        return None
    return Lattice(step_dps=st, offset_dps=offset, fraction=fraction)
