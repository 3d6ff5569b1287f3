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

An input (made in tools/fuzz/driveinputs.py) is an envelope
(:func:`tools.fuzz.driveinputs.pack`): the layout, a name, the files' bytes. The target
(:class:`DriveLogTarget`) lays it out in a fresh folder and runs the commands through their
own entry point (``hdrd.cli.main``, stdout and stderr captured): ``hdrd evaluate`` every
input, ``hdrd tune`` every 8th, ``hdrd gap --out DIR --report`` every 16th; every input, the
fitted-model paths ``hdrd gap --out`` would take.

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
import shutil
from pathlib import Path
from typing import Any

from .contract import Broken, Target, one_line
from .driveinputs import base_logs, unpack

__all__ = ["DriveLogTarget"]


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

    def _model_paths(self, given: str, out_dir: Path) -> None:
        """The paths ``hdrd gap --out`` would write the drives' models to: inside it, each
        refusal one line."""
        from hdrd.analysis.gap.fleet import model_paths
        from hdrd.io.files.drivecolumns import DriveLogError
        from hdrd.io.files.drivefiles import find_drives

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

    def _evaluate(self, given: str, out_dir: Path, extra: list[str]) -> int:
        """``hdrd evaluate`` (a method by turn): its exit status; its ``--json`` finite."""
        method = ("none", "hdr", "hdr+")[self.count % 3]
        rc, out, err = self._run(["evaluate", given, "--method", method, "--no-progress",
                                  "--json", str(out_dir / "e.json"), *extra])  # fmt: skip
        self._check("evaluate", rc, out, err)
        if rc == 0:
            doc = json.loads((out_dir / "e.json").read_text(), parse_constant=_no_constant)
            for row in doc["drives"] + [doc["mean"]]:
                for k, v in row.items():
                    if isinstance(v, float) and not math.isfinite(v):
                        raise Broken(f"--json {k} = {v!r}")
        return rc

    def run(self, data: bytes) -> str:
        self.count += 1
        target = self._layout(data)
        out_dir = self.root / "out"
        given = str(target)
        self._model_paths(given, out_dir)
        before = _files_under(self.root)
        extra = ["--strict"] if self.count % 5 == 0 else []
        rc = self._evaluate(given, out_dir, extra)
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
