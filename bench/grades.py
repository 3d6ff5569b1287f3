#!/usr/bin/env python3
"""HDR+ across gyro grades: none / paper HDR / HDR+ on simulated drives of every grade preset.

    python bench/grades.py [--routes 8] [--criterion 40] [--no-write]

For every grade of :mod:`hdrd.sim.grades` (crs03, phone, automotive, tactical), drives of the
paper-like benchmark's types with that grade's gyro at its own sample rate
(``hdrd simulate --grade NAME``; each drive's turn-on bias drawn from its seed), calibrated
over their 30 s start-up standstill, scored with the temperature given (as ``hdrd simulate``
writes it) and withheld (as on a real recording without a thermometer):

- ``none`` (static bias removal), ``hdr`` (paper HDR, Table III), ``hdr+`` as ``hdrd evaluate
  --method hdr+`` runs it once evaluate fits HDR+ to the drive (HdrPlusParams.fitted from the
  calibration window and the recording's output step; the grade is *not* known), ``hdr+
  (grade)`` with the grade's noise model given (as a daemon configured with it), and
  *oracle*: the gyro's true error smoothed over 121 s (centred) removed, known only in
  simulation, a bound on what knowing the bias buys.
- Sets, fixed before any result (seeds ``spec.seed + 1000 j``): *tuning* = the nine training
  types, j = 1..4 (the routes HDR+'s design was measured on); *judging* = the five test
  types, j = 60..(59 + routes), never used before; *criterion* = the five test types,
  j = 100..(99 + criterion), for the per-type rule "no drive type worse than paper HDR by
  more than 10 %" (a type's mean over that many held-out routes) and the share of single
  drives more than 10 % worse than HDR, HDR+ against the oracle.

Rewrites its own section of bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from _common import machine_line, replace_section

from hdrd.analysis.evaluate import PreparedDrive, method_yaw, prepare_drive
from hdrd.analysis.metrics import e_psi
from hdrd.drivelog import DriveLog
from hdrd.sim.benchmark import TEST_DRIVES, TRAIN_DRIVES, DriveSpec, generate
from hdrd.sim.grades import GRADES, Grade, grade_model, grade_noise

SECTION = "## HDR+ across gyro grades (simulated; held-out routes)"
CALIBRATE_S = 30.0
METHODS = ("none", "hdr", "hdr+", "hdr+ (grade)", "oracle")


ROAD_SD_DPS = 0.05
ROAD_TAU_S = 120.0
"""The *real-road* variant of a drive: a gentle road curvature, a Gauss-Markov yaw rate of
this sd (deg/s) and correlation time (s) while moving, added to the truth and the gyro alike.
The simulator's roads are straighter than real ones: on the real tuning drives the mean true
rate of the straight-driving windows HDR+ learns from is 0.025 deg/s (sd over drives), on the
simulator's 0.006; with this curvature 0.022 (measured on the tactical grade's tuning routes)."""


def curvy(prep: PreparedDrive, seed: int) -> PreparedDrive:
    """The drive on a real-road-like curving road (:data:`ROAD_SD_DPS`): the same gyro errors,
    a truth and a gyro that both turn by the added curvature (none while standing)."""
    s = prep.steps
    n = s.u.shape[0]
    rng = np.random.default_rng([seed, 0x726F6164])  # "road"
    a = math.exp(-s.T / ROAD_TAU_S)
    kicks = rng.normal(0.0, ROAD_SD_DPS * math.sqrt(1.0 - a * a), n)
    g = np.empty(n)
    x = rng.normal(0.0, ROAD_SD_DPS)
    for i in range(n):
        x = a * x + kicks[i]
        g[i] = x
    if s.speed is not None:
        g = np.where(np.isfinite(s.speed) & (s.speed > 0.3), g, 0.0)
    truth = np.mod(prep.truth - np.cumsum(g * s.T), 360.0)
    return replace(prep, steps=replace(s, u=s.u + g), truth=truth)


@dataclass(frozen=True)
class Scores:
    """Eψ (deg) of each method on one drive: temperature given, withheld, and withheld on a
    real-road-like curving road."""

    name: str
    kind: str  # drive type
    td_min: float
    e: dict[str, float]  # method -> Eψ, temperature given
    e_nt: dict[str, float]  # method -> Eψ, temperature withheld
    e_road: dict[str, float]  # method -> Eψ, temperature withheld, curving road


def oracle_yaw(log: DriveLog, prep: PreparedDrive, window_s: float = 121.0) -> np.ndarray:
    """Yaw with the gyro's true error (output minus the scaled true rate, smoothed over
    ``window_s`` centred) removed from every step: known in simulation only."""
    gain = 1.0
    for e in json.loads(log.meta.get("gyro_model", "[]")):
        if e.get("name") == "scale_factor":
            gain = 1.0 + float(e["error"])
    assert log.omega_truth is not None
    err = log.omega - gain * log.omega_truth
    t = log.t - log.t[0]
    T = prep.steps.T
    idx = np.floor(t / T + 1e-9).astype(np.int64)
    n_all = int(idx[-1]) + 1
    sums = np.bincount(idx, weights=err, minlength=n_all)
    counts = np.bincount(idx, minlength=n_all)
    step_err = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)
    k = max(1, int(round(window_s / T)))
    kernel = np.ones(k) / k
    smooth = np.convolve(step_err, kernel, mode="same")
    first = int(round(prep.start_s / T))
    corr = smooth[first : first + prep.steps.u.shape[0]] - prep.steps.bias_dps
    # u = raw - eps0 = true + err - eps0: removing (err - eps0) leaves the true rate.
    return np.cumsum((prep.steps.u - corr) * T)


def score_drive(spec: DriveSpec, grade: str) -> Scores:
    g = Grade.from_table(grade)
    log = generate(spec, hz=g.rate_hz, model=grade_model(grade, spec.seed))
    prep = prepare_drive(log, calibrate_seconds=CALIBRATE_S)
    s = prep.steps
    noise = grade_noise(grade)

    def methods(p: PreparedDrive) -> dict[str, float]:
        def ep(yaw: np.ndarray) -> float:
            return float(e_psi(yaw, p.truth, p.k))

        return {
            "none": ep(method_yaw(p, "none")),
            "hdr": ep(method_yaw(p, "hdr")),
            "hdr+": ep(method_yaw(p, "hdr+")),
            "hdr+ (grade)": ep(method_yaw(p, "hdr+", noise=noise)),
            "oracle": ep(oracle_yaw(log, p)),
        }

    nt = replace(prep, steps=replace(s, temp_c=None))
    return Scores(
        spec.name,
        spec.name,
        prep.duration_min,
        methods(prep),
        methods(nt),
        methods(curvy(nt, spec.seed)),
    )


def drive_set(specs: Sequence[DriveSpec], js: range, grade: str) -> list[Scores]:
    return [score_drive(replace(s, seed=s.seed + 1000 * j), grade) for j in js for s in specs]


# -- summaries ----------------------------------------------------------------------------------


CASES = ("given", "withheld", "withheld, curving road")
"""The temperature given / withheld / withheld on a real-road-like curving road."""


def _e(x: Scores, case: str) -> dict[str, float]:
    return {"given": x.e, "withheld": x.e_nt}.get(case, x.e_road)


def ne(scores: Sequence[Scores], m: str, case: str) -> np.ndarray:
    return np.array([_e(x, case)[m] / x.td_min for x in scores])


def worse(scores: Sequence[Scores], m: str, ref: str, case: str) -> float:
    """Share of drives whose Eψ exceeds 1.1 x ref's by more than 0.5 deg."""
    a = np.array([_e(x, case)[m] for x in scores])
    b = np.array([_e(x, case)[ref] for x in scores])
    return float(np.mean((a > 1.1 * b) & (a - b > 0.5)))


def worse_than_hdr(scores: Sequence[Scores], m: str, case: str) -> float:
    """Share of drives whose NEψ exceeds 1.1 x paper HDR's (the single-drive criterion)."""
    return float(np.mean(ne(scores, m, case) > 1.1 * ne(scores, "hdr", case)))


def type_ratios(scores: Sequence[Scores], m: str, case: str) -> dict[str, float]:
    """Per drive type: mean NEψ of m / mean NEψ of paper HDR."""
    out = {}
    for kind in dict.fromkeys(x.kind for x in scores):
        sub = [x for x in scores if x.kind == kind]
        out[kind] = float(np.mean(ne(sub, m, case)) / np.mean(ne(sub, "hdr", case)))
    return out


def f3(v: float) -> str:
    return f"{v:.3f}" if math.isfinite(v) else "–"


def set_table(sets: dict[str, dict[str, list[Scores]]], label: str) -> str:
    head = (
        "| grade | temperature | drives | "
        + " | ".join(f"NEψ {m}" for m in METHODS)
        + " | HDR+ / none | HDR / HDR+ | HDR+ drives worse than none (> 1.1x and +0.5°) |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for grade, by in sets.items():
        sc = by[label]
        for case in CASES:
            means = {m: float(np.mean(ne(sc, m, case))) for m in METHODS}
            lines.append(
                f"| {grade} | {case} | {len(sc)} | "
                + " | ".join(f3(means[m]) for m in METHODS)
                + f" | {means['hdr+'] / means['none']:.2f} | {means['hdr'] / means['hdr+']:.2f}x"
                + f" | {worse(sc, 'hdr+', 'none', case):.0%} |"
            )
    return "\n".join(lines)


def criterion_table(sets: dict[str, dict[str, list[Scores]]]) -> str:
    head = (
        "| grade | temperature | drives | worst type: HDR+ / HDR (type mean) | types > 1.1 | "
        "HDR+ drives > 1.1 x HDR | oracle drives > 1.1 x HDR | per type: HDR+ / HDR |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for grade, by in sets.items():
        sc = by["criterion"]
        for case in CASES:
            r = type_ratios(sc, "hdr+", case)
            worst = max(r, key=lambda k: r[k])
            lines.append(
                f"| {grade} | {case} | {len(sc)} | "
                f"{r[worst]:.2f} ({worst}) | {sum(v > 1.1 for v in r.values())} | "
                f"{worse_than_hdr(sc, 'hdr+', case):.0%} | {worse_than_hdr(sc, 'oracle', case):.0%} | "
                + ", ".join(f"{k} {v:.2f}" for k, v in r.items())
                + " |"
            )
    return "\n".join(lines)


DISCUSSION = """
**Reading** (written by hand from the run above; re-read the tables if the code changed).

- **Temperature given** (how `hdrd simulate` writes a drive, and how the paper-like benchmark is
  judged): on the held-out judging routes HDR+ is below static bias removal on every grade's
  mean — tactical IMU 0.106 vs 0.124 deg/min, the other grades 5-11x below — and 1.66x below
  paper HDR on the CRS03-04 (0.196 vs 0.326). Over 40 held-out routes of each test type no
  type is worse than paper HDR by more than 10 % on any grade (worst: phone, city3, 1.08). The
  share of single drives more than 10 % worse than paper HDR: 22 % / 34 % / 19 % / 10 %
  (CRS03-04 / phone / automotive / tactical) against 14 / 23 / 21 / 6 % for the oracle; a
  single drive against paper HDR stays partly luck. On the tactical grade HDR+ still makes a
  quarter to a third of the single drives worse than bias removal (by > 10 % and 0.5°): the
  default random walk with a temperature (1e-6) is far above this gyro's (2e-8); with the
  grade known (`hdr+ (grade)`) the mean drops to 0.079.
- **Temperature withheld, grade not known** (a real recording): HDR+ stays below bias
  removal on every grade's mean, but on the CRS03-04 and phone grades, whose warming cabin
  moves the bias 0.13-0.32 deg/s, it is slow to believe the drift (its online random walk
  rises at most 2.8x per window, to protect good gyros) and falls behind paper HDR (0.98x and
  0.72x; per type up to 1.9x and 2.3x worse). With the grade known it is 1.5x better than HDR.
- **What tuned what**: the tuning routes (and the real tuning drives, bench/real.py) chose
  every new setting; the judging and criterion routes were run once, with the settings fixed.
  Old HDR+ (fixed increment 0.0048, no standstill offset, fast random walk 4e-5 without a
  temperature) on the tuning routes with the temperature given, for comparison: CRS03-04
  0.164, phone 0.191, automotive 0.154, tactical 0.130 deg/min.
"""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--routes", type=int, default=8, help="judging routes per test type")
    ap.add_argument("--criterion", type=int, default=40, help="criterion routes per test type")
    ap.add_argument("--grades", default=",".join(GRADES), help="comma-separated grades")
    ap.add_argument("--no-write", action="store_true")
    a = ap.parse_args(argv)
    grades = [g for g in a.grades.split(",") if g]
    t0 = time.time()
    sets: dict[str, dict[str, list[Scores]]] = {}
    for grade in grades:
        sets[grade] = {
            "tuning": drive_set(TRAIN_DRIVES, range(1, 5), grade),
            "judging": drive_set(TEST_DRIVES, range(60, 60 + a.routes), grade),
            "criterion": drive_set(TEST_DRIVES, range(100, 100 + a.criterion), grade),
        }
        print(f"{grade}: {time.time() - t0:.0f} s", flush=True)
    tuning = set_table(sets, "tuning")
    judging = set_table(sets, "judging")
    crit = criterion_table(sets)
    print(tuning, judging, crit, sep="\n\n")
    section = f"""{SECTION}

Generated by `python bench/grades.py --routes {a.routes} --criterion {a.criterion}`
({machine_line()}; {time.time() - t0:.0f} s). Drives of the benchmark's types with each grade's
gyro (`hdrd simulate --grade NAME`, docs/gyro-model.md) at the grade's rate, calibrated over
their 30 s start-up standstill; mean NEψ in deg/min. *hdr+*: HDR+ fitted to the drive from its
calibration window and output step only (`HdrPlusParams.fitted`, as `hdrd evaluate` would; the
grade is not known); *hdr+ (grade)*: with the grade's noise model; *oracle*: the true gyro error
(smoothed over 121 s) removed, simulation only. Temperature *given* as the simulator writes it,
or *withheld* as on a real recording. Seeds `spec.seed + 1000 j`: **tuning** = the nine training
types, j = 1..4 (HDR+'s defaults were chosen on these and on the real tuning drives, see
docs/hdrplus.md); **judging** = the five test types, j = 60..{59 + a.routes}; **criterion** =
the five test types, j = 100..{99 + a.criterion} (never used before this run).

Tuning routes:

{tuning}

Judging routes (held out):

{judging}

The per-type criterion (held out; a type's mean over {a.criterion} routes; "> 1.1 x HDR" counts
single drives whose NEψ exceeds 1.1 x paper HDR's):

{crit}

{DISCUSSION.strip()}
"""
    if not a.no_write:
        replace_section(SECTION, section)
        print(f"wrote {SECTION!r}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
