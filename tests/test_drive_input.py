"""Drive logs that are wrong in every way a file can be wrong, through ``hdrd evaluate``,
``hdrd tune`` and ``hdrd gap`` as a user runs them: one line naming the drive, never a
traceback; among many drives the bad one is skipped and the others are scored (``--strict``:
the first bad one stops the command). The format's own rules: tests/test_drivelog.py,
tests/test_parquetlog.py."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hdrd.io.files.drivelog import DriveLog, read_drive, write_drive
from hdrd.sim.drive import simulate_drive
from tests.hdrd_process import ENV, hdrd

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")


@pytest.fixture(scope="module")
def good() -> DriveLog:
    return simulate_drive("city", 3.0, 3)


def _parquet(path: Path, cols: dict[str, object], meta: dict[bytes, bytes] | None = None) -> None:
    names = list(cols)
    table = pa.Table.from_arrays([pa.array(v) for v in cols.values()], names=names)
    pq.write_table(table.replace_schema_metadata(meta), path)


def _bad_drives(d: Path, log: DriveLog) -> dict[str, str]:
    """Each bad drive's file, and a piece of the one line that must name its trouble."""
    write_drive(d / "long_cell.csv", log)
    lines = (d / "long_cell.csv").read_text().splitlines()
    row = next(i for i, x in enumerate(lines) if x.startswith("t,")) + 5
    lines[row] += "9" * 131_073
    (d / "long_cell.csv").write_text("\n".join(lines) + "\n")
    h = log.heading_truth
    _parquet(d / "two_omega.parquet", {"t": log.t, "omega": log.omega, "omega ": log.omega})
    table = pq.read_table(d / "two_omega.parquet")
    pq.write_table(table.rename_columns(["t", "omega", "omega"]), d / "two_omega.parquet")
    t_int = (np.arange(len(log)) + 2**53).astype(np.int64)
    _parquet(d / "huge_t.parquet", {"t": t_int, "omega": log.omega, "heading_truth": h})
    deep = {b"hdrd.meta": b"[" * 100_000 + b"]" * 100_000}
    _parquet(d / "deep_meta.parquet", {"t": log.t, "omega": log.omega, "heading_truth": h}, deep)
    t_gap = log.t.copy()
    t_gap[len(log) // 2 :] += 1e9
    write_drive(d / "time_gap.csv", replace(log, t=t_gap))
    return {
        "time_gap": "column t jumps by 1e+09 s",
        "long_cell": "long_cell.csv:",
        "two_omega": "two_omega.parquet: column 'omega' appears more than once",
        "huge_t": "huge_t.parquet: row 2: column t: the integer 9007199254740993",
        "deep_meta": "deep_meta.parquet: schema metadata hdrd.meta nests too deep",
    }


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory, good: DriveLog) -> tuple[Path, dict[str, str]]:
    d = tmp_path_factory.mktemp("bad")
    write_drive(d / "a_good.csv", good)
    return d, _bad_drives(d, good)


def _skips(stderr: str, command: str) -> list[str]:
    return [x for x in stderr.splitlines() if x.startswith(f"hdrd {command}: skipped ")]


def _check_skipped(p: subprocess.CompletedProcess[str], command: str, bad: dict[str, str]) -> None:
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr and "Error:" not in p.stderr, p.stderr
    skips = _skips(p.stderr, command)
    assert len(skips) == len(bad), p.stderr
    for name, why in bad.items():
        assert sum(why in s for s in skips) == 1, (name, p.stderr)


RUNS = {
    "evaluate": ("evaluate", "--no-progress"),
    "tune": ("tune", "--candidates", "20", "--no-progress"),
    "gap": ("gap", "--no-progress"),
}


@pytest.mark.parametrize(
    "command",  # gap: a whole model-gap search
    [pytest.param(c, marks=pytest.mark.slow) if c == "gap" else c for c in RUNS],
)
def test_a_bad_drive_is_skipped_and_the_good_one_scored(
    command: str, fleet: tuple[Path, dict[str, str]]
) -> None:
    d, bad = fleet
    cmd, *opts = RUNS[command]
    files = sorted(os.listdir(d))
    p = hdrd(cmd, *files, *opts, cwd=d)
    _check_skipped(p, cmd, bad)
    if cmd == "evaluate":
        assert p.stdout.splitlines()[2].startswith("a_good ")
        assert "mean (1)" in p.stdout
    elif cmd == "tune":
        assert "1 training drive(s)" in p.stdout
    else:
        assert p.stdout.splitlines()[1].startswith("a_good ")
        assert "fleet: 1 drives analysed, 5 skipped" in p.stdout


@pytest.mark.parametrize(
    "command",  # gap: a whole model-gap search
    [pytest.param(c, marks=pytest.mark.slow) if c == "gap" else c for c in RUNS],
)
def test_strict_stops_at_the_first_bad_drive_with_one_line(
    command: str, fleet: tuple[Path, dict[str, str]]
) -> None:
    d, bad = fleet
    cmd, *opts = RUNS[command]
    p = hdrd(cmd, "a_good.csv", "deep_meta.parquet", "huge_t.parquet", *opts, "--strict", cwd=d)
    assert p.returncode == 1, p.stderr
    lines = [x for x in p.stderr.splitlines() if x.startswith("hdrd")]
    assert len(lines) == 1 and bad["deep_meta"] in lines[0], p.stderr
    assert "Traceback" not in p.stderr


@pytest.mark.parametrize("name", ["long_cell", "two_omega", "huge_t", "deep_meta", "time_gap"])
def test_one_bad_drive_alone_is_one_line(name: str, fleet: tuple[Path, dict[str, str]]) -> None:
    d, bad = fleet
    f = next(x for x in os.listdir(d) if x.startswith(name + "."))
    p = hdrd("evaluate", f, cwd=d)
    assert p.returncode == 1
    assert p.stderr.count("\n") == 1 and bad[name] in p.stderr, p.stderr


@pytest.mark.slow  # a Dask cluster of two worker processes per command
@pytest.mark.parametrize("command", list(RUNS))
def test_a_bad_drive_is_skipped_on_a_cluster_too(
    command: str, fleet: tuple[Path, dict[str, str]]
) -> None:
    d, bad = fleet
    cmd, *opts = RUNS[command]
    p = hdrd(cmd, *sorted(os.listdir(d)), *opts, "--workers", "2", cwd=d)
    _check_skipped(p, cmd, bad)


def test_a_drive_without_truth_is_still_just_skipped(good: DriveLog, tmp_path: Path) -> None:
    write_drive(tmp_path / "a.csv", good)
    write_drive(tmp_path / "b.csv", replace(good, heading_truth=None))
    p = hdrd("evaluate", "a.csv", "b.csv", cwd=tmp_path)
    assert p.returncode == 0
    assert _skips(p.stderr, "evaluate") == [
        "hdrd evaluate: skipped b: no truth heading (column heading_truth is absent or empty)"
    ]


# -- memory follows the rows, not the time they span ---------------------------------------------


@pytest.mark.parametrize("speed", [True, False])
def test_a_jump_in_time_costs_no_memory(good: DriveLog, speed: bool) -> None:
    """2,100 rows with one jump of 10^9 s (allowed here): the steps are the rows', not one per
    second of the span (once 7.45 GiB per array)."""
    import tracemalloc

    from hdrd.analysis.prepare import prepare_drive

    log = good.slice(0, 2100)
    t = log.t.copy()
    t[1500:] += 1e9
    log = replace(log, t=t, speed=log.speed if speed else None, meta={})
    tracemalloc.start()
    try:
        prep = prepare_drive(log, calibrate_seconds=20.0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20 << 20, f"{peak / 2**20:.0f} MiB"
    assert prep.steps.u.shape[0] < 300
    assert prep.missing_steps > 10**8  # the gap is there: a billion missing steps, counted


def test_a_time_gap_over_the_limit_is_refused_naming_the_row(
    good: DriveLog, tmp_path: Path
) -> None:
    t = good.t.copy()
    t[1000:] += 7200.0
    write_drive(tmp_path / "g.csv", replace(good, t=t))
    p = hdrd("evaluate", "g.csv", cwd=tmp_path)
    assert p.returncode == 1
    lines = (tmp_path / "g.csv").read_text().splitlines()
    line = next(i for i, x in enumerate(lines) if x.startswith("t,")) + 1 + 1000 + 1
    assert p.stderr.startswith(f"hdrd evaluate: error: g.csv:{line}: column t jumps by 7200.1 s")
    assert p.stderr.count("\n") == 1 and "--max-gap" in p.stderr
    allowed = hdrd("evaluate", "g.csv", "--max-gap", "7201", cwd=tmp_path)
    assert allowed.returncode == 0, allowed.stderr
    bad = hdrd("evaluate", "g.csv", "--max-gap", "-1", cwd=tmp_path)
    assert bad.returncode == 2 and "--max-gap" in bad.stderr


# -- a rate no gyro gives, a score that is no number ------------------------------------------------


@pytest.mark.slow
def test_an_absurd_rate_is_refused_naming_the_row(good: DriveLog, tmp_path: Path) -> None:
    """One omega of 1e200 once turned Epsi raw from 3.35 into 0.25 deg, exit 0."""
    w = good.omega.copy()
    w[1000] = 1e200
    write_drive(tmp_path / "h.csv", replace(good, omega=w))
    lines = (tmp_path / "h.csv").read_text().splitlines()
    line = next(i for i, x in enumerate(lines) if x.startswith("t,")) + 1 + 1000 + 1
    for cmd in ("evaluate", "tune", "gap"):
        p = hdrd(cmd, "h.csv", "--no-progress", cwd=tmp_path)
        assert p.returncode == 1, p.stderr
        assert p.stderr == (
            f"hdrd {cmd}: {'error: ' if cmd != 'gap' else ''}h.csv:{line}: column omega: 1e+200 "
            "deg/s is beyond the +/-1000 deg/s a gyro measures (--max-rate)\n"
        )
    v = np.ones(len(good))
    v[1000] = 0.0  # a row left out may hold what it likes
    write_drive(tmp_path / "v.csv", replace(good, omega=w, valid=v))
    assert hdrd("evaluate", "v.csv", cwd=tmp_path).returncode == 0
    w[1000] = 1500.0
    write_drive(tmp_path / "fast.csv", replace(good, omega=w))
    assert hdrd("evaluate", "fast.csv", cwd=tmp_path).returncode == 1
    assert hdrd("evaluate", "fast.csv", "--max-rate", "2000", cwd=tmp_path).returncode == 0
    assert hdrd("evaluate", "fast.csv", "--max-rate", "1e300", cwd=tmp_path).returncode == 2


def test_a_score_that_is_not_a_number_is_an_error(good: DriveLog) -> None:
    from hdrd.analysis.evaluate import EvaluationError, evaluate_drive

    w = good.omega.copy()
    w[1000:1003] = 1.7e308  # in memory, past the reader's limits: the block's sum overflows
    with np.errstate(all="ignore"), pytest.raises(EvaluationError, match="not a number to report"):
        evaluate_drive(replace(good, omega=w))


# -- valid = 0: the row is left out, as if dropped ---------------------------------------------------


@pytest.mark.slow
def test_evaluate_and_tune_leave_out_rows_marked_not_valid(good: DriveLog, tmp_path: Path) -> None:
    """The device handled for 20 s (its rate all over the place), marked valid = 0: scored as
    the drive with those rows dropped from the file, not with them (gap always honoured it)."""
    w = good.omega.copy()
    rng = np.random.default_rng(1)
    handled = slice(900, 1100)
    w[handled] += rng.normal(0.0, 200.0, 200)
    v = np.ones(len(good))
    v[handled] = 0.0
    write_drive(tmp_path / "marked.csv", replace(good, omega=w, valid=v, name="x"))
    dropped = replace(good, omega=w, name="x").slice(0, 900)
    rest = replace(good, omega=w).slice(1100)
    cols = {c: np.concatenate([getattr(dropped, c), getattr(rest, c)]) for c in good.columns()}
    write_drive(tmp_path / "dropped.csv", replace(dropped, **cols))  # type: ignore[arg-type]
    write_drive(tmp_path / "kept.csv", replace(good, omega=w))

    def table(f: str) -> list[str]:
        p = hdrd("evaluate", f, "--method", "hdr+", cwd=tmp_path)
        assert p.returncode == 0, p.stderr
        return [x.split(None, 1)[1] for x in p.stdout.splitlines()[2:3]]

    assert table("marked.csv") == table("dropped.csv")
    assert table("marked.csv") != table("kept.csv")

    def tuned(f: str) -> str:
        p = hdrd("tune", f, "--candidates", "30", "--no-progress", cwd=tmp_path)
        assert p.returncode == 0, p.stderr
        return p.stdout.split("\n", 1)[1].rsplit("\n", 3)[0]

    assert tuned("marked.csv") == tuned("dropped.csv")


def test_a_drive_with_every_row_left_out_is_one_line(good: DriveLog, tmp_path: Path) -> None:
    write_drive(tmp_path / "none.csv", replace(good, valid=np.zeros(len(good))))
    p = hdrd("evaluate", "none.csv", cwd=tmp_path)
    assert p.returncode == 1
    assert p.stderr == "hdrd evaluate: error: none: every row has valid = 0; nothing to evaluate\n"


# -- rows counted before they are read ---------------------------------------------------------------

_MAKE_40M = """
import sys
import numpy as np, pyarrow as pa, pyarrow.parquet as pq
n = 40_000_000
table = pa.table({"t": np.arange(n, dtype=np.int64), "omega": np.zeros(n, dtype=np.int32)})
pq.write_table(table, sys.argv[1], use_dictionary=False, compression="zstd",
               column_encoding={"t": "DELTA_BINARY_PACKED", "omega": "DELTA_BINARY_PACKED"})
"""

_PEAK = """
import resource, subprocess, sys
p = subprocess.run(sys.argv[1:], capture_output=True, text=True)
sys.stdout.write(p.stderr)
print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss // 1024, "MiB")
"""


@pytest.mark.slow
def test_a_tiny_file_of_40_million_rows_is_refused_before_it_is_read(tmp_path: Path) -> None:
    """360 KB of delta-encoded rows once took evaluate to 2.4 GB before any check."""
    f = tmp_path / "tiny.parquet"
    subprocess.run([sys.executable, "-c", _MAKE_40M, str(f)], check=True, timeout=300)
    assert f.stat().st_size < 1 << 20
    p = subprocess.run(
        [sys.executable, "-c", _PEAK, sys.executable, "-m", "hdrd", "evaluate", str(f)],
        capture_output=True, text=True, env=ENV, cwd=tmp_path, timeout=300,
    )  # fmt: skip
    err, peak = p.stdout.rsplit("\n", 2)[:2]
    assert err == (
        f"hdrd evaluate: error: {f}: 40000000 rows, more than the 10000000 a drive may have "
        "(--max-rows)"
    )
    assert int(peak.split()[0]) < 400, peak


def test_the_row_limit_holds_for_every_layout(good: DriveLog, tmp_path: Path) -> None:
    from hdrd.io.files.drivecolumns import ReadLimits
    from hdrd.io.files.drivefiles import find_drives
    from hdrd.io.files.parquetlog import write_dataset_drive, write_parquet_drive

    write_drive(tmp_path / "a.csv", good)
    write_parquet_drive(tmp_path / "b.parquet", good)
    n = len(good)
    _parquet(tmp_path / "many.parquet", {"drive": ["x"] * n + ["y"] * 10, "t": [*good.t, *good.t[:10]],
             "omega": [*good.omega, *good.omega[:10]]})  # fmt: skip
    write_dataset_drive(tmp_path / "ds", good.slice(0, 1000), "p")
    part = next((tmp_path / "ds").glob("drive=p"))
    write_parquet_drive(part / "part-1.parquet", good.slice(1000))
    limits = ReadLimits(max_rows=n - 1)
    for ref in find_drives([str(tmp_path)]):
        if ref.name == "many/y":
            assert len(ref.read(limits)) == 10
            continue
        with pytest.raises(Exception, match=r"more than the \d+ (rows a drive may have|a drive)"):
            ref.read(limits)
        assert len(ref.read(ReadLimits(max_rows=n))) == n
    p = hdrd("evaluate", "a.csv", "--max-rows", str(n - 1), cwd=tmp_path)
    assert p.returncode == 1 and f"more than the {n - 1} rows" in p.stderr
    assert p.stderr.count("\n") == 1


# -- files that are no drive log ---------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("protocol", ["hdr-bin", "hdr-text"])
def test_a_capture_is_recognised_and_convert_named(protocol: str, tmp_path: Path) -> None:
    """``hdrd evaluate drive.cap`` once showed a UnicodeDecodeError."""
    f = hdrd("fakegyro", "--drive", "city", "--minutes", "0.1", "--protocol", protocol,
             "--out", "drive.cap", cwd=tmp_path)  # fmt: skip
    assert f.returncode == 0, f.stderr
    for cmd in ("evaluate", "tune", "gap"):
        p = hdrd(cmd, "drive.cap", "--no-progress", cwd=tmp_path)
        assert p.returncode == 1
        prefix = "" if cmd == "gap" else "error: "
        assert p.stderr == (
            f"hdrd {cmd}: {prefix}drive.cap: a capture of the gyro's frames ({protocol}), not a "
            "drive log; make one with `hdrd convert drive.cap --out drive.csv`\n"
        )
    c = hdrd("convert", "drive.cap", "--protocol", protocol, "--out", "drive.csv", cwd=tmp_path)
    assert c.returncode == 0, c.stderr


@pytest.mark.slow
def test_the_hint_never_converts_a_capture_onto_itself(tmp_path: Path) -> None:
    # A capture renamed x.csv: the hint once said `hdrd convert x.csv --out x.csv`, which
    # overwrote the capture. It names another file now, and convert refuses its own input,
    # under its name, a symbolic link or a hard link.
    f = hdrd("fakegyro", "--drive", "city", "--minutes", "0.1", "--out", "renamed.csv",
             cwd=tmp_path)  # fmt: skip
    assert f.returncode == 0, f.stderr
    capture = (tmp_path / "renamed.csv").read_bytes()
    p = hdrd("evaluate", "renamed.csv", cwd=tmp_path)
    hint = "`hdrd convert renamed.csv --out renamed-drive.csv`"
    assert p.returncode == 1 and p.stderr.rstrip().endswith(hint), p.stderr
    (tmp_path / "link.csv").symlink_to("renamed.csv")
    os.link(tmp_path / "renamed.csv", tmp_path / "hard.csv")
    for out in ("renamed.csv", "link.csv", "hard.csv", "./renamed.csv"):
        c = hdrd("convert", "renamed.csv", "--out", out, cwd=tmp_path)
        assert c.returncode == 2 and c.stderr == (
            f"hdrd convert: --out {out} is the capture itself; name another file, e.g. "
            "--out renamed-drive.csv\n"
        )
        assert (tmp_path / "renamed.csv").read_bytes() == capture
    c = hdrd(*hint.strip("`").split()[1:], cwd=tmp_path)
    assert c.returncode == 0, c.stderr
    assert (tmp_path / "renamed.csv").read_bytes() == capture
    assert len(read_drive(tmp_path / "renamed-drive.csv")) == 360  # every frame of the capture


@pytest.mark.slow
def test_files_that_are_no_drive_log_are_one_line(good: DriveLog, tmp_path: Path) -> None:
    from hdrd.io.files.parquetlog import write_parquet_drive

    rng = np.random.default_rng(0)
    (tmp_path / "random.csv").write_bytes(rng.bytes(10_000))
    (tmp_path / "zeros.csv").write_bytes(bytes(100_000))
    write_parquet_drive(tmp_path / "p.parquet", good)
    (tmp_path / "p.csv").write_bytes((tmp_path / "p.parquet").read_bytes())
    (tmp_path / "latin1.csv").write_bytes("# who: Jos\xe9\nt,omega\n0,1\n".encode("latin-1"))
    (tmp_path / "late.csv").write_bytes(b"t,omega\n0,1\n0.1,2\n0.2,\xff3\n")
    os.mkfifo(tmp_path / "fifo.csv")
    os.mkfifo(tmp_path / "fifo.parquet")
    (tmp_path / "csv.parquet").write_bytes(b"t,omega\n0,1\n")
    expected = {
        "random.csv": "random.csv: binary data, not a drive log",
        "zeros.csv": "zeros.csv: binary data, not a drive log",
        "p.csv": "p.csv: a Parquet file; name it p.parquet",
        "latin1.csv": "latin1.csv:1: not UTF-8 text (byte 0xe9 at column 11); save the CSV as UTF-8",
        "late.csv": "late.csv:4: not UTF-8 text (byte 0xff at column 5)",
        "fifo.csv": "fifo.csv: is a FIFO, not a drive log file",
        "fifo.parquet": "fifo.parquet: is a FIFO, not a drive log file",
        "csv.parquet": "csv.parquet: not a readable Parquet drive log: ",
    }
    for f, why in expected.items():
        p = hdrd("evaluate", f, cwd=tmp_path, timeout=60)
        assert p.returncode == 1, (f, p.stderr)
        assert p.stderr.startswith(f"hdrd evaluate: error: {why}"), p.stderr
        assert p.stderr.count("\n") == 1
        assert p.stderr[:-1].isprintable(), p.stderr
    write_drive(tmp_path / "ok.csv", good)
    p = hdrd("evaluate", "ok.csv", *expected, cwd=tmp_path, timeout=60)
    assert p.returncode == 0 and len(_skips(p.stderr, "evaluate")) == len(expected), p.stderr
