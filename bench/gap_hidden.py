#!/usr/bin/env python3
"""Model gap on simulated drives with one hidden effect: the worst parameter error and the
gap ratio over eight gyro seeds, the figures behind tests/test_gap.py's tolerances.

    python bench/gap_hidden.py [--seeds 8] [--no-write]

Takes about 5 minutes. The drive, the hidden effects and their values are those of
tests/test_gap.py (docs/model-gap.md, "What the tests establish"); the seeds are 1..N.
Writes its section of bench/RESULTS.md (Model gap).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import machine_line, write_section

from hdrd.analysis.gap import run_gap
from hdrd.sim import DEFAULT_START_MODEL, simulate_drive
from hdrd.sim.effects import Saturation
from tests.test_gap import HIDDEN, measured, rail


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--no-write", action="store_true", help="print only")
    a = ap.parse_args(argv)
    print(machine_line(), flush=True)
    drive = simulate_drive("city", 10.0, 6, hz=5.0, model=DEFAULT_START_MODEL, lead_in_s=20.0)
    lines = [
        f"Command: `python bench/gap_hidden.py --seeds {a.seeds}`. " + machine_line(),
        "",
        "| hidden effect | value | named exactly it | worst error of the parameter | gap_final / gap_initial |",
        "|---|---|---|---|---|",
    ]
    for name, (effect, param, _tol) in HIDDEN.items():
        if effect is None:
            effect = Saturation(limit_dps=rail(drive))
        true = float(getattr(effect, param))
        worst, ratios, clean = 0.0, [], 0
        others: list[str] = []
        for seed in range(1, a.seeds + 1):
            res = run_gap(measured(drive, [effect], seed=seed))
            named = [s.effect for s in res.steps]
            if named == [name]:
                clean += 1
            got = res.final_model.get(name)
            if got is not None:
                worst = max(worst, abs(float(getattr(got, param)) / true - 1.0))
            else:
                others.append(f"seed {seed}: {' + '.join(named)}")
            ratios.append(res.final_sim.gap / res.initial_sim.gap)
        lines.append(
            f"| {name} `{param}` | {true:g} | {clean} of {a.seeds} | {100 * worst:.1f} % "
            f"(of the seeds that have it){''.join('; ' + o for o in others)} | "
            f"{min(ratios):.2f}-{max(ratios):.2f} |"
        )
        print(lines[-1], flush=True)
    text = "\n".join(lines)
    print(text)
    if not a.no_write:
        write_section("gap", "Model gap: one hidden effect on a simulated drive", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
