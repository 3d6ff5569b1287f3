#!/usr/bin/env python3
"""HDR+ across gyro grades: none / paper HDR / HDR+ on simulated drives of every grade preset.

    python bench/grades.py [--routes 8] [--criterion 40] [--no-write]

For every grade of :mod:`hdrd.core.grades` (crs03, phone, automotive, tactical), drives of the
paper-like benchmark's types with that grade's gyro at its own sample rate
(``hdrd simulate --grade NAME``; each drive's turn-on bias drawn from its seed), calibrated
over their 30 s start-up standstill, scored with the temperature given (as ``hdrd simulate``
writes it), withheld (as on a real recording without a thermometer), and withheld on a
real-road-like curving road (:func:`curvy`):

- ``none`` (static bias removal), ``hdr`` (paper HDR, Table III), ``hdr+`` as ``hdrd evaluate
  --method hdr+`` runs it (fitted to the drive by :func:`hdrd.core.methods.plus_settings` from its
  calibration and the log's output step; the grade is *not* known), ``hdr+ (grade)`` with the
  grade's error model given (``gyro.grade``, as a daemon configured with it), and
  *oracle*: the gyro's true error smoothed over 121 s (centred) removed, known only in
  simulation, a bound on what knowing the bias buys.
- Sets, fixed before any result (seeds ``spec.seed + 1000 j``): *tuning* = the nine training
  types, j = 1..4 (the routes HDR+'s design was measured on); *judging* = the five test
  types, j = 60..(59 + routes), never used before; *criterion* = the five test types,
  j = 100..(99 + criterion), for the per-type rule "no drive type worse than paper HDR by
  more than 10 %" (a type's mean over that many held-out routes) and the share of single
  drives more than 10 % worse than HDR, HDR+ against the oracle.

Rewrites its own section of bench/RESULTS.md (Accuracy: simulated drives).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from _common import fmt, machine_line, oracle_yaw, put_section, share_worse, type_means

from hdrd.analysis.evaluate import (
    DEFAULTS,
    EvaluationError,
    PreparedDrive,
    method_yaw,
    prepare_drive,
)
from hdrd.analysis.metrics import e_psi
from hdrd.core.grades import GRADES, Grade
from hdrd.core.gyronoise import GyroNoise, grade_noise
from hdrd.core.methods import MethodSetup
from hdrd.io.files.drivelog import DriveLog
from hdrd.sim.benchmark import TEST_DRIVES, TRAIN_DRIVES, DriveSpec, generate
from hdrd.sim.effects import StaticBias, WhiteNoise
from hdrd.sim.grades import grade_model

SECTION = "## HDR+ across gyro grades (simulated; held-out routes)"
CALIBRATE_S = 30.0
METHODS = ("none", "hdr", "hdr (grade)", "hdr+", "hdr+ (grade)", "oracle")


ROAD_SD_DPS = 0.05
ROAD_TAU_S = 120.0
"""The *real-road* variant of a drive: a gentle road curvature, a Gauss-Markov yaw rate of
this sd (deg/s) and correlation time (s) while moving, added to the truth and the gyro alike.
The simulator's roads are straighter than real ones: on the real tuning drives the mean true
rate of the straight-driving windows HDR+ learns from is 0.025 deg/s (sd over drives), on the
simulator's 0.006; with this curvature 0.022 (measured on the tactical grade's tuning routes)."""

CAL_ERROR_SD_DPS = 0.015
"""The *calibration error* case: after the start-up calibration the bias is off by a constant
drawn from N(0, this), deg/s, at stops and while driving alike (a warm gyro, an engine started
after the calibration; on real drives the best constant bias in hindsight differs from the
calibrated one by 0.01-0.02 deg/s) ..."""
MOVE_OFFSET_SD_DPS = 0.007
"""... and, while moving only, by a further constant from N(0, this), deg/s (vibration and
g-sensitivity: a stop reads a little differently from the driving bias)."""

COARSE_STEP_DPS = 0.244
"""The *coarse ADC* pseudo-grade: the automotive grade's gyro behind a 0.244 deg/s output step
(the Toyota CAN yaw rate), quiet at rest (white noise :data:`COARSE_WHITE`, 0.018 deg/s per
sample at 80 Hz, far below half a step: a standstill reads one code) ..."""
COARSE_WHITE = 0.002
"""... deg/s/sqrt(Hz); vibration while moving dithers the codes (:data:`COARSE_VIBRATION_DPS`
per sample), so driving averages to the true bias ..."""
COARSE_VIBRATION_DPS = 0.25
"""... deg/s per sample; and a turn-on bias of 0.03-0.09 deg/s (random sign), without a
temperature coefficient, that every standstill (the start-up calibration too) reads as 0: the
drive then drifts by it."""


def curvy(prep: PreparedDrive, seed: int) -> PreparedDrive:
    """The drive on a real-road-like curving road (:data:`ROAD_SD_DPS`): the same gyro errors,
    a truth and a gyro that both turn by the added curvature (none while standing)."""
    s = prep.steps
    n = s.u.shape[0]
    rng = np.random.default_rng([seed, 0x726F6164])  # "road"
    a = math.exp(-s.T / ROAD_TAU_S)
    kicks = np.asarray(rng.normal(0.0, ROAD_SD_DPS * math.sqrt(1.0 - a * a), size=n)).tolist()
    g = np.empty(n)
    x = float(rng.normal(0.0, ROAD_SD_DPS))
    for i in range(n):
        x = a * x + kicks[i]
        g[i] = x
    g = np.where(_moving(prep), g, 0.0)
    truth = np.mod(prep.truth - np.cumsum(g * s.T), 360.0)
    return replace(prep, steps=replace(s, u=s.u + g), truth=truth)


def _moving(prep: PreparedDrive) -> np.ndarray:
    s = prep.steps
    if s.speed is None:
        return np.ones(s.u.shape[0], bool)
    return np.isfinite(s.speed) & (s.speed > 0.3)


def calibration_error(prep: PreparedDrive, seed: int) -> tuple[PreparedDrive, np.ndarray]:
    """The drive with a start-up calibration error (:data:`CAL_ERROR_SD_DPS`) and a driving
    offset (:data:`MOVE_OFFSET_SD_DPS`) added to every step's rate; and that error per step,
    deg/s (for the oracle)."""
    rng = np.random.default_rng([seed, 0x63616C])  # "cal"
    d_all = float(rng.normal(0.0, CAL_ERROR_SD_DPS))
    d_move = float(rng.normal(0.0, MOVE_OFFSET_SD_DPS))
    err = d_all + np.where(_moving(prep), d_move, 0.0)
    s = prep.steps
    return replace(prep, steps=replace(s, u=s.u + err)), err


def coarse_log(spec: DriveSpec) -> DriveLog:
    """A drive of the *coarse ADC* pseudo-grade (:data:`COARSE_STEP_DPS`)."""
    g = Grade.from_table("automotive")
    rng = np.random.default_rng([spec.seed, 0x636F61])  # "coa"
    bias = float(rng.uniform(0.03, 0.09)) * (1.0 if rng.uniform() < 0.5 else -1.0)
    model = grade_model("automotive", spec.seed).without("quantization")
    model = model.with_effect(StaticBias(bias)).with_effect(WhiteNoise(COARSE_WHITE))
    model = model.without("temperature_bias")  # a standstill reads 0 at any cabin temperature
    log = generate(spec, hz=g.rate_hz, model=model)
    assert log.speed is not None
    moving = np.isfinite(log.speed) & (log.speed > 0.3)
    vib = rng.normal(0.0, COARSE_VIBRATION_DPS, size=log.omega.shape[0])
    raw = log.omega + np.where(moving, vib, 0.0)
    q = COARSE_STEP_DPS
    meta = dict(log.meta, coarse_bias_dps=f"{bias:.6f}")
    return replace(log, omega=q * np.round(raw / q), meta=meta)


GRADE_ROWS: tuple[str, ...] = (*GRADES, "coarse")
"""The grades of the tables: every preset and the coarse-ADC pseudo-grade."""


def noise_of(grade: str) -> GyroNoise:
    """The error model a daemon configured for this gyro would be given (``gyro.grade``)."""
    if grade == "coarse":
        g = grade_noise("automotive")
        return replace(
            g, white_dps_per_rthz=COARSE_WHITE, temp_coeff_dps_per_c=0.0, source="grade coarse"
        )
    return grade_noise(grade)


def log_of(spec: DriveSpec, grade: str) -> DriveLog:
    if grade == "coarse":
        return coarse_log(spec)
    g = Grade.from_table(grade)
    return generate(spec, hz=g.rate_hz, model=grade_model(grade, spec.seed))


CASES = ("given", "withheld", "withheld, curving road", "curving, calibration error")
"""The temperature given / withheld / withheld on a real-road-like curving road / that and a
start-up calibration error with a driving offset."""


def case_drives(
    spec: DriveSpec, grade: str
) -> tuple[DriveLog, dict[str, tuple[PreparedDrive, np.ndarray]]]:
    """The drive's log and, per case, its prepared drive and the error added to its steps
    (deg/s; zeros but for the calibration-error case)."""
    log = log_of(spec, grade)
    prep = prepare_drive(log, calibrate_seconds=CALIBRATE_S)
    s = prep.steps
    zero = np.zeros(s.u.shape[0])
    nt = replace(prep, steps=replace(s, temp_c=None))
    road = curvy(nt, spec.seed)
    cal, err = calibration_error(road, spec.seed)
    return log, {
        "given": (prep, zero),
        "withheld": (nt, zero),
        "withheld, curving road": (road, zero),
        "curving, calibration error": (cal, err),
    }


@dataclass(frozen=True)
class Scores:
    """Eψ (deg) of each method on one drive, per case (:data:`CASES`)."""

    name: str
    kind: str  # drive type
    td_min: float
    e: dict[str, dict[str, float]]  # case -> method -> Eψ


def with_noise(noise: GyroNoise) -> MethodSetup:
    """The default configuration with ``noise`` given as HDR+'s error model (as ``gyro.*``)."""
    return replace(DEFAULTS, given_noise=tuple(noise.to_dict().items()))


def method_scores(
    log: DriveLog, p: PreparedDrive, extra: np.ndarray, noise: GyroNoise
) -> dict[str, float]:
    def ep(yaw: np.ndarray) -> float:
        return float(e_psi(yaw, p.truth, p.k, p.align_n))

    return {
        "none": ep(method_yaw(p, "none")),
        "hdr": ep(method_yaw(p, "hdr")),
        "hdr+": ep(method_yaw(p, "hdr+")),
        "hdr (grade)": ep(method_yaw(p, "hdr", setup=with_noise(noise))),
        "hdr+ (grade)": ep(method_yaw(p, "hdr+", setup=with_noise(noise))),
        "oracle": ep(oracle_yaw(log, p, extra)),
    }


def score_drive(spec: DriveSpec, grade: str) -> Scores:
    log, cases = case_drives(spec, grade)
    noise = noise_of(grade)
    prep = cases["given"][0]
    e = {case: method_scores(log, p, extra, noise) for case, (p, extra) in cases.items()}
    return Scores(spec.name, spec.name, prep.duration_min, e)


def step_timing(prep: PreparedDrive, repeats: int = 3) -> tuple[float, float]:
    """CPU microseconds per step of HDR+'s two forms on one drive (best of ``repeats``):
    :func:`hdrd.core.hdrplus.step` looped, as the daemon runs it once per T, and
    :func:`hdrd.core.hdrplus.run_batch`, as evaluate runs it. Settings as evaluate fits them."""
    from hdrd.analysis.evaluate import method_settings
    from hdrd.core.hdrplus import INITIAL_PLUS_STATE, run_batch, step

    s = prep.steps
    p = method_settings(prep, "hdr+")
    inputs = [s.input(i) for i in range(s.u.shape[0])]
    best_step = best_batch = math.inf
    for _ in range(repeats):
        t0 = time.process_time()
        state = INITIAL_PLUS_STATE
        for inp in inputs:
            state, _ = step(state, inp, p)
        t1 = time.process_time()
        run_batch(s.u, s.omega_std, s.speed, s.temp_c, s.T, p)
        t2 = time.process_time()
        best_step, best_batch = min(best_step, t1 - t0), min(best_batch, t2 - t1)
    n = len(inputs)
    return 1e6 * best_step / n, 1e6 * best_batch / n


SKIPPED: list[str] = []
"""Drives whose start-up calibration failed (listed under the tables, not scored)."""


def drive_set(specs: Sequence[DriveSpec], js: range, grade: str) -> list[Scores]:
    out = []
    for j in js:
        for s in specs:
            spec = replace(s, seed=s.seed + 1000 * j)
            try:
                out.append(score_drive(spec, grade))
            except EvaluationError as e:  # as evaluate would: the drive is listed, not scored
                SKIPPED.append(f"{grade} {spec.name} seed {spec.seed}: {e}")
    return out


# -- summaries ----------------------------------------------------------------------------------


def _e(x: Scores, case: str) -> dict[str, float]:
    return x.e[case]


def ne(scores: Sequence[Scores], m: str, case: str) -> np.ndarray:
    return np.array([_e(x, case)[m] / x.td_min for x in scores])


def worse(scores: Sequence[Scores], m: str, ref: str, case: str) -> float:
    """Share of drives whose Eψ exceeds 1.1 x ref's by more than 0.5 deg."""
    a = np.array([_e(x, case)[m] for x in scores])
    b = np.array([_e(x, case)[ref] for x in scores])
    return float(np.mean((a > 1.1 * b) & (a - b > 0.5)))


def worse_than_hdr(scores: Sequence[Scores], m: str, case: str) -> float:
    """Share of drives whose NEψ exceeds 1.1 x paper HDR's (the single-drive criterion)."""
    return share_worse(ne(scores, m, case), ne(scores, "hdr", case))


def type_ratios(scores: Sequence[Scores], m: str, case: str) -> dict[str, float]:
    """Per drive type: mean NEψ of m / mean NEψ of paper HDR."""
    kinds = [x.kind for x in scores]
    mine, hdr = type_means(ne(scores, m, case), kinds), type_means(ne(scores, "hdr", case), kinds)
    return {k: mine[k] / hdr[k] for k in mine}


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
                + " | ".join(fmt(means[m]) for m in METHODS)
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

- **Never worse than bias removal on a grade's mean** (judging routes, held out): met in every
  grade and case. The closest is the tactical IMU with the temperature given: HDR+ / none 0.89
  (0.111 vs 0.124 deg/min); on the curving road 0.79 (0.098 vs 0.124). Single drives worse
  than bias removal by > 10 % and 0.5°: tactical 30 / 12 / 22 / 18 % (given / withheld /
  curving / calibration error), automotive 20 and 22 % on the two curving-road cases, the
  others 0-10 %.
- **Temperature given** (how `hdrd simulate` writes a drive): 1.70x below paper HDR on the
  CRS03-04 (0.192 vs 0.326), 1.26x on the phone, 1.36x automotive, 2.43x tactical, 1.53x
  coarse ADC. Per type only the phone's rural3 is worse than paper HDR by more than 10 %
  (1.11). Single drives > 1.1 x HDR: 20 / 35 / 20 / 9 / 22 % (CRS03-04 / phone / automotive /
  tactical / coarse), against 14 / 23 / 21 / 6 / 4 % for the oracle.
- **Temperature withheld** (a real recording), grade not known: the CRS03-04 is 0.89x of paper
  HDR, still worse (0.366 vs 0.326; the bank's first form of evidence had 0.491), the phone
  1.18x below it (0.254 vs 0.300; the first form 0.364); automotive 1.80x, tactical 3.27x,
  coarse 1.45x. Per type the CRS03-04 is still 2.90x and 3.39x worse than paper HDR on rural3
  and highway3 (the first form 4.41x and 4.13x), the phone 2.16x and 1.32x (3.14x and 2.49x):
  the test types whose cabin warms most (5 -> 21 and 8 -> 21 degC); the coarse ADC's rural3
  1.18x. On the tuning routes the CRS03-04 withheld is 0.467 vs 0.259 for paper HDR (the first
  form 0.676). With the grade known (`hdr+ (grade)`): CRS03-04 0.206, phone 0.278.
- **Curving road** (temperature withheld; and with a calibration error): paper HDR 0.58-0.64
  deg/min on every grade (it straightens the curves). HDR+ on the tactical IMU 0.098 (the
  first form 0.112), with the calibration error 0.208 vs 0.353 for bias removal (unchanged);
  the CRS03-04 1.19x / 1.15x below paper HDR (0.489, 0.511; the first form 1.03x / 1.00x), the
  phone 1.41x / 1.47x, automotive 1.18x / 1.13x, coarse 1.09x / 1.05x.
- **Against the targets**: never worse than bias removal on a grade's mean: met. On the
  CRS03-04 1.5x below paper HDR: met only with the temperature given (1.70x); without it 0.89x,
  on the curving road 1.19x, with a calibration error 1.15x.
- **What tuned what**: the bank's evidence (each filter's prediction of every straight step
  and stop) and `drift_prior` 0.3 were chosen on the tuning routes (the nine training types,
  j = 1..4, of every grade and the coarse ADC, in all four cases) and the real tuning drives;
  the judging and criterion routes were run once afterwards, the settings fixed.
"""


def _timing() -> str:
    """The speed of one HDR+ step, the daemon's and evaluate's, on the first test drive."""
    g0 = Grade.from_table("crs03")
    timing_prep = prepare_drive(
        generate(TEST_DRIVES[0], hz=g0.rate_hz, model=grade_model("crs03", 0)),
        calibrate_seconds=CALIBRATE_S,
    )
    us_step, us_batch = step_timing(timing_prep)
    timing = (
        f"Speed (CPU time, best of 3, on {TEST_DRIVES[0].name}: "
        f"{timing_prep.steps.u.shape[0]} steps): `hdrd.core.hdrplus.step` (the daemon's form, "
        f"composed of `hdrd.core.hdr.step` and `hdrd.core.standstill`'s functions) {us_step:.0f} µs per step, "
        f"`run_batch` (evaluate's, the same recursion inlined) {us_batch:.1f} µs per step. "
        "The daemon takes one step per second: either is far inside its budget."
    )
    return timing


def _section(
    a: argparse.Namespace,
    elapsed_s: float,
    tuning: str,
    judging: str,
    crit: str,
    skipped: str,
    timing: str,
) -> str:
    """The section: how the drives were made and scored, the three tables, the drives not
    scored, the speed and the discussion."""
    return f"""{SECTION}

Generated by `python bench/grades.py --routes {a.routes} --criterion {a.criterion}`
({machine_line()}; {elapsed_s:.0f} s). Drives of the benchmark's types with each grade's
gyro (`hdrd simulate --grade NAME`, docs/gyro-model.md) at the grade's rate, calibrated over
their 30 s start-up standstill; mean NEψ in deg/min. Each method exactly as `hdrd evaluate
--calibrate-seconds 30 --method hdr+` runs it (`method_yaw`): *hdr+* fitted to the drive by
`hdrd.core.methods.plus_settings` from its calibration and the log's output step (the grade is not
known); *hdr+ (grade)* with the grade's error model given (`gyro.grade` in the config, as a
configured daemon); *oracle*: the true gyro error (smoothed over 121 s) removed, simulation
only. Temperature *given* as the simulator writes it, *withheld* as on a real recording, or
withheld on a *curving road*: the same drive with a gentle road curvature added to truth and
gyro alike (a Gauss-Markov yaw rate of 0.05 deg/s, 120 s, while moving), so that the
straight-driving windows HDR+ learns from mislead it as much as on the real tuning drives
(0.022 vs 0.025 deg/s per drive; the simulator's own roads 0.006). Seeds `spec.seed + 1000 j`:
**tuning** = the nine training types, j = 1..4 (HDR+'s settings were chosen on these and on
the real tuning drives, docs/hdrplus.md); **judging** = the five test types, j =
60..{59 + a.routes}; **criterion** = the five test types, j = 100..{99 + a.criterion}.

Tuning routes:

{tuning}

Judging routes (held out):

{judging}

The per-type criterion (held out; a type's mean over {a.criterion} routes; "> 1.1 x HDR" counts
single drives whose NEψ exceeds 1.1 x paper HDR's):

{crit}

{skipped}

{timing}

{DISCUSSION.strip()}
"""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--routes", type=int, default=8, help="judging routes per test type")
    ap.add_argument("--criterion", type=int, default=40, help="criterion routes per test type")
    ap.add_argument("--grades", default=",".join(GRADE_ROWS), help="comma-separated grades")
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
    timing = _timing()
    print(timing)
    tuning = set_table(sets, "tuning")
    judging = set_table(sets, "judging")
    crit = criterion_table(sets)
    print(tuning, judging, crit, sep="\n\n")
    skipped = (
        "Not scored (the start-up calibration refused the drive, as `hdrd evaluate` would): "
        + "; ".join(SKIPPED)
        if SKIPPED
        else "Every drive was scored."
    )
    print(skipped)
    section = _section(a, time.time() - t0, tuning, judging, crit, skipped, timing)
    if not a.no_write:
        put_section("sim", section)
        print(f"wrote {SECTION!r}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
