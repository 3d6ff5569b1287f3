"""hdrd.io.files.drivefiles: which drives a command line names (files, directories searched at any
depth, globs, a dataset's partitions), what each is called, and a drive read or written by
its format. Real files in a temporary folder.

Parquet's own layouts (a file holding many drives, a partitioned dataset): test_parquetlog.py;
names from data kept inside the output folder by the commands: test_drive_names.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hdrd.io.files.drivecolumns import DriveLogError
from hdrd.io.files.drivefiles import (
    MAX_NAME_CHARS,
    DriveRef,
    drive_name,
    find_drives,
    log_format,
    write_log,
)
from hdrd.io.files.drivelog import DriveLog, read_drive, write_drive
from hdrd.sim.drive import simulate_drive


@pytest.fixture(scope="module")
def city() -> DriveLog:
    return simulate_drive("city", 2.0, 3)


@pytest.fixture(scope="module")
def short(tmp_path_factory: pytest.TempPathFactory) -> DriveLog:
    """A short drive as a CSV file gives it back: at the precision the writer keeps, so that
    writing it again in any format and reading it back gives the same values."""
    p = tmp_path_factory.mktemp("short") / "standstill.csv"
    write_drive(p, simulate_drive("standstill", 0.5, 2))
    return read_drive(p)


def same(a: DriveLog, b: DriveLog) -> bool:
    return a.columns() == b.columns() and all(
        np.array_equal(getattr(a, c), getattr(b, c), equal_nan=True) for c in a.columns()
    )


def test_a_file_is_named_by_its_stem_and_reads_back(short: DriveLog, tmp_path: Path) -> None:
    p = tmp_path / "drive 05.csv"
    write_drive(p, short)
    (ref,) = find_drives([str(p)])
    assert ref == DriveRef(str(p), "drive 05") and not ref.parquet and ref.problem is None
    assert same(ref.read(), short)


def test_a_directory_is_searched_at_any_depth_sorted_and_named_inside_it(
    short: DriveLog, tmp_path: Path
) -> None:
    for rel in ("b.csv", "a/z.csv", "a/deeper/m.csv", "c/n.csv"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        write_drive(tmp_path / rel, short)
    (tmp_path / "a" / "notes.txt").write_text("not a log")
    (tmp_path / "a" / "deeper" / "x.csv.bak").write_text("not a log either")
    refs = find_drives([str(tmp_path)])
    assert [r.name for r in refs] == ["a/deeper/m", "a/z", "b", "c/n"]
    assert [Path(r.path).relative_to(tmp_path).as_posix() for r in refs] == [
        "a/deeper/m.csv", "a/z.csv", "b.csv", "c/n.csv",
    ]  # fmt: skip


def test_paths_keep_the_command_lines_order_and_a_glob_is_expanded_sorted(
    short: DriveLog, tmp_path: Path
) -> None:
    for name in ("d3", "d1", "d2"):
        write_drive(tmp_path / f"{name}.csv", short)
    refs = find_drives([str(tmp_path / "d3.csv"), str(tmp_path / "d?.csv")])
    assert [r.name for r in refs] == ["d3", "d1", "d2", "d3"]  # named twice: listed twice


def test_what_names_no_drive_is_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(DriveLogError, match=r"missing\.csv: no such file"):
        find_drives([str(tmp_path / "missing.csv")])
    with pytest.raises(DriveLogError, match=r"nothing-\*\.csv: no file matches"):
        find_drives([str(tmp_path / "nothing-*.csv")])
    (tmp_path / "empty").mkdir()
    with pytest.raises(DriveLogError, match=r"a directory without drive logs \(\*\.csv"):
        find_drives([str(tmp_path / "empty")])
    assert find_drives([]) == []


def test_a_file_named_as_a_glob_is_taken_as_it_is(short: DriveLog, tmp_path: Path) -> None:
    p = tmp_path / "run[1].csv"  # exists: not a pattern (which would match run1.csv)
    write_drive(p, short)
    (ref,) = find_drives([str(p)])
    assert ref.name == "run[1]"


def test_a_bad_drive_is_that_drives_error_when_read(tmp_path: Path) -> None:
    p = tmp_path / "bad.csv"
    p.write_text("t,omega\n0,0.1\n1,not-a-number\n")
    (ref,) = find_drives([str(tmp_path)])  # listing reads no samples
    with pytest.raises(DriveLogError, match="bad"):
        ref.read()
    with pytest.raises(DriveLogError, match="^why not$"):
        DriveRef(str(p), "bad", problem="why not").read()


def test_the_format_follows_the_name_unless_given() -> None:
    assert log_format("x.parquet", None) == "parquet"
    assert log_format("x.csv", None) == "csv" and log_format("x", None) == "csv"
    assert log_format("x.parquet", "dataset") == "dataset"


@pytest.mark.parametrize("fmt", ["csv", "parquet", "dataset"])
def test_write_log_writes_what_find_drives_reads(short: DriveLog, tmp_path: Path, fmt: str) -> None:
    if fmt != "csv":
        pytest.importorskip("pyarrow")
    out = tmp_path / ("out.parquet" if fmt == "parquet" else "out.csv" if fmt == "csv" else "ds")
    written = write_log(str(out), short, fmt, "veh 7")
    assert Path(written).is_file()
    (ref,) = find_drives([str(out)])
    assert ref.name == ("veh 7" if fmt == "dataset" else "out")
    assert ref.parquet == (fmt != "csv")
    assert same(ref.read(), short)


def test_a_name_from_data_is_shown_escaped_and_clipped() -> None:
    assert drive_name("a\x1b[2Jb") == "a\\x1b[2Jb"
    assert drive_name("\u202eevil") == "\\u202eevil"
    long = drive_name("y" * 100_000)
    assert len(long) == MAX_NAME_CHARS and long.endswith("...")
    assert drive_name(17) == "17"


def test_directories_globs_and_mixed_formats(city: DriveLog, tmp_path: Path) -> None:
    pytest.importorskip("pyarrow")
    from hdrd.io.files.parquetlog import write_dataset_drive, write_parquet_drive

    (tmp_path / "a" / "b").mkdir(parents=True)
    write_drive(tmp_path / "a" / "x.csv", city)
    write_parquet_drive(tmp_path / "a" / "b" / "y.parquet", city)
    write_dataset_drive(tmp_path / "a" / "ds", city, "z")
    (tmp_path / "a" / "notes.txt").write_text("not a log")
    refs = find_drives([str(tmp_path / "a")])
    assert [r.name for r in refs] == ["b/y", "ds/z", "x"]
    assert all(isinstance(r, DriveRef) for r in refs)
    logs = [r.read() for r in refs]
    for log in logs[1:]:
        for c in log.columns():
            assert np.array_equal(getattr(log, c), getattr(logs[0], c), equal_nan=True)
    globbed = find_drives([str(tmp_path / "a" / "**" / "*.parquet")])
    assert [Path(r.path).name for r in globbed] == ["y.parquet", "part-0.parquet"]
    with pytest.raises(DriveLogError, match="no file matches"):
        find_drives([str(tmp_path / "nothing-*.csv")])
    with pytest.raises(DriveLogError, match="no such file"):
        find_drives([str(tmp_path / "missing.csv")])
    (tmp_path / "empty").mkdir()
    with pytest.raises(DriveLogError, match="a directory without drive logs"):
        find_drives([str(tmp_path / "empty")])
