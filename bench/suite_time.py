#!/usr/bin/env python3
"""How long the test suite takes: the whole suite and the quick set, as README states them.

    python bench/suite_time.py [--no-write]

Runs, from the repository root, one after the other, the two commands README gives:
``python -m pytest -q`` (what ``.ci/run`` runs) and ``python -m pytest -m "not slow" -q``, each
as a process; measures its wall time and its CPU time (user + system of it and every process it
waited for: the pytest-xdist workers and the daemons the tests start), counts the tests that
passed, and notes the load average (1/5/15 min) before each run: on a shared machine the wall
time is the neighbours' as much as the suite's, and the load says how busy it was. Writes its
section of bench/RESULTS.md (Speed). About 10 minutes on this machine.
"""

from __future__ import annotations

import argparse
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

from _common import loadavg, machine_line, write_section

RUNS = (
    ("whole suite", ["-m", "pytest", "-q", "-p", "no:cacheprovider"]),
    ("quick set", ["-m", "pytest", "-m", "not slow", "-q", "-p", "no:cacheprovider"]),
)


def run(args: list[str]) -> dict[str, float | str]:
    """One pytest run as a process: wall s, CPU s (user + system, children), tests passed,
    the load before it, its exit status."""
    load = loadavg()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    p = subprocess.run(
        [sys.executable, *args], cwd=REPO, capture_output=True, text=True, check=False
    )
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    tail = p.stdout.strip().splitlines()[-1] if p.stdout.strip() else ""
    passed = re.search(r"(\d+) passed", tail)
    return {
        "wall": wall,
        "cpu": cpu,
        "passed": float(passed.group(1)) if passed else 0.0,
        "load": load,
        "rc": float(p.returncode),
        "tail": tail,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--no-write", action="store_true", help="print, leave RESULTS.md alone")
    a = ap.parse_args(argv)
    head = machine_line()
    rows = []
    for name, args in RUNS:
        r = run(args)
        shown = "python " + " ".join(x if " " not in x else f'"{x}"' for x in args)
        print(f"{name}: {r['tail']} ({r['wall']:.0f} s wall, {r['cpu']:.0f} s CPU)", flush=True)
        rows.append(
            f"| {name} | `{shown}` | {int(r['passed']):,} | {r['wall']:.0f} s "
            f"({float(r['wall']) / 60:.1f} min) | {r['cpu']:.0f} s | {r['load']} |"
            + ("" if r["rc"] == 0 else f" exit {int(r['rc'])}: {r['tail']} |")
        )
    body = (
        f"Command: `python bench/suite_time.py` ({head}). Each run a process from the "
        "repository root, one after the other; CPU: user + system of pytest and everything it "
        "waited for (its xdist workers, the daemons the tests run); load: the load average "
        "(1/5/15 min) just before the run. `-p no:cacheprovider` only keeps the tree clean.\n\n"
        "| run | command | tests passed | wall | CPU | load before |\n"
        "|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
    )
    print(write_section("speed", "Test suite time", body, write=not a.no_write))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
