"""The drive log: one CSV row per gyro sample, with optional ground truth (docs/drive-format.md).

Columns (header required, any order, unknown columns are an error):

=============== ======== ===============================================================
t               s        monotonic sample time (required)
omega           deg/s    raw gyro rate, + = CCW (left turn), bias NOT removed (required)
temp_c          deg C    board/cabin temperature (optional)
heading_truth   deg      compass heading, clockwise from north, [0, 360); empty = unknown
omega_truth     deg/s    true yaw rate, + = CCW (optional)
speed           m/s      vehicle speed (optional)
valid           0 / 1    1 = the sample counts, 0 = excluded (handling, ...) (optional)
gps_course      deg      a GPS receiver's course, compass, at its fixes (optional)
gps_speed       m/s      that receiver's ground speed at its fixes (optional)
=============== ======== ===============================================================

Empty cells are NaN in memory ("unknown"), never 0. Here: :class:`DriveLog`, the CSV read and
written, and what a file that is no drive log is instead; the columns' limits and the checks
every drive log passes are :mod:`hdrd.io.files.drivecolumns`'.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import shlex
import stat
from array import array
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import BinaryIO

import numpy as np

from hdrd.errors import clipped
from hdrd.io.files.access import atomic_output, printable, shown_path
from hdrd.io.files.drivecolumns import (
    COLUMNS,
    DEFAULT_READ_LIMITS,
    REQUIRED,
    DriveLogError,
    FloatArray,
    ReadLimits,
    check_columns,
)
from hdrd.io.wire.capture import decode_capture

__all__ = [
    "DriveLog",
    "converted_name",
    "csv_values",
    "escape_meta",
    "open_regular",
    "parse_cell",
    "read_drive",
    "text_lines",
    "unescape_meta",
    "write_drive",
]


@dataclass(frozen=True)
class DriveLog:
    """A drive's samples. Optional columns are None when absent, NaN where a cell is empty."""

    t: FloatArray
    omega: FloatArray
    temp_c: FloatArray | None = None
    heading_truth: FloatArray | None = None
    omega_truth: FloatArray | None = None
    speed: FloatArray | None = None
    valid: FloatArray | None = None
    """1.0 where the sample counts, 0.0 where it is excluded (e.g. the device was handled)."""
    gps_course: FloatArray | None = None
    """A GPS receiver's course over ground, compass deg, at its fixes (NaN between them),
    when the log has one beside a better truth (``hdrd evaluate --outages`` aids from it)."""
    gps_speed: FloatArray | None = None
    """That receiver's ground speed, m/s, at its fixes."""
    name: str = ""
    meta: dict[str, str] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self) else 0.0

    @property
    def rate_hz(self) -> float:
        """Median sample rate, Hz."""
        return float(1.0 / np.median(np.diff(self.t))) if len(self) > 1 else 0.0

    def columns(self) -> list[str]:
        return [c for c in COLUMNS if getattr(self, c) is not None]

    def slice(self, start: int, stop: int | None = None) -> DriveLog:
        """Rows [start, stop)."""
        kw = {c: getattr(self, c)[start:stop] for c in self.columns()}
        return replace(self, **kw)

    def counted(self) -> DriveLog:
        """The rows that count: those with ``valid`` 1 (all, without a ``valid`` column), as if
        the others had been dropped from the file (a time gap where they were)."""
        if self.valid is None or bool((self.valid != 0.0).all()):
            return self
        keep = self.valid != 0.0
        kw = {c: getattr(self, c)[keep] for c in self.columns()}
        return replace(self, **kw)


MAX_LINE_CHARS = 1 << 16
"""Longest line of a drive-log CSV, characters: a row of seven numbers takes ~70, a metadata
line a few thousand; a longer line (a cell of megabytes, a file without line breaks) is
refused before it is held."""


def parse_cell(text: str, path: str, line: int, col: str) -> float:
    """A cell: a decimal number in ASCII (``1.5``, ``-2e-3``), empty or ``nan`` for unknown.
    Python's float() takes more, which a drive log does not: ``1_000`` (a digit separator,
    most likely a typo) and digits of other scripts (``١٢``)."""
    if text == "" or text.lower() == "nan":
        return math.nan
    if "_" in text or not text.isascii():
        raise DriveLogError(
            f"{path}:{line}: column {col}: {clipped(repr(text), 60)} is not a number (only "
            "ASCII digits, '.', a sign and an exponent)"
        )
    try:
        v = float(text)
    except ValueError:
        raise DriveLogError(
            f"{path}:{line}: column {col}: {clipped(repr(text), 60)} is not a number"
        ) from None
    if math.isinf(v):
        raise DriveLogError(f"{path}:{line}: column {col}: {clipped(repr(text), 60)} is not finite")
    return v


def read_drive(
    path: str | os.PathLike[str] | io.TextIOBase,
    name: str | None = None,
    limits: ReadLimits = DEFAULT_READ_LIMITS,
) -> DriveLog:
    """Read a drive log CSV. Lines starting with '#' before the header are metadata
    (``# key: value``). Raises DriveLogError naming the file, line and column on bad input
    (and on a value beyond ``limits``)."""
    if isinstance(path, (str, os.PathLike)):
        label = shown_path(path)
        try:
            with open_regular(path, label) as f:
                return _read(f, label, name or Path(path).stem, limits)
        except DriveLogError:
            what = _not_a_drive_log(path, label)
            if what is not None:
                raise DriveLogError(what) from None
            raise
    return _read(path, "<stream>", name or "", limits)


_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def open_regular(path: str | os.PathLike[str], label: str) -> BinaryIO:
    """The file, if it is a regular file (a FIFO would block the reader, a device never end):
    opened without blocking, then checked; DriveLogError otherwise."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = next((k for test, k in _KINDS if test(mode)), "not a regular file")
            raise DriveLogError(f"{label}: is {kind}, not a drive log file")
        return open(fd, "rb", closefd=True)
    except BaseException:
        os.close(fd)
        raise


PARQUET_MAGIC = b"PAR1"
"""The first (and last) four bytes of every Parquet file."""
SNIFF_BYTES = 4096
"""Bytes looked at to say what a file that is no drive log is."""


def _not_a_drive_log(path: str | os.PathLike[str], label: str) -> str | None:
    """What a file that failed to read as a drive log is instead, if its first bytes say: a
    capture of the gyro's frames (hdr-bin or hdr-text: ``hdrd convert`` makes a drive log of
    it), a Parquet file under another name, binary data. None: a text file, whose own error
    stands."""
    try:
        with open_regular(path, "") as f:
            head = f.read(SNIFF_BYTES)
    except (OSError, DriveLogError):
        return None

    for protocol in ("hdr-bin", "hdr-text"):
        frames, _ = decode_capture(head, protocol)
        if frames.shape[0] >= 3:
            given = str(path) if len(str(path)) <= 80 else Path(path).name
            out = converted_name(path)
            cmd = f"hdrd convert {shlex.quote(given)} --out {shlex.quote(out)}"
            return (
                f"{label}: a capture of the gyro's frames ({protocol}), not a drive log; "
                f"make one with `{clipped(printable(cmd), 200)}`"
            )
    if head.startswith(PARQUET_MAGIC):
        return f"{label}: a Parquet file; name it {printable(Path(path).stem)}.parquet"
    if b"\x00" in head:
        return (
            f"{label}: binary data, not a drive log (a CSV file in UTF-8, or a .parquet file: "
            "docs/drive-format.md)"
        )
    return None


def drive_log_kind(head: bytes) -> str | None:
    """``CSV`` or ``Parquet`` when a file's first bytes are those of a drive log (a Parquet
    file's magic; a CSV's ``# key: value`` lines, then a header naming ``t`` and ``omega``),
    else None: for the capture tools to say what they were given instead."""
    if head.startswith(PARQUET_MAGIC):
        return "Parquet"
    text = head.decode("utf-8", "replace")
    for line in text.splitlines()[:200]:
        if not line.strip() or line.startswith("#"):
            continue
        cells = {c.strip() for c in line.split(",")}
        return "CSV" if {"t", "omega"} <= cells else None
    return None


def converted_name(capture: str | os.PathLike[str]) -> str:
    """The drive log's file name to suggest for ``hdrd convert CAPTURE``: the capture's stem
    with ``.csv``, or with ``-drive.csv`` when that is the capture's own name (a capture
    renamed ``x.csv``: converting it onto itself would lose it)."""
    p = Path(capture)
    stem = p.stem or "drive"
    return stem + ("-drive.csv" if p.name == stem + ".csv" else ".csv")


def text_lines(f: io.TextIOBase | BinaryIO, label: str) -> Iterator[str]:
    """The lines of ``f`` as text, none longer than :data:`MAX_LINE_CHARS`; bytes are UTF-8
    (DriveLogError naming the line otherwise)."""
    n = 0
    while True:
        line = f.readline(MAX_LINE_CHARS + 1)
        if not line:
            return
        n += 1
        if len(line) > MAX_LINE_CHARS:
            raise DriveLogError(
                f"{label}:{n}: a line longer than {MAX_LINE_CHARS} characters; a drive log's "
                "rows are a few numbers each"
            )
        if isinstance(line, bytes):
            try:
                line = line.decode("utf-8")
            except UnicodeDecodeError as e:
                raise DriveLogError(
                    f"{label}:{n}: not UTF-8 text (byte 0x{line[e.start]:02x} at column "
                    f"{e.start + 1}); save the CSV as UTF-8"
                ) from None
        yield line


def _meta_and_header(lines: Iterator[str], label: str) -> tuple[dict[str, str], str, int]:
    """The ``# key: value`` lines before the header, the header line and its line number."""
    meta: dict[str, str] = {}
    lineno = 0
    for raw in lines:
        lineno += 1
        if lineno == 1:
            raw = raw.removeprefix("\ufeff")  # a byte-order mark (Excel's "CSV UTF-8")
        s = raw.strip()
        if not s:
            continue
        if s.startswith("#"):
            k, colon, v = s[1:].partition(":")
            if colon:
                meta[unescape_meta(k.strip())] = unescape_meta(v.strip())
            continue
        return meta, s, lineno
    raise DriveLogError(f"{label}: empty file, expected a header line 't,omega,...'")


_UNESCAPE = re.compile(r"\\(\\|n|r|t|x[0-9a-fA-F]{2}|u[0-9a-fA-F]{4}|U[0-9a-fA-F]{8})")


def escape_meta(text: str, key: bool = False) -> str:
    """A metadata key or value as its ``# key: value`` line holds it, on that one line: a
    backslash as ``\\\\``, a line break, tab or any other character a terminal could act on as
    its Python escape (``\\n``, ``\\t``, ``\\x1b``, ``\\u2028``), a space at either end as
    ``\\x20`` (the reader strips the line), and in a ``key`` a ``:`` as ``\\x3a`` (the line
    splits at its first colon). A value from data (a file's name in ``source``) can then never
    add a line of its own. :func:`unescape_meta` undoes it."""
    plain = text.isprintable() and "\\" not in text and not (key and ":" in text)
    if plain and text.strip(" ") == text:
        return text
    out = []
    for c in text:
        if c == "\\":
            out.append("\\\\")
        elif key and c == ":":
            out.append("\\x3a")
        else:
            out.append(c if c.isprintable() else repr(c)[1:-1])
    line = "".join(out)
    if line.startswith(" "):
        line = "\\x20" + line[1:]
    if line.endswith(" "):
        line = line[:-1] + "\\x20"
    return line


def unescape_meta(text: str) -> str:
    """A metadata key or value as :func:`escape_meta` wrote it, back to its text; a backslash
    that starts no escape is kept as it is (a value written before escaping reads the same
    unless it held one)."""
    if "\\" not in text:
        return text

    def one(m: re.Match[str]) -> str:
        code = m.group(1)
        if len(code) == 1:
            return {"\\": "\\", "n": "\n", "r": "\r", "t": "\t"}[code]
        n = int(code[1:], 16)
        return chr(n) if n <= 0x10FFFF else m.group(0)

    return _UNESCAPE.sub(one, text)


def _header(header_line: str, label: str, lineno: int) -> list[str]:
    """The column names of the header line, checked: known, the required ones, none twice."""
    try:
        header = [h.strip() for h in next(csv.reader([header_line]))]
    except csv.Error as e:
        raise DriveLogError(f"{label}:{lineno}: the header is not a CSV line ({e})") from None
    for h in header:
        if h not in COLUMNS:
            raise DriveLogError(
                f"{label}:{lineno}: unknown column {clipped(repr(h), 60)} "
                f"(allowed: {', '.join(COLUMNS)})"
            )
    for r in REQUIRED:
        if r not in header:
            raise DriveLogError(f"{label}:{lineno}: missing required column {r!r}")
    if len(set(header)) != len(header):
        raise DriveLogError(f"{label}:{lineno}: repeated column in header")
    return header


def _rows(
    lines: Iterator[str], header: list[str], label: str, header_lineno: int, limits: ReadLimits
) -> tuple[array[float], array[int]]:
    """The data rows' values one after the other (8 bytes a cell) and each row's file line
    (for error messages)."""
    width = len(header)
    flat = array("d")
    row_lines = array("q")
    reader = csv.reader(lines)
    try:
        for row in reader:
            lineno = header_lineno + reader.line_num
            if not row or (len(row) == 1 and not row[0].strip()):
                continue
            row_lines.append(lineno)
            if len(row_lines) > limits.max_rows:
                raise DriveLogError(
                    f"{label}:{lineno}: more than the {limits.max_rows} rows a drive may have "
                    "(--max-rows)"
                )
            if len(row) != width:
                raise DriveLogError(f"{label}:{lineno}: {len(row)} fields, header has {width}")
            plain = "".join(row)
            if plain.isascii() and "_" not in plain:
                try:  # the common row: plain numbers and empty cells, taken at C speed
                    flat.extend([float(c or "nan") for c in row])
                    continue
                except ValueError:
                    pass
            flat.extend([parse_cell(c.strip(), label, lineno, h) for h, c in zip(header, row)])
    except csv.Error as e:
        raise DriveLogError(
            f"{label}:{header_lineno + reader.line_num}: not a CSV row ({e})"
        ) from None
    return flat, row_lines


def _read(f: io.TextIOBase | BinaryIO, label: str, name: str, limits: ReadLimits) -> DriveLog:
    lines = text_lines(f, label)
    meta, header_line, header_lineno = _meta_and_header(lines, label)
    header = _header(header_line, label, header_lineno)
    flat, row_lines = _rows(lines, header, label, header_lineno, limits)
    table = np.frombuffer(flat, dtype=np.float64).reshape(-1, len(header))
    arrays = {h: np.array(table[:, j]) for j, h in enumerate(header)}
    del table, flat
    if arrays["t"].shape[0] == 0:
        raise DriveLogError(f"{label}: no data rows")
    check_columns(arrays, lambda i: f"{label}:{row_lines[i]}", limits)
    return DriveLog(name=name, meta=meta, **arrays)


def _fmt(v: float, digits: tuple[int, int]) -> str:
    """``v`` with up to digits[1] decimals, trailing zeros dropped down to digits[0]."""
    if math.isnan(v):
        return ""
    lo, hi = digits
    s = f"{v:.{hi}f}"
    if hi > lo:
        s = s[: len(s) - hi + lo] + s[len(s) - hi + lo :].rstrip("0")
    return s


# Decimals per column, (at least, at most). Rates keep 7 decimals where they have them, so that
# an ADC's step survives the CSV: a CRS03-04 on a 16-bit ADC steps by 0.00763 deg/s, a
# +/-1000 deg/s MEMS by 0.0305 deg/s (1/32.8), neither a round decimal; rounded to 1e-7 deg/s
# their codes stay within 1e-5 of a step. A value with 5 decimals or fewer is written as before.
_DIGITS = {
    "t": (4, 4),
    "omega": (5, 7),
    "temp_c": (3, 3),
    "heading_truth": (3, 3),
    "omega_truth": (5, 7),
    "speed": (3, 3),
    "valid": (0, 0),
    "gps_course": (3, 3),
    "gps_speed": (3, 3),
}


def csv_values(column: str, values: FloatArray) -> FloatArray:
    """``values`` as a CSV written by :func:`write_drive` reads them back: each rounded to the
    column's most decimals (the nearest double to the decimal the writer prints; NaN stays
    NaN). The Parquet writer stores these, so a drive written in either format reads back the
    same, bit for bit."""
    digits = _DIGITS[column][1]
    scale = 10.0**digits
    v = np.asarray(values, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        x = v * scale  # an overflow goes to the writer's way below
    out: FloatArray = np.rint(x) / scale  # an exact integer over 10**digits: correctly rounded
    # Where the product's own rounding could put x on the other side of a half, or x is too
    # large for rint to be exact, do what the writer does.
    with np.errstate(invalid="ignore"):
        near = np.abs(x - np.floor(x) - 0.5) <= 4 * np.spacing(np.abs(x))
        huge = ~(np.abs(x) < 2.0**52)
    for i in np.flatnonzero((near | huge) & np.isfinite(v)).tolist():
        out[i] = float(f"{v[i]:.{digits}f}")
    return out


def write_drive(
    path: str | os.PathLike[str] | io.TextIOBase,
    log: DriveLog,
    inside: str | os.PathLike[str] | None = None,
) -> None:
    """Write a drive log CSV (metadata as leading '# key: value' lines). A path is written
    whole or not at all (:func:`hdrd.io.files.access.atomic_output`: its missing folders made; a
    character device or a FIFO is written through; ``inside``: a file hdrd names in that
    folder, only a regular file replaced); OSError if it cannot be."""
    if isinstance(path, (str, os.PathLike)):
        with atomic_output(path, make_parents=True, inside=inside) as raw:
            f = io.TextIOWrapper(raw, "utf-8", newline="")
            _write(f, log)
            f.flush()
            f.detach()  # the file stays open: atomic_output syncs and closes it
    else:
        _write(path, log)


def _write(f: io.TextIOBase, log: DriveLog) -> None:
    for k, v in log.meta.items():
        f.write(f"# {escape_meta(k, key=True)}: {escape_meta(v)}\n")
    cols = log.columns()
    f.write(",".join(cols) + "\n")
    data = [getattr(log, c).tolist() for c in cols]
    digits = [_DIGITS[c] for c in cols]
    for row in zip(*data):
        f.write(",".join(_fmt(v, d) for v, d in zip(row, digits)) + "\n")
