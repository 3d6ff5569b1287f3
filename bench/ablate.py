#!/usr/bin/env python3
"""HDR+ and HDR ideas, one at a time, on the tuning data only (never the judging drives).

    python bench/ablate.py [--routes 2] [--no-write]

Sets (all *tuning*, fixed before any idea was tried):

- ``real``: the real tuning drives of bench/real.py (:data:`real.TUNING`) that ``hdrd
  evaluate`` can calibrate and that score at least 5 minutes, converted by
  ``tools/convert_real.py`` into ``/tmp/hdrd-real/real`` (run ``python bench/real.py
  --tuning-only`` once first); judging drives are skipped before they are read;
- simulated training routes (the nine training types, seeds ``spec.seed + 1000 j``, j =
  1..routes) of bench/grades.py's cases: ``crs03 T`` (CRS03-04, temperature given; ``crs03 no
  T`` withheld, the simulator's own roads), ``crs03 T
  curving`` (and a real-road-like curving road), ``crs03`` / ``phone`` / ``automotive`` /
  ``tactical`` / ``coarse`` (temperature withheld, curving road), ``cal. error`` (CRS03-04,
  curving road, a start-up calibration error and a driving offset);
- ``constant``: the nine training types on a gyro whose bias is a constant (white noise
  only), calibrated over 30 s, temperature withheld (tests/test_guardrails.py's drives).

Each variant is HDR+ as ``hdrd evaluate --method hdr+`` runs it, with one of its settings
(:func:`_common.plus_with`) changed in the context's base settings
(``MethodSetup.plus``; what :func:`hdrd.core.methods.plus_settings` then fits to each drive).
Printed: mean NEψ (deg/min) per set and how many drives are harmed (NEψ above 1.1 x bias
removal's and Eψ 0.5 deg above it). Rewrites its own section of bench/RESULTS.md (Accuracy:
simulated drives).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

import grades as G  # noqa: E402
import real as R  # noqa: E402
from _common import machine_line, plus_with, put_section  # noqa: E402

from hdrd.analysis.evaluate import DEFAULTS, method_yaw  # noqa: E402
from hdrd.analysis.metrics import e_psi  # noqa: E402
from hdrd.analysis.prepare import EvaluationError, PreparedDrive, prepare_drive  # noqa: E402
from hdrd.core.methods import MethodSetup  # noqa: E402
from hdrd.core.plusparams import PLUS_CORE  # noqa: E402
from hdrd.io.drivefiles import read_drive  # noqa: E402
from hdrd.sim.benchmark import TRAIN_DRIVES, generate  # noqa: E402
from hdrd.sim.gyro import GyroModel, StaticBias, WhiteNoise  # noqa: E402

SECTION = "## HDR+ ideas one at a time (tuning data only)"
REAL_DIR = Path("/tmp/hdrd-real/real")

Drives = list[tuple[str, PreparedDrive]]


def real_tuning() -> Drives:
    out: Drives = []
    for p in sorted(REAL_DIR.glob("*.csv")):
        if p.stem not in R.TUNING:  # the judging drives are not even read
            continue
        try:
            prep = prepare_drive(read_drive(p, p.stem))
        except EvaluationError:
            continue
        if prep.duration_min >= R.MIN_SCORED_MIN:
            out.append((p.stem, prep))
    return out


def sim_case(grade: str, case: str, routes: int, curving: bool = False) -> Drives:
    out: Drives = []
    for j in range(1, routes + 1):
        for s in TRAIN_DRIVES:
            spec = replace(s, seed=s.seed + 1000 * j)
            try:
                _, cases = G.case_drives(spec, grade)
            except EvaluationError:
                continue
            prep = cases[case][0]
            out.append((f"{spec.name}/{j}", G.curvy(prep, spec.seed) if curving else prep))
    return out


def constant_bias() -> Drives:
    model = GyroModel((StaticBias(0.2), WhiteNoise(0.02)))
    out: Drives = []
    for s in TRAIN_DRIVES:
        log = generate(replace(s, minutes=min(s.minutes, 20.0)), hz=10.0, model=model)
        prep = prepare_drive(log, calibrate_seconds=30.0)
        out.append((s.name, replace(prep, steps=replace(prep.steps, temp_c=None))))
    return out


def sets(routes: int) -> dict[str, Callable[[], Drives]]:
    curving = "withheld, curving road"
    return {
        "real": real_tuning,
        "crs03 T": lambda: sim_case("crs03", "given", routes),
        "crs03 no T": lambda: sim_case("crs03", "withheld", routes),
        "crs03 T curving": lambda: sim_case("crs03", "given", routes, curving=True),
        "crs03": lambda: sim_case("crs03", curving, routes),
        "phone": lambda: sim_case("phone", curving, routes),
        "automotive": lambda: sim_case("automotive", curving, routes),
        "tactical": lambda: sim_case("tactical", curving, routes),
        "coarse": lambda: sim_case("coarse", curving, routes),
        "cal. error": lambda: sim_case("crs03", "curving, calibration error", routes),
        "constant": constant_bias,
    }


def base() -> MethodSetup:
    return DEFAULTS


def with_plus(**kw: object) -> MethodSetup:
    """HDR+ as it ships with some settings overridden (:func:`_common.plus_with`)."""
    return replace(DEFAULTS, plus=plus_with(DEFAULTS.plus, **kw))


# Ideas measured and rejected here were deleted from hdrd/ (bench/RESULTS.md, "HDR+ ideas one
# at a time", names the commit that held them): a motion offset of the drifting filter, a
# "moved" second or third filter, the road's spread by speed.
VARIANTS: dict[str, tuple[str, Callable[[], MethodSetup]]] = {
    "today": ("HDR+ as it ships", base),
    "drift prior 0.1": ("a lower prior weight of 'drifting'", lambda: with_plus(drift_prior=0.1)),
    "no straight": ("no straight-driving measurements", lambda: with_plus(straight_r=0.0)),
    "straight r 0.01": (
        "straight-driving measurements trusted more",
        lambda: with_plus(straight_r=0.01),
    ),
    "straight r 0.01, q_drifting 3e-5": (
        "straight driving trusted more and a faster drifting bias",
        lambda: with_plus(q_drifting=3e-5, straight_r=0.01),
    ),
    "no increment": (
        "the HDR core's increment off (ic_alpha 0, i_c 0)",
        lambda: with_plus(hdr=replace(PLUS_CORE, i_c=0.0), ic_alpha=0.0),
    ),
    "road var /6": (
        "a straighter road model (road_var 0.0004)",
        lambda: with_plus(road_var=0.0004),
    ),
}


def ne(drives: Drives, method: str, ctx: MethodSetup) -> np.ndarray:
    return np.array(
        [
            e_psi(method_yaw(p, method, setup=ctx), p.truth, p.k, p.align_n) / p.duration_min
            for _, p in drives
        ]
    )


def harmed(v: np.ndarray, none: np.ndarray, drives: Drives) -> int:
    td = np.array([p.duration_min for _, p in drives])
    return int(np.sum((v > 1.1 * none) & ((v - none) * td > 0.5)))


def run(routes: int, names: Sequence[str]) -> str:
    rows = []
    head = "| set | drives | none | hdr | " + " | ".join(names) + " |"
    rows.append(head)
    rows.append("|---" * (4 + len(names)) + "|")
    ctxs = {n: VARIANTS[n][1]() for n in names}
    for sname, make in sets(routes).items():
        drives = make()
        if not drives:
            rows.append(f"| {sname} | 0 | – | – |" + " – |" * len(names))
            continue
        none = ne(drives, "none", DEFAULTS)
        hdr = ne(drives, "hdr", DEFAULTS)
        cells = []
        for n in names:
            v = ne(drives, "hdr+", ctxs[n])
            cells.append(f"{v.mean():.3f} ({harmed(v, none, drives)})")
        row = (
            f"| {sname} | {len(drives)} | {none.mean():.3f} | {hdr.mean():.3f} | "
            + " | ".join(cells)
            + " |"
        )
        print(row, flush=True)
        rows.append(row)
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--routes", type=int, default=2, help="simulated routes per training type")
    ap.add_argument("--no-write", action="store_true", help="print only")
    a = ap.parse_args(argv)
    if not any(REAL_DIR.glob("*.csv")):
        print(f"bench/ablate.py: no drives in {REAL_DIR}: run python bench/real.py --tuning-only "
              "first; the real set is left out", file=sys.stderr)  # fmt: skip
    names = list(VARIANTS)
    table = run(a.routes, names)
    legend = "\n".join(f"- *{n}*: {VARIANTS[n][0]}" for n in names)
    text = (
        f"{SECTION}\n\n{machine_line()}\n\nCommand: `python bench/ablate.py --routes {a.routes}`. "
        "Mean NEψ, deg/min, per set (in brackets: drives harmed, NEψ > 1.1 x bias removal's "
        "and Eψ 0.5° above it). Tuning data only: the real tuning drives and simulated "
        "training routes (the script's docstring); no judging drive is read.\n\n"
        f"{table}\n\n{legend}\n"
    )
    print(text)
    if not a.no_write:
        put_section("sim", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
