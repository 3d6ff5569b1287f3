#!/usr/bin/env python3
"""The HDR kernel's cost: CPU microseconds per step of paper HDR (:func:`hdr.step` looped, as
the daemon runs it, and :func:`hdr.run_batch`, as replay and evaluate run it) and of HDR+
(:func:`hdrplus.run_batch`; and :func:`hdrplus.step` as the daemon runs it while aided, a
course every step and the self-check's virtual outages beside it), on two hours of 1 Hz
steps (seeded), best of 7.

    python bench/kernel.py [--vs CHECKOUT] [--no-write]

``--vs`` times an older checkout too (``git worktree add /tmp/old COMMIT``; the same script
run as a process with that checkout first on its path): the timing pair of one definition of
the kernel against the copies it replaced. Writes its section of
bench/RESULTS.md (Speed).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

try:  # the layered layout
    hdr = importlib.import_module("hdrd.core.hdr")
    hdrplus = importlib.import_module("hdrd.core.hdrplus")
except ImportError:  # an older, flat checkout (--vs)
    hdr = importlib.import_module("hdrd.hdr")
    hdrplus = importlib.import_module("hdrd.hdrplus")

STEPS = 7200
REPEATS = 7


def inputs() -> np.ndarray:
    """Two hours of 1 Hz block means, deg/s: straight driving with noise and turns."""
    rng = np.random.default_rng(7)
    u = rng.normal(0.0, 0.05, STEPS) + 0.02
    for start in rng.integers(0, STEPS - 20, 120):
        u[start : start + 10] += rng.choice([-9.0, 9.0])
    return u


def best(fn: Callable[[], object]) -> float:
    times = []
    for _ in range(REPEATS):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return 1e6 * min(times) / STEPS


def measure() -> dict[str, float]:
    u = inputs()
    p = hdr.HdrParams()

    def loop() -> None:
        s = hdr.INITIAL_STATE
        for x in u.tolist():
            s, _ = hdr.step(s, x, p)

    def plus_aided() -> None:
        # The daemon's aided step: a course every step, the self-check's virtual outages.
        from hdrd.core.selfcheck import SelfCheck
        from hdrd.core.steps import StepInput

        s, check = hdrplus.INITIAL_PLUS_STATE, SelfCheck()
        for i, x in enumerate(u.tolist()):
            inp = StepInput(x, 0.05, 15.0, float("nan"), 1.0, 0.1, 0.25, i == 0)
            before = s
            s, o = hdrplus.step(s, inp)
            check.on_step(before, inp, hdrplus.DEFAULTS, o.yaw, True)

    forms = {
        "hdr.step, looped": best(loop),
        "hdr.run_batch": best(lambda: hdr.run_batch(u, p)),
        "hdrplus.run_batch (speed, spread given)": best(
            lambda: hdrplus.run_batch(u, np.full(STEPS, 0.05), np.full(STEPS, 15.0), None, 1.0)
        ),
    }
    if hasattr(hdrplus, "DEFAULTS") and importlib.util.find_spec("hdrd.core.selfcheck"):
        forms["hdrplus.step, a course every step, with the self-check"] = best(plus_aided)
    return forms


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vs", metavar="CHECKOUT", help="an older checkout to time beside this one")
    ap.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--no-write", action="store_true")
    a = ap.parse_args(argv)
    now = measure()
    if a.json:
        print(json.dumps(now))
        return 0
    old: dict[str, float] = {}
    if a.vs:
        env = dict(os.environ, PYTHONPATH=str(Path(a.vs).resolve()))
        out = subprocess.run(
            [sys.executable, __file__, "--json"], env=env, capture_output=True, text=True,
            check=True,
        )  # fmt: skip
        old = json.loads(out.stdout)
    from _common import machine_line, write_section

    head = "| form | µs/step |" + (f" µs/step at `{a.vs}` | ratio |" if old else "")
    sep = "|---|---|" + ("---|---|" if old else "")
    lines = []
    for k, v in now.items():
        extra = f" {old[k]:.2f} | {v / old[k]:.2f} |" if k in old else (" – | – |" if old else "")
        lines.append(f"| {k} | {v:.2f} |{extra}")
    body = (
        f"{machine_line()}.\n\nCommand: `python bench/kernel.py"
        + (f" --vs {a.vs}" if old else "")
        + f"`. CPU microseconds per step, best of {REPEATS} runs over {STEPS} steps.\n\n"
        + "\n".join([head, sep, *lines])
    )
    print(write_section("speed", "HDR kernel: CPU time per step", body, write=not a.no_write))
    return 0


if __name__ == "__main__":
    sys.exit(main())
