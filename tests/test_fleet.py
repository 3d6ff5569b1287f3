"""Fleets (docs/fleet.md): evaluate, tune and gap on many drives, in this process or on a real
Dask cluster of worker processes, with the same results bit for bit; a worker killed mid-run;
an existing cluster reached by its scheduler's address; the default path never imports Dask.

Every Dask cluster runs in a child process (the command line, or tests/fleet_cluster.py), so
that this process never holds Dask's threads and sockets.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdrd.analysis.evaluate import evaluate_logs, load_drives, to_json
from hdrd.analysis.fleet import MAX_BATCH, LocalRunner, batches
from hdrd.analysis.fleet_jobs import EvaluateJob, evaluate_refs, parameter_blocks, tune_fleet
from hdrd.analysis.tune import tune
from hdrd.cli import main as cli
from hdrd.io.files.drivefiles import find_drives
from hdrd.io.files.drivelog import write_drive
from hdrd.io.files.parquetlog import write_dataset_drive, write_parquet_drive
from hdrd.sim.drive import simulate_drive

ROOT = Path(__file__).resolve().parents[1]
# HDRD_FLEET_MIN_WORK_S=0: --workers starts its cluster however small the fleet (the rule that
# keeps small work in this process has its own test)
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "HDRD_FLEET_MIN_WORK_S": "0"}


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Five drives of two to three minutes in every format: CSV files, a Parquet file, a
    dataset partitioned by drive; one that cannot be evaluated (no truth heading)."""
    root = tmp_path_factory.mktemp("fleet")
    kinds = ["city", "rural", "suburbs", "highway", "mixed"]
    for i, kind in enumerate(kinds):
        log = simulate_drive(kind, 2.0 + 0.25 * i, 10 + i)
        if i < 2:
            write_drive(root / f"{kind}.csv", log)
        elif i == 2:
            write_parquet_drive(root / f"{kind}.parquet", log)
        else:
            write_dataset_drive(root / "ds", log, kind)
    blind = simulate_drive("city", 1.0, 99)
    write_drive(root / "zz_no_truth.csv", replace(blind, heading_truth=None))
    return root


def hdrd(*args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hdrd", *args],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


# -- in this process: the runner's contract, no Dask -------------------------------------------


@pytest.mark.slow
def test_the_default_path_does_not_import_dask(fleet: Path) -> None:
    two = [str(fleet / "city.csv"), str(fleet / "rural.csv")]
    code = (
        "import sys\n"
        "from hdrd.cli import main\n"
        f"rc = [main(['evaluate', *{two!r}]),\n"
        f"      main(['tune', *{two!r}, '--candidates', '20', '--no-progress']),\n"
        f"      main(['gap', *{two!r}, '--no-progress'])]\n"
        "heavy = sorted(m for m in sys.modules if m.split('.')[0] in "
        "('dask', 'distributed', 'pyarrow'))\n"
        "print('RC', rc, 'HEAVY', heavy)\n"
    )
    p = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=ENV, timeout=120
    )
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines()[-1] == "RC [0, 0, 0] HEAVY []"


def test_local_runner_gives_evaluate_logs_results(fleet: Path) -> None:
    refs = find_drives([str(fleet)])
    assert [r.name for r in refs] == [
        "city",
        "ds/highway",
        "ds/mixed",
        "rural",
        "suburbs",
        "zz_no_truth",
    ]
    job = EvaluateJob()
    got, skipped = evaluate_refs(refs, job, LocalRunner())
    want, skipped_want = evaluate_logs(load_drives([str(fleet)]))
    assert json.dumps(to_json(got)) == json.dumps(to_json(want))
    assert skipped == skipped_want and len(skipped) == 1 and "no truth heading" in skipped[0]
    assert all(r.t_end.shape == (0,) and r.heading == {} for r in got)  # slim results


@pytest.mark.parametrize("threads", [1, 8])
def test_tune_on_a_runner_is_tune_bit_for_bit(fleet: Path, threads: int) -> None:
    """The objective summed per drive, in parameter blocks (split further with 8 threads),
    is the single-process mean bit for bit: the same sets, objectives, best and rows."""
    refs = find_drives([str(fleet)])[:5]
    train, test = refs[:4], refs[4:]
    runner = LocalRunner()
    runner.threads = threads
    got = tune_fleet(runner, train, test, 300, 5)
    want = tune([r.read() for r in train], [r.read() for r in test], 300, 5)
    assert got.best == want.best and got.top == want.top
    assert got.objective_best == want.objective_best
    for split in ("train", "test"):
        for label in ("baseline", "tuned"):
            a = getattr(got, split)[label]
            b = getattr(want, split)[label]
            assert [(r.name, r.e_psi, r.ne_psi) for r in a] == [
                (r.name, r.e_psi, r.ne_psi) for r in b
            ]


def test_parameter_blocks_never_hold_one_set_the_single_process_chunk_did_not() -> None:
    # numpy's mean over one set sums differently from its mean over several
    for n, chunk, n_batches, threads in [(700, 6990, 1, 8), (1401, 700, 2, 4), (33, 16, 1, 64)]:
        blocks = parameter_blocks(n, chunk, n_batches, threads)
        assert blocks[0][0] == 0 and blocks[-1][1] == n
        assert all(a < b and b == c for (a, b), (c, _) in zip(blocks, blocks[1:]))
        chunks = {(a // chunk) for a, _ in blocks}
        for a, b in blocks:
            assert b - a >= 2 or (b - a == 1 and n - a == 1 and n % chunk == 1)
        assert len(chunks) == -(-n // chunk)


def test_tasks_shrink_to_single_drives_at_the_end() -> None:
    for n, threads in [(1000, 2), (10**5, 100), (3, 2), (1, 1), (64 * 9, 1)]:
        parts = batches(n, threads)
        assert [i for r in parts for i in r] == list(range(n))  # every item once, in order
        sizes = [len(r) for r in parts]
        assert sizes == sorted(sizes, reverse=True) and max(sizes) <= MAX_BATCH
        assert sizes[-1] == 1  # the last tasks are single drives: the workers finish together
    assert len(batches(1000, 2)) < 150 and len(batches(10**5, 100)) < 100_000 / 20


def test_a_fleet_has_a_summary_and_a_distribution_plot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for i in range(14):
        write_parquet_drive(tmp_path / f"d{i:02}.parquet", simulate_drive("city", 1.0, 40 + i))
    png = tmp_path / "fleet.png"
    assert cli(["evaluate", str(tmp_path), "--plot", str(png), "--no-progress"]) == 0
    out = capsys.readouterr().out.splitlines()
    i = next(k for k, line in enumerate(out) if line.startswith("fleet: 14 drives evaluated"))
    assert out[i + 1].split()[:5] == ["NEpsi", "deg/min", "p10", "p50", "p90"]
    assert out[i + 2].split()[0] == "raw" and out[i + 3].split()[0] == "hdr"
    assert "worse than raw on" in out[i + 4]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


# -- a real cluster of worker processes -------------------------------------------------------


def _strip_seconds(path: Path) -> dict[str, Any]:
    doc = json.loads(path.read_text())
    doc.pop("seconds")
    return doc


@pytest.mark.slow
def test_evaluate_on_a_cluster_is_bit_identical(fleet: Path, tmp_path: Path) -> None:
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    one = hdrd("evaluate", str(fleet), "--method", "hdr+", "--json", str(a))
    two = hdrd("evaluate", str(fleet), "--method", "hdr+", "--json", str(b), "--workers", "2")
    assert one.returncode == 0 and two.returncode == 0, two.stderr
    assert a.read_bytes() == b.read_bytes()
    assert one.stdout == two.stdout
    said = [x for x in two.stderr.splitlines() if x.startswith("hdrd")]
    assert said[0] == "hdrd evaluate: note: about 0.0 s of work: on a local cluster of 2 workers"
    assert said[1].startswith("hdrd evaluate: skipped zz_no_truth: no truth heading")
    assert "evaluate 6 drives: 100.0%" in two.stderr  # progress, plain lines off a terminal


@pytest.mark.slow
def test_two_fleets_at_once_neither_collide_nor_warn(fleet: Path, tmp_path: Path) -> None:
    """Each local cluster's scheduler serves its HTTP routes on a free port of localhost: two
    runs at once on one machine (two users, two tests) both finish without a word of Dask's."""
    cmd = [sys.executable, "-m", "hdrd", "evaluate", str(fleet), "--workers", "1", "--json"]
    runs = [
        subprocess.Popen(
            [*cmd, str(tmp_path / f"{i}.json")],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=ENV,
            cwd=ROOT,
            stdin=subprocess.DEVNULL,
        )
        for i in range(2)
    ]
    outs = [p.communicate(timeout=600) for p in runs]
    for p, (_, err) in zip(runs, outs, strict=True):
        assert p.returncode == 0, err
        assert "already in use" not in err and "Warning" not in err, err
    assert (tmp_path / "0.json").read_bytes() == (tmp_path / "1.json").read_bytes()


@pytest.mark.slow
def test_tune_on_a_cluster_finds_the_same_parameters(fleet: Path, tmp_path: Path) -> None:
    drives = [str(p) for p in (fleet / "city.csv", fleet / "rural.csv", fleet / "ds")]
    test = str(fleet / "suburbs.parquet")
    out = {}
    for label, extra in (("one", []), ("two", ["--workers", "2"])):
        y, j = tmp_path / f"{label}.yaml", tmp_path / f"{label}.json"
        p = hdrd("tune", *drives, "--test", test, "--candidates", "400", "--seed", "3",
                 "--out", str(y), "--json", str(j), "--no-progress", *extra)  # fmt: skip
        assert p.returncode == 0, p.stderr
        out[label] = (y.read_bytes(), _strip_seconds(j))
    assert out["one"][0] == out["two"][0]
    assert json.dumps(out["one"][1]) == json.dumps(out["two"][1])


@pytest.mark.slow
def test_gap_on_a_cluster_writes_the_same_reports_and_models(fleet: Path, tmp_path: Path) -> None:
    drives = [str(fleet / "city.csv"), str(fleet / "suburbs.parquet")]
    runs = {}
    for label, extra in (("one", []), ("two", ["--workers", "2"])):
        rep, models = tmp_path / f"{label}.json", tmp_path / label
        p = hdrd(
            "gap", *drives, "--report", str(rep), "--out", str(models), "--no-progress", *extra
        )
        assert p.returncode == 0, p.stderr
        runs[label] = (
            p.stdout,
            rep.read_bytes(),
            {f.name: f.read_bytes() for f in models.iterdir()},
        )
    assert runs["one"] == runs["two"]
    doc = json.loads(runs["one"][1])
    assert [d["log"]["name"] for d in doc["drives"]] == ["city", "suburbs"]
    assert doc["skipped"] == [] and sorted(runs["one"][2]) == ["city.yaml", "suburbs.yaml"]
    assert runs["one"][0].splitlines()[-1].startswith("fleet: 2 drives analysed")


@pytest.mark.slow
def test_a_worker_killed_mid_task_is_retried_without_a_wrong_or_missing_result(
    fleet: Path, tmp_path: Path
) -> None:
    out = tmp_path / "kill.json"
    p = subprocess.run(
        [sys.executable, str(ROOT / "tests" / "fleet_cluster.py"), "kill", str(fleet), str(out)],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    killed_pid, first = doc["killed"].split()
    assert int(killed_pid) in doc["pids_before"] and int(killed_pid) not in doc["pids_after"]
    names = [r.name for r in find_drives([str(fleet)])]
    assert first in names  # the first task to start killed its worker mid-task...
    assert doc["tasks_run_twice"] >= 1  # ...the scheduler saw its tasks lost, and ran them again
    assert doc["names"] == names
    assert json.dumps(doc["fleet"]) == json.dumps(doc["local"])
    assert doc["fleet_skipped"] == doc["local_skipped"] and len(doc["local_skipped"]) == 1


@pytest.mark.slow
def test_a_drive_that_kills_every_worker_is_an_error_not_a_missing_row(
    fleet: Path, tmp_path: Path
) -> None:
    out = tmp_path / "always.json"
    p = subprocess.run(
        [sys.executable, str(ROOT / "tests" / "fleet_cluster.py"), "always", str(fleet), str(out)],
        capture_output=True, text=True, env=ENV, timeout=600,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    error = json.loads(out.read_text())["error"]
    # The drive named is rural, or one queued on the same worker when it died (Dask counts
    # the tasks a dying worker held against each of them).
    name, _, why = error.partition(": ")
    assert name in {r.name for r in find_drives([str(fleet)])}, error
    assert why.startswith("its workers died too often") and "\n" not in error


@pytest.mark.slow
def test_results_come_back_in_order_whatever_order_they_finish_in(tmp_path: Path) -> None:
    out = tmp_path / "order.json"
    p = subprocess.run(
        [sys.executable, str(ROOT / "tests" / "fleet_cluster.py"), "order", str(out)],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    assert doc["batch1"] == list(range(12)) and doc["batch5"] == list(range(12))
    # progress shows done only what is handed over (the task about to be, at most): a Ctrl-C
    # at "40 %" keeps 40 % of the work, not a part that finished out of order and is lost
    for batch in (1, 5):
        shown = doc[f"progress{batch}"]
        assert [d for d, _ in shown] == sorted(d for d, _ in shown) and shown[-1][0] == 12
        assert all(done - had <= batch for done, had in shown), shown


@pytest.mark.slow
def test_a_starting_cluster_and_this_process_share_the_items_in_order(tmp_path: Path) -> None:
    out = tmp_path / "hybrid.json"
    p = subprocess.run(
        [sys.executable, str(ROOT / "tests" / "fleet_cluster.py"), "hybrid", str(out)],
        capture_output=True, text=True, env=ENV, timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    assert [i for i, _ in doc["got"]] == list(range(120))
    assert {pid for _, pid in doc["got"]} <= {doc["client"], *doc["workers"]}
    assert len(doc["workers"]) == 2 and doc["client"] not in doc["workers"]


@pytest.fixture
def cluster() -> Iterator[str]:
    """A LocalCluster of two worker processes in a child process; its scheduler's address."""
    p = subprocess.Popen(
        [sys.executable, str(ROOT / "tests" / "fleet_cluster.py"), "serve", "2"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    assert p.stdin is not None and p.stdout is not None
    try:
        address = p.stdout.readline().strip()
        assert address.startswith("tcp://"), address
        yield address
    finally:
        p.stdin.close()
        try:
            assert p.wait(timeout=60) == 0
        finally:
            p.stdout.close()
            if p.poll() is None:
                p.kill()
                p.wait()


@pytest.mark.slow
def test_an_existing_cluster_by_its_scheduler_address(
    fleet: Path, tmp_path: Path, cluster: str
) -> None:
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    one = hdrd("evaluate", str(fleet), "--json", str(a))
    two = hdrd("evaluate", str(fleet), "--json", str(b), "--scheduler", cluster)
    assert one.returncode == 0 and two.returncode == 0, two.stderr
    assert a.read_bytes() == b.read_bytes() and one.stdout == two.stdout
    # a cluster that cannot load a task's code (another hdrd, or none): one line, no traceback
    p = subprocess.run(
        [sys.executable, str(ROOT / "tests" / "fleet_cluster.py"), "foreign", cluster],
        capture_output=True, text=True, env=ENV, timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    (line,) = p.stdout.splitlines()
    assert "the cluster cannot run hdrd's code" in line and "pip install 'hdrd[fleet]'" in line


@pytest.mark.slow
def test_cluster_errors_are_one_line(fleet: Path, tmp_path: Path) -> None:
    env = {**ENV, "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "2s"}
    p = subprocess.run(
        [sys.executable, "-m", "hdrd", "evaluate", str(fleet), "--scheduler", "tcp://127.0.0.1:9"],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert p.returncode == 1
    assert p.stderr.splitlines()[-1].startswith(
        "hdrd evaluate: error: cannot reach the Dask scheduler at tcp://127.0.0.1:9"
    )
    no_dask = (
        "import sys; sys.modules['distributed'] = None\n"
        "from hdrd.cli import main\n"
        f"sys.exit(main(['evaluate', {str(fleet)!r}, '--workers', '2']))\n"
    )
    p = subprocess.run([sys.executable, "-c", no_dask], capture_output=True, text=True, env=ENV)
    assert p.returncode == 1
    assert p.stderr.splitlines() == [
        "hdrd evaluate: error: --workers and --scheduler need Dask: pip install 'hdrd[fleet]'"
    ]
    assert hdrd("evaluate", str(fleet), "--workers", "0").returncode == 2
    bad = tmp_path / "bad.csv"
    bad.write_text("t,omega\n0,1\n0,2\n")
    p = hdrd("evaluate", str(fleet / "city.csv"), str(bad), "--workers", "2")
    assert p.returncode == 0  # a drive that cannot be read is skipped, the others scored
    assert p.stderr.splitlines()[-1].startswith("hdrd evaluate: skipped ")
    assert "column t is not strictly increasing" in p.stderr.splitlines()[-1]
    p = hdrd("evaluate", str(fleet / "city.csv"), str(bad), "--workers", "2", "--strict")
    assert p.returncode == 1
    assert p.stderr.splitlines()[-1].startswith("hdrd evaluate: error: ")
    assert "column t is not strictly increasing" in p.stderr.splitlines()[-1]


def test_the_fleet_summary_counts_skipped_drives() -> None:
    from hdrd.analysis.evaluate import evaluate_drive
    from hdrd.analysis.fleet_jobs import slim
    from hdrd.analysis.fleet_report import fleet_summary

    r = slim(evaluate_drive(simulate_drive("city", 1.0, 7)))
    text = fleet_summary([r, r], skipped=1)
    assert text.splitlines()[0].startswith("fleet: 2 drives evaluated, 1 skipped")
    assert np.isfinite(float(text.splitlines()[2].split()[1]))


def test_the_streamed_gap_report_is_the_json_of_the_whole(tmp_path: Path) -> None:
    from hdrd.analysis.gap.fleet import ReportStream

    reports: list[dict[str, Any]] = [
        {"log": {"name": "a"}, "steps": [{"effect": "x", "params": {"k": 1.5}}], "e": []},
        {"log": {"name": "b"}, "steps": [], "nested": {"deep": [1, {"z": None}]}},
    ]
    cases = [(reports, ["c: why"]), (reports[:1], []), ([], ["d: why"])]
    for i, (drives, skipped) in enumerate(cases):
        path = tmp_path / f"r{i}.json"
        with ReportStream(path) as stream:
            for d in drives:
                stream.add(d)
            assert not path.exists()  # not there until whole
            stream.finish(skipped)
        want = json.dumps({"drives": drives, "skipped": skipped}, indent=2) + "\n"
        assert path.read_text() == want
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r0.json", "r1.json", "r2.json"]


def test_the_gap_fleet_summary_orders_ties_by_name_whatever_the_arrival_order() -> None:
    from collections import Counter

    from hdrd.analysis.gap.fleet import gap_fleet_summary

    lines = {
        gap_fleet_summary(Counter(dict(order)), 2, 0)
        for order in (
            [("scale_factor", 2), ("quantization", 2), ("white_noise", 1)],
            [("quantization", 2), ("white_noise", 1), ("scale_factor", 2)],
        )
    }
    assert lines == {
        "fleet: 2 drives analysed; effects found: quantization in 2 (100 %), "
        "scale_factor in 2 (100 %), white_noise in 1 (50 %)"
    }
