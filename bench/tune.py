#!/usr/bin/env python3
"""Tune: seconds for 10,000 HDR parameter sets over the nine-drive simulated benchmark.

    python bench/tune.py [--candidates 10000] [--repeats 3] [--seed 0] [--no-write]

Takes about 30 s. The nine training drives of :mod:`hdrd.sim.benchmark` (4.45 h, generated
in memory at 10 Hz, not timed) are prepared (block means, truth; timed) and searched by
:func:`hdrd.analysis.tune.tune` with ``--candidates`` parameter sets (random search, then
refinement; every set scored on all nine drives by :func:`hdrd.core.hdr.run_many`, the winner and
the paper's set re-run with the scalar stepper). Best and median of ``--repeats`` runs, wall and
CPU time; a profile split from one more run (scoring vs the rest).

Target: <= 30 s. Prints the figures and writes its section of bench/RESULTS.md (Speed).
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import machine_line, ratio, time_in_process, write_section

TARGET_S = 30.0


def _profile(run: Callable[[], object]) -> tuple[dict[str, float], float]:
    """One more run under cProfile: the cumulative seconds of the functions that matter
    (``run_many``, ``e_psi``, ...), and the profiled total (s)."""
    prof = cProfile.Profile()
    prof.runcall(run)
    st = pstats.Stats(prof)
    total = max(st.total_tt, 1e-9)  # type: ignore[attr-defined]
    by_name: dict[str, float] = {}
    for (file, _, name), (_, _, _, cum, _) in st.stats.items():  # type: ignore[attr-defined]
        for key in ("run_many", "e_psi", "prepare_drive", "evaluate_prepared"):
            if name == key and file.replace("\\", "/").split("/")[-2:][0] in ("hdrd", "analysis"):
                by_name[key] = by_name.get(key, 0.0) + cum
    return by_name, total


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--candidates", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-write", action="store_true", help="print only; do not write RESULTS.md")
    a = ap.parse_args(argv)
    print(machine_line(), flush=True)

    from hdrd.analysis.evaluate import prepare_drive
    from hdrd.analysis.tune import tune
    from hdrd.sim.benchmark import generate_all

    logs = generate_all("train")
    hours = sum(float(d.t[-1] - d.t[0]) for d in logs) / 3600

    def run() -> object:
        prepared = [prepare_drive(d) for d in logs]
        return tune(prepared, (), a.candidates, a.seed)

    t, result = time_in_process(run, a.repeats)
    steps = sum(int(prepare_drive(d).steps.u.shape[0]) for d in logs)
    print(
        f"tune {a.candidates} sets: best {t.best_wall:.2f} s, median {t.median_wall:.2f} s, CPU {t.best_cpu:.2f} s",
        flush=True,
    )

    by_name, total = _profile(run)

    lines = [
        f"`python bench/tune.py --candidates {a.candidates} --repeats {a.repeats}` on {machine_line()}.",
        "",
        (
            f"`tune()` on the nine simulated training drives ({hours:.2f} h, {steps:,} steps of 1 s; "
            f"preparation included, generation not), {a.candidates:,} parameter sets, seed {a.seed}; "
            f"{result.n_evaluated:,} sets scored."
        ),
        "",
        "| | best wall | median wall | CPU | target | vs target |",
        "|---|---|---|---|---|---|",
        (
            f"| tune, {a.candidates:,} sets x 9 drives | {t.best_wall:.2f} s | {t.median_wall:.2f} s | "
            f"{t.best_cpu:.2f} s | <= {TARGET_S:g} s | {ratio(t.best_wall, TARGET_S, False)} |"
        ),
        "",
        "Where the time goes (cProfile of one more run, cumulative, share of the profiled total): "
        + ", ".join(
            f"`{k}` {100 * v / total:.0f} %"
            for k, v in sorted(by_name.items(), key=lambda kv: -kv[1])
        )
        + f". Rate: {a.candidates * steps / t.best_wall / 1e6:.1f} M parameter-set steps per second.",
    ]
    text = "\n".join(lines)
    title = "Tuning: `tune()` on the nine training drives"
    write_section("speed", title, text, write=not a.no_write)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
