"""Angles in degrees: a difference wrapped to [-180, 180), a heading to compass [0, 360). Pure.

Each takes a float or a numpy array: Python's ``%`` and numpy's ``mod`` are the same floor
modulo, bit for bit, so the daemon's steps and the analysis's arrays wrap alike.
"""

from __future__ import annotations

from typing import Any, overload

import numpy as np
import numpy.typing as npt

__all__ = ["compass", "wrap180"]

_Floats = npt.NDArray[np.float64]


@overload
def wrap180(deg: float) -> float: ...
@overload
def wrap180(deg: _Floats) -> _Floats: ...
def wrap180(deg: Any) -> Any:
    """An angle difference wrapped to [-180, 180), deg: +180 is -180."""
    return (deg + 180.0) % 360.0 - 180.0


@overload
def compass(deg: float) -> float: ...
@overload
def compass(deg: _Floats) -> _Floats: ...
def compass(deg: Any) -> Any:
    """A heading as a compass reads it, deg clockwise from north in [0, 360). A hair below a
    multiple of 360 (-1e-20) is north: its floor modulo rounds to 360.0, which is 0."""
    h = deg % 360.0
    if isinstance(h, np.ndarray):
        return np.where(h >= 360.0, 0.0, h)
    return 0.0 if h >= 360.0 else h
