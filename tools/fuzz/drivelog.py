"""Drive-log surfaces of tools/fuzz: the files ``hdrd evaluate``, ``hdrd tune`` and
``hdrd gap`` are handed, and the names in them that become paths.

Two surfaces:

- ``drivecsv``: a drive log CSV (a short simulated drive written by :func:`hdrd.io.files.drivelog.
  write_drive`) with its cells, header, metadata, times and rows mutated (hostile numbers,
  ``1_000``, digits of other scripts, giant cells, time jumps, a flipped or scaled rate, a
  ``valid`` column of anything), its bytes damaged, or another file entirely (random bytes, a
  capture, a Parquet file); written under a file name that may hold control characters;
- ``driveparquet``: a Parquet drive (pyarrow) whose columns change type (int64 beyond 2^53,
  strings, lists, timestamps), repeat or go missing, whose ``drive`` column names drives
  ``../../x``, ``/abs/x``, NUL, 300 characters (or holds names of megabytes: a string bomb,
  16 MB in a few KB of zstd, refused from the metadata), whose ``hdrd.meta`` nests 100,000
  deep, whose row groups are tiny, or which holds 10 million delta-encoded rows in a few KB;
  laid out as a file, a file of many drives or a dataset partition ``drive=NAME`` (NAME from
  the input), its bytes sometimes damaged.

An input is an envelope (:func:`pack`): the layout, a name, the files' bytes. The target
(:class:`DriveLogTarget`) lays it out in a fresh folder and runs the commands through their
own entry point (``hdrd.cli.main``, stdout and stderr
captured): ``hdrd evaluate`` every input, ``hdrd tune`` every 8th, ``hdrd gap --out DIR
--report`` every 16th; every input, the fitted-model paths ``hdrd gap --out`` would take.

Promises checked (else :class:`tools.fuzz.targets.Broken`): exit status 0 or 1; every line on
stderr is one printable line of the command (``hdrd evaluate: ...``), never an internal error
or "too large to analyse" (memory is bounded by the limits, not by luck); a table without a
NaN; a ``--json`` whose numbers are finite or null; nothing written outside the command's
output folder; every model path inside it.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import random
import shutil
import struct
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from .contract import Broken, Target, one_line
from .inputs import serial_input
from .mutate import giant_string, mutate_bytes

__all__ = ["DriveLogTarget", "drivecsv_input", "driveparquet_input", "pack", "unpack"]


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


def _mutate_lines(rng: random.Random, lines: list[str]) -> None:
    if not lines:  # cut to nothing by an earlier mutation
        lines.append(rng.choice(("", "t,omega", "#")))
        return
    head = next((i for i, x in enumerate(lines) if x and not x.startswith("#")), 0)
    cols = lines[head].split(",")
    data = list(range(head + 1, len(lines)))
    r = rng.randrange(12)
    if r <= 3 and data:  # a cell
        i = rng.choice(data)
        cells = lines[i].split(",")
        cells[rng.randrange(len(cells))] = (
            giant_string(rng) if rng.random() < 0.05 else rng.choice(HOSTILE_CELLS)
        )
        lines[i] = ",".join(cells)
    elif r == 4:  # the header
        j = rng.randrange(len(cols))
        cols[j] = rng.choice(
            ("tt", "omega", "t", "", "valid", "\ufefft", "heading_truth", "drive", "T", "x" * 70)
        )
        if rng.random() < 0.3:
            cols.append(rng.choice(("valid", "speed", "omega")))
        lines[head] = ",".join(cols)
    elif r == 5 and data and "t" in cols:  # time: a jump, back, the same, tiny steps
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
    elif r == 6 and data:  # rows: removed, repeated, swapped, blank, a comment among them
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
    elif r == 7:  # metadata
        key = rng.choice(("lead_in_s", "source", "x", "drive", ""))
        value = rng.choice(
            ("1e308", "-5", "nan", "1e9", "30", "0.1", giant_string(rng)[:5000], "\x1b")
        )
        lines.insert(0, f"# {key}: {value}")
    elif r == 8 and data and "omega" in cols:  # the whole rate: flipped, scaled, absurd
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
    elif r == 9:  # a valid column of anything
        lines[head] += ",valid"
        for j in data:
            lines[j] += "," + rng.choice(("1", "1", "1", "0", "2", "", "0.5", "nan"))
    elif r == 10:  # cut short
        del lines[rng.randrange(len(lines) + 1) :]
    else:  # a heading beyond a turn, or a day-long pause
        if data and "heading_truth" in cols:
            k = cols.index("heading_truth")
            i = rng.choice(data)
            cells = lines[i].split(",")
            if len(cells) == len(cols):
                cells[k] = rng.choice(("725", "-721", "1e6", "360.0001", "-360"))
                lines[i] = ",".join(cells)


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


def _parquet_bytes(rng: random.Random, log: Any, plain: bool = False) -> bytes:
    """A Parquet file of one drive (or, with a ``drive`` column, of several), its columns,
    types, metadata and row groups mutated unless ``plain``."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols: dict[str, Any] = {c: pa.array(getattr(log, c)) for c in log.columns()}
    meta: dict[bytes, bytes] = {b"hdrd.meta": json.dumps(log.meta).encode()}
    kw: dict[str, Any] = {}
    for _ in range(0 if plain else rng.choice((1, 1, 2, 3))):
        r = rng.randrange(12)
        n = len(log)
        if r == 0:  # a column's type
            c = rng.choice(list(cols))
            cols[c] = _retyped(rng.randrange(9), np.asarray(getattr(log, c)), n)
        elif r == 1:  # a column twice, one unknown, one missing
            op = rng.randrange(3)
            if op == 0:
                c = rng.choice(list(cols))
                cols[c + "\x00dup"] = cols[c]
            elif op == 1:
                cols[rng.choice(("x", "__index_level_0__", "Omega", "omega_truth", ""))] = cols["t"]
            else:
                cols.pop(rng.choice(list(cols)), None)
        elif r == 2:  # a drive column: many drives, names that could become paths
            names = [rng.choice(HOSTILE_NAMES) for _ in range(rng.randint(1, 4))]
            if rng.random() < 0.2:
                per_row: Any = [rng.choice((7, -1, 2**63 - 1, 0)) for _ in range(n)]
            else:
                per_row = [names[i * len(names) // n] for i in range(n)]
                if rng.random() < 0.1:
                    per_row[rng.randrange(n)] = None
            cols["drive"] = pa.array(per_row)
            if rng.random() < 0.1:
                cols["drive"] = pa.array([[x] for x in per_row])
            kw["row_group_size"] = rng.choice((7, 50, 100_000))
        elif r == 3:  # metadata
            key = rng.choice((b"hdrd.meta", b"hdrd.drive_meta"))
            meta[key] = rng.choice(
                (
                    b"[" * 100_000 + b"]" * 100_000,
                    b"not json",
                    b"[1, 2]",
                    b'{"a": 1}',
                    b'{"a": {"b": "c"}}',
                    b'{"lead_in_s": "1e308"}',
                    json.dumps({"x": "y" * 1_000_000}).encode(),
                    b'{"ok": {"lead_in_s": 5}}',
                    b"\xff\xfe",
                )
            )
        elif r == 4:  # rows: none, one, time jumps, absurd rates
            if rng.random() < 0.3:
                cols = {k: v.slice(0, rng.choice((0, 1, 2))) for k, v in cols.items()}
            else:
                t = np.asarray(log.t, dtype=np.float64).copy()
                t[rng.randrange(n) :] += rng.choice((1e9, 3601.0, -1.0, 0.0))
                cols["t"] = pa.array(t)
        elif r == 5 and "omega" in cols:
            w = np.asarray(log.omega, dtype=np.float64).copy()
            w[rng.randrange(n)] = rng.choice((1e200, -1e200, 1001.0, math.nan, math.inf))
            cols["omega"] = pa.array(w)
        elif r == 6:  # row groups
            kw["row_group_size"] = rng.choice((1, 3, 64))
        elif r == 7 and rng.random() < 0.05:  # ten million rows in a few KB
            big = 10_000_001
            cols = {
                "t": pa.array(np.arange(big, dtype=np.int64)),
                "omega": pa.array(np.zeros(big, dtype=np.int32)),
            }
            kw["column_encoding"] = {"t": "DELTA_BINARY_PACKED", "omega": "DELTA_BINARY_PACKED"}
            kw["use_dictionary"] = False
        elif r == 8 and "heading_truth" in cols:
            h = np.asarray(log.heading_truth, dtype=np.float64).copy()
            h[rng.randrange(n)] = rng.choice((725.0, -721.0, 1e6))
            cols["heading_truth"] = pa.array(h)
        elif r == 9 and "omega" in cols:
            cols["omega"] = pa.array(-np.asarray(log.omega))
        elif r == 10:  # a string bomb: two names of megabytes, in a few KB of zstd
            big = rng.choice((70_000, 1 << 20, 8 << 20))
            names = pa.array(["a" * big, "b" * big])
            half = (np.arange(n) >= n // 2).astype(np.int32)
            cols["drive"] = pa.DictionaryArray.from_arrays(pa.array(half), names)
            kw["use_dictionary"] = True  # each name stored once, however many rows
            kw["compression"] = "zstd"
        else:
            kw["compression"] = rng.choice(("zstd", "snappy", "none", "gzip"))
    lengths = {len(v) for v in cols.values()}
    if len(lengths) > 1:  # the columns of one table: as long as the shortest
        m = min(lengths)
        cols = {k: v.slice(0, m) for k, v in cols.items()}
    names = list(cols)
    names = [x.split("\x00")[0] for x in names]  # a duplicate's name back to its original
    table = pa.Table.from_arrays(list(cols.values()), names=names).replace_schema_metadata(meta)
    if table.num_rows > 100_000:  # ten million rows in row groups of one: gigabytes of footer
        kw.pop("row_group_size", None)
    buf = io.BytesIO()
    pq.write_table(table, buf, **kw)
    return buf.getvalue()


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


# -- the target --------------------------------------------------------------------------------


def _fs_name(raw: bytes, limit: int = 200) -> str:
    """A name from the input that the file system takes: no ``/``, no NUL, at most ``limit``
    bytes, ``%``-escaped where it would not be (the rest of it kept as is)."""
    text = raw.decode("utf-8", "surrogateescape").replace("%", "%25")
    text = text.replace("/", "%2F").replace("\x00", "%00")
    if text in ("", ".", ".."):
        text = "%2E" + text
    b = os.fsencode(text)[:limit]
    return os.fsdecode(b)


def _files_under(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


class DriveLogTarget(Target):
    """The commands on one laid-out input (module doc)."""

    def __init__(self, surface: str, seed: int, workdir: Path) -> None:
        self.surface = surface
        self.root = workdir / "case"
        self.count = 0
        self.every_command = False
        """Run tune and gap on every input too (a saved input that once found a defect)."""
        base_logs()  # made once, before the first input

    def _layout(self, data: bytes) -> Path:
        shutil.rmtree(self.root, ignore_errors=True)
        (self.root / "in").mkdir(parents=True)
        layout, raw_name, files = unpack(data)
        name = _fs_name(raw_name)
        suffix = ".csv" if self.surface == "drivecsv" else ".parquet"
        if layout == "D":
            part = self.root / "in" / ("drive=" + name)[:220]
            part.mkdir()
            for i, f in enumerate(files):
                (part / f"part-{i}.parquet").write_bytes(f)
            return part
        path = self.root / "in" / (name[:200] + suffix)
        path.write_bytes(files[0] if files else b"")
        return path.parent if layout == "S" else path

    def _run(self, argv: list[str]) -> tuple[int, str, str]:
        """``hdrd ARGV`` through the entry point's :func:`hdrd.cli.main`, in process."""
        from hdrd.cli import main

        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                rc = main(argv)
            except SystemExit as e:  # a usage error: not what the inputs test
                raise Broken(
                    f"usage error {e.code} for {argv[:3]}: {err.getvalue()[:200]}"
                ) from None
        return rc, out.getvalue(), err.getvalue()

    def _check(self, cmd: str, rc: int, out: str, err: str) -> None:
        if rc not in (0, 1):
            raise Broken(f"hdrd {cmd} exit {rc}: {err[-300:]!r}")
        for line in err.splitlines():
            one_line(line, f"hdrd {cmd}'s stderr")
            if not line.startswith(f"hdrd {cmd}: "):
                raise Broken(f"hdrd {cmd}: a stderr line not its own: {line[:200]!r}")
            for bad in ("internal error", "too large to analyse", "Traceback"):
                if bad in line:
                    raise Broken(f"hdrd {cmd}: {line[:300]!r}")
        if rc == 1 and not err.strip():
            raise Broken(f"hdrd {cmd} exit 1 without a word")
        for line in out.splitlines():
            if not line.isprintable():
                raise Broken(f"hdrd {cmd} printed a control character: {line[:200]!r}")
        if cmd == "evaluate" and rc == 0 and " nan " in f" {out} ".lower():
            raise Broken(f"hdrd evaluate printed NaN: {out[:400]!r}")

    def run(self, data: bytes) -> str:
        from hdrd.analysis.gap.fleet import model_paths
        from hdrd.io.files.drivecolumns import DriveLogError
        from hdrd.io.files.drivefiles import find_drives

        self.count += 1
        target = self._layout(data)
        out_dir = self.root / "out"
        given = str(target)
        try:
            refs = find_drives([given])
        except DriveLogError as e:
            one_line(str(e), "find_drives")
            refs = []
        _, paths, why = model_paths(refs, str(out_dir))
        for p in paths.values():
            if out_dir.resolve() not in p.resolve().parents:
                raise Broken(f"a model path outside --out: {p}")
        for w in why:
            one_line(w, "model path refusal")
        before = _files_under(self.root)
        method = ("none", "hdr", "hdr+")[self.count % 3]
        extra = ["--strict"] if self.count % 5 == 0 else []
        rc, out, err = self._run(["evaluate", given, "--method", method, "--no-progress",
                                  "--json", str(out_dir / "e.json"), *extra])  # fmt: skip
        self._check("evaluate", rc, out, err)
        if rc == 0:
            doc = json.loads((out_dir / "e.json").read_text(), parse_constant=_no_constant)
            for row in doc["drives"] + [doc["mean"]]:
                for k, v in row.items():
                    if isinstance(v, float) and not math.isfinite(v):
                        raise Broken(f"--json {k} = {v!r}")
        outcome = "scored" if rc == 0 else "refused"
        if self.count % 8 == 0 or self.every_command:
            rc, out, err = self._run(["tune", given, "--candidates", "6", "--no-progress", *extra])
            self._check("tune", rc, out, err)
        if self.count % 16 == 3 or self.every_command:
            rc, out, err = self._run(["gap", given, "--out", str(out_dir / "m"), "--report",
                                      str(out_dir / "r.json"), "--no-progress"])  # fmt: skip
            self._check("gap", rc, out, err)
        after = _files_under(self.root)
        outside = {f for f in after - before if not f.startswith("out")}
        if outside:
            raise Broken(f"written outside the output folder: {sorted(outside)[:5]}")
        return outcome


def _no_constant(name: str) -> Any:
    raise Broken(f"--json holds {name}")
