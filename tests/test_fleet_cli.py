"""Evaluate, tune and gap at the edges of their command lines (docs/evaluation.md, docs/fleet.md):
Ctrl-C in one process and on a cluster (one line, no worker's traceback; tune writes its best
so far); test drives that are training drives; output files checked before the work; drive
names that look like TeX; gap models whose names are each other's folders; a YAML file, a
FIFO or the same drive twice given as drives; what a folder's scan cannot read; --bias checked
as run checks it; --help's defaults.

Each command runs as a child process, as from a shell; Ctrl-C is SIGINT to its whole process
group, as a terminal sends it.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

from hdrd.io.files.drivelog import write_drive
from hdrd.sim.drive import simulate_drive

ROOT = Path(__file__).resolve().parents[1]
# HDRD_FLEET_MIN_WORK_S=0: --workers starts its cluster however small the fleet (the rule that
# keeps small work in this process has its own test)
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "HDRD_FLEET_MIN_WORK_S": "0"}
KINDS = ("city", "suburbs", "rural", "highway", "mixed")
SLOW = pytest.mark.slow


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """40 drives of 6 minutes (CSV)."""
    root = tmp_path_factory.mktemp("fleet")
    for i in range(40):
        kind = KINDS[i % len(KINDS)]
        write_drive(root / f"{kind}-{i:02d}.csv", simulate_drive(kind, 6.0, 100 + i))
    return root


def hdrd(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hdrd", *args],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
        timeout=600,
        stdin=subprocess.DEVNULL,
    )


def _default_sigint() -> None:
    """In the child before exec: SIGINT as a terminal gives it (a test run started in the
    background by a shell inherits it ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def past(percent: float) -> Callable[[str], bool]:
    """Whether a progress line on stderr says more than ``percent`` of the work is done."""
    return lambda line: "%" in line and float(line.split("%")[0].split()[-1]) > percent


def interrupted(*args: str, after: Callable[[str], bool]) -> tuple[int, str, str]:
    """Run ``hdrd ARGS`` in a process group of its own; once a line of its stderr is
    ``after``, Ctrl-C (SIGINT to the group). Its exit status, stdout and stderr."""
    p = subprocess.Popen(
        [sys.executable, "-m", "hdrd", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
        env=ENV,
        cwd=ROOT,
        start_new_session=True,
        preexec_fn=_default_sigint,
    )
    assert p.stderr is not None
    seen = []
    try:
        for line in p.stderr:
            seen.append(line)
            if after(line):
                os.killpg(p.pid, signal.SIGINT)
                break
        out, err = p.communicate(timeout=300)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    return p.returncode, out, "".join(seen) + err


@pytest.mark.slow
@pytest.mark.parametrize("workers", [[], ["--workers", "2"]], ids=["one process", "cluster"])
def test_ctrl_c_during_evaluate_is_one_line(fleet: Path, workers: list[str]) -> None:
    rc, out, err = interrupted("evaluate", str(fleet), *workers, after=past(0))
    assert rc == 130, err
    assert "Traceback" not in err and "Error" not in err, err
    assert err.splitlines()[-1] == "hdrd evaluate: interrupted"
    assert out == ""


@pytest.mark.slow
@pytest.mark.parametrize("workers", [[], ["--workers", "2"]], ids=["one process", "cluster"])
def test_ctrl_c_during_tune_writes_the_best_so_far(
    fleet: Path, tmp_path: Path, workers: list[str]
) -> None:
    train = [str(p) for p in sorted(fleet.glob("*.csv"))[:6]]
    out_yaml, out_json = tmp_path / "best.yaml", tmp_path / "best.json"
    args = ["tune", *train, "--candidates", "40000", "--out", str(out_yaml), "--json"]
    rc, out, err = interrupted(*args, str(out_json), *workers, after=past(40))
    assert rc == 130, err
    assert "Traceback" not in err, err
    last = err.splitlines()[-1]
    assert last.startswith("hdrd tune: interrupted: the best of the first "), last
    assert " of 40000 parameter sets (seed 0): mean training NEpsi " in last
    assert last.endswith(f"written to {out_yaml} and {out_json}")
    snippet = yaml.safe_load(out_yaml.read_text())
    assert out == out_yaml.read_text()  # the best set on stdout as well
    doc = json.loads(out_json.read_text())
    assert doc["interrupted"] is True and doc["train"] is None
    assert 0 < doc["candidates"] < 40000 and doc["candidates_asked"] == 40000
    assert snippet["hdr"] == {"method": "hdr", **doc["params"]["tuned"]}
    # the best so far is the best of the sets scored: never worse than the paper's, the first
    assert doc["objective"]["tuned"] <= doc["objective"]["baseline"]


@pytest.mark.parametrize(
    "workers",
    [
        pytest.param([], id="one process"),
        pytest.param(["--workers", "2"], id="cluster", marks=SLOW),
    ],
)
@pytest.mark.slow
def test_tune_refuses_test_drives_that_are_training_drives(
    fleet: Path, tmp_path: Path, workers: list[str]
) -> None:
    from hdrd.io.files.drivelog import read_drive
    from hdrd.io.files.parquetlog import write_parquet_drive

    train = sorted(fleet.glob("*.csv"))[:3]
    held = tmp_path / "held"
    held.mkdir()
    (held / "renamed.csv").write_bytes(train[1].read_bytes())  # the same file, another name
    write_parquet_drive(held / "as-parquet.parquet", read_drive(train[2]))  # another format
    write_drive(held / "new.csv", simulate_drive("rural", 3.0, 999))  # truly held out
    args = ["tune", *map(str, train), "--candidates", "20", "--no-progress", *workers]
    p = hdrd(*args, "--test", str(held))
    assert p.returncode == 1, p.stderr
    assert p.stderr.splitlines() == [
        "hdrd tune: error: 2 of the 3 test drives are training drives too (the same data): "
        f"as-parquet (training drive {train[2].stem}), renamed (training drive "
        f"{train[1].stem}); a test drive must be held out of the training"
    ]
    p = hdrd(*args, "--test", *map(str, train))  # the same set
    assert p.returncode == 1 and "3 of the 3 test drives are training drives too" in p.stderr
    p = hdrd(*args, "--test", str(held / "new.csv"))
    assert p.returncode == 0, p.stderr


def _stand(path: Path, seed: int = 1) -> None:
    write_drive(path, simulate_drive("standstill", 1.0, seed))


@pytest.mark.slow
def test_output_files_are_checked_before_the_work(fleet: Path, tmp_path: Path) -> None:
    drive = str(sorted(fleet.glob("*.csv"))[0])
    long = "y" * 240
    cases = [
        (["evaluate", drive, "--plot", str(tmp_path / "out.txt")], "matplotlib cannot write .txt"),
        (["evaluate", drive, "--plot", str(tmp_path / f"{long}{long}.png")], "bytes"),
        (["evaluate", drive, "--json", str(tmp_path / f"{long}.json")], "at most 231 can be"),
        (["evaluate", drive, "--json", f"{drive}/x.json"], "is not a directory"),
        (["evaluate", drive, "--json", str(tmp_path)], "is a directory"),
        (["tune", drive, "--out", str(tmp_path / f"{long}.yaml")], "at most 231 can be"),
    ]
    for args, why in cases:
        p = hdrd(*args)
        assert p.returncode == 1 and p.stdout == "", p.stderr
        (line,) = p.stderr.splitlines()
        assert line.startswith(f"hdrd {args[0]}: error: {args[2]} ") and why in line, line
    stand = tmp_path / "stand.csv"
    _stand(stand)
    p = hdrd("gap", str(stand), "--standstill", "--report", str(tmp_path / f"{long}.json"))
    assert p.returncode == 1 and p.stdout == "", p.stderr
    assert p.stderr.startswith("hdrd gap: --report ") and "at most 231" in p.stderr


@pytest.mark.slow
def test_a_drive_named_like_tex_is_plotted_as_text(fleet: Path, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    src = sorted(fleet.glob("*.csv"))[0]
    named = tmp_path / "$x^$ and $\\frac{a}{0}$.csv"
    named.write_bytes(src.read_bytes())
    out = tmp_path / "plot.png"
    p = hdrd("evaluate", str(named), "--plot", str(out))
    assert p.returncode == 0, p.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
@pytest.mark.parametrize("first", ["a", "a.yaml/b"])
def test_gap_models_whose_names_are_each_others_folders(tmp_path: Path, first: str) -> None:
    pytest.importorskip("scipy")
    (tmp_path / "sub" / "a.yaml").mkdir(parents=True)
    _stand(tmp_path / "sub" / "a.yaml" / "b.csv", 1)
    _stand(tmp_path / "a.csv", 2)
    _stand(tmp_path / "y.csv", 3)
    given = {"a": str(tmp_path / "a.csv"), "a.yaml/b": str(tmp_path / "sub")}
    out = tmp_path / "models"
    order = [given[first], given[next(k for k in given if k != first)]]
    p = hdrd("gap", *order, str(tmp_path / "y.csv"), "--standstill", "--out", str(out),
             "--no-progress")  # fmt: skip
    assert p.returncode == 0, p.stderr
    if first == "a":
        assert (out / "a.yaml").is_file() and not (out / "a.yaml" / "b.yaml").exists()
        assert "skipped a.yaml/b: its model would be " in p.stderr
        assert "inside drive a's model file" in p.stderr
    else:
        assert (out / "a.yaml" / "b.yaml").is_file()
        assert "skipped a: its model would be " in p.stderr
        assert "a folder of drive a.yaml/b's model" in p.stderr
    assert (out / "y.yaml").is_file()
    assert "fleet: 2 drives analysed, 1 skipped" in p.stdout


@pytest.mark.slow
def test_a_config_file_given_as_a_drive_is_refused(fleet: Path, tmp_path: Path) -> None:
    cfg = tmp_path / "tuned.yaml"
    cfg.write_text("hdr:\n  method: hdr\n")
    p = hdrd("evaluate", str(fleet), str(cfg))
    assert p.returncode == 1 and p.stdout == ""
    assert p.stderr.splitlines() == [
        f"hdrd evaluate: error: {cfg}: a YAML file, not a drive log (.csv, .parquet); did you "
        f"mean --config {cfg}?"
    ]
    p = hdrd("gap", str(cfg))
    assert p.returncode == 1 and f"did you mean --model {cfg}?" in p.stderr
    p = hdrd("tune", str(fleet), "--test", str(cfg))
    assert p.returncode == 1 and "a YAML file, not a drive log (.csv, .parquet)" in p.stderr


@pytest.mark.slow
def test_a_drive_named_twice_is_scored_once(fleet: Path, tmp_path: Path) -> None:
    one = sorted(fleet.glob("*.csv"))[0]
    p = hdrd("evaluate", str(one), str(one), "--json", str(tmp_path / "twice.json"))
    assert p.returncode == 0, p.stderr
    assert p.stderr.splitlines() == [
        f"hdrd evaluate: warning: {one.stem}: named more than once; taken once"
    ]
    assert [d["name"] for d in json.loads((tmp_path / "twice.json").read_text())["drives"]] == [
        one.stem
    ]
    p = hdrd("evaluate", str(fleet), str(one), "--no-progress")  # in the folder, and by name
    assert p.returncode == 0 and "fleet: 40 drives evaluated" in p.stdout
    assert "named more than once" in p.stderr


def _lower_privileges() -> list[str]:
    """A command prefix under which a folder without permissions cannot be read, as root too
    (root without the capabilities that pass over file permissions)."""
    if os.geteuid() != 0:
        return []
    import shutil

    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("root, and no setpriv to give up reading every folder")
    return [setpriv, "--inh-caps=-all", "--bounding-set=-dac_override,-dac_read_search"]


@pytest.mark.slow
def test_what_a_fleet_scan_cannot_read_is_said(fleet: Path, tmp_path: Path) -> None:
    src = sorted(fleet.glob("*.csv"))
    scan = tmp_path / "scan"
    (scan / "locked").mkdir(parents=True)
    for f in src[:2]:
        (scan / f.name).write_bytes(f.read_bytes())
    (scan / "locked" / "hidden.csv").write_bytes(src[2].read_bytes())
    os.mkfifo(scan / "fifo.csv")
    (scan / "gone.csv").symlink_to(tmp_path / "nowhere.csv")
    (scan / "locked").chmod(0)
    try:
        cmd = [*_lower_privileges(), sys.executable, "-m", "hdrd", "evaluate", str(scan)]
        run = lambda *extra: subprocess.run(  # noqa: E731
            [*cmd, *extra], capture_output=True, text=True, env=ENV, timeout=300,
            stdin=subprocess.DEVNULL,
        )  # fmt: skip
        p = run()
        assert p.returncode == 0, p.stderr
        assert sorted(p.stderr.splitlines()) == [
            f"hdrd evaluate: warning: {scan}/fifo.csv: is a FIFO, not a drive log file",
            f"hdrd evaluate: warning: {scan}/gone.csv: a symbolic link to nothing",
            f"hdrd evaluate: warning: {scan}/locked: a folder that cannot be read "
            "(Permission denied)",
        ]
        assert "mean (2)" in p.stdout
        p = run("--strict")
        assert p.returncode == 1 and p.stdout == ""
        (line,) = p.stderr.splitlines()
        assert line.startswith(f"hdrd evaluate: error: {scan}/")
    finally:
        (scan / "locked").chmod(0o755)
    p = hdrd("evaluate", str(scan / "fifo.csv"))  # named: an error, never a wait for a writer
    assert p.returncode == 1
    assert p.stderr.splitlines() == [
        f"hdrd evaluate: error: {scan}/fifo.csv: is a FIFO, not a drive log file"
    ]


@pytest.mark.slow
def test_evaluate_refuses_a_bias_run_and_replay_refuse(fleet: Path) -> None:
    drive = str(sorted(fleet.glob("*.csv"))[0])
    for value in ("5", "nan", "-inf"):
        p = hdrd("evaluate", drive, f"--bias={value}")
        assert p.returncode == 78 and p.stdout == ""
        assert p.stderr.splitlines()[-1].startswith(
            "hdrd evaluate: config error in command line: --bias = "
        )
        assert "must be a finite number within +/-3 deg/s (calibration.max_bias_dps)" in p.stderr
    assert hdrd("evaluate", drive, "--bias", "0.01").returncode == 0


def test_evaluate_help_gives_every_default() -> None:
    p = hdrd("evaluate", "--help")
    text = " ".join(p.stdout.split())
    assert "--bias DPS static bias, deg/s (default: each drive's own)" in text
    assert "--json FILE write the table as JSON (default: none)" in text
    for flag in ("--plot", "--outages"):
        option = text.split(f" {flag} ")[1].split(" --")[0]
        assert option.endswith("(default: none)") or "default: none)" in option, option


@pytest.mark.slow
def test_little_work_stays_in_this_process(fleet: Path) -> None:
    from hdrd.analysis.fleet_jobs import WORK_S_PER_BYTE, estimated_work_s
    from hdrd.io.files.drivefiles import find_drives

    refs = find_drives([str(fleet)])
    size = sum(Path(r.path).stat().st_size for r in refs)
    assert estimated_work_s(refs) == pytest.approx(WORK_S_PER_BYTE * size)
    env = {k: v for k, v in ENV.items() if k != "HDRD_FLEET_MIN_WORK_S"}
    code = (
        "import sys; from hdrd.cli import main; rc = main(sys.argv[1:]); "
        "print('dask imported' if 'distributed' in sys.modules else 'no dask', file=sys.stderr); "
        "sys.exit(rc)"
    )
    args = ["evaluate", str(fleet), "--workers", "2", "--no-progress"]
    p = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                       env=env, timeout=300)  # fmt: skip
    assert p.returncode == 0, p.stderr
    note, last = p.stderr.splitlines()
    assert note.startswith("hdrd evaluate: note: about ") and "run in this process" in note
    assert last == "no dask"
    assert p.stdout == hdrd("evaluate", str(fleet), "--no-progress").stdout
    env["HDRD_FLEET_MIN_WORK_S"] = "-1"
    p = subprocess.run([sys.executable, "-m", "hdrd", *args], capture_output=True, text=True,
                       env=env, timeout=300)  # fmt: skip
    assert p.returncode == 1 and "HDRD_FLEET_MIN_WORK_S='-1': give seconds" in p.stderr
