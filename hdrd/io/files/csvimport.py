"""A drive log made from your own CSV, its columns, units and signs mapped (``hdrd import``,
:mod:`hdrd.commands.importcsv`; docs/drive-format.md, "Your own CSV: hdrd import").

A logger writes its own columns (``timestamp_ms``, ``gyro_z``, ``yaw``, ``vel_kmh``), in its
own units (ms, rad/s, km/h) and signs (a z axis pointing down turns clockwise positive). Each
is named on the command line with its unit and sign; the result is a drive log in hdrd's
units and signs (t s from the first row, omega deg/s + = counter-clockwise, heading_truth
compass deg [0, 360), speed m/s, temp_c deg C) that reads back as it was written. Every error
names the source's line and its column (and the option that named it). The command checks
the rate against the heading where the log has one.

Pure except :func:`import_csv` (which reads a file).
"""

from __future__ import annotations

import csv
import math
import os
from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from hdrd.core.angles import compass
from hdrd.errors import clipped
from hdrd.io.files.access import printable, shown_path
from hdrd.io.files.drivecolumns import (
    DEFAULT_READ_LIMITS,
    HEADING_LIMIT_DEG,
    DriveLogError,
    ReadLimits,
    check_columns,
)
from hdrd.io.files.drivelog import DriveLog, csv_values, open_regular, parse_cell, text_lines

__all__ = [
    "HEADING_UNITS",
    "OMEGA_UNITS",
    "SPEED_UNITS",
    "TIME_UNITS",
    "Mapping",
    "convert",
    "import_csv",
    "unit_warnings",
]

FloatArray = npt.NDArray[np.float64]

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
"""Seconds per unit of the source's time column."""
OMEGA_UNITS = {"deg/s": 1.0, "rad/s": 180.0 / math.pi}
"""deg/s per unit of the source's rate."""
HEADING_UNITS = {"deg": 1.0, "rad": 180.0 / math.pi}
"""deg per unit of the source's heading."""
SPEED_UNITS = {"m/s": 1.0, "km/h": 1.0 / 3.6, "mph": 0.44704}
"""m/s per unit of the source's speed."""


class SourceCsvError(DriveLogError):
    """A source CSV that cannot be imported; the message names the line and column."""


@dataclass(frozen=True)
class Mapping:
    """Which source column is which drive-log column, and in what unit and sign.

    t, omega: required source column names; heading, speed, temp: optional (None). Units and
    signs as the command line's options (:data:`TIME_UNITS` ...)."""

    t: str
    omega: str
    heading: str | None = None
    speed: str | None = None
    temp: str | None = None
    time_unit: str = "s"
    omega_unit: str = "deg/s"
    omega_sign: str = "ccw"
    heading_unit: str = "deg"
    heading_ref: str = "compass"
    """compass: clockwise from north (a GPS course); enu: counter-clockwise from east (a yaw
    angle in an east-north-up frame, ROS REP 103): compass = 90 - yaw."""
    speed_unit: str = "m/s"

    def columns(self) -> dict[str, tuple[str, str]]:
        """Drive-log column -> (source column, the option that named it)."""
        out = {"t": (self.t, "--t"), "omega": (self.omega, "--omega")}
        if self.heading is not None:
            out["heading_truth"] = (self.heading, "--heading")
        if self.speed is not None:
            out["speed"] = (self.speed, "--speed")
        if self.temp is not None:
            out["temp_c"] = (self.temp, "--temp")
        return out


def _integer(text: str) -> int | None:
    """``text`` as an integer if it is one in plain ASCII digits that fits in 64 bits (a time
    in ms, us or ns keeps every digit that way), else None."""
    body = text[1:] if text[:1] in "+-" else text
    if not (body.isascii() and body.isdigit()):
        return None
    v = int(text)
    return v if -(2**63) <= v < 2**63 else None


def _index(
    header: list[str], mapping: Mapping, label: str
) -> tuple[dict[str, int], dict[str, str]]:
    """Drive-log column -> its index in the source's header, and what to call it in a message
    (the source's name and the option that named it)."""
    index: dict[str, int] = {}
    shown: dict[str, str] = {}
    for col, (src, opt) in mapping.columns().items():
        hits = [i for i, h in enumerate(header) if h == src]
        if not hits:
            have = clipped(", ".join(repr(h) for h in header), 200)
            raise SourceCsvError(
                f"{label}: no column {clipped(repr(src), 60)} ({opt}); the header has {have}"
            )
        if len(hits) > 1:
            raise SourceCsvError(f"{label}: column {clipped(repr(src), 60)} ({opt}) appears twice")
        index[col] = hits[0]
        shown[col] = f"{clipped(repr(src), 60)} ({opt})"
    return index, shown


def convert(
    arrays: dict[str, FloatArray],
    t_s: FloatArray,
    mapping: Mapping,
    where: Callable[[int], str],
    shown: dict[str, str],
    limits: ReadLimits = DEFAULT_READ_LIMITS,
) -> DriveLog:
    """The drive log of a source's columns as read (``arrays``: drive-log column -> values in
    the source's units; ``t_s``: seconds since the first row): each converted to hdrd's units
    and signs, then checked as a drive log is, ``where(i)`` naming row i and ``shown`` each
    column in a message. DriveLogError on the first problem."""
    out = dict(arrays)
    out["t"] = t_s
    sign = -1.0 if mapping.omega_sign == "cw" else 1.0
    out["omega"] = arrays["omega"] * (OMEGA_UNITS[mapping.omega_unit] * sign)
    if "heading_truth" in arrays:
        h = arrays["heading_truth"] * HEADING_UNITS[mapping.heading_unit]
        _check_heading(arrays["heading_truth"], h, mapping, where, shown["heading_truth"])
        if mapping.heading_ref == "enu":
            h = 90.0 - h
        with np.errstate(invalid="ignore"):
            h = compass(h)
        out["heading_truth"] = h
    if "speed" in arrays:
        out["speed"] = arrays["speed"] * SPEED_UNITS[mapping.speed_unit]
    check_columns(out, where, limits, shown)
    written = csv_values("t", out["t"])  # what the drive log will hold: 0.1 ms steps
    close = np.flatnonzero(np.diff(written) <= 0)
    if close.shape[0]:
        k = int(close[0]) + 1
        raise SourceCsvError(
            f"{where(k)}: column {shown['t']}: {out['t'][k]:.6g} s, "
            f"{out['t'][k] - out['t'][k - 1]:.2g} s after the row before; a drive log keeps t "
            "to 0.1 ms (10 kHz at most)"
        )
    return DriveLog(**out)  # type: ignore[arg-type]


def _check_heading(
    raw: FloatArray, deg: FloatArray, mapping: Mapping, where: Callable[[int], str], shown: str
) -> None:
    """SourceCsvError for a heading beyond a turn either way (+/- :data:`HEADING_LIMIT_DEG`,
    in degrees, before it is wrapped: 999 would become 279 and -1e300 0), naming the unit
    option when the value would fit in the other unit."""
    with np.errstate(invalid="ignore"):
        out = np.abs(deg) > HEADING_LIMIT_DEG
    if not out.any():
        return
    i = int(np.flatnonzero(out)[0])
    hint = ""
    if mapping.heading_unit == "rad" and abs(raw[i]) <= HEADING_LIMIT_DEG:
        hint = "; is the column in degrees? --heading-unit deg"
    raise SourceCsvError(
        f"{where(i)}: column {shown}: {raw[i]:.6g} {mapping.heading_unit} is outside +/-"
        f"{HEADING_LIMIT_DEG:g} deg; a heading is a direction (not unwrapped, not a "
        f"placeholder such as 999){hint}"
    )


def _header(lines: Iterator[str], label: str, delimiter: str) -> tuple[list[str], int]:
    """The header's cells (the first line that is neither empty nor a ``#`` comment) and its
    line number."""
    lineno = 0
    for raw in lines:
        lineno += 1
        if lineno == 1:
            raw = raw.removeprefix("\ufeff")
        s = raw.strip()
        if s and not s.startswith("#"):
            try:
                return [h.strip() for h in next(csv.reader([s], delimiter=delimiter))], lineno
            except csv.Error as e:
                raise SourceCsvError(
                    f"{label}:{lineno}: the header is not a CSV line ({e})"
                ) from None
    raise SourceCsvError(f"{label}: empty file, expected a header line naming the columns")


def _rows(
    lines: Iterator[str],
    header_no: int,
    width: int,
    index: dict[str, int],
    shown: dict[str, str],
    label: str,
    limits: ReadLimits,
    delimiter: str = ",",
) -> tuple[dict[str, array[float]], array[int] | None, array[int]]:
    """The data rows after the header: each mapped column's values (8 bytes a cell), the
    times as integers (None once one is not an integer) and each row's file line."""
    cols = {c: array("d") for c in index}
    t_int: array[int] | None = array("q")
    line_nos = array("q")
    reader = csv.reader(lines, delimiter=delimiter)
    try:
        for cells in reader:
            line = header_no + reader.line_num
            if not cells or (len(cells) == 1 and not cells[0].strip()):
                continue
            if len(line_nos) >= limits.max_rows:
                raise SourceCsvError(
                    f"{label}:{line}: more than the {limits.max_rows} rows a drive may "
                    "have (--max-rows)"
                )
            if len(cells) != width:
                raise SourceCsvError(f"{label}:{line}: {len(cells)} fields, the header has {width}")
            line_nos.append(line)
            for c, i in index.items():
                text = cells[i].strip()
                cols[c].append(parse_cell(text, label, line, shown[c]))
            if t_int is not None:
                ti = _integer(cells[index["t"]].strip())
                if ti is None:
                    t_int = None  # a time that is no integer: all are taken as decimals
                else:
                    t_int.append(ti)
    except csv.Error as e:
        raise SourceCsvError(
            f"{label}:{header_no + reader.line_num}: not a CSV row ({e})"
        ) from None
    return cols, t_int, line_nos


def _seconds(
    t_src: npt.NDArray[np.float64], t_int: array[int] | None, scale: float
) -> npt.NDArray[np.float64]:
    """The times in seconds from the first row; integers are subtracted exactly before they
    are scaled (unless two are further apart than an int64 holds: a time that went back past
    the integers' wrap); an empty time stays empty (NaN: refused by the checks)."""
    t_s = (t_src - t_src[0]) * scale
    if t_int is not None:
        ti64 = np.frombuffer(t_int, dtype=np.int64)
        d = ti64 - ti64[0]  # wraps where beyond int64: the sign says where
        if not (((ti64 ^ ti64[0]) & (ti64 ^ d)) < 0).any():
            t_s = d.astype(np.float64) * scale
    t_s[np.isnan(t_src)] = math.nan
    return t_s


def import_csv(
    path: str | os.PathLike[str],
    mapping: Mapping,
    delimiter: str = ",",
    limits: ReadLimits = DEFAULT_READ_LIMITS,
) -> DriveLog:
    """Read a source CSV (a regular file of UTF-8 text, a byte-order mark skipped; only the
    mapped columns are kept, 8 bytes a cell) and make a drive log of it (:func:`convert`),
    named by the file's stem. DriveLogError naming the line and column; OSError if it cannot
    be opened."""
    label = shown_path(path)
    with open_regular(path, label) as f:
        lines = text_lines(f, label)
        header, header_no = _header(lines, label, delimiter)
        index, shown = _index(header, mapping, label)
        cols, t_int, line_nos = _rows(
            lines, header_no, len(header), index, shown, label, limits, delimiter
        )
    if not line_nos:
        raise SourceCsvError(f"{label}: no data rows")
    arrays = {c: np.frombuffer(v, dtype=np.float64).copy() for c, v in cols.items()}
    t_s = _seconds(arrays.pop("t"), t_int, TIME_UNITS[mapping.time_unit])
    log = convert(arrays, t_s, mapping, lambda k: f"{label}:{line_nos[k]}", shown, limits)
    return DriveLog(
        t=log.t,
        omega=log.omega,
        temp_c=log.temp_c,
        heading_truth=log.heading_truth,
        speed=log.speed,
        name=Path(path).stem,
        meta={"source": f"hdrd import {Path(path).name}", **_described(mapping)},
    )


MIN_RATE_HZ = 0.5
"""Below this rate, Hz, :func:`unit_warnings` suspects the time unit: a gyro logs at 1 Hz or
more (a millisecond column read as seconds gives 0.01 Hz at 10 Hz)."""
TURN_DPS = 3.0
"""A rate above this, deg/s, counts as turning in :func:`unit_warnings` (a gyro's bias stays
below it)."""
MIN_TURN_DEG = 90.0
"""Turning the rate must show, deg, before a heading that barely moves is suspected."""


def unit_warnings(log: DriveLog, mapping: Mapping) -> list[str]:
    """What an imported log suggests of a wrong unit, each naming the option that fixes it:
    times that give fewer than :data:`MIN_RATE_HZ` samples a second (a millisecond column
    read as seconds), and a heading that moves within 2 pi degrees while the rate turns at
    least :data:`MIN_TURN_DEG` (radians read as degrees)."""
    out = []
    if len(log) > 2:
        step = float(np.median(np.diff(log.t)))
        rate = 1.0 / step
        if rate < MIN_RATE_HZ:
            here = TIME_UNITS[mapping.time_unit]
            fits = [
                (abs(math.log10(rate * here / scale / 100.0)), u)
                for u, scale in TIME_UNITS.items()
                if 1.0 <= rate * here / scale <= 10_000.0
            ]
            hint = f"; is it in {min(fits)[1]}? --time-unit {min(fits)[1]}" if fits else ""
            out.append(
                f"column {mapping.t!r} (--t) gives a sample every {step:.6g} s ({rate:.3g} Hz, "
                f"{len(log)} rows over {log.duration_s:,.1f} s); a gyro logs at 1 Hz or more{hint}"
            )
    h = log.heading_truth
    if h is not None and mapping.heading_unit == "deg" and np.isfinite(h).sum() > 1:
        ok = np.isfinite(h)
        moved = np.degrees(np.unwrap(np.radians(h[ok])))
        span = float(moved.max() - moved.min())
        w = np.abs(log.omega)
        turned = float(np.sum(np.where(w[1:] > TURN_DPS, w[1:], 0.0) * np.diff(log.t)))
        if turned >= MIN_TURN_DEG and span <= 2 * math.pi + 0.01:  # radians, as degrees
            out.append(
                f"column {mapping.heading!r} (--heading) moves within {span:.3g} deg while the "
                f"rate turns {turned:.0f} deg; is it in radians? --heading-unit rad"
            )
    return out


def _described(mapping: Mapping) -> dict[str, str]:
    """The metadata that says where each column came from, in what unit and sign."""
    parts = [f"t={mapping.t} ({mapping.time_unit}, from the first row)"]
    parts.append(f"omega={mapping.omega} ({mapping.omega_unit}, {mapping.omega_sign})")
    if mapping.heading is not None:
        parts.append(
            f"heading_truth={mapping.heading} ({mapping.heading_unit}, {mapping.heading_ref})"
        )
    if mapping.speed is not None:
        parts.append(f"speed={mapping.speed} ({mapping.speed_unit})")
    if mapping.temp is not None:
        parts.append(f"temp_c={mapping.temp} (deg C)")
    return {"imported": printable("; ".join(parts))}
