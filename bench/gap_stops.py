#!/usr/bin/env python3
"""Model gap on simulated drives whose only truth is a GPS course, empty at the stops: a bias
while moving, an ADC its noise does not dither at rest, neither; over eight drive seeds each
(the figures behind tests/test_gap_stops.py's tolerances).

    python bench/gap_stops.py [--seeds 8] [--no-write]

Takes about 15 minutes. The drives are tests/test_gap_stops.py's ``gps_drive`` (12 minutes of
city driving at 10 Hz, the 1 Hz GPS course the only truth, the speed and the start-up
standstill as the simulator writes them); the seeds are 11..10+N (the tests use 3-6). Cases:

- a motion offset of 0.05-0.1 deg/s (both signs): named, within 25 %;
- the undithered quantizer of ``UNDITHERED`` (0.573 deg/s codes, a noise of 0.06 step): the
  step named within 10 %, no motion offset named;
- neither: nothing named;
- ``span_drive``'s unit and twin: an INS rate only while moving beside 0.01 rad/s codes, with
  and without -0.085 deg/s while driving.

Writes its section of bench/RESULTS.md (Model gap).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import machine_line, write_section

from hdrd.analysis.gap import run_gap
from hdrd.sim.effects import Effect, MotionOffset
from tests.gap_standins import span_drive
from tests.test_gap_stops import STEP_DPS, UNDITHERED, gps_drive

OFFSETS = (0.05, -0.06, 0.07, -0.08, 0.09, -0.1, 0.06, -0.05)
"""The hidden motion offsets, deg/s, one per seed (cycled)."""


def twin_case(kind: str, seed: int) -> tuple[bool, str, float, float]:
    """:func:`case` for tests/test_gap_stops.py's ``span_drive``: the unit (-0.085 deg/s while
    driving: the step, the offset within 25 %, the gap down >= 30 %) or its twin (no offset
    named)."""
    res = run_gap(span_drive(seed, -0.085 if kind == "unit" else 0.0))
    names = [s.effect for s in res.steps]
    got = next((s.params["offset_dps"] for s in res.steps if s.effect == "motion_offset"), None)
    if kind == "unit":
        ok = got is not None and abs(got / -0.085 - 1.0) <= 0.25 and "quantization" in names
        ok = ok and res.final_sim.gap <= 0.7 * res.initial_sim.gap
    else:
        ok = got is None and "quantization" in names
    shown = (" -> ".join(names) or "nothing") + (f" ({got:+.4f})" if got is not None else "")
    return ok, shown, res.initial_sim.gap, res.final_sim.gap


def case(kind: str, seed: int, j: int) -> tuple[bool, str, float, float]:
    """(target met, what was named with its figure, gap initial, gap final)."""
    if kind in ("unit", "twin"):
        return twin_case(kind, seed)
    hidden: tuple[Effect, ...] = ()
    if kind == "motion_offset":
        hidden = (MotionOffset(offset_dps=OFFSETS[j % len(OFFSETS)]),)
    elif kind == "quantization":
        hidden = UNDITHERED
    res = run_gap(gps_drive(seed, hidden))
    names = [s.effect for s in res.steps]
    ok, figure = _judged(kind, j, res.steps, names)
    shown = (" -> ".join(names) or "nothing") + figure
    return ok, shown, res.initial_sim.gap, res.final_sim.gap


def _judged(kind: str, j: int, steps: Any, names: list[str]) -> tuple[bool, str]:
    """Whether ``hdrd gap`` found what was hidden (the offset within 25 %, the ADC step within
    10 % and no offset beside it; nothing at all when nothing was), and the figure it named."""
    if kind == "motion_offset":
        true = OFFSETS[j % len(OFFSETS)]
        got = next((s.params["offset_dps"] for s in steps if s.effect == kind), None)
        ok = got is not None and abs(got / true - 1.0) <= 0.25
        return ok, f" ({got if got is None else f'{got:+.4f}'} of {true:+.2f})"
    if kind == "quantization":
        got = next((s.params["step_dps"] for s in steps if s.effect == kind), None)
        ok = got is not None and abs(got / STEP_DPS - 1.0) <= 0.10
        ok = ok and "motion_offset" not in names
        return ok, f" (step {got if got is None else f'{got:.4g}'})"
    return not names, ""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--no-write", action="store_true", help="print only")
    a = ap.parse_args(argv)
    print(machine_line(), flush=True)
    lines = [
        f"Command: `python bench/gap_stops.py --seeds {a.seeds}`. " + machine_line(),
        "",
        "Drives: tests/test_gap_stops.py's `gps_drive` (12 min of city at 10 Hz, the 1 Hz GPS "
        "course, empty below 2 m/s, the only truth; the stops and the start-up standstill "
        f"truth by the speed), seeds 11-{10 + a.seeds}. Targets: a motion offset named within "
        "25 %; the undithered 0.573 deg/s quantizer named within 10 % and no motion offset; "
        "neither: nothing named. `unit` / `twin`: `span_drive`, an INS rate given only while "
        "moving (9 decimals) beside 0.01 rad/s codes (7 decimals), 78 % of the rows at rest "
        "exactly 0, with -0.085 deg/s while driving (target: the step, the offset within 25 %, "
        "the gap down >= 30 %) or without (target: the step, no motion offset).",
        "",
        "| hidden | seed | named | gap initial -> final | target met | s |",
        "|---|---|---|---|---|---|",
    ]
    met: dict[str, int] = {}
    for kind in ("motion_offset", "quantization", "nothing", "unit", "twin"):
        for j in range(a.seeds):
            seed = 11 + j
            t0 = time.perf_counter()
            ok, shown, g0, g1 = case(kind, seed, j)
            met[kind] = met.get(kind, 0) + ok
            lines.append(
                f"| {kind} | {seed} | {shown} | {g0:.3g} -> {g1:.3g} | {'yes' if ok else 'NO'} "
                f"| {time.perf_counter() - t0:.0f} |"
            )
            print(lines[-1], flush=True)
    lines += ["", "Targets met: " + ", ".join(f"{k} {v} of {a.seeds}" for k, v in met.items())]
    text = "\n".join(lines)
    print(text)
    if not a.no_write:
        write_section("gap", "Model gap: stops as truth on GPS-course drives", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
