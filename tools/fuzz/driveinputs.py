"""The inputs of the drive-log surfaces of tools/fuzz (tools/fuzz/drivelog.py says what each
holds and what the target checks): the envelope, the short drives they start from, the mutated
CSV and the mutated Parquet files."""

from __future__ import annotations

import io
import json
import math
import random
import struct
from collections.abc import Callable
from functools import cache
from typing import Any

import numpy as np

from .inputs import serial_input
from .mutate import giant_string, mutate_bytes

__all__ = [
    "HOSTILE_CELLS",
    "HOSTILE_NAMES",
    "base_logs",
    "drivecsv_input",
    "driveparquet_input",
    "pack",
    "unpack",
]


# -- the envelope -----------------------------------------------------------------------------


def pack(layout: str, name: str, files: list[bytes]) -> bytes:
    """``layout`` (one letter), a name (UTF-8, surrogates kept), then each file's bytes with
    its length."""
    nb = name.encode("utf-8", "surrogatepass")[:600]
    out = [layout.encode(), struct.pack("<H", len(nb)), nb, struct.pack("<B", len(files))]
    for f in files:
        out += [struct.pack("<I", len(f)), f]
    return b"".join(out)


def unpack(data: bytes) -> tuple[str, bytes, list[bytes]]:
    layout = data[:1].decode("latin-1") or "F"
    (n,) = struct.unpack_from("<H", data, 1)
    name = data[3 : 3 + n]
    at = 3 + n
    (k,) = struct.unpack_from("<B", data, at)
    at += 1
    files = []
    for _ in range(k):
        (m,) = struct.unpack_from("<I", data, at)
        files.append(data[at + 4 : at + 4 + m])
        at += 4 + m
    return layout, name, files


# -- the drives the inputs start from ---------------------------------------------------------


@cache
def base_logs() -> tuple[Any, ...]:
    """Short simulated drives (a few hundred rows): city at 2 Hz, suburbs at 5 Hz with a
    ``valid`` column, a standstill (no heading)."""
    from dataclasses import replace

    from hdrd.sim.drive import simulate_drive

    city = simulate_drive("city", 1.5, 1, hz=2.0)
    sub = simulate_drive("suburbs", 1.0, 2, hz=5.0)
    valid = np.ones(len(sub))
    valid[200:230] = 0.0
    still = simulate_drive("standstill", 1.0, 3, hz=2.0)
    return (city, replace(sub, valid=valid), still)


def _csv_text(log: Any) -> str:
    from hdrd.io.files.drivelog import write_drive

    buf = io.StringIO()
    write_drive(buf, log)
    return buf.getvalue()


HOSTILE_CELLS = (
    "", "nan", "NaN", "inf", "-inf", "Infinity", "1e308", "1e309", "-1e400", "1_000", "1_0.5",
    "\u0661\u0662", "\uff11", "0x10", "1e200", "-1e200", "  5 ", "+", "-", ".", "1e", "999",
    "725", "-361", "360", "-360", "1.7976931348623157e308", "5e-324", "1" + "0" * 310,
    "9007199254740993", "\x00", "\x1b[2J", '"', '"a,b"', "\u202e12", "1e-400", "0", "-0",
    "1001", "-1000.5", "3600", "1e9", "true", "None", "\ufeff1",
)  # fmt: skip

HOSTILE_NAMES = (
    "../../x", "/abs/x", "/etc/hdrd/hdrd", "..", ".", "", "a\x00b", "a\x1b[2Jb", "\u202eevil",
    "x" * 300, "\u00e9" * 150, "a/../../y", "drive=..%2Fz", "a//b", "a/", "ok", "sub/ok",
    "%2F..%2F", "\n", "CON", "0", "-1",
)  # fmt: skip


def _cell(
    rng: random.Random, lines: list[str], head: int, cols: list[str], data: list[int]
) -> None:
    """One cell: a hostile number or a giant string."""
    i = rng.choice(data)
    cells = lines[i].split(",")
    cells[rng.randrange(len(cells))] = (
        giant_string(rng) if rng.random() < 0.05 else rng.choice(HOSTILE_CELLS)
    )
    lines[i] = ",".join(cells)


def _header(
    rng: random.Random, lines: list[str], head: int, cols: list[str], data: list[int]
) -> None:
    """A column renamed, sometimes one more column named."""
    j = rng.randrange(len(cols))
    cols[j] = rng.choice(
        ("tt", "omega", "t", "", "valid", "\ufefft", "heading_truth", "drive", "T", "x" * 70)
    )
    if rng.random() < 0.3:
        cols.append(rng.choice(("valid", "speed", "omega")))
    lines[head] = ",".join(cols)


def _time_step(
    rng: random.Random, lines: list[str], head: int, cols: list[str], data: list[int]
) -> None:
    """Time from a row on: a jump, back, the same, tiny steps (s)."""
    k = cols.index("t")
    i = rng.choice(data)
    step = rng.choice((1e9, 3601.0, 1e300, -5.0, 0.0, 1e-9, 1e15))
    for j in range(i, len(lines)):
        cells = lines[j].split(",")
        if len(cells) == len(cols):
            try:
                cells[k] = repr(float(cells[k]) + step)
            except ValueError:
                pass
            lines[j] = ",".join(cells)


def _rows(
    rng: random.Random, lines: list[str], head: int, cols: list[str], data: list[int]
) -> None:
    """Rows removed, repeated, swapped, blank, a comment among them, or one cell too many."""
    i = rng.choice(data)
    op = rng.randrange(5)
    if op == 0:
        del lines[i : i + rng.randint(1, 50)]
    elif op == 1:
        lines.insert(i, lines[i])
    elif op == 2:
        j = rng.choice(data)
        lines[i], lines[j] = lines[j], lines[i]
    elif op == 3:
        lines.insert(i, rng.choice(("", " ", "# a: b", ",,,", "t,omega")))
    else:
        lines[i] += "," + rng.choice(HOSTILE_CELLS)


def _metadata(
    rng: random.Random, lines: list[str], head: int, cols: list[str], data: list[int]
) -> None:
    """A metadata line of an odd key or value on top."""
    key = rng.choice(("lead_in_s", "source", "x", "drive", ""))
    value = rng.choice(("1e308", "-5", "nan", "1e9", "30", "0.1", giant_string(rng)[:5000], "\x1b"))
    lines.insert(0, f"# {key}: {value}")


def _rate(
    rng: random.Random, lines: list[str], head: int, cols: list[str], data: list[int]
) -> None:
    """The whole rate (deg/s) flipped, scaled (to rad/s or from it) or absurd."""
    k = cols.index("omega")
    factor = rng.choice((-1.0, math.pi / 180, 57.29577951308232, 1e6, 0.0))
    for j in data:
        cells = lines[j].split(",")
        if len(cells) == len(cols):
            try:
                cells[k] = f"{float(cells[k]) * factor:.7f}"
            except ValueError:
                pass
            lines[j] = ",".join(cells)


def _valid_column(
    rng: random.Random, lines: list[str], head: int, cols: list[str], data: list[int]
) -> None:
    """A ``valid`` column of anything."""
    lines[head] += ",valid"
    for j in data:
        lines[j] += "," + rng.choice(("1", "1", "1", "0", "2", "", "0.5", "nan"))


def _cut(rng: random.Random, lines: list[str], head: int, cols: list[str], data: list[int]) -> None:
    """The file cut short."""
    del lines[rng.randrange(len(lines) + 1) :]


def _heading(
    rng: random.Random, lines: list[str], head: int, cols: list[str], data: list[int]
) -> None:
    """A heading (compass deg) beyond a turn, or nothing without rows or a heading column."""
    if data and "heading_truth" in cols:
        k = cols.index("heading_truth")
        i = rng.choice(data)
        cells = lines[i].split(",")
        if len(cells) == len(cols):
            cells[k] = rng.choice(("725", "-721", "1e6", "360.0001", "-360"))
            lines[i] = ",".join(cells)


_LineMutation = Callable[[random.Random, list[str], int, list[str], list[int]], None]
# By the draw 0..11: a cell four times in twelve, the heading the rest.
_LINE_MUTATIONS: tuple[_LineMutation, ...] = (
    _cell, _cell, _cell, _cell, _header, _time_step, _rows, _metadata, _rate, _valid_column,
    _cut, _heading,
)  # fmt: skip
# The draws that need data rows, and those that need a column; without them, the heading's.
_NEEDS_ROWS = frozenset({0, 1, 2, 3, 5, 6, 8})
_NEEDS_COLUMN = {5: "t", 8: "omega"}


def _mutate_lines(rng: random.Random, lines: list[str]) -> None:
    """One mutation of a drive log CSV's lines, in place (module doc)."""
    if not lines:  # cut to nothing by an earlier mutation
        lines.append(rng.choice(("", "t,omega", "#")))
        return
    head = next((i for i, x in enumerate(lines) if x and not x.startswith("#")), 0)
    cols = lines[head].split(",")
    data = list(range(head + 1, len(lines)))
    r = rng.randrange(12)
    column = _NEEDS_COLUMN.get(r)
    if (r in _NEEDS_ROWS and not data) or (column is not None and column not in cols):
        r = 11
    _LINE_MUTATIONS[r](rng, lines, head, cols, data)


def drivecsv_input(rng: random.Random) -> bytes:
    """A drive log CSV to read (module doc), in the envelope: layout ``C`` (the file given)
    or ``S`` (its folder given: the name comes from the file name), a file name."""
    name = rng.choice(("drive", "drive", "a\x1b[2Jb", "\u202eevil", "x" * 200, "sp ace", "d\u00e9"))
    layout = rng.choice("CCS")
    r = rng.random()
    if r < 0.04:
        body = rng.randbytes(rng.randint(0, 5000))
    elif r < 0.07:
        body = serial_input(rng, 300)[1:]
    elif r < 0.08:
        body = _parquet_bytes(rng, base_logs()[0], plain=True)
    else:
        log = rng.choice(base_logs())
        lines = _csv_text(log).split("\n")
        for _ in range(rng.choice((1, 1, 2, 3, 4))):
            _mutate_lines(rng, lines)
        text = rng.choice(("\n", "\n", "\r\n")).join(lines)
        if rng.random() < 0.05:
            text = "\ufeff" + text
        body = text.encode("utf-8", "surrogatepass")
        if rng.random() < 0.1:
            body = mutate_bytes(body, rng, (b",", b"\n", b"#", b"_", b"\xff", b"\x00"))
    return pack(layout, name, [body])


# -- Parquet -----------------------------------------------------------------------------------


def _retyped(kind: int, v: Any, n: int) -> Any:
    """A column's values as another Arrow type: int64 beyond 2^53, uint64's top, float32,
    strings, nulls, lists, timestamps, booleans, int32."""
    import pyarrow as pa

    if kind == 0:
        return pa.array((np.arange(n) + 2**53).astype(np.int64))
    if kind == 1:
        return pa.array(np.full(n, 2**64 - 1, dtype=np.uint64))
    if kind == 2:
        return pa.array(v.astype(np.float32))
    if kind == 3:
        return pa.array([str(x) for x in v.tolist()])
    if kind == 4:
        return pa.array([None] * n, type=pa.null())
    if kind == 5:
        return pa.array([[x] for x in v.tolist()])
    if kind == 6:
        return pa.array(np.arange(n, dtype="datetime64[s]"))
    if kind == 7:
        return pa.array(np.arange(n) % 2 == 0)
    return pa.array(np.nan_to_num(np.rint(v * 1000)).astype(np.int32))


class _Parquet:
    """A table being mutated: its columns (in order), its schema metadata and the writer's
    keyword arguments."""

    def __init__(self, log: Any) -> None:
        import pyarrow as pa

        self.log = log
        self.n = len(log)
        self.cols: dict[str, Any] = {c: pa.array(getattr(log, c)) for c in log.columns()}
        self.meta: dict[bytes, bytes] = {b"hdrd.meta": json.dumps(log.meta).encode()}
        self.kw: dict[str, Any] = {}

    def replace_columns(self, cols: dict[str, Any]) -> None:
        self.cols.clear()
        self.cols.update(cols)

    def to_bytes(self) -> bytes:
        """The file: columns cut to the shortest, a duplicate under its original name."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        cols, kw = self.cols, self.kw
        lengths = {len(v) for v in cols.values()}
        if len(lengths) > 1:  # the columns of one table: as long as the shortest
            m = min(lengths)
            cols = {k: v.slice(0, m) for k, v in cols.items()}
        names = list(cols)
        names = [x.split("\x00")[0] for x in names]  # a duplicate's name back to its original
        table = pa.Table.from_arrays(list(cols.values()), names=names)
        table = table.replace_schema_metadata(self.meta)
        if table.num_rows > 100_000:  # ten million rows in row groups of one: gigabytes of footer
            kw.pop("row_group_size", None)
        buf = io.BytesIO()
        pq.write_table(table, buf, **kw)
        return buf.getvalue()


# Each mutation returns whether it applied; one that did not gives way to a compression.


def _pq_type(rng: random.Random, p: _Parquet) -> bool:
    """A column's type."""
    c = rng.choice(list(p.cols))
    p.cols[c] = _retyped(rng.randrange(9), np.asarray(getattr(p.log, c)), p.n)
    return True


def _pq_columns(rng: random.Random, p: _Parquet) -> bool:
    """A column twice, one unknown, one missing."""
    op = rng.randrange(3)
    if op == 0:
        c = rng.choice(list(p.cols))
        p.cols[c + "\x00dup"] = p.cols[c]
    elif op == 1:
        p.cols[rng.choice(("x", "__index_level_0__", "Omega", "omega_truth", ""))] = p.cols["t"]
    else:
        p.cols.pop(rng.choice(list(p.cols)), None)
    return True


def _pq_drives(rng: random.Random, p: _Parquet) -> bool:
    """A drive column: many drives, names that could become paths."""
    import pyarrow as pa

    n = p.n
    names = [rng.choice(HOSTILE_NAMES) for _ in range(rng.randint(1, 4))]
    if rng.random() < 0.2:
        per_row: Any = [rng.choice((7, -1, 2**63 - 1, 0)) for _ in range(n)]
    else:
        per_row = [names[i * len(names) // n] for i in range(n)]
        if rng.random() < 0.1:
            per_row[rng.randrange(n)] = None
    p.cols["drive"] = pa.array(per_row)
    if rng.random() < 0.1:
        p.cols["drive"] = pa.array([[x] for x in per_row])
    p.kw["row_group_size"] = rng.choice((7, 50, 100_000))
    return True


_HOSTILE_META = (
    b"[" * 100_000 + b"]" * 100_000,
    b"not json",
    b"[1, 2]",
    b'{"a": 1}',
    b'{"a": {"b": "c"}}',
    b'{"lead_in_s": "1e308"}',
    None,  # a megabyte string (made on demand)
    b'{"ok": {"lead_in_s": 5}}',
    b"\xff\xfe",
)


def _pq_metadata(rng: random.Random, p: _Parquet) -> bool:
    """The drive's or the drives' metadata: deep, not JSON, not an object, huge."""
    key = rng.choice((b"hdrd.meta", b"hdrd.drive_meta"))
    value = rng.choice(_HOSTILE_META)
    p.meta[key] = json.dumps({"x": "y" * 1_000_000}).encode() if value is None else value
    return True


def _pq_rows(rng: random.Random, p: _Parquet) -> bool:
    """Rows: none, one, two, or time (s) jumping from a row on."""
    import pyarrow as pa

    if rng.random() < 0.3:
        p.replace_columns({k: v.slice(0, rng.choice((0, 1, 2))) for k, v in p.cols.items()})
    else:
        t = np.asarray(p.log.t, dtype=np.float64).copy()
        t[rng.randrange(p.n) :] += rng.choice((1e9, 3601.0, -1.0, 0.0))
        p.cols["t"] = pa.array(t)
    return True


def _pq_absurd_rate(rng: random.Random, p: _Parquet) -> bool:
    """One rate (deg/s) absurd, NaN or infinite."""
    import pyarrow as pa

    if "omega" not in p.cols:
        return False
    w = np.asarray(p.log.omega, dtype=np.float64).copy()
    w[rng.randrange(p.n)] = rng.choice((1e200, -1e200, 1001.0, math.nan, math.inf))
    p.cols["omega"] = pa.array(w)
    return True


def _pq_row_groups(rng: random.Random, p: _Parquet) -> bool:
    """Tiny row groups."""
    p.kw["row_group_size"] = rng.choice((1, 3, 64))
    return True


def _pq_ten_million(rng: random.Random, p: _Parquet) -> bool:
    """Once in twenty: ten million rows in a few KB."""
    import pyarrow as pa

    if rng.random() >= 0.05:
        return False
    big = 10_000_001
    p.replace_columns(
        {
            "t": pa.array(np.arange(big, dtype=np.int64)),
            "omega": pa.array(np.zeros(big, dtype=np.int32)),
        }
    )
    p.kw["column_encoding"] = {"t": "DELTA_BINARY_PACKED", "omega": "DELTA_BINARY_PACKED"}
    p.kw["use_dictionary"] = False
    return True


def _pq_heading(rng: random.Random, p: _Parquet) -> bool:
    """A heading (compass deg) beyond a turn."""
    import pyarrow as pa

    if "heading_truth" not in p.cols:
        return False
    h = np.asarray(p.log.heading_truth, dtype=np.float64).copy()
    h[rng.randrange(p.n)] = rng.choice((725.0, -721.0, 1e6))
    p.cols["heading_truth"] = pa.array(h)
    return True


def _pq_flipped_rate(rng: random.Random, p: _Parquet) -> bool:
    """The rate's sign flipped."""
    import pyarrow as pa

    if "omega" not in p.cols:
        return False
    p.cols["omega"] = pa.array(-np.asarray(p.log.omega))
    return True


def _pq_string_bomb(rng: random.Random, p: _Parquet) -> bool:
    """A string bomb: two names of megabytes, in a few KB of zstd."""
    import pyarrow as pa

    big = rng.choice((70_000, 1 << 20, 8 << 20))
    names = pa.array(["a" * big, "b" * big])
    half = (np.arange(p.n) >= p.n // 2).astype(np.int32)
    p.cols["drive"] = pa.DictionaryArray.from_arrays(pa.array(half), names)
    p.kw["use_dictionary"] = True  # each name stored once, however many rows
    p.kw["compression"] = "zstd"
    return True


def _pq_compression(rng: random.Random, p: _Parquet) -> bool:
    """A compression."""
    p.kw["compression"] = rng.choice(("zstd", "snappy", "none", "gzip"))
    return True


# By the draw 0..11.
_PARQUET_MUTATIONS: tuple[Callable[[random.Random, _Parquet], bool], ...] = (
    _pq_type, _pq_columns, _pq_drives, _pq_metadata, _pq_rows, _pq_absurd_rate, _pq_row_groups,
    _pq_ten_million, _pq_heading, _pq_flipped_rate, _pq_string_bomb, _pq_compression,
)  # fmt: skip


def _parquet_bytes(rng: random.Random, log: Any, plain: bool = False) -> bytes:
    """A Parquet file of one drive (or, with a ``drive`` column, of several), its columns,
    types, metadata and row groups mutated unless ``plain``."""
    p = _Parquet(log)
    for _ in range(0 if plain else rng.choice((1, 1, 2, 3))):
        if not _PARQUET_MUTATIONS[rng.randrange(12)](rng, p):
            _pq_compression(rng, p)
    return p.to_bytes()


def driveparquet_input(rng: random.Random) -> bytes:
    """A Parquet drive to read (module doc), in the envelope: layout ``F`` (a file), ``D``
    (a dataset partition ``drive=NAME``, one or two files), ``S`` (the file's folder given),
    NAME from :data:`HOSTILE_NAMES` or the input."""
    log = rng.choice(base_logs())
    layout = rng.choice("FFDS")
    name = rng.choice(HOSTILE_NAMES) if rng.random() < 0.8 else giant_string(rng)[:300]
    try:
        files = [_parquet_bytes(rng, log)]
        if layout == "D" and rng.random() < 0.3:
            files.append(_parquet_bytes(rng, rng.choice(base_logs()), plain=rng.random() < 0.5))
    except Exception:  # noqa: BLE001 - pyarrow refused to write this table: a plain one instead
        files = [_parquet_bytes(rng, log, plain=True)]
    if rng.random() < 0.1:
        files[0] = mutate_bytes(files[0], rng, (b"PAR1", b"\x00" * 8, b"\xff" * 4))
    return pack(layout, name, files)
