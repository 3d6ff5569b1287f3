"""Drive logs as Parquet (docs/drive-format.md, "Parquet"): one file per drive, a file holding
many drives in a ``drive`` column, or a dataset partitioned by drive (``DIR/drive=NAME/``).

The same columns, units and signs as the CSV (:mod:`hdrd.io.files.drivelog`); a drive is read into the
same :class:`~hdrd.io.files.drivelog.DriveLog` and passes the same checks. Metadata (the CSV's
``# key: value`` lines) is the Parquet schema's key-value metadata ``hdrd.meta``: a JSON
object of strings. The writer keeps the CSV's decimals (:func:`hdrd.io.files.drivelog.csv_values`), so
a drive written as CSV and as Parquet reads back bit for bit the same.

pyarrow is imported only here, and only when a Parquet file is read or written; without it a
one-line :class:`~hdrd.io.files.drivecolumns.DriveLogError` says how to install it.
"""

from __future__ import annotations

import json
import math
import os
import stat
import urllib.parse
from pathlib import Path
from typing import Any

import numpy as np

from hdrd.errors import clipped
from hdrd.io.files.access import (
    UnsafeNameError,
    atomic_output,
    path_inside,
    printable,
    shown_path,
    size_text,
)
from hdrd.io.files.drivecolumns import (
    COLUMNS,
    DEFAULT_READ_LIMITS,
    REQUIRED,
    DriveLogError,
    ReadLimits,
    check_columns,
)
from hdrd.io.files.drivelog import DriveLog, csv_values

__all__ = [
    "DRIVE_COLUMN",
    "DRIVE_META_KEY",
    "META_KEY",
    "PARTITION_PREFIX",
    "SUFFIX",
    "drives_in_file",
    "is_partition",
    "partition_dir",
    "partition_value",
    "read_parquet_drive",
    "write_dataset_drive",
    "write_parquet_drive",
]

SUFFIX = ".parquet"
DRIVE_COLUMN = "drive"
"""The column (or hive partition key) that names the drive in a file or dataset of many."""
PARTITION_PREFIX = DRIVE_COLUMN + "="
META_KEY = "hdrd.meta"
"""Schema metadata key of a drive's metadata: a JSON object of strings."""
DRIVE_META_KEY = "hdrd.drive_meta"
"""In a file holding many drives: a JSON object, drive name -> its metadata object."""
IGNORED_PREFIX = "__index_level_"
"""Columns pandas adds for a named index: not drive-log data, skipped."""
INSTALL = "pip install 'hdrd[fleet]'"


def _pyarrow() -> tuple[Any, Any, Any]:
    """(pyarrow, pyarrow.compute, pyarrow.parquet); DriveLogError if pyarrow is missing."""
    try:
        import pyarrow as pa
        import pyarrow.compute as pc
        import pyarrow.parquet as pq
    except ImportError:
        raise DriveLogError(f"Parquet drive logs need pyarrow: {INSTALL}") from None
    return pa, pc, pq


def is_partition(path: str | os.PathLike[str]) -> bool:
    """A directory of a dataset partitioned by drive: its name is ``drive=VALUE``."""
    return Path(path).name.startswith(PARTITION_PREFIX)


def partition_value(path: str | os.PathLike[str]) -> str:
    """The drive named by a partition directory ``drive=VALUE`` (VALUE URI-decoded, as
    pyarrow writes it)."""
    return urllib.parse.unquote(Path(path).name[len(PARTITION_PREFIX) :])


def partition_dir(root: str | os.PathLike[str], name: str) -> Path:
    """The partition directory of drive ``name`` in the dataset at ``root``: ``drive=NAME``
    with NAME URI-encoded (a ``/`` is ``%2F``), always directly inside ``root``
    (:func:`hdrd.io.files.access.path_inside`); DriveLogError for an empty name or one too long."""
    if not name:
        raise DriveLogError(f"{root}: a drive needs a name to be a partition of the dataset")
    try:
        return path_inside(root, PARTITION_PREFIX + urllib.parse.quote(name, safe=""))
    except UnsafeNameError as e:
        raise DriveLogError(str(e)) from None


# -- reading ------------------------------------------------------------------------------------


def _meta_of(schema: Any, label: str, key: str = META_KEY) -> dict[str, Any]:
    raw = (schema.metadata or {}).get(key.encode())
    if raw is None:
        return {}
    try:
        meta = json.loads(raw)
    except (UnicodeDecodeError, ValueError):
        raise DriveLogError(f"{label}: schema metadata {key} is not JSON") from None
    except RecursionError:
        raise DriveLogError(
            f"{label}: schema metadata {key} nests too deep (an object of strings expected)"
        ) from None
    if not isinstance(meta, dict):
        raise DriveLogError(f"{label}: schema metadata {key} is not a JSON object")
    return meta


def _strings(meta: Any, label: str) -> dict[str, str]:
    if not isinstance(meta, dict):
        raise DriveLogError(f"{label}: a drive's metadata is {type(meta).__name__}, not an object")
    for k, v in meta.items():
        if not isinstance(v, str):
            raise DriveLogError(
                f"{label}: metadata {clipped(repr(k), 60)} is {type(v).__name__}, not a string (as a CSV's "
                "'# key: value' lines)"
            )
    return dict(meta)


def _numeric(pa: Any, typ: Any) -> bool:
    """Whether a column of this Arrow type reads as numbers (nulls read as NaN)."""
    return bool(
        pa.types.is_floating(typ)
        or pa.types.is_integer(typ)
        or pa.types.is_boolean(typ)
        or pa.types.is_null(typ)
    )


def _columns(schema: Any, label: str) -> list[str]:
    """The drive-log columns of a file, checked as the CSV header is."""
    pa, _, _ = _pyarrow()
    names = [n for n in schema.names if n != DRIVE_COLUMN and not n.startswith(IGNORED_PREFIX)]
    if len(set(names)) != len(names) or schema.names.count(DRIVE_COLUMN) > 1:
        twice = next(n for n in schema.names if schema.names.count(n) > 1)
        raise DriveLogError(f"{label}: column {clipped(repr(twice), 60)} appears more than once")
    for n in names:
        if n not in COLUMNS:
            raise DriveLogError(
                f"{label}: unknown column {clipped(repr(n), 60)} (allowed: {', '.join(COLUMNS)})"
            )
        typ = schema.field(n).type
        if not _numeric(pa, typ):
            raise DriveLogError(f"{label}: column {n} holds {clipped(str(typ), 60)}, not numbers")
    for r in REQUIRED:
        if r not in names:
            raise DriveLogError(f"{label}: missing required column {r!r}")
    return names


EXACT_INT = 2**53
"""Integers beyond +/- this are not all float64 values: such a cell is refused, not rounded."""


def _arrays(table: Any, names: list[str], label: str) -> dict[str, Any]:
    """float64 numpy arrays (their own, writable), a null read as NaN as an empty CSV cell;
    DriveLogError for an integer that no float64 holds exactly."""
    pa, pc, _ = _pyarrow()
    out = {}
    for n in names:
        col = table.column(n)
        if pa.types.is_integer(col.type) and col.type.bit_width == 64:
            over = pc.greater(col, EXACT_INT)
            if pa.types.is_signed_integer(col.type):
                over = pc.or_(over, pc.less(col, -EXACT_INT))
            i = pc.index(over, True).as_py()
            if i >= 0:
                raise DriveLogError(
                    f"{label}: row {i + 1}: column {n}: the integer {col[i].as_py()} is beyond "
                    "2^53, which a float64 does not hold exactly"
                )
        col = pc.fill_null(pc.cast(col, pa.float64()), math.nan)
        out[n] = np.array(col.to_numpy(), dtype=np.float64, copy=True)
    return out


def _log(
    arrays: dict[str, Any], label: str, name: str, meta: dict[str, str], limits: ReadLimits
) -> DriveLog:
    if arrays["t"].shape[0] == 0:
        raise DriveLogError(f"{label}: no data rows")
    check_columns(arrays, lambda i: f"{label}: row {i + 1}", limits)
    return DriveLog(name=name, meta=meta, **arrays)


def _too_many(label: str, rows: int, limits: ReadLimits) -> DriveLogError:
    return DriveLogError(
        f"{label}: {rows} rows, more than the {limits.max_rows} a drive may have (--max-rows)"
    )


MAX_CHUNK_BYTES = 256 << 20
"""Largest column chunk a drive log's file may hold, uncompressed bytes, read from the file's
metadata before any value is read: a column of 10 million numbers in one row group takes 80 MB;
the decoder holds a chunk's page whole, however small the file (zstd turns a gigabyte of one
letter into 30 KB)."""
MAX_VALUE_BYTES = 1024
"""Most uncompressed bytes a column chunk may take per value, on average (beyond
:data:`CHUNK_SLACK_BYTES`): a number takes 8, a drive's name in the ``drive`` column a few dozen
(one longer than 200 bytes cannot name a file anyway)."""
CHUNK_SLACK_BYTES = 64 << 10
"""Uncompressed bytes a column chunk may take beyond :data:`MAX_VALUE_BYTES` a value: page
headers and a dictionary of names."""


def _check_sizes(pf: Any, columns: list[str], groups: list[int], label: str) -> None:
    """DriveLogError if a chunk of ``columns`` in row groups ``groups`` is larger, uncompressed,
    than :data:`MAX_CHUNK_BYTES` or :data:`MAX_VALUE_BYTES` a value: from the file's metadata,
    before anything is read (a string bomb: two 1 GB names in a 33 KB file)."""
    md = pf.metadata
    # a column's leaves (a list column's is "drive.list.element"); the names read hold no dot
    leaves = [j for j in range(md.num_columns) if md.schema.column(j).path.split(".")[0] in columns]
    for i in groups:
        rg = md.row_group(i)
        for j in leaves:
            cc = rg.column(j)
            size, n = cc.total_uncompressed_size, cc.num_values
            if size > min(MAX_CHUNK_BYTES, n * MAX_VALUE_BYTES + CHUNK_SLACK_BYTES):
                raise DriveLogError(
                    f"{label}: column {clipped(printable(cc.path_in_schema), 60)} takes "
                    f"{size_text(size)} uncompressed for {n} values in row group {i + 1}; a "
                    f"drive log's column takes at most {MAX_VALUE_BYTES} bytes a value and "
                    f"{size_text(MAX_CHUNK_BYTES)} a row group (refused before reading)"
                )


def _regular(path: str | os.PathLike[str], label: str) -> None:
    """DriveLogError unless ``path`` is a regular file (opening a FIFO would wait for ever)."""
    mode = os.stat(path).st_mode
    if not stat.S_ISREG(mode):
        kind = "a FIFO" if stat.S_ISFIFO(mode) else "not a regular file"
        raise DriveLogError(f"{label}: is {kind}, not a drive log file")


def _read_file(
    path: Path, drive: Any = None, limits: ReadLimits = DEFAULT_READ_LIMITS
) -> tuple[Any, list[str], dict[str, str]]:
    """(table, columns, metadata) of one file; with ``drive``, only that drive's rows. The
    columns and the number of rows are checked from the file's metadata before any is read."""
    pa, pc, pq = _pyarrow()
    label = shown_path(path)
    _regular(path, label)
    pf = pq.ParquetFile(path)
    try:  # closed on every path: a bad file must not keep its descriptor
        schema = pf.schema_arrow
        names = _columns(schema, label)
        if drive is None:
            if pf.metadata.num_rows > limits.max_rows:
                raise _too_many(label, pf.metadata.num_rows, limits)
            _check_sizes(pf, names, list(range(pf.num_row_groups)), label)
            table = pf.read(columns=names)
            meta = _strings(_meta_of(schema, label), label)
        else:
            if DRIVE_COLUMN not in schema.names:
                raise DriveLogError(
                    f"{label}: no column {DRIVE_COLUMN!r} to find drive "
                    f"{clipped(repr(drive), 80)} in"
                )
            label = f"{label} (drive {printable(clipped(str(drive), 80))})"
            groups = _groups_with(pf, drive)
            _check_sizes(pf, [*names, DRIVE_COLUMN], groups, label)
            parts = []
            n = 0
            for batch in pf.iter_batches(
                batch_size=BATCH_ROWS,
                row_groups=groups,
                columns=[*names, DRIVE_COLUMN],
                use_threads=False,
            ):
                part = batch.filter(pc.equal(batch.column(DRIVE_COLUMN), drive))
                n += part.num_rows
                if n > limits.max_rows:
                    raise _too_many(label, n, limits)
                if part.num_rows:
                    parts.append(part.select(names))
            if not parts:
                raise DriveLogError(f"{label}: no rows of this drive")
            table = pa.Table.from_batches(parts)
            by_drive = _meta_of(schema, label, DRIVE_META_KEY)
            meta = _strings(by_drive.get(str(drive), {}), label)
    finally:
        pf.close()
    return table, names, meta


BATCH_ROWS = 1 << 16
"""Rows read at a time from a file holding many drives (a row group may hold millions)."""


def _groups_with(pf: Any, drive: Any) -> list[int]:
    """The row groups whose statistics of the ``drive`` column allow ``drive`` (all of them
    where there are no statistics): a worker reads only the row groups of its drive."""
    col = pf.schema_arrow.get_field_index(DRIVE_COLUMN)
    out = []
    for i in range(pf.num_row_groups):
        st = pf.metadata.row_group(i).column(col).statistics
        try:
            if st is not None and st.has_min_max and not (st.min <= drive <= st.max):
                continue
        except TypeError:  # statistics of another type than the value: read the group
            pass
        out.append(i)
    return out


def _partition_rows(files: list[Path], label: str, limits: ReadLimits) -> None:
    """DriveLogError if a partition's files hold more rows than a drive may (from their
    metadata, before any is read)."""
    _, _, pq = _pyarrow()
    total = 0
    for f in files:
        _regular(f, shown_path(f))
        pf = pq.ParquetFile(f)
        try:
            total += pf.metadata.num_rows
        finally:
            pf.close()
        if total > limits.max_rows:
            raise _too_many(label, total, limits)


def read_parquet_drive(
    path: str | os.PathLike[str],
    name: str | None = None,
    drive: Any = None,
    limits: ReadLimits = DEFAULT_READ_LIMITS,
) -> DriveLog:
    """One drive from Parquet: a file (``drive``: the value of its ``drive`` column to take,
    for a file holding many drives), or a partition directory ``drive=NAME`` of a dataset
    (its files, in the order of their first ``t``). ``name`` defaults to the file's stem, the
    drive's value or the partition's. DriveLogError on bad input (or beyond ``limits``, the
    number of rows checked before any is read), naming the file and row; OSError if the file
    cannot be opened."""
    pa, _, _ = _pyarrow()
    p = Path(path)
    label = shown_path(p)
    if drive is not None:
        label += f" (drive {printable(clipped(str(drive), 80))})"
    try:
        if p.is_dir():
            files = sorted(f for f in p.rglob("*" + SUFFIX) if f.is_file())
            if not files:
                raise DriveLogError(f"{label}: a partition without Parquet files")
            _partition_rows(files, label, limits)
            parts = [_read_file(f, None, limits) for f in files]
            parts.sort(key=lambda x: _first_t(x[0]))
            names = parts[0][1]
            for f, (_, other, _) in zip(files, parts):
                if sorted(other) != sorted(names):
                    raise DriveLogError(
                        f"{shown_path(f)}: columns {clipped(str(other), 100)} differ from "
                        f"those of the partition's first file, {names}"
                    )
            table = pa.concat_tables([t.select(names) for t, _, _ in parts])
            meta = parts[0][2]
            default = partition_value(p)
        else:
            table, names, meta = _read_file(p, drive, limits)
            default = p.stem if drive is None else str(drive)
        arrays = _arrays(table, names, label)
    except (pa.ArrowException, OSError, UnicodeDecodeError) as e:
        unreadable = _unreadable(label, e)
    else:
        return _log(arrays, label, name or default, meta, limits)
    # raised here, not in the except clause: as its context, pyarrow's exception would keep
    # the half-made reader, and with it the file's descriptor, as long as ours lives
    raise DriveLogError(unreadable)


def _unreadable(label: str, e: Exception) -> str:
    """One line for a file pyarrow cannot read: the system's reason for an I/O error, else
    pyarrow's (a corrupt file: pyarrow raises OSError for those too, and UnicodeDecodeError
    for a column name that is not UTF-8)."""
    if isinstance(e, OSError) and e.errno is not None:
        return f"{label}: cannot be read: {e.strerror or e}"
    return f"{label}: not a readable Parquet drive log: {_why(e)}"


def _why(e: Exception) -> str:
    """pyarrow's message, on one line and cut short."""
    return clipped(printable(" ".join(str(e).split())), 200)


def _first_t(table: Any) -> float:
    col = table.column("t")
    return float(col[0].as_py()) if len(col) and col[0].is_valid else math.inf


MAX_DRIVES_PER_FILE = 1_000_000
"""Most drives one Parquet file may hold (its ``drive`` column's distinct values)."""


def drives_in_file(path: str | os.PathLike[str]) -> list[Any] | None:
    """The drives of a Parquet file holding many (its ``drive`` column's values, in the order
    they first appear; read :data:`BATCH_ROWS` rows at a time), or None for a file of one
    drive. DriveLogError beyond :data:`MAX_DRIVES_PER_FILE` drives."""
    pa, pc, pq = _pyarrow()
    label = shown_path(path)
    _regular(path, label)
    try:
        pf = pq.ParquetFile(path)
        try:
            names = pf.schema_arrow.names
            if DRIVE_COLUMN not in names:
                return None
            if names.count(DRIVE_COLUMN) > 1:
                raise DriveLogError(f"{label}: column {DRIVE_COLUMN!r} appears more than once")
            typ = pf.schema_arrow.field(DRIVE_COLUMN).type
            if pa.types.is_dictionary(typ):
                typ = typ.value_type
            if not (
                pa.types.is_string(typ) or pa.types.is_large_string(typ) or pa.types.is_integer(typ)
            ):
                raise DriveLogError(
                    f"{label}: column {DRIVE_COLUMN!r} holds {clipped(str(typ), 60)}; a drive's name is a string "
                    "or an integer"
                )
            _check_sizes(pf, [DRIVE_COLUMN], list(range(pf.num_row_groups)), label)
            seen: dict[Any, None] = {}
            for batch in pf.iter_batches(
                batch_size=BATCH_ROWS, columns=[DRIVE_COLUMN], use_threads=False
            ):
                for v in pc.unique(batch.column(0)).to_pylist():
                    if v is None:
                        raise DriveLogError(f"{label}: an empty {DRIVE_COLUMN!r} cell")
                    seen.setdefault(v, None)
                if len(seen) > MAX_DRIVES_PER_FILE:
                    raise DriveLogError(
                        f"{label}: more than {MAX_DRIVES_PER_FILE} drives in one file"
                    )
        finally:
            pf.close()
    except (pa.ArrowException, OSError, UnicodeDecodeError) as e:
        unreadable = _unreadable(label, e)
    else:
        return list(seen)
    raise DriveLogError(unreadable)  # outside the except clause: as in read_parquet_drive


# -- writing ------------------------------------------------------------------------------------


def _table(log: DriveLog) -> Any:
    pa, _, _ = _pyarrow()
    cols = log.columns()
    arrays = [pa.array(csv_values(c, getattr(log, c)), type=pa.float64()) for c in cols]
    meta = {META_KEY: json.dumps(log.meta, ensure_ascii=False)}
    return pa.Table.from_arrays(arrays, names=cols).replace_schema_metadata(meta)


def write_parquet_drive(
    path: str | os.PathLike[str], log: DriveLog, inside: str | os.PathLike[str] | None = None
) -> None:
    """Write one drive as a Parquet file (zstd), whole or not at all
    (:func:`hdrd.io.files.access.atomic_output`: its missing folders made; a character device or a
    FIFO is written through; ``inside``: a file hdrd names in that folder, only a regular file
    replaced); OSError if it cannot be."""
    _, _, pq = _pyarrow()
    with atomic_output(path, make_parents=True, inside=inside) as f:
        pq.write_table(_table(log), f, compression="zstd")


def write_dataset_drive(root: str | os.PathLike[str], log: DriveLog, name: str) -> Path:
    """Add drive ``name`` to the dataset partitioned by drive at ``root``:
    ``ROOT/drive=NAME/part-0.parquet`` (NAME URI-encoded, as pyarrow's hive partitioning
    reads it), replacing the drive if it is there; ROOT and the partition's folder are made if
    need be. The partition is a file hdrd names in the folder the user named
    (:func:`hdrd.io.files.access.atomic_output`'s ``inside``: a link or a FIFO there is refused, and
    a partition folder that leads out of ROOT). OSError if it cannot be written. Returns the
    file written."""
    part = partition_dir(root, name)
    path = part / ("part-0" + SUFFIX)
    write_parquet_drive(path, log, inside=root)
    real_root = Path(root).resolve()
    if real_root in part.resolve().parents:  # what the write found: inside ROOT
        for old in part.glob("*" + SUFFIX):
            if old.name != "part-0" + SUFFIX:
                old.unlink()
    return path
