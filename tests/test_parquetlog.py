"""Drive logs as Parquet (hdrd/io/files/parquetlog.py): read exactly like the CSV, the same checks,
files, a file holding many drives, a dataset partitioned by drive, as the drives a command
line names find them (hdrd/io/files/drivefiles.py; its directories, globs and mixed formats:
test_drivefiles.py)."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.cli import main as cli
from hdrd.io.files.drivecolumns import NO_LIMITS, DriveLogError
from hdrd.io.files.drivefiles import find_drives
from hdrd.io.files.drivelog import DriveLog, csv_values, read_drive, write_drive
from hdrd.io.files.parquetlog import (
    DRIVE_META_KEY,
    META_KEY,
    drives_in_file,
    partition_dir,
    read_parquet_drive,
    write_dataset_drive,
    write_parquet_drive,
)
from hdrd.sim.drive import simulate_drive
from hdrd.sim.fakegyro import FakeGyro
from tests.test_daemon import drive_profile
from tests.test_drivelog import assert_same_log, drive_logs

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def city() -> DriveLog:
    return simulate_drive("city", 2.0, 3)


def test_a_drive_reads_back_the_same_from_csv_and_parquet(city: DriveLog, tmp_path: Path) -> None:
    """The writer keeps the CSV's decimals: both files give the same DriveLog, bit for bit,
    metadata (lead_in_s, the gyro model JSON) included."""
    write_drive(tmp_path / "c.csv", city)
    write_parquet_drive(tmp_path / "c.parquet", city)
    a = read_drive(tmp_path / "c.csv")
    b = read_parquet_drive(tmp_path / "c.parquet")
    assert_same_log(a, b)
    assert b.name == "c" and b.meta["lead_in_s"] == city.meta["lead_in_s"]
    assert list(b.meta) == list(city.meta)  # the order kept too
    for c in a.columns():
        assert getattr(a, c).tobytes() == getattr(b, c).tobytes(), c
    # and the arrays are the reader's own: writable, as the CSV reader's
    b.omega[0] += 1.0


@settings(max_examples=60)
@given(drive_logs())
def test_parquet_round_trip(tmp_path_factory: pytest.TempPathFactory, log: DriveLog) -> None:
    path = tmp_path_factory.mktemp("pq") / "d.parquet"
    write_parquet_drive(path, log)
    assert_same_log(read_parquet_drive(path), log)


VALUES = st.floats(allow_nan=True, allow_infinity=False, width=64) | st.floats(-1e6, 1e6).map(
    lambda v: round(v, 7) + 5e-8  # near the half of the last decimal written
)


@given(
    st.sampled_from(["temp_c", "heading_truth", "omega_truth", "speed", "omega"]),
    st.lists(VALUES, min_size=1, max_size=30),
)
def test_csv_values_are_what_the_csv_reads_back(column: str, values: list[float]) -> None:
    """csv_values (the Parquet writer's rounding) gives exactly the number a CSV holds, halves
    and huge values included."""
    v = np.array(values)
    if column == "omega":
        v = np.nan_to_num(v)  # required in every row
    if column == "heading_truth":  # the format takes headings within +/-360 deg only
        v = np.where(np.abs(v) <= 360.0, v, np.fmod(v, 360.0))
    if column == "temp_c":  # and temperatures within [-100, 200] deg C
        v = np.where(np.abs(v) <= 100.0, v, np.fmod(v, 100.0))
    if column == "speed":  # and speeds not negative
        v = np.abs(v)
    t = np.arange(v.shape[0], dtype=np.float64)
    cols = {"omega": np.zeros_like(t), column: v}
    log = DriveLog(t=t, **cols)  # type: ignore[arg-type]
    buf = io.StringIO()
    write_drive(buf, log)
    back = getattr(read_drive(io.StringIO(buf.getvalue()), limits=NO_LIMITS), column)
    assert np.array_equal(back, csv_values(column, v), equal_nan=True)


@settings(max_examples=100)
@given(st.lists(st.floats(0, 1e9), min_size=1, max_size=30, unique=True))
def test_csv_values_of_times(values: list[float]) -> None:
    t = csv_values("t", np.array(sorted(values)))
    if np.any(np.diff(t) <= 0):
        return  # times closer than the CSV's 0.1 ms: not a log either way
    buf = io.StringIO()
    write_drive(buf, DriveLog(t=np.array(sorted(values)), omega=np.zeros(len(values))))
    assert np.array_equal(read_drive(io.StringIO(buf.getvalue()), limits=NO_LIMITS).t, t)


def _table(cols: dict[str, object], meta: dict[str, str] | None = None) -> pa.Table:
    t = pa.table(cols)
    return t.replace_schema_metadata(meta) if meta else t


@pytest.mark.parametrize(
    "cols, match",
    [
        ({"t": [0.0, 1.0], "omega": [0.1, 0.2], "yaw": [1.0, 2.0]}, "unknown column 'yaw'"),
        ({"t": [0.0, 1.0]}, "missing required column 'omega'"),
        ({"t": [0.0, 1.0], "omega": ["a", "b"]}, "column omega holds string, not numbers"),
        ({"t": [0.0, 1.0], "omega": [0.1, float("inf")]}, r"row 2: column omega: inf"),
        ({"t": [0.0, 0.0], "omega": [0.1, 0.2]}, r"row 2: column t is not strictly increasing"),
        ({"t": [0.0, 1.0], "omega": [0.1, None]}, r"row 2: column omega is empty"),
        ({"t": [0.0, 1.0], "omega": [0.1, 0.2], "valid": [1, 2]}, r"row 2: column valid: 2.0"),
        ({"t": [0.0, 1.0], "omega": [0.1, 0.2], "temp_c": [20.0, 1e200]}, r"row 2: column temp_c"),
        ({"t": pa.array([], pa.float64()), "omega": pa.array([], pa.float64())}, "no data rows"),
    ],
)
def test_errors_name_the_file_and_row(tmp_path: Path, cols: dict, match: str) -> None:
    path = tmp_path / "bad.parquet"
    pq.write_table(_table(cols), path)
    with pytest.raises(DriveLogError, match=match) as e:
        read_parquet_drive(path)
    assert str(path) in str(e.value)


def test_a_column_name_that_is_not_utf8_is_an_unreadable_file(tmp_path: Path) -> None:
    """A damaged footer whose column name is not UTF-8: pyarrow raises UnicodeDecodeError
    (once a traceback from evaluate, tune and gap); one line naming the file instead."""
    buf = io.BytesIO()
    pq.write_table(_table({"t": [0.0, 1.0], "omega": [0.1, 0.2], "zzzz": [1.0, 2.0]}), buf,
                   store_schema=False)  # fmt: skip
    path = tmp_path / "damaged.parquet"
    path.write_bytes(buf.getvalue().replace(b"zzzz", b"\xff\xfezz"))
    for read in (read_parquet_drive, drives_in_file):
        with pytest.raises(DriveLogError, match="not a readable Parquet drive log") as e:
            read(path)
        assert str(e.value).startswith(str(path)) and str(e.value).isprintable()


def test_not_parquet_and_bad_metadata(tmp_path: Path) -> None:
    junk = tmp_path / "junk.parquet"
    junk.write_text("t,omega\n0,1\n")
    with pytest.raises(DriveLogError, match="not a readable Parquet drive log"):
        read_parquet_drive(junk)
    bad = tmp_path / "meta.parquet"
    pq.write_table(_table({"t": [0.0], "omega": [0.0]}, {META_KEY: '{"a": 1}'}), bad)
    with pytest.raises(DriveLogError, match="metadata 'a' is int, not a string"):
        read_parquet_drive(bad)


def test_integers_booleans_and_nulls_read_as_the_csv_would(tmp_path: Path) -> None:
    path = tmp_path / "types.parquet"
    cols = {
        "t": pa.array([0, 1, 2], pa.int64()),
        "omega": pa.array([0.5, 0.25, 0.0], pa.float32()),
        "heading_truth": pa.array([None, 10.0, None], pa.float64()),
        "valid": pa.array([True, False, True]),
        "__index_level_0__": pa.array([7, 8, 9]),  # pandas' index: not data
    }
    pq.write_table(_table(cols), path)
    log = read_parquet_drive(path)
    assert log.t.dtype == np.float64 and list(log.t) == [0.0, 1.0, 2.0]
    assert list(log.omega) == [0.5, 0.25, 0.0]
    assert log.heading_truth is not None and np.isnan(log.heading_truth[[0, 2]]).all()
    assert log.valid is not None and list(log.valid) == [1.0, 0.0, 1.0]
    assert log.columns() == ["t", "omega", "heading_truth", "valid"]


def test_a_file_holding_many_drives(city: DriveLog, tmp_path: Path) -> None:
    """A `drive` column (as pandas writes a fleet's table): each value a drive, its rows in
    file order, its metadata from hdrd.drive_meta; row groups need not split at drives."""
    a, b = city.slice(0, 700), city.slice(700)
    names = ["veh 7", "veh 3"]
    tables = [
        pa.table({"drive": [n] * len(x), "t": x.t, "omega": x.omega}) for n, x in zip(names, (a, b))
    ]
    meta = {DRIVE_META_KEY: json.dumps({"veh 7": {"lead_in_s": "30"}})}
    path = tmp_path / "fleet.parquet"
    pq.write_table(pa.concat_tables(tables).replace_schema_metadata(meta), path, row_group_size=500)
    assert drives_in_file(path) == names
    refs = find_drives([str(path)])
    assert [r.name for r in refs] == names and [r.key for r in refs] == names
    first, second = (r.read() for r in refs)
    assert np.array_equal(first.t, a.t) and np.array_equal(second.omega, b.omega)
    assert first.meta == {"lead_in_s": "30"} and second.meta == {}
    # inside a directory, a file's drives are named under the file
    assert [r.name for r in find_drives([str(tmp_path)])] == ["fleet/veh 7", "fleet/veh 3"]


def test_a_dataset_partitioned_by_drive(city: DriveLog, tmp_path: Path) -> None:
    root = tmp_path / "ds"
    write_dataset_drive(root, city, "city/3 a")  # a name pyarrow must URI-encode
    write_dataset_drive(root, city.slice(0, 500), "short")
    part = partition_dir(root, "city/3 a")
    assert part.name == "drive=city%2F3%20a" and (part / "part-0.parquet").is_file()
    refs = find_drives([str(root)])
    assert [r.name for r in refs] == ["city/3 a", "short"]
    assert_same_log(refs[0].read(), read_parquet_drive(part / "part-0.parquet"))
    # pyarrow's own dataset reader sees the same drives
    import pyarrow.dataset as ds

    seen = ds.dataset(root, partitioning="hive").to_table(columns=["drive"]).column(0)
    assert sorted(set(seen.to_pylist())) == ["city/3 a", "short"]
    # a partition named directly; one split over files, read in the order of their first t
    split = tmp_path / "drive=split"
    split.mkdir()
    write_parquet_drive(split / "b.parquet", city.slice(600))
    write_parquet_drive(split / "a.parquet", city.slice(0, 600))
    (split / "a.parquet").rename(split / "z.parquet")  # name order != time order
    (ref,) = find_drives([str(split)])
    assert ref.name == "split"
    assert np.array_equal(ref.read().t, np.concatenate([city.t[:600], city.t[600:]]))


def test_simulate_and_convert_write_parquet(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    common = ["simulate", "--drive", "city", "--minutes", "1", "--seed", "4"]
    assert cli([*common, "--out", str(tmp_path / "s.csv")]) == 0
    assert cli([*common, "--out", str(tmp_path / "s.parquet")]) == 0
    assert cli([*common, "--out", str(tmp_path / "ds"), "--format", "dataset"]) == 0
    assert cli([*common, "--format", "parquet"]) == 2  # Parquet to stdout: refused
    assert "needs --out" in capsys.readouterr().err
    csv = read_drive(tmp_path / "s.csv")
    assert_same_log(read_parquet_drive(tmp_path / "s.parquet"), csv)
    assert_same_log(read_parquet_drive(tmp_path / "ds" / "drive=city-4"), csv)
    assert (
        cli(
            ["simulate", "--benchmark", "test", "--out", str(tmp_path / "b"), "--format", "parquet"]
        )
        == 0
    )
    assert len(list((tmp_path / "b").glob("*.parquet"))) == 5
    cap = tmp_path / "c.bin"
    FakeGyro(drive_profile(seconds=20)).write_capture(cap)
    assert cli(["convert", str(cap), "--out", str(tmp_path / "c.csv")]) == 0
    assert cli(["convert", str(cap), "--out", str(tmp_path / "c.parquet")]) == 0
    assert_same_log(read_parquet_drive(tmp_path / "c.parquet"), read_drive(tmp_path / "c.csv"))


def test_evaluate_gives_the_same_numbers_on_csv_and_parquet(city: DriveLog, tmp_path: Path) -> None:
    write_drive(tmp_path / "d.csv", city)
    write_parquet_drive(tmp_path / "d.parquet", city)
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert cli(["evaluate", str(tmp_path / "d.csv"), "--json", str(a)]) == 0
    assert cli(["evaluate", str(tmp_path / "d.parquet"), "--json", str(b)]) == 0
    assert a.read_bytes() == b.read_bytes()


def test_without_pyarrow_a_one_line_error(city: DriveLog, tmp_path: Path) -> None:
    write_parquet_drive(tmp_path / "d.parquet", city)
    code = (
        "import sys; sys.modules['pyarrow'] = None\n"
        "from hdrd.cli import main\n"
        f"sys.exit(main(['evaluate', {str(tmp_path / 'd.parquet')!r}]))\n"
    )
    p = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert p.returncode == 1
    assert p.stderr.strip().splitlines() == [
        "hdrd evaluate: error: Parquet drive logs need pyarrow: pip install 'hdrd[fleet]'"
    ]


# -- a string bomb: refused from the metadata, before any value is read ------------------------


def _bomb(path: Path, n_bytes: int, rows: int = 2, row_group_size: int | None = None) -> Path:
    """A Parquet file of ``rows`` samples whose ``drive`` column holds ``n_bytes``-long names,
    each its own (its number, then one letter repeated: zstd makes 40 MB of them a few KB)."""
    names = [str(i) + "x" * (n_bytes - len(str(i))) for i in range(rows)]
    t = pa.table({"t": np.arange(rows) * 0.01, "omega": np.zeros(rows), "drive": names})
    pq.write_table(t, path, compression="zstd", row_group_size=row_group_size)
    return path


@pytest.fixture
def no_reading(monkeypatch: pytest.MonkeyPatch) -> None:
    """Reading any value of a Parquet file fails the test: a refusal must come from the
    metadata alone."""

    def refused(*a: object, **k: object) -> None:
        raise AssertionError("values were read")

    for name in ("read", "read_row_group", "read_row_groups", "iter_batches"):
        monkeypatch.setattr(pq.ParquetFile, name, refused)


def test_a_string_bomb_is_refused_from_the_metadata(tmp_path: Path, no_reading: None) -> None:
    bomb = _bomb(tmp_path / "bomb.parquet", 20_000_000)  # two names of 20 MB: 40 MB in ~3 KB
    assert bomb.stat().st_size < 100_000
    why = "column drive takes 38.1 MiB uncompressed for 2 values in row group 1"
    with pytest.raises(DriveLogError, match=why):
        drives_in_file(bomb)  # listing the drives of a fleet
    with pytest.raises(DriveLogError, match=why):
        read_parquet_drive(bomb, drive="0" + "x" * 19_999_999)  # a worker reading its drive


def test_a_string_bomb_is_one_line_of_evaluate(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bomb = _bomb(tmp_path / "bomb.parquet", 20_000_000)
    assert cli(["evaluate", str(bomb), "--no-progress"]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "refused before reading" in err, err


def test_a_chunk_too_large_is_refused_whatever_its_values(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, no_reading: None
) -> None:
    # 20,000 names of 100 bytes (short each) in one row group: 2 MB, over a lowered cap.
    import hdrd.io.files.parquetlog as parquetlog

    monkeypatch.setattr(parquetlog, "MAX_CHUNK_BYTES", 1 << 20)
    big = _bomb(tmp_path / "big.parquet", 100, rows=20_000)
    with pytest.raises(DriveLogError, match=r"for 20000 values in row group 1.* 1 MiB a row"):
        drives_in_file(big)
    ok = _bomb(tmp_path / "ok.parquet", 100, rows=20_000, row_group_size=5_000)  # 0.5 MB each
    monkeypatch.undo()
    assert len(drives_in_file(ok) or []) == 20_000


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        low, n = n & 0x7F, n >> 7
        out.append(low | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _claiming(data: bytes, column: str, claimed: int) -> bytes:
    """A Parquet file's bytes whose footer says the first chunk of ``column`` takes
    ``claimed`` bytes uncompressed (Thrift compact: ColumnMetaData field 6, an i64 after field
    5), its data as it was."""
    import struct

    pf = pq.ParquetFile(io.BytesIO(data))
    k = pf.schema_arrow.get_field_index(column)
    size = pf.metadata.row_group(0).column(k).total_uncompressed_size
    n = struct.unpack("<I", data[-8:-4])[0]
    footer = data[-8 - n : -8]
    field = b"\x16" + _varint(size << 1)  # the zigzag of a positive number: twice it
    assert footer.count(field) == 1
    footer = footer.replace(field, b"\x16" + _varint(claimed << 1))
    return data[: -8 - n] + footer + struct.pack("<I", len(footer)) + b"PAR1"


def test_a_real_size_bomb_is_refused_from_its_metadata_alone(tmp_path: Path) -> None:
    # The bomb as found (two 1 GB names), as its metadata states it, without making 2 GB: a
    # file of two short names whose footer claims 2 GB. Its values read fine (pyarrow does not
    # trust the footer's size): the refusal comes from the metadata, before reading.
    _bomb(tmp_path / "small.parquet", 3000)
    data = (tmp_path / "small.parquet").read_bytes()
    fake = tmp_path / "bomb.parquet"
    fake.write_bytes(_claiming(data, "drive", 2_000_000_100))
    assert pq.read_table(fake).num_rows == 2 and len(data) < 20_000
    with pytest.raises(DriveLogError, match="takes 1.86 GiB uncompressed for 2 values"):
        drives_in_file(fake)
