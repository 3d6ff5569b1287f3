"""A drive log's columns, what each may hold, and the checks every drive log passes whatever
its file format (CSV: :mod:`hdrd.io.files.drivelog`; Parquet: :mod:`hdrd.io.files.parquetlog`),
each failure a :class:`DriveLogError` naming the row (docs/drive-format.md, "Limits").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hdrd.errors import HdrdError

__all__ = [
    "COLUMNS",
    "DEFAULT_READ_LIMITS",
    "DIRECTION_COLUMNS",
    "HEADING_LIMIT_DEG",
    "MAX_GAP_S",
    "MAX_RATE_DPS",
    "MAX_ROWS",
    "NO_LIMITS",
    "OPTIONAL",
    "RATE_COLUMNS",
    "REQUIRED",
    "SPEED_COLUMNS",
    "TEMP_LIMITS_C",
    "DriveLogError",
    "FloatArray",
    "ReadLimits",
    "check_columns",
]

COLUMNS = (
    "t",
    "omega",
    "temp_c",
    "heading_truth",
    "omega_truth",
    "speed",
    "valid",
    "gps_course",
    "gps_speed",
)
REQUIRED = ("t", "omega")
OPTIONAL = COLUMNS[2:]
DIRECTION_COLUMNS = ("heading_truth", "gps_course")
SPEED_COLUMNS = ("speed", "gps_speed")

FloatArray = npt.NDArray[np.float64]


class DriveLogError(HdrdError, ValueError):
    """A drive log that does not follow docs/drive-format.md; the message says where."""


HEADING_LIMIT_DEG = 360.0
"""``heading_truth`` is a direction: compass [0, 360), a signed course in [-180, 180] read as
the same direction; anything beyond +/- this (an unwrapped heading, radians times 1000, a
sentinel such as 999) is refused."""
TEMP_LIMITS_C = (-100.0, 200.0)
"""``temp_c`` is a board or cabin temperature, deg C, within these; anything outside (a
sentinel such as 999 or -999, a temperature in kelvin or in tenths of a degree) is refused."""
MAX_ROWS = 10_000_000
"""Most rows a drive log may have (``--max-rows``): 28 hours at 100 Hz, 11 days at 10 Hz; a
drive of that many takes ~0.6 GB to read and a few times that to analyse."""
MAX_RATE_DPS = 1000.0
"""Largest yaw rate a drive log may hold, deg/s (``--max-rate``): beyond what a vehicle's
gyro measures (a +/-1000 deg/s MEMS is the widest common range; a car turns at < 100)."""
RATE_COLUMNS = ("omega", "omega_truth")
MAX_GAP_S = 3600.0
"""Longest time gap a drive may have, s (``--max-gap``): a longer one is two drives, or a
clock that jumped; the analyses' work and Td would follow the span, not the samples."""


@dataclass(frozen=True)
class ReadLimits:
    """What a drive log may hold beyond the format's own rules, each refused with a one-line
    error naming the row (docs/drive-format.md, "Limits"): ``max_rows``, the most rows (a
    Parquet file's counted from its metadata before any is read); ``max_rate_dps``, the
    largest ``|omega|`` and ``|omega_truth|``, deg/s; ``max_gap_s``, the longest step in
    ``t``, s; both in the rows that count (``valid`` not 0)."""

    max_rows: int = MAX_ROWS
    max_rate_dps: float = MAX_RATE_DPS
    max_gap_s: float = MAX_GAP_S


DEFAULT_READ_LIMITS = ReadLimits()
NO_LIMITS = ReadLimits(max_rows=2**62, max_rate_dps=math.inf, max_gap_s=math.inf)
"""The format's own rules only (a test of the format, a tool that splits long logs)."""


def check_columns(
    arrays: dict[str, FloatArray],
    where: Callable[[int], str],
    limits: ReadLimits | None = DEFAULT_READ_LIMITS,
    names: dict[str, str] | None = None,
) -> None:
    """The checks every drive log passes, whatever its file format: ``valid`` is 0 or 1 in
    every row, ``t`` and ``omega`` are present in every row, no value is infinite, directions
    within +/- :data:`HEADING_LIMIT_DEG`, speeds not negative, ``temp_c`` within
    :data:`TEMP_LIMITS_C`, ``t`` strictly increases; and, unless ``limits`` is None, its :class:`ReadLimits`. ``where(i)``
    names row i for the message (``file:line`` for a CSV, ``file: row N`` for Parquet);
    ``names`` what to call a column in it (``hdrd import``: the source's own column).
    DriveLogError on the first problem."""
    shown = names or {}

    def col(c: str) -> str:
        return shown.get(c, c)

    _check_valid(arrays, where, col)
    _check_present_and_finite(arrays, where, col)
    _check_ranges(arrays, where, col)
    t = arrays["t"]
    if np.any(np.diff(t) <= 0):
        bad = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise DriveLogError(
            f"{where(bad)}: column {col('t')} is not strictly increasing "
            f"({float(t[bad])!r} after {float(t[bad - 1])!r})"
        )
    if limits is not None:
        _check_limits(arrays, where, limits, col)


def _check_valid(
    arrays: dict[str, FloatArray], where: Callable[[int], str], col: Callable[[str], str]
) -> None:
    """:func:`check_columns`: ``valid`` is 0 or 1 in every row."""
    if "valid" in arrays:
        vcol = arrays["valid"]
        bad_v = np.flatnonzero((vcol != 0.0) & (vcol != 1.0))  # NaN (empty) included
        if bad_v.shape[0]:
            i = int(bad_v[0])
            what = "is empty" if math.isnan(vcol[i]) else f"{float(vcol[i])!r} is not 0 or 1"
            raise DriveLogError(
                f"{where(i)}: column {col('valid')}: {what}; every row needs 1 (the sample "
                "counts) or 0 (excluded)"
            )


def _check_present_and_finite(
    arrays: dict[str, FloatArray], where: Callable[[int], str], col: Callable[[str], str]
) -> None:
    """:func:`check_columns`: the required columns in every row, no value infinite."""
    for c in REQUIRED:
        if np.isnan(arrays[c]).any():
            bad = int(np.flatnonzero(np.isnan(arrays[c]))[0])
            raise DriveLogError(
                f"{where(bad)}: column {col(c)} is empty; it is required in every row"
            )
    for c, a in arrays.items():
        if np.isinf(a).any():
            bad = int(np.flatnonzero(np.isinf(a))[0])
            raise DriveLogError(f"{where(bad)}: column {col(c)}: {float(a[bad])!r} is not finite")


def _check_ranges(
    arrays: dict[str, FloatArray], where: Callable[[int], str], col: Callable[[str], str]
) -> None:
    """:func:`check_columns`: directions, speeds and temperatures within their limits."""
    for c in DIRECTION_COLUMNS:
        if c not in arrays:
            continue
        h = arrays[c]
        with np.errstate(invalid="ignore"):
            out = np.abs(h) > HEADING_LIMIT_DEG
        if out.any():
            i = int(np.flatnonzero(out)[0])
            raise DriveLogError(
                f"{where(i)}: column {col(c)}: {float(h[i])!r} deg is outside "
                f"[-{HEADING_LIMIT_DEG:g}, {HEADING_LIMIT_DEG:g}]; a compass heading is in "
                "[0, 360) (a signed one in [-180, 180] is taken too), not unwrapped"
            )
    for c in SPEED_COLUMNS:
        if c in arrays:
            with np.errstate(invalid="ignore"):
                neg = arrays[c] < 0.0  # NaN (empty) is not
            if neg.any():
                i = int(np.flatnonzero(neg)[0])
                raise DriveLogError(
                    f"{where(i)}: column {col(c)}: {float(arrays[c][i]):.6g} m/s is negative; a "
                    "speed is a magnitude, >= 0 (reversing too)"
                )
    if "temp_c" in arrays:
        lo, hi = TEMP_LIMITS_C
        tc = arrays["temp_c"]
        with np.errstate(invalid="ignore"):
            out = (tc < lo) | (tc > hi)  # NaN (empty) is neither
        if out.any():
            i = int(np.flatnonzero(out)[0])
            raise DriveLogError(
                f"{where(i)}: column {col('temp_c')}: {float(tc[i]):.6g} deg C is outside "
                f"[{lo:g}, {hi:g}]; a board or cabin temperature in deg C is expected"
            )


def _check_limits(
    arrays: dict[str, FloatArray],
    where: Callable[[int], str],
    limits: ReadLimits,
    col: Callable[[str], str],
) -> None:
    counts = np.ones(arrays["t"].shape[0], dtype=bool)
    if "valid" in arrays:
        counts = arrays["valid"] != 0.0
    rows = np.flatnonzero(counts)
    for c in RATE_COLUMNS:
        if c in arrays:
            with np.errstate(invalid="ignore"):
                over = counts & (np.abs(arrays[c]) > limits.max_rate_dps)
            if over.any():
                i = int(np.flatnonzero(over)[0])
                raise DriveLogError(
                    f"{where(i)}: column {col(c)}: {float(arrays[c][i]):.6g} deg/s is beyond the "
                    f"+/-{limits.max_rate_dps:g} deg/s a gyro measures (--max-rate)"
                )
    t = arrays["t"][rows]
    if t.shape[0] > 1:
        steps = np.diff(t)
        j = int(np.argmax(steps))
        if steps[j] > limits.max_gap_s:
            i = int(rows[j + 1])
            raise DriveLogError(
                f"{where(i)}: column {col('t')} jumps by {float(steps[j]):.6g} s (from {float(t[j])!r} to "
                f"{float(t[j + 1])!r}); a drive may have gaps of at most {limits.max_gap_s:g} s "
                "(--max-gap): split the log there"
            )
