#!/usr/bin/env python3
"""Fleet: what a local Dask cluster costs and buys, end to end (``hdrd evaluate DIR`` in one
process against ``--workers 2``), where its overhead goes, and, on 1,000 simulated drives of
10 minutes, the work per drive on 1 and 2 workers, worker memory, tune, and the time projected
for 100,000 drives (docs/fleet.md).

    python bench/fleet.py [--repeat 3] [--only ratios|library] [--drives 1000] [--minutes 10]
                          [--candidates 2000] [--memory-drives 100] [--skip-tune]
                          [--no-write] [--force]

End to end (``--only ratios``): two fleets of CSV drive logs (a mix of city, suburbs, rural,
highway and mixed, seeds 1..N, CRS03 grade at 10 Hz; made once under /tmp/hdrd-bench, not
timed): 300 drives of 20 minutes (about 160 MB) and 60 drives of 12 minutes (about 20 MB).
Each command is run ``--repeat`` times, the one-process and cluster runs alternating, each as a
user runs it (a new process: imports, the cluster's start and stop counted); the best and the
median wall time of each, their ratio, and the load average at each run. The 60-drive fleet is
below the work at which ``--workers`` starts a cluster (``MIN_CLUSTER_WORK_S``), so it is also
run with ``HDRD_FLEET_MIN_WORK_S=0``: what the cluster would have cost. Every cluster run's
output must be the one-process output, byte for byte. Where the overhead goes: the CPU of the
client (this process: imports, scheduler, the drives it evaluates while the cluster starts),
of the workers and of the fork server, on the 300-drive fleet, against one process's.

Targets: ``--workers 2`` >= 1.7x faster than one process on the 300-drive fleet; never slower
than one process on the 60-drive one (as run). On 1,000 drives (``--only library``): 2 workers
>= 1.8x faster than 1; worker memory flat from 100 to 1,000 drives.

This machine has 2 cores shared with other sessions, and Linux shares the CPU between sessions
(autogroups), not processes: while another session is busy, two workers share one session's
half and the cluster cannot be faster. The best of several runs is the figure closest to an
idle machine; the load averages say how busy it was. Below a 1-minute load average of 0.3 at
the start it replaces its section of bench/RESULTS.md (Speed), above it only with ``--force``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import REPO, hdrd_command, machine, machine_line, write_section

TARGET_SPEEDUP = 1.8
TARGET_OVERHEAD = 0.05
MAX_LOAD = 0.3
KINDS = ("city", "suburbs", "rural", "highway", "mixed")
DATA = Path("/tmp/hdrd-bench")
TITLE = "Fleet (Dask): one process against local workers"


def make_fleet(n: int, minutes: float) -> Path:
    """The dataset of n drives (made once; a marker file says it is complete)."""
    from hdrd.io.files.parquetlog import write_dataset_drive
    from hdrd.sim.drive import simulate_drive

    root = DATA / f"fleet-{n}-{minutes:g}"
    done = root / "COMPLETE"
    if done.exists():
        return root
    t0 = time.perf_counter()
    for i in range(n):
        kind = KINDS[i % len(KINDS)]
        write_dataset_drive(root, simulate_drive(kind, minutes, i + 1), f"{kind}-{i + 1:06d}")
    done.write_text(str(n))
    print(f"wrote {n} drives to {root} in {time.perf_counter() - t0:.0f} s", flush=True)
    return root


def noop(i: int) -> int:
    return i


def _drain(it: Iterator[Any]) -> list[Any]:
    return list(it)


def timed(fn: Callable[[], Any]) -> tuple[float, float, Any]:
    """(wall s, CPU s of this process, result)."""
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return time.perf_counter() - w, time.process_time() - c, out


def worker_memory(runner: Any) -> list[tuple[float, float]]:
    """(peak RSS, RSS) of each worker process, MB."""

    def mem() -> tuple[float, float]:
        status = Path("/proc/self/status").read_text().splitlines()
        kb = {ln.split(":")[0]: float(ln.split()[1]) for ln in status if ln.startswith("Vm")}
        return kb["VmHWM"] / 1024, kb["VmRSS"] / 1024

    return sorted(runner.client.run(mem).values())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs of each end-to-end command")
    ap.add_argument("--only", choices=("ratios", "library"), help="one part only")
    ap.add_argument("--drives", type=int, default=1000)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--candidates", type=int, default=2000)
    ap.add_argument("--memory-drives", type=int, default=100)
    ap.add_argument("--skip-tune", action="store_true")
    ap.add_argument("--no-write", action="store_true", help="print only")
    ap.add_argument("--force", action="store_true", help=f"write even at a load >= {MAX_LOAD}")
    a = ap.parse_args(argv)
    m = machine()
    load1 = float(os.getloadavg()[0])
    print(machine_line(m), flush=True)
    if load1 >= MAX_LOAD:
        print(f"load average {load1:.2f} >= {MAX_LOAD}: the speed figures mean little", flush=True)
    lines: list[str] = []

    def say(s: str = "") -> None:
        print(s, flush=True)
        lines.append(s)

    if a.only != "library":
        end_to_end(a.repeat, say)
        where_it_goes(say)
    if a.only != "ratios":
        say()
        library(a, say)
    cmd = "python bench/fleet.py " + " ".join(argv if argv is not None else sys.argv[1:])
    body = f"{machine_line(m)}\n\nCommand: `{cmd.strip()}`\n\n" + "\n".join(lines)
    if a.no_write:
        return 0
    if load1 >= MAX_LOAD and not a.force:
        print(f"not written to RESULTS.md: load average {load1:.2f} >= {MAX_LOAD} (--force)")
        return 0
    write_section("speed", TITLE, body)
    return 0


# -- end to end: one process against --workers 2 -----------------------------------------------


def make_csv_fleet(n: int, minutes: float) -> Path:
    """n CSV drive logs of ``minutes`` (made once; a marker file says the fleet is complete)."""
    from hdrd.io.files.drivelog import write_drive
    from hdrd.sim.drive import simulate_drive

    root = DATA / f"fleet-csv-{n}-{minutes:g}"
    done = root / "COMPLETE"
    if done.exists():
        return root
    root.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        kind = KINDS[i % len(KINDS)]
        write_drive(root / f"{kind}-{i + 1:06d}.csv", simulate_drive(kind, minutes, i + 1))
    done.write_text(str(n))
    return root


def _run(args: list[str], env: dict[str, str]) -> tuple[float, float, str]:
    """(wall s, 1-minute load average at the start, stdout) of ``hdrd ARGS`` in a new
    process."""
    load = os.getloadavg()[0]
    t = time.perf_counter()
    p = subprocess.run([*hdrd_command(), *args], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t
    if p.returncode != 0:
        raise SystemExit(f"hdrd {' '.join(args)} failed ({p.returncode}): {p.stderr}")
    return wall, load, p.stdout


def end_to_end(repeat: int, say: Callable[..., None]) -> None:
    """The two fleets, one process against ``--workers 2``, ``repeat`` runs each, alternating."""
    import statistics

    say(
        "| fleet | how | runs, wall s (load average at the start) | best | median | one process / this, best (median) |"
    )
    say("|---|---|---|---|---|---|")
    plain = {**os.environ, "PYTHONPATH": str(REPO)}
    forced = {**plain, "HDRD_FLEET_MIN_WORK_S": "0"}
    for n, minutes in ((300, 20.0), (60, 12.0)):
        root = str(make_csv_fleet(n, minutes))
        size = sum(f.stat().st_size for f in Path(root).glob("*.csv")) / 1e6
        hows = [("one process", [], plain), ("--workers 2", ["--workers", "2"], plain)]
        if n == 60:
            hows.append(("--workers 2, cluster forced", ["--workers", "2"], forced))
        runs: dict[str, list[tuple[float, float]]] = {h: [] for h, _, _ in hows}
        want = None
        for _ in range(repeat):
            for how, extra, env in hows:
                wall, load, out = _run(["evaluate", root, "--no-progress", *extra], env)
                want = out if want is None else want
                assert out == want, f"{how}: output differs from one process"
                runs[how].append((wall, load))
        base = [w for w, _ in runs["one process"]]
        for how, _, _ in hows:
            walls = [w for w, _ in runs[how]]
            shown = ", ".join(f"{w:.2f} ({ld:.1f})" for w, ld in runs[how])
            vs = ""
            if how != "one process":
                vs = (
                    f"{min(base) / min(walls):.2f}x "
                    f"({statistics.median(base) / statistics.median(walls):.2f}x)"
                )
            say(
                f"| {n} x {minutes:g} min ({size:.0f} MB) | {how} | {shown} | {min(walls):.2f} | "
                f"{statistics.median(walls):.2f} | {vs} |"
            )


_LOCAL: list[float] = [0.0, 0.0]


def _counted(ref: Any, job: Any) -> Any:
    """evaluate_one, counting the drives (and their CPU) evaluated in this process."""
    from hdrd.analysis.fleet_jobs import evaluate_one

    t = time.thread_time()
    out = evaluate_one(ref, job)
    _LOCAL[0] += 1
    _LOCAL[1] += time.thread_time() - t
    return out


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def where_it_goes(say: Callable[..., None]) -> None:
    """CPU of one process against the client, workers and fork server of ``--workers 2``, on
    the 300-drive fleet, in a fresh process each (this script's imports not counted)."""
    root = str(make_csv_fleet(300, 20.0))
    here = str(Path(__file__).parent)
    code = (
        f"import json, sys; sys.path.insert(0, {here!r}); import fleet; "
        f"print(json.dumps(fleet.cpu_of({root!r}, int(sys.argv[1]))))"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO), "HDRD_FLEET_MIN_WORK_S": "0"}
    got = {}
    for n in (0, 2):
        p = subprocess.run(
            [sys.executable, "-c", code, str(n)], capture_output=True, text=True, env=env
        )
        if p.returncode != 0:
            raise SystemExit(p.stderr)
        got[n] = json.loads(p.stdout.splitlines()[-1])
    one, two = got[0], got[2]
    total = two["client"] + two["workers"] + two["forkserver"]
    per = one["client"] / 300
    say()
    say(
        f"Where the cluster's CPU goes (300 x 20 min, one run each, load {two['load']:.1f}): one "
        f"process {one['client']:.2f} s ({1000 * per:.1f} ms a drive, imports included); "
        f"--workers 2: client {two['client']:.2f} s (of which {two['local_drives']} drives "
        f"evaluated while the cluster started, {two['local_cpu']:.2f} s), workers "
        f"{two['workers']:.2f} s ({1000 * two['workers'] / (300 - two['local_drives']):.1f} ms "
        f"a drive, their start included), fork server {two['forkserver']:.2f} s; in all "
        f"{total:.2f} s, {total - one['client']:+.2f} s over one process "
        f"({100 * (total - one['client']) / one['client']:+.0f} %). On two cores that bounds "
        f"the speed-up at {2 * one['client'] / total:.2f}x."
    )


def cpu_of(root: str, workers: int) -> dict[str, Any]:
    """CPU seconds of evaluating ``root`` in this (fresh) process, or with ``workers``: this
    process's, the workers' (from their start), the fork server's."""
    from hdrd.analysis.fleet import DaskRunner, LocalRunner
    from hdrd.analysis.fleet_jobs import EvaluateJob, evaluate_refs
    from hdrd.io.files.drivefiles import find_drives

    refs = find_drives([root])
    if not workers:
        evaluate_refs(refs, EvaluateJob(), LocalRunner())
        return {"client": _cpu()}
    import psutil

    with DaskRunner.start(workers) as runner:  # as --workers starts it
        list(runner.map(_counted, refs, EvaluateJob()))
        done = sum(runner.client.run(_cpu).values())
        servers = [c for c in psutil.Process().children() if "forkserver" in " ".join(c.cmdline())]
        forkserver = sum(c.cpu_times().user + c.cpu_times().system for c in servers)
    return {
        "client": _cpu(),
        "workers": done,
        "forkserver": forkserver,
        "local_drives": int(_LOCAL[0]),
        "local_cpu": _LOCAL[1],
        "load": os.getloadavg()[0],
    }


# -- 1,000 drives, through the library ----------------------------------------------------------


def library(a: argparse.Namespace, say: Callable[..., None]) -> None:
    """The work per drive on 1 and 2 workers, memory, tune, the projection (module docstring)."""
    from hdrd.analysis.fleet_jobs import EvaluateJob
    from hdrd.io.files.drivefiles import find_drives

    root = make_fleet(a.drives, a.minutes)
    refs = find_drives([str(root)])
    assert len(refs) == a.drives, len(refs)
    job = EvaluateJob()
    w_local, want, reads = _one_process(a, refs, job, say)
    walls, speedup = _on_workers(refs, job, w_local, want, reads, say)
    _memory(a, refs, job, say)
    tune_walls = {} if a.skip_tune else _tune(a, refs, say)
    _projection(len(refs), walls, tune_walls, speedup, say)


def _one_process(
    a: argparse.Namespace, refs: list[Any], job: Any, say: Callable[..., None]
) -> tuple[float, str, tuple[float, float, int]]:
    """The work per drive in one process, and reading Parquet against CSV: the wall time (s),
    the results' JSON (for the workers' to match) and the reads (s per drive from Parquet, from
    CSV, of how many drives); says the evaluate table's head and first row."""
    from hdrd.analysis.evaluate import to_json
    from hdrd.analysis.fleet import LocalRunner, batches
    from hdrd.analysis.fleet_jobs import evaluate_refs
    from hdrd.io.files.drivelog import read_drive, write_drive

    n = len(refs)
    w_local, c_local, (res, skipped) = timed(lambda: evaluate_refs(refs, job, LocalRunner()))
    assert not skipped, skipped[:3]
    want = json.dumps(to_json(res))
    per = w_local / n
    sample = refs[: min(50, n)]
    csv_dir = DATA / "fleet-csv-sample"
    csv_dir.mkdir(parents=True, exist_ok=True)
    for r in sample:
        write_drive(csv_dir / f"{r.name}.csv", r.read())
    w_pq, _, _ = timed(lambda: [r.read() for r in sample])
    w_csv, _, _ = timed(lambda: [read_drive(csv_dir / f"{r.name}.csv") for r in sample])
    hours = sum(r.duration_min for r in res) / 60
    say(
        f"{n} drives of {a.minutes:g} min ({hours:.0f} h of driving), a Parquet dataset "
        f"partitioned by drive; {len(batches(n, 1))} tasks on 1 worker, {len(batches(n, 2))} "
        f"on 2 (guided: {len(batches(n, 2)[0])} drives in the first, 1 in the last)"
    )
    say()
    say("| evaluate | wall, s | per drive, ms | speed-up | overhead per drive |")
    say("|---|---|---|---|---|")
    say(f"| one process | {w_local:.2f} | {1000 * per:.2f} (CPU {1000 * c_local / n:.2f}) | | |")
    return w_local, want, (w_pq / len(sample), w_csv / len(sample), len(sample))


def _on_workers(
    refs: list[Any],
    job: Any,
    w_local: float,
    want: str,
    reads: tuple[float, float, int],
    say: Callable[..., None],
) -> tuple[dict[int, float], float]:
    """Evaluate on 1 and 2 workers, each result checked against one process's: the wall
    times (s) by workers and the speed-up of 2 over 1."""
    from hdrd.analysis.evaluate import to_json
    from hdrd.analysis.fleet import DaskRunner, batches
    from hdrd.analysis.fleet_jobs import evaluate_refs

    n = len(refs)
    walls: dict[int, float] = {}
    starts: dict[int, float] = {}
    per_task = 0.0
    for workers in (1, 2):
        s0 = time.perf_counter()
        with DaskRunner.open(workers=workers) as runner:
            starts[workers] = time.perf_counter() - s0
            w, _, (got, _) = timed(partial(evaluate_refs, refs, job, runner))
            if workers == 1:  # a task's round trip through the scheduler, doing nothing
                k = 300
                w_noop, _, _ = timed(partial(_drain, runner.map(noop, range(k), batch=1)))
                per_task = w_noop / k
        assert json.dumps(to_json(got)) == want, "results differ from one process"
        walls[workers] = w
    over = (walls[1] - w_local) / w_local
    speedup = walls[1] / walls[2]
    say(
        f"| 1 worker | {walls[1]:.2f} | {1000 * walls[1] / n:.2f} | | "
        f"{1000 * (walls[1] - w_local) / n:+.2f} ms ({100 * over:+.1f} %) |"
    )
    say(f"| 2 workers | {walls[2]:.2f} | {1000 * walls[2] / n:.2f} | {speedup:.2f}x | |")
    say()
    say(
        f"Read per drive: Parquet {1000 * reads[0]:.1f} ms, CSV "
        f"{1000 * reads[1]:.1f} ms (the same {reads[2]} drives). A local cluster "
        f"starts in {starts[1]:.1f} s (1 worker), {starts[2]:.1f} s (2), not counted above. "
        f"An empty task's round trip through the scheduler, one at a time in a window of "
        f"tasks in flight: {1000 * per_task:.2f} ms, i.e. "
        f"{1000 * per_task * len(batches(n, 1)) / n:.3f} ms per drive in {len(batches(n, 1))} "
        "tasks. "
        f"Targets: speed-up {speedup:.2f}x (>= {TARGET_SPEEDUP}x: "
        f"{'met' if speedup >= TARGET_SPEEDUP else 'NOT met'}); overhead {100 * over:.1f} % "
        f"(<= {100 * TARGET_OVERHEAD:.0f} %: {'met' if over <= TARGET_OVERHEAD else 'NOT met'})."
    )
    return walls, speedup


def _memory(a: argparse.Namespace, refs: list[Any], job: Any, say: Callable[..., None]) -> None:
    """Worker memory (MB) after ``--memory-drives`` and after all drives, and its growth."""
    from hdrd.analysis.fleet import DaskRunner
    from hdrd.analysis.fleet_jobs import evaluate_refs

    n = len(refs)
    mems: dict[int, list[tuple[float, float]]] = {}
    for k in sorted({min(a.memory_drives, n), n}):
        with DaskRunner.open(workers=2) as runner:
            idle = worker_memory(runner)
            list(evaluate_refs(refs[:k], job, runner)[0])
            mems[k] = worker_memory(runner)
        say()
        say(
            f"Worker memory after {k} drives (2 workers; peak / current RSS, MB): "
            + ", ".join(f"{p:.0f} / {r:.0f}" for p, r in mems[k])
            + f" (idle: {', '.join(f'{r:.0f}' for _, r in idle)})"
        )
    ks = sorted(mems)
    growth = max(p for p, _ in mems[ks[-1]]) / max(p for p, _ in mems[ks[0]])
    say(f"Peak worker RSS at {ks[-1]} / at {ks[0]} drives: {growth:.2f}x (flat: <= 1.10x).")
    say(
        f"Client (this process) peak RSS: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB."
    )


def _tune(a: argparse.Namespace, refs: list[Any], say: Callable[..., None]) -> dict[int, float]:
    """``tune`` in one process and on 1 and 2 workers, the same best set on each: the
    workers' wall times (s) by workers."""
    from hdrd.analysis.fleet import DaskRunner, LocalRunner
    from hdrd.analysis.fleet_jobs import tune_fleet

    n = len(refs)
    tune_walls: dict[int, float] = {}
    w_t, _, best = timed(lambda: tune_fleet(LocalRunner(), refs, (), a.candidates, 0))
    for workers in (1, 2):
        with DaskRunner.open(workers=workers) as runner:
            w, _, got_t = timed(partial(tune_fleet, runner, refs, (), a.candidates, 0))
            if workers == 2:
                tune_mem = worker_memory(runner)
        assert got_t.best == best.best and got_t.top == best.top, "tune differs"
        tune_walls[workers] = w
    t_over = (tune_walls[1] - w_t) / w_t
    say()
    say(f"| tune, {a.candidates} sets | wall, s | per drive, ms | speed-up | overhead |")
    say("|---|---|---|---|---|")
    say(f"| one process | {w_t:.1f} | {1000 * w_t / n:.1f} | | |")
    say(
        f"| 1 worker | {tune_walls[1]:.1f} | {1000 * tune_walls[1] / n:.1f} | | "
        f"{100 * t_over:+.1f} % |"
    )
    say(
        f"| 2 workers | {tune_walls[2]:.1f} | {1000 * tune_walls[2] / n:.1f} | "
        f"{tune_walls[1] / tune_walls[2]:.2f}x | |"
    )
    say()
    say(f"The same best parameters on every runner: {best.best}.")
    say(
        "Worker memory after the tune (2 workers; peak / current RSS, MB): "
        + ", ".join(f"{p:.0f} / {r:.0f}" for p, r in tune_mem)
        + f": the prepared drives stay on the workers for the search's rounds "
        f"(about {n / 2:.0f} drives each)."
    )
    return tune_walls


def _projection(
    n: int,
    walls: dict[int, float],
    tune_walls: dict[int, float],
    speedup: float,
    say: Callable[..., None],
) -> None:
    """The time for 100,000 drives on N workers, from one worker's time per drive and the
    efficiency at 2."""
    from hdrd.analysis.fleet import batches

    eff = speedup / 2
    say()
    say(
        "Projected for 100,000 drives of this length on N workers (a core each): the time per "
        f"drive on one worker ({1000 * walls[1] / n:.2f} ms evaluate"
        + (f", {1000 * tune_walls[1] / n:.1f} ms tune" if tune_walls else "")
        + f") x 100,000 / (N x {eff:.2f}, the efficiency measured at 2 workers), the cluster's "
        "start-up apart; reading from shared storage instead of a local disk is not counted. "
        f"The scheduler is no limit there: 100,000 drives on 128 workers are "
        f"{len(batches(100_000, 128))} tasks."
    )
    say()
    head = "| N | evaluate |" + (" tune |" if tune_walls else "")
    say(head)
    say("|---|---|" + ("---|" if tune_walls else ""))
    for workers in (1, 2, 8, 32, 128):
        ev = 1e5 * walls[1] / n / (workers * (eff if workers > 1 else 1.0))
        row = f"| {workers} | {_dur(ev)} |"
        if tune_walls:
            tu = 1e5 * tune_walls[1] / n / (workers * (eff if workers > 1 else 1.0))
            row += f" {_dur(tu)} |"
        say(row)


def _dur(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.0f} min" if s < 7200 else f"{s / 3600:.1f} h"


if __name__ == "__main__":
    raise SystemExit(main())
