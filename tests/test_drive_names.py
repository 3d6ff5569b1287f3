"""Names that come from data (a Parquet ``drive`` value, a hive folder ``drive=NAME``) become
paths only inside the output folder (hdrd.io.files.access.path_inside): ``hdrd gap --out DIR`` on a fleet,
``hdrd simulate``/``hdrd convert --format dataset``. Each command is run as a user runs it and
the file system is searched afterwards for anything written outside the output folder."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from hdrd.io.files.drivefiles import find_drives
from hdrd.sim.drive import simulate_drive
from tests.hdrd_process import hdrd

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")


def files_under(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


def _fleet_file(path: Path, names: list[str]) -> None:
    """A Parquet file holding one short standstill drive per name (a ``drive`` column)."""
    log = simulate_drive("standstill", 0.5, 2)
    n = len(log)
    cols: dict[str, list[object]] = {"drive": [], "t": [], "omega": []}
    for name in names:
        cols["drive"] += [name] * n
        cols["t"] += log.t.tolist()
        cols["omega"] += log.omega.tolist()
    pq.write_table(pa.table(cols), path)


@pytest.mark.slow  # a whole model-gap search
def test_gap_out_writes_every_model_inside_its_folder(tmp_path: Path) -> None:
    """Drives named ``../../x``, ``/abs/x`` and ``../../y`` (a hive folder
    ``drive=..%2F..%2Fy``) once wrote ``x.yaml`` and ``y.yaml`` outside ``--out``."""
    work = tmp_path / "work" / "deep"
    work.mkdir(parents=True)
    _fleet_file(work / "fleet.parquet", ["../../x", "/abs/x", "ok"])
    part = work / "ds" / "drive=..%2F..%2Fy"
    part.mkdir(parents=True)
    _fleet_file(tmp_path / "one.parquet", ["z"])
    table = pq.read_table(tmp_path / "one.parquet").drop_columns(["drive"])
    pq.write_table(table, part / "part-0.parquet")
    (tmp_path / "one.parquet").unlink()
    assert [r.name for r in find_drives([str(work / "ds")])] == ["../../y"]
    before = files_under(tmp_path)
    out = work / "models"
    p = hdrd("gap", "fleet.parquet", "ds", "--standstill", "--out", "models", "--no-progress",
             cwd=work)  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    written = files_under(tmp_path) - before
    assert {w for w in written if not w.startswith("work/deep/models")} == set(), written
    assert sorted(os.listdir(out)) == ["ok.yaml"]
    skips = [x for x in p.stderr.splitlines() if x.startswith("hdrd gap: skipped")]
    assert len(skips) == 3, p.stderr
    for name in ("../../x", "/abs/x", "../../y"):
        assert any(s.startswith(f"hdrd gap: skipped {name}: ") for s in skips), p.stderr
    assert not Path("/abs/x.yaml").exists()
    strict = hdrd("gap", "fleet.parquet", "--standstill", "--out", "m2", "--no-progress",
                  "--strict", cwd=work)  # fmt: skip
    assert strict.returncode == 1 and len(strict.stderr.splitlines()) == 1, strict.stderr
    assert "../../x" in strict.stderr and not (work / "m2").exists()


@pytest.mark.slow  # a whole model-gap search
def test_gap_out_leaves_out_a_second_drive_with_the_same_file(tmp_path: Path) -> None:
    """city.csv and city.parquet are both the drive ``city``: one model file, not one written
    over the other."""
    from hdrd.io.files.drivelog import write_drive
    from hdrd.io.files.parquetlog import write_parquet_drive

    log = simulate_drive("standstill", 0.5, 3)
    write_drive(tmp_path / "city.csv", log)
    write_parquet_drive(tmp_path / "city.parquet", log)
    p = hdrd("gap", "city.csv", "city.parquet", "--standstill", "--out", "m", "--no-progress",
             cwd=tmp_path)  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert os.listdir(tmp_path / "m") == ["city.yaml"]
    assert "hdrd gap: skipped city: its model would be" in p.stderr


def test_a_dataset_partition_stays_inside_its_folder(tmp_path: Path) -> None:
    from hdrd.io.files.drivecolumns import DriveLogError
    from hdrd.io.files.parquetlog import partition_value, write_dataset_drive

    log = simulate_drive("standstill", 0.2, 1)
    root = tmp_path / "ds"
    for name in ("../../x", "/abs/x", "..", "a\x00b", "a/b"):
        path = write_dataset_drive(root, log, name)
        assert path.parent.parent == root
        assert partition_value(path.parent) == name
    for bad in ("", "x" * 300):
        with pytest.raises(DriveLogError):
            write_dataset_drive(root, log, bad)
    assert {p.parent.name for p in tmp_path.rglob("*.parquet")} == {
        "drive=..%2F..%2Fx", "drive=%2Fabs%2Fx", "drive=..", "drive=a%00b", "drive=a%2Fb"
    }  # fmt: skip


@pytest.mark.slow
def test_simulate_and_convert_write_a_dataset_inside_out(tmp_path: Path) -> None:
    """``--format dataset`` names the partition from the drive (simulate) or the capture's
    stem (convert; ``...cap``'s stem is ``..``): a folder directly inside OUT either way."""
    p = hdrd("simulate", "--drive", "city", "--minutes", "0.2", "--seed", "3", "--out", "ds",
             "--format", "dataset", cwd=tmp_path)  # fmt: skip
    assert p.returncode == 0, p.stderr
    cap = tmp_path / "...cap"
    f = hdrd("fakegyro", "--drive", "standstill", "--minutes", "0.05", "--out", str(cap),
             cwd=tmp_path)  # fmt: skip
    assert f.returncode == 0, f.stderr
    c = hdrd("convert", "...cap", "--out", "ds", "--format", "dataset", cwd=tmp_path)
    assert c.returncode == 0, c.stderr
    assert sorted(os.listdir(tmp_path / "ds")) == ["drive=..", "drive=city-3"]
    assert sorted(files_under(tmp_path)) == [
        "...cap", "ds", "ds/drive=..", "ds/drive=../part-0.parquet", "ds/drive=city-3",
        "ds/drive=city-3/part-0.parquet",
    ]  # fmt: skip


@pytest.mark.slow  # a whole model-gap search
def test_a_name_with_a_line_break_cannot_write_yaml_keys(tmp_path: Path) -> None:
    """Drive names go into the comments of the YAML that tune --out and gap --gyro-out write:
    a name with a line break would start a key of its own there."""
    import yaml

    from hdrd.io.files.drivelog import write_drive

    log = simulate_drive("city", 1.0, 4)
    evil = "x\nhdr:\n  c1: 999\n#"
    cols = {c: getattr(log, c) for c in log.columns()}
    pq.write_table(pa.table({"drive": [evil] * len(log), **cols}), tmp_path / "f.parquet")
    p = hdrd("tune", "f.parquet", "--candidates", "4", "--no-progress", "--out", "t.yaml",
             cwd=tmp_path)  # fmt: skip
    assert p.returncode == 0, p.stderr
    text = (tmp_path / "t.yaml").read_text()
    assert "x\\nhdr:\\n  c1: 999" in text  # the name, escaped, in the comment
    doc = yaml.safe_load(text)
    assert list(doc) == ["hdr"] and doc["hdr"]["c1"] != 999
    named = tmp_path / "a\ngyro:\n  grade: phone\n.csv"
    write_drive(named, log)
    g = hdrd("gap", named.name, "--gyro-out", "plus.yaml", "--no-progress", cwd=tmp_path)
    assert g.returncode == 0, g.stderr
    text = (tmp_path / "plus.yaml").read_text()
    assert "grade" not in yaml.safe_load(text)["gyro"]
    assert text.startswith("# HDR+'s error model, fitted by `hdrd gap` to a\\ngyro:")
