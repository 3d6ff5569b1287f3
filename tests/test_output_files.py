"""Files hdrd writes where the user said: each command run as a user runs it (a real ``hdrd``
process, real files, links and FIFOs), and the file system looked at afterwards.

A file hdrd names itself in a folder the user named (``evaluate --trace DIR``'s DIR/NAME.csv,
``simulate --benchmark``'s drive logs, a dataset's partitions, ``gap --out DIR``'s models)
replaces only a regular file: a symbolic link planted there is never written through (a file
outside the folder replaced) nor a FIFO opened (the command hung), and no folder on the way
leads out of it."""

from __future__ import annotations

import os
import shutil
import stat
from pathlib import Path

import pytest

from tests.hdrd_process import hdrd


def plant(where: Path, kind: str, outside: Path) -> None:
    """A symbolic link to the file ``outside`` (kind "link") or a FIFO (kind "fifo") at
    ``where``."""
    where.parent.mkdir(parents=True, exist_ok=True)
    if kind == "link":
        where.symlink_to(outside)
    else:
        os.mkfifo(where)


def unchanged(where: Path, kind: str, outside: Path) -> bool:
    """The planted thing is still there, as it was, and the file outside holds what it held."""
    mode = where.lstat().st_mode
    still = stat.S_ISLNK(mode) if kind == "link" else stat.S_ISFIFO(mode)
    return still and outside.read_text() == "not hdrd's\n"


@pytest.fixture
def outside(tmp_path: Path) -> Path:
    f = tmp_path / "elsewhere" / "precious.txt"
    f.parent.mkdir()
    f.write_text("not hdrd's\n")
    return f


@pytest.mark.parametrize("kind", ["link", "fifo"])
def test_evaluate_trace_replaces_only_a_regular_file_in_its_folder(
    tmp_path: Path, outside: Path, kind: str
) -> None:
    # Before: the trace was written through a link (the file outside DIR replaced) and the
    # command hung on a FIFO.
    work = tmp_path / "work"
    work.mkdir()
    assert hdrd("simulate", "--drive", "city", "--minutes", "2", "--out", "city.csv",
                cwd=work).returncode == 0  # fmt: skip
    plant(work / "traces" / "city.csv", kind, outside)
    p = hdrd("evaluate", "city.csv", "--trace", "traces", "--no-progress", cwd=work, timeout=120)
    assert p.returncode == 1, p.stderr
    last = p.stderr.splitlines()[-1]
    assert last.startswith("hdrd evaluate: error: cannot write the trace of city: "), p.stderr
    assert "traces/city.csv is a " in last and "only a regular file is replaced" in last
    assert "Traceback" not in p.stderr
    assert unchanged(work / "traces" / "city.csv", kind, outside)
    assert os.listdir(work / "traces") == ["city.csv"]  # no temporary file left


def test_evaluate_trace_still_replaces_its_own_file(tmp_path: Path) -> None:
    assert hdrd("simulate", "--drive", "city", "--minutes", "2", "--out", "city.csv",
                cwd=tmp_path).returncode == 0  # fmt: skip
    (tmp_path / "traces").mkdir()
    (tmp_path / "traces" / "city.csv").write_text("an old trace\n")
    p = hdrd("evaluate", "city.csv", "--trace", "traces", "--no-progress", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "traces" / "city.csv").read_text().startswith("t,heading_truth,")


@pytest.mark.parametrize("kind", ["link", "fifo"])
def test_simulate_benchmark_replaces_only_a_regular_file_in_its_folder(
    tmp_path: Path, outside: Path, kind: str
) -> None:
    plant(tmp_path / "bench" / "city3.csv", kind, outside)
    p = hdrd("simulate", "--benchmark", "test", "--out", "bench", cwd=tmp_path, timeout=120)
    assert p.returncode == 1, p.stderr
    assert len(p.stderr.splitlines()) == 1, p.stderr
    assert "bench/city3.csv is a " in p.stderr, p.stderr
    assert unchanged(tmp_path / "bench" / "city3.csv", kind, outside)


def test_a_dataset_partition_never_leads_out_of_its_folder(tmp_path: Path, outside: Path) -> None:
    # A partition folder that is a link to another folder: the drive was written there.
    pytest.importorskip("pyarrow")
    (tmp_path / "fleet").mkdir()
    (tmp_path / "fleet" / "drive=city-3").symlink_to(outside.parent)
    p = hdrd("simulate", "--drive", "city", "--minutes", "1", "--seed", "3", "--out", "fleet",
             "--format", "dataset", cwd=tmp_path)  # fmt: skip
    assert p.returncode == 1, p.stderr
    assert len(p.stderr.splitlines()) == 1, p.stderr
    assert "fleet/drive=city-3 leads out of fleet" in p.stderr, p.stderr
    assert os.listdir(outside.parent) == ["precious.txt"]


@pytest.mark.slow  # a model-gap search of two drives
@pytest.mark.parametrize("kind", ["link", "fifo"])
def test_gap_out_replaces_only_a_regular_file_in_its_folder(
    tmp_path: Path, outside: Path, kind: str
) -> None:
    pytest.importorskip("scipy")
    for seed in ("1", "2"):
        assert hdrd("simulate", "--drive", "standstill", "--minutes", "0.5", "--seed", seed,
                    "--out", f"s{seed}.csv", cwd=tmp_path).returncode == 0  # fmt: skip
    plant(tmp_path / "models" / "s1.yaml", kind, outside)
    p = hdrd("gap", "s1.csv", "s2.csv", "--standstill", "--out", "models", "--no-progress",
             cwd=tmp_path, timeout=300)  # fmt: skip
    assert p.returncode == 1, p.stderr
    assert "models/s1.yaml is a " in p.stderr.splitlines()[-1], p.stderr
    assert unchanged(tmp_path / "models" / "s1.yaml", kind, outside)


def test_a_link_inside_the_folder_is_followed_one_out_of_it_is_not(tmp_path: Path) -> None:
    from hdrd.io.files.access import OutputFileError, atomic_write_text

    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    (out / "inner").mkdir(parents=True)
    elsewhere.mkdir()
    (out / "in").symlink_to(out / "inner")
    (out / "away").symlink_to(elsewhere)
    atomic_write_text(out / "in" / "x.yaml", "x\n", inside=out)
    assert (out / "inner" / "x.yaml").read_text() == "x\n"
    with pytest.raises(OutputFileError, match="away leads out of .*out"):
        atomic_write_text(out / "away" / "deeper" / "y.yaml", "y\n", inside=out)
    assert os.listdir(elsewhere) == []  # not even the folder "deeper"


# -- the folders an output needs, made; what cannot be written, said before the work ----------


def test_simulate_and_convert_make_the_folders_their_out_needs(tmp_path: Path) -> None:
    # The README's `hdrd simulate --benchmark test --out drives/test` in an empty folder said
    # "the folder drives does not exist", and every example after it failed.
    pytest.importorskip("pyarrow")
    runs = [
        ("simulate", "--benchmark", "test", "--out", "drives/test"),
        ("simulate", "--drive", "city", "--minutes", "1", "--out", "a/b/c.csv"),
        ("simulate", "--drive", "city", "--minutes", "1", "--out", "p/q/c.parquet"),
        ("simulate", "--drive", "city", "--minutes", "1", "--out", "d/fleet", "--format",
         "dataset"),
        ("fakegyro", "--drive", "city", "--minutes", "1", "--out", "drive.cap"),
        ("convert", "drive.cap", "--out", "e/f/drive.csv"),
    ]  # fmt: skip
    for args in runs:
        p = hdrd(*args, cwd=tmp_path)
        assert p.returncode == 0, (args, p.stderr)
    assert len(os.listdir(tmp_path / "drives" / "test")) == 5
    for made in ("a/b/c.csv", "p/q/c.parquet", "d/fleet/drive=city-1/part-0.parquet",
                 "e/f/drive.csv"):  # fmt: skip
        assert (tmp_path / made).is_file(), made


def test_a_plot_in_a_missing_folder_is_made(tmp_path: Path) -> None:
    # Was: the table printed, then "cannot write nodir/x.png: No such file or directory".
    pytest.importorskip("matplotlib")
    assert hdrd("simulate", "--drive", "city", "--minutes", "1", "--out", "c.csv",
                cwd=tmp_path).returncode == 0  # fmt: skip
    p = hdrd("evaluate", "c.csv", "--plot", "nodir/x.png", "--no-progress", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "nodir" / "x.png").stat().st_size > 0


NOWHERE = "/proc/hdrd-nowhere"
"""A folder no one can make, root included (/proc takes no new entries)."""


@pytest.fixture(scope="module")
def work_inputs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two simulated drive logs and a capture, made once (by the commands a user runs) for
    the cases below, which copy them: each case's own folder stays its own."""
    folder = tmp_path_factory.mktemp("inputs")
    for made in (("simulate", "--drive", "city", "--minutes", "1", "--out", "c.csv"),
                 ("simulate", "--drive", "city", "--minutes", "1", "--out", "c2.csv"),
                 ("fakegyro", "--drive", "city", "--minutes", "0.5", "--out", "drive.cap")):  # fmt: skip
        assert hdrd(*made, cwd=folder).returncode == 0
    return folder


@pytest.mark.parametrize(
    "args",
    [
        ("evaluate", "c.csv", "--plot", f"{NOWHERE}/x.png"),
        ("evaluate", "c.csv", "--json", f"{NOWHERE}/x.json"),
        ("evaluate", "c.csv", "--trace", f"{NOWHERE}/traces"),
        ("tune", "c.csv", "--candidates", "20", "--out", f"{NOWHERE}/tuned.yaml"),
        ("tune", "c.csv", "--candidates", "20", "--json", f"{NOWHERE}/tune.json"),
        ("gap", "c.csv", "--report", f"{NOWHERE}/r.json"),
        ("gap", "c.csv", "--plot", f"{NOWHERE}/g.png"),
        ("gap", "c.csv", "--out", f"{NOWHERE}/m.yaml"),
        ("gap", "c.csv", "--gyro-out", f"{NOWHERE}/g.yaml"),
        ("gap", "c.csv", "c2.csv", "--out", f"{NOWHERE}/models"),
        ("simulate", "--drive", "city", "--minutes", "1", "--out", f"{NOWHERE}/x.csv"),
        ("simulate", "--benchmark", "test", "--out", f"{NOWHERE}/drives"),
        ("convert", "drive.cap", "--out", f"{NOWHERE}/x.csv"),
    ],
    ids=lambda a: " ".join(a[:1] + a[-2:-1]),
)
def test_an_output_that_cannot_be_written_is_said_before_the_work(
    tmp_path: Path, args: tuple[str, ...], work_inputs: Path
) -> None:
    # Was: evaluate printed its table, gap ran its search, then "cannot write".
    if not os.path.isdir("/proc/self"):
        pytest.skip("no /proc here: the folder no one can make is /proc's")
    for name in ("c.csv", "c2.csv", "drive.cap"):
        shutil.copy(work_inputs / name, tmp_path / name)
    p = hdrd(*args, "--no-progress", cwd=tmp_path) if args[0] in ("evaluate", "tune", "gap") \
        else hdrd(*args, cwd=tmp_path)  # fmt: skip
    assert p.returncode == 1, p.stderr
    assert p.stdout == "", p.stdout  # no table, no search: nothing done
    assert len(p.stderr.splitlines()) == 1 and NOWHERE in p.stderr, p.stderr


@pytest.mark.parametrize(
    ("args", "flag"),
    [
        (("gap", "s1.csv", "s2.csv", "--standstill", "--out", "one.yaml"), "--out one.yaml"),
        (("simulate", "--benchmark", "test", "--out", "bench.csv"), "--out bench.csv"),
        (("evaluate", "s1.csv", "--trace", "trace.csv"), "--trace trace.csv"),
    ],
)
def test_a_folder_output_named_like_a_file_is_refused(
    tmp_path: Path, args: tuple[str, ...], flag: str
) -> None:
    # Was: `gap a b --out one.yaml` made a folder named one.yaml, silently.
    for seed in ("1", "2"):
        assert hdrd("simulate", "--drive", "standstill", "--minutes", "0.5", "--seed", seed,
                    "--out", f"s{seed}.csv", cwd=tmp_path).returncode == 0  # fmt: skip
    p = hdrd(*args, cwd=tmp_path)
    assert p.returncode == 1, p.stderr
    assert p.stdout == "" and len(p.stderr.splitlines()) == 1, p.stderr
    assert f"{flag}: " in p.stderr and "a folder" in p.stderr, p.stderr
    assert sorted(os.listdir(tmp_path)) == ["s1.csv", "s2.csv"]  # nothing made
