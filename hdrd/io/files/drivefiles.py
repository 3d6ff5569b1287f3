"""Which drives a command line names: files, directories and globs of drive logs, CSV or
Parquet (docs/drive-format.md), each drive as a small :class:`DriveRef` that a worker can
read by itself. Listing a fleet reads no samples (a Parquet file holding many drives: its
``drive`` column only).
"""

from __future__ import annotations

import glob
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hdrd.errors import clipped
from hdrd.io.files.access import printable, shown_path
from hdrd.io.files.drivecolumns import DEFAULT_READ_LIMITS, DriveLogError, ReadLimits
from hdrd.io.files.drivelog import DriveLog, read_drive, write_drive
from hdrd.io.files.parquetlog import (
    drives_in_file,
    partition_value,
    read_parquet_drive,
    write_dataset_drive,
    write_parquet_drive,
)

__all__ = ["FORMATS", "DriveRef", "find_drives", "log_format", "write_log"]

CSV_SUFFIX = ".csv"
PARQUET_SUFFIX = (
    ".parquet"  # hdrd.io.files.parquetlog.SUFFIX (not imported: it needs no pyarrow here)
)
PARTITION_PREFIX = "drive="  # hdrd.io.files.parquetlog.PARTITION_PREFIX
MAX_NAME_CHARS = 100
"""A drive's name is cut to this many characters (ending in "..."): names come from data (a
``drive`` column, a folder's name) and are shown in every line about the drive."""
GLOB_CHARS = frozenset("*?[")
FORMATS = ("csv", "parquet", "dataset")
"""What ``--format`` writes: a CSV file, a Parquet file, a drive of a dataset partitioned by
drive (OUT/drive=NAME/part-0.parquet)."""


def drive_name(value: Any) -> str:
    """What results and messages call a drive whose name in the data is ``value``: its text
    with non-printable characters escaped (:func:`hdrd.io.files.access.printable`), at most
    :data:`MAX_NAME_CHARS` characters. A name becomes a path only through
    :func:`hdrd.io.files.access.path_inside`."""
    return clipped(printable(str(value)), MAX_NAME_CHARS)


@dataclass(frozen=True)
class DriveRef:
    """Where one drive is: ``path`` a CSV file, a Parquet file or a dataset's partition
    directory; ``key`` the drive's value in the ``drive`` column of a Parquet file holding many
    (None otherwise); ``name`` what results call it."""

    path: str
    name: str
    key: Any = None
    problem: str | None = None
    """Why the file could not even be listed (a Parquet file that cannot be opened): reading
    the drive raises it, so that it is that drive's error, not the whole fleet's."""

    @property
    def parquet(self) -> bool:
        return self.path.endswith(PARQUET_SUFFIX) or Path(self.path).name.startswith(
            PARTITION_PREFIX
        )

    def read(self, limits: ReadLimits = DEFAULT_READ_LIMITS) -> DriveLog:
        """The drive's samples; DriveLogError on bad content (or beyond ``limits``), OSError
        (or UnicodeDecodeError) if the file cannot be read."""
        if self.problem is not None:
            raise DriveLogError(self.problem)
        if self.parquet:
            return read_parquet_drive(self.path, self.name, self.key, limits)
        return read_drive(self.path, self.name, limits)


def _in_file(path: Path, name: str) -> list[DriveRef]:
    """The drives of one file: a CSV is one drive; a Parquet file one, or one per value of its
    ``drive`` column (named ``NAME/VALUE``, or VALUE when the file was named itself: ``name``
    empty)."""
    if path.suffix == PARQUET_SUFFIX:
        try:
            keys = drives_in_file(path)
        except (DriveLogError, OSError) as e:
            why = str(e) if isinstance(e, DriveLogError) else f"{path}: {e.strerror or e}"
            return [DriveRef(str(path), drive_name(name or path.stem), problem=printable(why))]
        if keys == []:  # a drive column, but no row: no drive to name
            why = f"{shown_path(path)}: a file with a {'drive'!r} column and no rows"
            return [DriveRef(str(path), drive_name(name or path.stem), problem=why)]
        if keys is not None:
            return [DriveRef(str(path), drive_name(f"{name}/{k}" if name else k), k) for k in keys]
    return [DriveRef(str(path), drive_name(name or path.stem))]


def _not_a_file(path: Path) -> str | None:
    """Why ``path`` (found or named as a drive log) is not a file to read, or None: a link to
    nothing, a FIFO (reading it would wait for a writer), a socket, a device."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except OSError as e:
        if os.path.islink(path):
            return f"{shown_path(path)}: a symbolic link to nothing"
        return f"{shown_path(path)}: cannot be read ({e.strerror or e})"
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return None
    kind = "a FIFO" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else "a device"
    return f"{shown_path(path)}: is {kind}, not a drive log file"


def _scan(root: Path, problems: list[str]) -> list[Path]:
    """Drive logs under a directory at any depth, sorted: ``*.csv`` and ``*.parquet`` files,
    and partition directories ``drive=NAME`` (whose files are that drive's). What is left out
    is said in ``problems``: a folder that cannot be read, and a FIFO, socket, device or link
    to nothing named as a drive log."""

    def unreadable(e: OSError) -> None:
        where = shown_path(e.filename) if e.filename else "a folder"
        problems.append(f"{where}: a folder that cannot be read ({e.strerror or e})")

    found: list[Path] = []
    for dirpath, dirnames, filenames in os.walk(root, onerror=unreadable):
        here = Path(dirpath)
        found.extend(here / d for d in dirnames if d.startswith(PARTITION_PREFIX))
        dirnames[:] = [d for d in dirnames if not d.startswith(PARTITION_PREFIX)]
        found.extend(here / f for f in filenames if f.endswith((CSV_SUFFIX, PARQUET_SUFFIX)))
    out = []
    for f in found:
        why = _not_a_file(f)
        if why is None:
            out.append(f)
        else:
            problems.append(why)
    return sorted(out)


def _partition(path: Path, parent: str = ".") -> DriveRef:
    """A partition directory ``drive=NAME``: named NAME, under the directories above it."""

    value = partition_value(path)
    return DriveRef(str(path), drive_name(value if parent == "." else f"{parent}/{value}"))


def _in_dir(root: Path, given: str, problems: list[str]) -> list[DriveRef]:
    out: list[DriveRef] = []
    for f in _scan(root, problems):
        rel = f.relative_to(root)
        if f.is_dir():
            out.append(_partition(f, rel.parent.as_posix()))
        else:
            out.extend(_in_file(f, rel.with_suffix("").as_posix()))
    if not out:
        raise DriveLogError(f"{given}: a directory without drive logs (*.csv, *.parquet)")
    return out


def _one(path: Path, given: str, problems: list[str]) -> list[DriveRef]:
    if path.is_dir():
        if path.name.startswith(PARTITION_PREFIX):
            return [_partition(path)]
        return _in_dir(path, given, problems)
    if path.exists():
        return _in_file(path, "")  # (reading it refuses a FIFO or a device)
    raise DriveLogError(f"{given}: no such file")


def find_drives(paths: Sequence[str], problems: list[str] | None = None) -> list[DriveRef]:
    """The drives named, in order: a file as given (a CSV, a Parquet file: named by its stem;
    a Parquet file with a ``drive`` column: each of its drives, named by the value), a
    directory searched at any depth (sorted; named by the path inside it without the suffix),
    a partition directory ``drive=NAME``, or a glob (``'fleet/**/*.parquet'``, quoted so that
    the shell leaves it: a fleet may be more files than a command line holds), expanded
    sorted. DriveLogError for a path that does not exist, a glob that matches nothing or a
    directory without logs. What a directory's scan leaves out (a
    folder that cannot be read, a FIFO, socket, device or link to nothing named as a drive
    log) is added to ``problems``, one line each."""
    problems = [] if problems is None else problems
    out: list[DriveRef] = []
    for p in paths:
        path = Path(p)
        if not path.exists() and GLOB_CHARS & set(p):
            matches = sorted(glob.glob(p, recursive=True))
            if not matches:
                raise DriveLogError(f"{p}: no file matches")
            for m in matches:
                why = _not_a_file(Path(m))
                if why is not None:  # a glob is a scan: its odd matches are left out, said
                    problems.append(why)
                    continue
                out.extend(_one(Path(m), m, problems))
        else:
            out.extend(_one(path, p, problems))
    return out


def log_format(out: str, fmt: str | None) -> str:
    """The format to write ``out`` in: ``fmt``, else parquet for a ``.parquet`` name, else csv."""
    if fmt is not None:
        return fmt
    return "parquet" if out.endswith(PARQUET_SUFFIX) else "csv"


def write_log(
    out: str, log: DriveLog, fmt: str, name: str, inside: str | os.PathLike[str] | None = None
) -> str:
    """Write a drive log as ``fmt`` (:data:`FORMATS`), its missing folders made; ``name``: the
    drive's name in a dataset; ``inside``: ``out`` is a file hdrd names in that folder the user
    named (a benchmark's drive), as :func:`hdrd.io.files.access.atomic_output`'s ``inside`` (a
    dataset's partitions are always). Returns what was written (the file). OSError if it
    cannot be written."""
    if fmt == "csv":
        write_drive(out, log, inside)
        return out
    if fmt == "parquet":
        write_parquet_drive(out, log, inside)
        return out

    return str(write_dataset_drive(out, log, name))
