#!/usr/bin/env python3
"""HDR+ vs paper HDR on held-out drives, every idea's ablation, and the 1 s vs 30 s calibration.

    python bench/hdrplus.py [--workdir /tmp/hdrd-hdrplus] [--routes 12] [--no-write]
    python bench/hdrplus.py --tune 300 [--seed 0]     # the training-set search (no write)
    python bench/hdrplus.py --city-study train|held-out  # the city study's rows (no write)
    python bench/hdrplus.py --single-drive 40  # how often one drive is worse than paper HDR

1. As processes, the commands a user runs (listed in bench/RESULTS.md): ``hdrd simulate
   --benchmark train|test``, ``hdrd evaluate --method hdr+`` on both (the JSON has none, hdr
   and hdr+ side by side), ``python tools/convert_real.py all`` and ``hdrd evaluate --method
   hdr+`` on the two real recordings of ../shared/data/ (skipped, and said so, if absent).
2. In-process, on the same nine training and five test drives and on more routes of each drive
   type (``--routes`` per type; seeds ``spec.seed + 1000 j``, j = 1..routes): the ablation
   table, one row per idea (added to paper HDR, and taken out of HDR+), with speed and
   temperature withheld; the calibration study (a 1 s start-up calibration plus standstill
   re-calibration vs a 30 s one); the cost of a step.
3. Rewrites its own section of bench/RESULTS.md, leaving every other section as it is.

Honesty rules this script keeps: HDR+'s parameters were tuned on the nine training drives'
types only (``--tune`` repeats that search on them); the five test drives and the test-type
routes are evaluated, never searched. Eψ/NEψ are hdrd evaluate's (Eqs. 12, 13; truth at step
ends, aligned at the first step with truth).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from hdrd.analysis.evaluate import PreparedDrive, prepare_drive
from hdrd.analysis.metrics import align_index, e_psi
from hdrd.core.hdr import HdrParams
from hdrd.core.hdr import run_batch as hdr_batch
from hdrd.core.hdrplus import (
    INITIAL_PLUS_STATE,
    PLUS_CORE,
    HdrPlusParams,
    run_batch,
    step,
)
from hdrd.core.methods import SettingsContext, StepInputs, plus_settings
from hdrd.core.standstill import StandstillParams
from hdrd.core.steps import StepInput
from hdrd.io.drivelog import DriveLog
from hdrd.sim.benchmark import TEST_DRIVES, TRAIN_DRIVES, VARIANTS, DriveSpec, generate
from hdrd.sim.drive import simulate_legs
from hdrd.sim.gyro import ScaleFactor, crs03_default_model

RESULTS = REPO / "bench" / "RESULTS.md"
SECTION = "## Beyond the paper: HDR+ and standstill re-calibration (held-out)"
DATA = REPO.parent / "shared" / "data"
SMARTLOC_FIT_BIAS_DPS = 0.053  # as bench/tables.py: least-squares bias of the whole run
COMMA_ANDROID_BIAS_DPS = -3.9167  # Android's own estimate, in hdrd's CCW convention
PAPER = HdrParams()


# -- running the user's commands ------------------------------------------------------------


def run(cmd: list[str], log: list[str]) -> subprocess.CompletedProcess[str]:
    """Run a command from the repository root, record it, fail loudly if it fails."""
    shown = " ".join(shlex.quote(c) for c in cmd).replace(sys.executable, "python")
    print(f"$ {shown}", flush=True)
    log.append(shown)
    p = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, check=False)
    if p.returncode != 0:
        sys.stderr.write(p.stdout + p.stderr)
        raise SystemExit(f"command failed ({p.returncode}): {shown}")
    return p


def hdrd(*args: str) -> list[str]:
    return ["hdrd", *args]


# -- methods on prepared drives ---------------------------------------------------------------


@dataclass(frozen=True)
class Variant:
    """One ablation row: a method (none / hdr / hdr+ with params), and inputs withheld."""

    label: str
    kind: str  # "none", "hdr", "plus"
    params: HdrPlusParams | None = None
    speed: bool = True
    temp: bool = True
    gate_speed_mps: float = 0.0
    """Ablation (bench only): below this known speed, m/s, I does not move and no
    straight-driving measurement is taken."""
    holdoff_steps: int = 0
    """Ablation (bench only): steps after the turn switch opened during which I stays frozen."""


def gated_yaw(
    steps: StepInputs, p: HdrPlusParams, gate_speed_mps: float, holdoff_steps: int, temp: bool
) -> np.ndarray:
    """HDR+ step by step (:func:`hdrd.core.hdrplus.step`) with I frozen, and no straight-driving
    measurement, on gated steps: below a speed, or within ``holdoff_steps`` after the turn
    switch opened (the step's own filtered rate beyond theta_w, or the steps after it). The
    production step has no such gates: they did not help (docs/hdrplus.md)."""
    frozen = p.with_(hdr=replace(p.hdr, i_c=0.0)).ablated(ic_alpha=0.0, straight_r=0.0)
    state, hold, yaw = INITIAL_PLUS_STATE, 0, []
    for i in range(steps.u.shape[0]):
        inp = steps.input(i)
        if not temp:
            inp = inp._replace(temp_c=math.nan)
        held = hold > 0
        gated = held or (gate_speed_mps > 0.0 and inp.speed_mps < gate_speed_mps)
        state, o = step(state, inp, frozen if gated else p)
        if holdoff_steps and abs(o.filtered) > p.hdr.theta_w:
            hold = holdoff_steps  # the switch opened (W = 0 here anyway): freeze the next ones
        elif held:
            hold -= 1
        yaw.append(o.yaw)
    return np.array(yaw)


def yaw_of(v: Variant, prep: PreparedDrive) -> np.ndarray:
    s = prep.steps
    if v.kind == "none":
        return np.cumsum(s.u * s.T)
    if v.kind == "hdr":
        return hdr_batch(s.u, PAPER).yaw
    assert v.params is not None
    q = prep.quant_step_dps if prep.quant_step_dps > 0 else None
    # as hdrd evaluate fits HDR+ to the drive (hdrd.core.methods.plus_settings)
    ctx = SettingsContext(HdrParams(T=s.T), v.params, prep.samples_per_step, prep.bias, q)
    p = plus_settings(ctx)
    if v.gate_speed_mps > 0.0 or v.holdoff_steps > 0:
        return gated_yaw(s, p, v.gate_speed_mps, v.holdoff_steps, v.temp)
    return run_batch(
        s.u,
        s.omega_std,
        s.speed if v.speed else None,
        s.temp_c if v.temp else None,
        s.T,
        p,
    ).yaw


def ne(prep: PreparedDrive, yaw: np.ndarray, drop: int = 0) -> float:
    """NEψ (deg/min) over the steps from ``drop`` on, aligned at the first with truth there."""
    truth = prep.truth[drop:]
    y = yaw[drop:]
    k = align_index(y, truth)
    return float(e_psi(y, truth, k)) / (y.shape[0] * prep.steps.T / 60.0)


@dataclass
class SetScores:
    """NEψ per drive of one variant on one set, and the paper-HDR reference."""

    names: list[str]
    values: np.ndarray
    hdr: np.ndarray
    types: int  # drives cycle through this many types (for per-type means)

    @property
    def mean(self) -> float:
        return float(np.mean(self.values))

    @property
    def worst_drive(self) -> tuple[float, str]:
        r = self.values / self.hdr
        i = int(np.argmax(r))
        return float(r[i]), self.names[i]

    @property
    def worst_type(self) -> tuple[float, str]:
        ratios = [
            float(np.mean(self.values[t :: self.types]) / np.mean(self.hdr[t :: self.types]))
            for t in range(self.types)
        ]
        i = int(np.argmax(ratios))
        return ratios[i], self.names[i]


def score(v: Variant, preps: Sequence[PreparedDrive], hdr: np.ndarray, types: int) -> SetScores:
    vals = np.array([ne(p, yaw_of(v, p)) for p in preps])
    return SetScores([p.name for p in preps], vals, hdr, types)


# -- the drive sets ---------------------------------------------------------------------------


def routes(specs: Sequence[DriveSpec], n: int) -> list[DriveLog]:
    """n more routes of each spec's drive type (same legs, duration, temperature profile and
    gyro; seed spec.seed + 1000 j, j = 1..n), ordered route by route."""
    return [generate(replace(s, seed=s.seed + 1000 * j)) for j in range(1, n + 1) for s in specs]


def drive_off(spec: DriveSpec, lead_in_s: float = 1.0) -> DriveLog:
    """The spec's drive with only ``lead_in_s`` of standstill after power-on (the car leaves
    1 s after the gyro is switched on): same route, legs, temperature profile and gyro model."""
    legs = [(VARIANTS[p], f) for p, f in spec.legs]
    return simulate_legs(
        legs,
        spec.minutes,
        spec.seed,
        lead_in_s=lead_in_s,
        temperature=spec.temperature,
        name=spec.name,
    )


def true_gyro_error(log: DriveLog) -> np.ndarray:
    """Per sample, the simulated gyro's output minus its true rate scaled by the default
    model's scale factor, deg/s: its bias and noise, known in simulation only."""
    sf = crs03_default_model().get("scale_factor")
    gain = 1.0 + (sf.error if isinstance(sf, ScaleFactor) else 0.0)
    assert log.omega_truth is not None
    return log.omega - gain * log.omega_truth


def truth_bias_30s(log: DriveLog) -> float:
    """What a 30 s standstill calibration at power-on would have measured, known only in
    simulation: the mean over the first 30 s of the gyro output minus its scaled true rate."""
    w = log.t < log.t[0] + 30.0
    return float(np.mean(true_gyro_error(log)[w]))


# -- the rows ---------------------------------------------------------------------------------


def variants() -> list[tuple[str, list[Variant]]]:
    P = HdrPlusParams()
    paper = HdrPlusParams.paper()
    ss_off = StandstillParams(enabled=False)
    return [
        (
            "references",
            [
                Variant("no correction (static bias only)", "none"),
                Variant("paper HDR, Table III", "hdr"),
            ],
        ),
        (
            "one idea added to paper HDR",
            [
                Variant(
                    "HDR+'s retuned core alone (i_c, τ, Θw, c1, c2; no extras)",
                    "plus",
                    HdrPlusParams.paper(PLUS_CORE),
                ),
                Variant(
                    "+ standstill zero-rate updates (speed)",
                    "plus",
                    paper.with_(standstill=P.standstill),
                ),
                Variant(
                    "+ standstill + temperature model",
                    "plus",
                    paper.with_(standstill=P.standstill).ablated(temp_model=True),
                ),
                Variant(
                    "+ straight-driving bias measurements",
                    "plus",
                    paper.ablated(straight_r=P.ablation.straight_r),
                ),
                Variant(
                    "+ straight measurements + temperature model",
                    "plus",
                    paper.ablated(straight_r=P.ablation.straight_r, temp_model=True),
                ),
                Variant("+ speed gate (I frozen below 3 m/s)", "plus", paper, gate_speed_mps=3.0),
                Variant("+ hold-off 3 steps after a turn", "plus", paper, holdoff_steps=3),
            ],
        ),
        (
            "HDR+ and one idea taken out or added",
            [
                Variant("**HDR+ (defaults)**", "plus", P),
                Variant("HDR+ without standstill updates", "plus", P.with_(standstill=ss_off)),
                Variant(
                    "HDR+ with stops used from their 1st step (steps_speed 1, not 3)",
                    "plus",
                    P.with_(standstill=StandstillParams(steps_speed=1)),
                ),
                Variant(
                    "HDR+ without straight-driving measurements", "plus", P.ablated(straight_r=0.0)
                ),
                Variant("HDR+ without the temperature model", "plus", P.ablated(temp_model=False)),
                Variant("HDR+ with the paper's core (Table III)", "plus", P.with_(hdr=PAPER)),
                Variant("HDR+ + speed gate (3 m/s)", "plus", P, gate_speed_mps=3.0),
                Variant("HDR+ + hold-off 3 steps", "plus", P, holdoff_steps=3),
                Variant(
                    "HDR+ with the fixed increment (i_c 0.0048, not 0.1 x the bias sd)",
                    "plus",
                    P.ablated(ic_alpha=0.0),
                ),
            ],
        ),
        (
            "HDR+ with inputs withheld",
            [
                Variant("HDR+, speed withheld (no standstill detection)", "plus", P, speed=False),
                Variant(
                    "HDR+, speed withheld, gyro-only standstill detection",
                    "plus",
                    P.with_(standstill=StandstillParams(gyro_only=True)),
                    speed=False,
                ),
                Variant(
                    "HDR+, speed withheld, gyro-only detection, loose (0.5 deg/s spread, 0.3 level, 5 steps)",
                    "plus",
                    P.with_(
                        standstill=StandstillParams(
                            gyro_only=True, gyro_spread_dps=0.5, gyro_level_dps=0.3, steps_gyro=5
                        )
                    ),
                    speed=False,
                ),
                Variant("HDR+, temperature withheld", "plus", P, temp=False),
                Variant("HDR+, speed and temperature withheld", "plus", P, speed=False, temp=False),
            ],
        ),
    ]


# -- calibration study ------------------------------------------------------------------------


def one_second(log: DriveLog) -> PreparedDrive:
    """The whole log with the bias of its first 1 s (the mean of those samples, its variance
    the samples' variance / their number, for HDR+'s prior). No standstill test: with 10
    samples, its trend check (first vs last third) rejects about one real standstill in ten,
    and the daemon would simply try the next second; the mean is what it would then keep."""
    w = log.t < log.t[0] + 1.0
    b = float(np.mean(log.omega[w]))
    var = float(np.var(log.omega[w], ddof=1)) / int(np.count_nonzero(w))
    prep = prepare_drive(log, bias=b)
    return replace(prep, steps=replace(prep.steps, bias_var=var))


def calibration_rows(logs: Sequence[DriveLog]) -> dict[str, list[float]]:
    """Scenario A: the benchmark's logs (30 s standstill after power-on). Every method is
    scored on the same window, from 30 s on; the 1 s methods run from power-on."""
    P = HdrPlusParams()
    no_ss = P.with_(standstill=StandstillParams(enabled=False))
    out: dict[str, list[float]] = {}

    def add(k: str, v: float) -> None:
        out.setdefault(k, []).append(v)

    for log in logs:
        p30 = prepare_drive(log, calibrate_seconds=30.0)
        p1 = one_second(log)
        drop = 30
        add("HDR, 30 s calibration", ne(p30, hdr_batch(p30.steps.u).yaw))
        add("HDR, 1 s calibration", ne(p1, hdr_batch(p1.steps.u).yaw, drop))
        add("HDR+, 30 s calibration", ne(p30, yaw_of(Variant("", "plus", P), p30)))
        add(
            "HDR+, 1 s calibration + standstill re-calibration",
            ne(p1, yaw_of(Variant("", "plus", P), p1), drop),
        )
        add(
            "HDR+ without standstill updates, 1 s calibration",
            ne(p1, yaw_of(Variant("", "plus", no_ss), p1), drop),
        )
    return out


def drive_off_rows(specs: Sequence[DriveSpec]) -> tuple[dict[str, list[float]], int]:
    """Scenario B: the car leaves 1 s after power-on; stops happen only during the drive."""
    P = HdrPlusParams()
    no_ss = P.with_(standstill=StandstillParams(enabled=False))
    out: dict[str, list[float]] = {}
    stopped = 0

    def add(k: str, v: float) -> None:
        out.setdefault(k, []).append(v)

    for spec in specs:
        log = drive_off(spec)
        p1 = one_second(log)
        b30 = truth_bias_30s(log)
        pb = prepare_drive(log, bias=b30)
        drop = 1  # scored from the end of the 1 s calibration, every row alike
        assert pb.steps.speed is not None
        stopped += int(np.count_nonzero(pb.steps.speed[drop:] <= 0.3))
        add(
            "HDR, bias of a 30 s standstill (known in simulation only)",
            ne(pb, hdr_batch(pb.steps.u).yaw, drop),
        )
        add(
            "HDR+, bias of a 30 s standstill (known in simulation only)",
            ne(pb, yaw_of(Variant("", "plus", P.with_(bias_p0=0.155**2 / 300)), pb), drop),
        )
        add("HDR, 1 s calibration", ne(p1, hdr_batch(p1.steps.u).yaw, drop))
        add(
            "HDR+, 1 s calibration + standstill re-calibration",
            ne(p1, yaw_of(Variant("", "plus", P), p1), drop),
        )
        add(
            "HDR+ without standstill updates, 1 s calibration",
            ne(p1, yaw_of(Variant("", "plus", no_ss), p1), drop),
        )
    return out, stopped


def real_diagnostics(folder: Path) -> list[tuple[str, str, dict[str, float]]]:
    """Eψ (deg) of HDR+ variants on the converted real recordings (post hoc diagnostics)."""
    from hdrd.io.drivelog import read_drive

    P = HdrPlusParams()
    out = []
    for label, f, bias in (
        ("smartLoc Berlin", "smartloc_berlin.csv", 0.0),
        ("smartLoc Berlin", "smartloc_berlin.csv", SMARTLOC_FIT_BIAS_DPS),
        ("comma2k19", "comma2k19.csv", COMMA_ANDROID_BIAS_DPS),
    ):
        prep = prepare_drive(read_drive(folder / f), bias=bias)
        cols: dict[str, float] = {}
        for name, v in (
            ("HDR+", Variant("", "plus", P)),
            (
                "HDR+, stops used from their 1st step",
                Variant("", "plus", P.with_(standstill=StandstillParams(steps_speed=1))),
            ),
            ("HDR+, speed withheld", Variant("", "plus", P, speed=False)),
            ("HDR+, bias_p0 2.6e-3", Variant("", "plus", P.with_(bias_p0=2.6e-3))),
            ("HDR+ + speed gate 3 m/s", Variant("", "plus", P, gate_speed_mps=3.0)),
        ):
            yaw = yaw_of(v, prep)
            cols[name] = float(e_psi(yaw, prep.truth, prep.k))
        out.append((label, f"--bias {bias:g}", cols))
    return out


def perfect_gyro(logs: Sequence[DriveLog]) -> dict[str, list[float]]:
    """NEψ of each method fed the *true* rate (a gyro without any error, bias 0), scored from
    30 s on: what a method does to real motion alone (no drift to remove)."""
    out: dict[str, list[float]] = {}
    for log in logs:
        assert log.omega_truth is not None
        prep = prepare_drive(replace(log, omega=log.omega_truth), bias=0.0)
        for label, v in (
            ("no correction", Variant("", "none")),
            ("paper HDR", Variant("", "hdr")),
            ("HDR+", Variant("", "plus", HdrPlusParams())),
        ):
            out.setdefault(label, []).append(ne(prep, yaw_of(v, prep), 30))
    return out


# -- cost of a step ---------------------------------------------------------------------------


def step_cost(prep: PreparedDrive, repeats: int = 3) -> tuple[float, float]:
    """(us per step of step(), us per step of run_batch()) on one drive, best of repeats."""
    s = prep.steps
    P = HdrPlusParams()
    assert s.speed is not None and s.temp_c is not None and s.omega_std is not None
    rows = [
        StepInput(float(u), float(sp), float(v), float(tc), s.T)
        for u, sp, v, tc in zip(s.u, s.omega_std, s.speed, s.temp_c, strict=True)
    ]
    best_step = best_batch = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        st = INITIAL_PLUS_STATE
        for r in rows:
            st, _o = step(st, r, P)
        best_step = min(best_step, time.perf_counter() - t0)
        t0 = time.perf_counter()
        run_batch(s.u, s.omega_std, s.speed, s.temp_c, s.T, P)
        best_batch = min(best_batch, time.perf_counter() - t0)
    n = len(rows)
    return best_step / n * 1e6, best_batch / n * 1e6


# -- the search on training drives (not run by default) ---------------------------------------


def tune(n: int, seed: int, routes_n: int) -> None:
    """Random search of HDR+'s main parameters on the training types (more routes of the nine
    training drives), printing the best sets by mean NEψ; the test drives are never used."""
    rng = np.random.default_rng(seed)
    preps = [prepare_drive(d) for d in routes(TRAIN_DRIVES, routes_n)]
    hdr = np.array([ne(p, hdr_batch(p.steps.u).yaw) for p in preps])

    def lu(a: float, b: float) -> float:
        return float(math.exp(rng.uniform(math.log(a), math.log(b))))

    found: list[tuple[float, float, dict[str, Any]]] = []
    for i in range(n):
        core = {
            "i_c": lu(0.003, 0.03),
            "tau": float(rng.uniform(0, 3)),
            "theta_w": float(rng.uniform(0.2, 1.0)),
            "c1": lu(0.05, 1.0),
            "c2": float(rng.uniform(0.3, 2.5)),
        }
        extra = {
            "bias_q": lu(1e-8, 1e-4),
            "bias_q_no_temp": lu(1e-6, 1e-4),
            "straight_r": lu(0.003, 0.3),
            "straight_gate_dps": lu(0.05, 2.0),
            "bias_p0": lu(1e-5, 1e-2),
            "temp_coeff_sd": lu(0.002, 0.03),
        }
        P = HdrPlusParams(hdr=HdrParams(**core), **extra)  # type: ignore[arg-type]
        sc = score(Variant("", "plus", P), preps, hdr, len(TRAIN_DRIVES))
        found.append((sc.mean, sc.worst_type[0], {**core, **extra}))
        print(
            f"{i + 1}/{n} mean NEψ {sc.mean:.4f} (paper HDR {hdr.mean():.4f})", end="\r", flush=True
        )
    print()
    found.sort(key=lambda x: x[0])
    for m, wt, kw in found[:5]:
        print(
            f"mean NEψ {m:.4f}, worst type ratio {wt:.2f}: "
            + ", ".join(f"{k}={v:.3g}" for k, v in kw.items())
        )


# -- the city study (why HDR+ gains least in city grids; not run by default) ------------

CITY_SEEDS = {"city": 70001, "suburbs": 80001, "mixed": 90001}
"""First seeds of the city study's extra training routes (seed + 37 j): none is a test
spec's seed + 1000 j (checked in :func:`city_training_specs`)."""


def city_training_specs() -> list[tuple[str, DriveSpec]]:
    """The city study's training set: 24 downtown ("city" profile, 18 min) routes, 12 suburbs
    (22 min) and 12 suburbs/highway/city (30 min) routes with new seeds, the training drives'
    temperature profiles in turn; then the 108 training-type routes and the nine drives."""
    temps = [s.temperature for s in TRAIN_DRIVES]
    legs = {
        "city": (18.0, (("city", 1.0),)),
        "suburbs": (22.0, (("suburbs", 1.0),)),
        "mixed": (30.0, (("suburbs", 0.3), ("highway", 0.4), ("city", 0.3))),
    }
    out: list[tuple[str, DriveSpec]] = []
    for kind, n in (("city", 24), ("suburbs", 12), ("mixed", 12)):
        minutes, lg = legs[kind]
        for j in range(n):
            seed = CITY_SEEDS[kind] + 37 * j
            out.append(
                (f"new {kind}", DriveSpec(f"{kind}N{j}", "", minutes, lg, seed, temps[j % 9]))
            )
    out += [
        (s.name, replace(s, seed=s.seed + 1000 * j)) for j in range(1, 13) for s in TRAIN_DRIVES
    ]
    out += [("the nine", s) for s in TRAIN_DRIVES]
    taken = {s.seed + 1000 * j for s in TEST_DRIVES for j in range(100)}
    assert not taken & {s.seed for _, s in out}, "a city-study seed is a test seed"
    return out


@dataclass(frozen=True)
class CityIdea:
    """A prototype variant of HDR+'s stop and straight-driving handling (city study)."""

    label: str
    fold: str = "hard"  # at a stop's first update: "hard" b -= I, "soft" Kalman, "drop" I discarded
    bump: float = -1.0  # p_bb added at a stop's first update, (deg/s)^2 (-1: i_c^2, the default)
    bump_i2: bool = False  # ... plus I^2 (the size of what is folded)
    win_steps: int = 0  # windowed straight measurement: mean u over this many gated steps
    win_r: float = 0.01  # its variance, (deg/s)^2
    i_c: float = 0.0  # core increment (0: PLUS_CORE's)
    slow_core: HdrParams | None = None  # core used while the smoothed speed is below slow_mps
    slow_mps: float = 0.0  # speed-aware core: threshold, m/s
    slow_tc_s: float = 0.0  # ... on the speed low-passed with this time constant, s (0: raw)
    blend_hdr: float = 0.0  # published yaw = w * paper HDR's + (1 - w) * the prototype's


def city_prototype(prep: PreparedDrive, idea: CityIdea) -> np.ndarray:
    """HDR+'s run_batch with the defaults' branches only (no gate, hold-off, adaptive
    increment, gyro-only detection) and the idea's switches; yaw per step. With
    ``CityIdea("")`` it equals hdrd.core.hdrplus.run_batch (checked in :func:`city_study`)."""
    s = prep.steps
    P = HdrPlusParams()
    p0 = s.bias_var if math.isfinite(s.bias_var) else P.bias_p0
    hp, ss = P.hdr, P.standstill
    i_c = idea.i_c or hp.i_c
    bump0 = hp.i_c * hp.i_c if idea.bump < 0 else idea.bump
    assert s.speed is not None and s.temp_c is not None and s.omega_std is not None
    b, k, p_bb, p_bk, p_kk, t_ref = 0.0, 0.0, p0, 0.0, P.temp_coeff_sd**2, math.nan
    x = I = yaw = 0.0
    r, s_prev, still, wsum, wcnt = 0, 0, 0, 0.0, 0
    T = s.T
    out = np.empty(s.u.shape[0])
    v_s = math.nan  # the speed, low-passed (speed-aware core)
    for i, (ui, sp, v, te) in enumerate(
        zip(s.u.tolist(), s.omega_std.tolist(), s.speed.tolist(), s.temp_c.tolist(), strict=True)
    ):
        have_temp = not math.isnan(te)
        if have_temp and math.isnan(t_ref):
            t_ref = te
        dT = te - t_ref if have_temp else 0.0
        p_bb += (P.bias_q if have_temp else P.bias_q_no_temp) * T
        uc = ui - (b + k * dT)
        if idea.slow_core is not None and not math.isnan(v):
            v_s = v if math.isnan(v_s) else v_s + (v - v_s) * T / (idea.slow_tc_s + T)
        core = idea.slow_core if idea.slow_core is not None and v_s < idea.slow_mps else hp
        inc = idea.slow_core.i_c if core is idea.slow_core else i_c
        level = uc + I
        cand = not math.isnan(v) and v <= ss.speed_mps and not sp > ss.spread_dps
        cand = cand and abs(level) <= ss.level_dps
        still = still + 1 if cand else 0
        if cand and still >= ss.steps_speed:
            if still == ss.steps_speed:
                p_bb += bump0 + (I * I if idea.bump_i2 else 0.0)
                if idea.fold == "hard":
                    b -= I
                elif idea.fold == "soft":
                    b, k, p_bb, p_bk, p_kk = _proto_update(
                        b, k, p_bb, p_bk, p_kk, b + k * dT - I, hp.i_c * hp.i_c, dT
                    )
            sp_ = ss.spread_dps if math.isnan(sp) else sp
            rr = (sp_ * sp_ + ss.noise_floor_dps**2) / ss.samples_per_step
            b, k, p_bb, p_bk, p_kk = _proto_update(b, k, p_bb, p_bk, p_kk, ui, rr, dT)
            x, I, r, s_prev, wsum, wcnt = 0.0, 0.0, 1, 0, 0.0, 0
            out[i] = yaw
            continue
        x = (T * uc + core.tau * x) / (T + core.tau)
        y = x + I
        yaw = yaw + (uc + I) * T
        sg = 1 if y > 0.0 else (-1 if y < 0.0 else 0)
        r = r + 1 if sg == s_prev else 1
        R = (1.0 + core.c1) / (1.0 + core.c1 * math.pow(r, core.c2))
        W = 1 if abs(y) <= core.theta_w else 0
        I_next = I - sg * W * R * inc
        if W and abs(uc + I) <= P.straight_gate_dps:
            b, k, p_bb, p_bk, p_kk = _proto_update(
                b, k, p_bb, p_bk, p_kk, ui, P.ablation.straight_r, dT
            )
            if idea.win_steps:
                wsum, wcnt = wsum + ui, wcnt + 1
                if wcnt == idea.win_steps:
                    z = wsum / wcnt
                    b, k, p_bb, p_bk, p_kk = _proto_update(
                        b, k, p_bb, p_bk, p_kk, z, idea.win_r, dT
                    )
                    wsum, wcnt = 0.0, 0
        else:
            wsum, wcnt = 0.0, 0
        out[i] = yaw
        I = I_next
        s_prev = sg
    if idea.blend_hdr:
        return idea.blend_hdr * hdr_batch(s.u, PAPER).yaw + (1.0 - idea.blend_hdr) * out
    return out


def _proto_update(
    b: float, k: float, p_bb: float, p_bk: float, p_kk: float, z: float, r: float, dT: float
) -> tuple[float, float, float, float, float]:
    ph0, ph1 = p_bb + dT * p_bk, p_bk + dT * p_kk
    sv = ph0 + dT * ph1 + r
    k0, k1 = ph0 / sv, ph1 / sv
    innov = z - (b + k * dT)
    return b + k0 * innov, k + k1 * innov, p_bb - k0 * ph0, p_bk - k0 * ph1, p_kk - k1 * ph1


CITY_IDEAS = (
    CityIdea("HDR+ (defaults)"),
    CityIdea("stop: I folded into b, P_bb += 2e-4 (not i_c^2)", bump=2e-4),
    CityIdea("stop: I folded into b, P_bb += 1e-3", bump=1e-3),
    CityIdea("stop: I folded into b, P_bb += i_c^2 + 4 I^2", bump_i2=True),
    CityIdea("stop: I folded as a Kalman measurement (b and k share it)", fold="soft"),
    CityIdea("stop: I discarded, P_bb += 3e-4", fold="drop", bump=3e-4),
    CityIdea("stop: I discarded, P_bb += 1e-3", fold="drop", bump=1e-3),
    CityIdea("+ windowed straight measurement (10 steps, r 0.01)", win_steps=10),
    CityIdea("+ windowed (10 steps, r 0.003), i_c 0.0025", win_steps=10, win_r=0.003, i_c=0.0025),
    # session 3: a core that depends on how fast the car goes (the issue's "speed-aware
    # gating"; paper HDR does comparatively well downtown), and a blend with paper HDR
    CityIdea("speed-aware core: paper Table III below 8 m/s", slow_core=PAPER, slow_mps=8.0),
    CityIdea(
        "speed-aware core: paper Table III below 8 m/s (speed low-passed 60 s)",
        slow_core=PAPER,
        slow_mps=8.0,
        slow_tc_s=60.0,
    ),
    CityIdea(
        "speed-aware core: i_c 0.015 below 8 m/s (speed low-passed 60 s)",
        slow_core=replace(PLUS_CORE, i_c=0.015),
        slow_mps=8.0,
        slow_tc_s=60.0,
    ),
    CityIdea("blend: 0.3 x paper HDR's yaw + 0.7 x HDR+'s", blend_hdr=0.3),
    CityIdea("blend: 0.5 x paper HDR's yaw + 0.5 x HDR+'s", blend_hdr=0.5),
)


def city_study(held_out: bool) -> None:
    """Print mean NEψ per drive group of every CITY_IDEAS row on the city study's training
    set, and with ``held_out`` on the five test drives and 12 routes of each test type."""
    from multiprocessing import Pool

    groups = city_training_specs()
    if held_out:
        groups = [("test", s) for s in TEST_DRIVES] + [
            (f"{s.name} type", replace(s, seed=s.seed + 1000 * j))
            for j in range(1, 13)
            for s in TEST_DRIVES
        ]
    with Pool(min(2, os.cpu_count() or 1)) as pool:
        preps = pool.map(_city_prep, [s for _, s in groups], chunksize=4)
    names = [g for g, _ in groups]
    keys = list(dict.fromkeys(names))
    P = HdrPlusParams()
    ref = [yaw_of(Variant("", "plus", P), p) for p in preps[:20]]
    got = [city_prototype(p, CityIdea("")) for p in preps[:20]]
    assert all(np.array_equal(a, b) for a, b in zip(ref, got, strict=True)), "prototype != HDR+"
    hdr = np.array([ne(p, hdr_batch(p.steps.u).yaw) for p in preps])
    print("row | all | " + " | ".join(keys) + " | drives > 1.1 x paper HDR")
    for row in [None, *CITY_IDEAS]:
        v = hdr if row is None else np.array([ne(p, city_prototype(p, row)) for p in preps])
        per = [float(np.mean(v[[n == k for n in names]])) for k in keys]
        label = "paper HDR" if row is None else row.label
        worse = float(np.mean(v > 1.1 * hdr))
        print(
            f"{label} | {np.mean(v):.4f} | " + " | ".join(f"{x:.3f}" for x in per),
            f"| {100 * worse:.0f}%",
            flush=True,
        )


def _city_prep(spec: DriveSpec) -> PreparedDrive:
    return prepare_drive(generate(spec))


# -- single drives: how often HDR+ (or anything) is worse than paper HDR on one drive -----------

SINGLE_SECTION = "## HDR+ vs paper HDR on single drives (how often one drive is worse)"
SINGLE_FIRST_ROUTE = 13
"""Routes j = 13.. of each type (seeds spec.seed + 1000 j): none of them was used by the tuning
(j = 1..12 at most) or any study above."""


def oracle_yaw(log: DriveLog, prep: PreparedDrive, window_s: int = 121) -> np.ndarray:
    """Yaw with the gyro's true error removed as a smoother would: the error (gyro output
    minus its scaled true rate, known in simulation only) averaged over a centred
    ``window_s`` window, white noise left in. Not causal: a bound no real-time method reaches."""
    s = prep.steps
    n = s.u.shape[0]
    per = round(s.T * log.rate_hz)
    off = round(prep.start_s * log.rate_hz)
    err = true_gyro_error(log)[off : off + n * per].reshape(n, per).mean(axis=1)
    eps0 = float(np.mean(log.omega[:off])) if off else 0.0
    half = window_s // 2
    smooth = np.convolve(
        np.pad(err, (half, half), mode="edge"), np.ones(window_s) / window_s, "valid"
    )
    return np.cumsum((s.u - (smooth - eps0)) * s.T)


def _single_drive(spec: DriveSpec) -> tuple[str, float, float, float, float]:
    log = generate(spec)
    prep = prepare_drive(log)
    plus = Variant("", "plus", HdrPlusParams())
    return (
        spec.name,
        ne(prep, np.cumsum(prep.steps.u * prep.steps.T)),
        ne(prep, hdr_batch(prep.steps.u, PAPER).yaw),
        ne(prep, yaw_of(plus, prep)),
        ne(prep, oracle_yaw(log, prep)),
    )


def single_drive_odds(n_routes: int, write: bool) -> None:
    """Fraction of single drives on which HDR+ is more than 10 % worse than paper HDR (the
    issue's per-drive-type criterion read per drive), with the same fraction for a smoothed
    bias oracle: how often *any* bias estimate loses to HDR's luck on one drive."""
    from multiprocessing import Pool

    js = range(SINGLE_FIRST_ROUTE, SINGLE_FIRST_ROUTE + n_routes)
    sets = {
        "train types": [replace(s, seed=s.seed + 1000 * j) for j in js for s in TRAIN_DRIVES],
        "test types": [replace(s, seed=s.seed + 1000 * j) for j in js for s in TEST_DRIVES],
    }
    L = [
        SINGLE_SECTION,
        "",
        (
            f"Generated by `python bench/hdrplus.py --single-drive {n_routes}` "
            f"({time.strftime('%Y-%m-%d')}, {machine()}): {n_routes} new routes of each drive "
            f"type (seeds `spec.seed + 1000 j`, j = {js.start}..{js.stop - 1}: used by no search and "
            "no study; computed once, after every HDR+ choice was settled). NEψ in deg/min; "
            "*> 1.1 HDR* = the share of single drives on which the method's NEψ exceeds 1.1 × "
            "paper HDR's. *Oracle* = the gyro's true error, smoothed over 121 s (centred, known in "
            "simulation only), subtracted: not a method, a bound on what knowing the bias buys."
        ),
        "",
        (
            "| set | type | drives | NEψ none | NEψ paper HDR | NEψ HDR+ | NEψ oracle | HDR+ > 1.1 HDR "
            "| oracle > 1.1 HDR |"
        ),
        "|---|---|---|---|---|---|---|---|---|",
    ]
    pass_all: dict[str, tuple[float, float]] = {}
    type_ratios: list[float] = []
    with Pool(min(2, os.cpu_count() or 1)) as pool:
        for set_name, specs in sets.items():
            rows = pool.map(_single_drive, specs, chunksize=8)
            names = [r[0] for r in rows]
            a = np.array([r[1:] for r in rows])
            p_plus = p_orc = 1.0
            for t in dict.fromkeys(names):
                m = np.array([n == t for n in names])
                v = a[m]
                f_plus = float(np.mean(v[:, 2] > 1.1 * v[:, 1]))
                f_orc = float(np.mean(v[:, 3] > 1.1 * v[:, 1]))
                p_plus *= 1.0 - f_plus
                type_ratios.append(float(v[:, 2].mean() / v[:, 1].mean()))
                p_orc *= 1.0 - f_orc
                L.append(
                    f"| {set_name} | {t} | {int(m.sum())} | {fm(float(v[:, 0].mean()))} | "
                    f"{fm(float(v[:, 1].mean()))} | {fm(float(v[:, 2].mean()))} | "
                    f"{fm(float(v[:, 3].mean()))} | {f_plus:.0%} | {f_orc:.0%} |"
                )
            L.append(
                f"| **{set_name}** | all | {a.shape[0]} | **{fm(float(a[:, 0].mean()))}** | "
                f"**{fm(float(a[:, 1].mean()))}** | **{fm(float(a[:, 2].mean()))}** | "
                f"**{fm(float(a[:, 3].mean()))}** | **{np.mean(a[:, 2] > 1.1 * a[:, 1]):.0%}** | "
                f"**{np.mean(a[:, 3] > 1.1 * a[:, 1]):.0%}** |"
            )
            pass_all[set_name] = (p_plus, p_orc)
    L += [
        "",
        (
            "Chance that one drive of each type (as the benchmark's nine or five) are *all* within "
            "1.1 × paper HDR, from the shares above (independent drives):"
        ),
        "",
        "| set | HDR+ | oracle |",
        "|---|---|---|",
    ]
    L += [f"| {k} | {p:.0%} | {o:.0%} |" for k, (p, o) in pass_all.items()]
    L += [
        "",
        (
            f"Reading: on the mean of every drive type HDR+ is better than paper HDR (HDR+ / HDR "
            f"{min(type_ratios):.2f}-{max(type_ratios):.2f}), yet on a single drive it is more than "
            "10 % worse fairly often, and so, less often, is the oracle: HDR's binary increments "
            "make its error on one drive partly luck, and on a lucky drive it lands near the "
            'oracle. The issue\'s "no worse than paper HDR by more than 10 % on any drive type" '
            "is therefore met here per type (over many routes) and cannot be promised per drive by "
            "any bias estimate; the benchmark's test drive city3 (HDR 0.066, HDR+ 0.181, see above) "
            "is one of the drives where it fails."
        ),
    ]
    text = "\n".join(L) + "\n"
    print(text)
    if write:
        from _common import replace_section

        replace_section(SINGLE_SECTION, text)
        print(f"wrote {RESULTS.relative_to(REPO)} ({SINGLE_SECTION})")


# -- formatting -------------------------------------------------------------------------------


def fm(v: float, d: int = 3) -> str:
    return "–" if not math.isfinite(v) else f"{v:.{d}f}"


def machine() -> str:
    """What the figures were measured on (bench/_common.py, shared by every benchmark)."""
    from _common import machine_line  # bench/ is on sys.path when run as a script

    return machine_line()


def evaluate_json(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text(encoding="utf-8"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", default="/tmp/hdrd-hdrplus", help="drive logs and outputs")
    ap.add_argument("--routes", type=int, default=12, help="extra routes per drive type")
    ap.add_argument("--no-write", action="store_true", help="print, do not touch RESULTS.md")
    ap.add_argument("--tune", type=int, default=0, metavar="N", help="only run the training search")
    ap.add_argument("--seed", type=int, default=0, help="seed of --tune")
    ap.add_argument(
        "--city-study",
        choices=("train", "held-out"),
        help="only the city study's prototype rows (docs/hdrplus.md), on its training set or held out",
    )
    ap.add_argument(
        "--single-drive",
        type=int,
        default=0,
        metavar="N",
        help="only the single-drive table: N new routes per type, HDR+ and an oracle vs HDR",
    )
    args = ap.parse_args()
    if args.single_drive:
        single_drive_odds(args.single_drive, not args.no_write)
        return 0
    if args.city_study:
        city_study(args.city_study == "held-out")
        return 0
    if args.tune:
        tune(args.tune, args.seed, args.routes)
        return 0

    W = Path(args.workdir)
    W.mkdir(parents=True, exist_ok=True)
    cmds: list[str] = []
    wq = shlex.quote(str(W))
    train_files = [W / "train" / f"{s.name}.csv" for s in TRAIN_DRIVES]
    test_files = [W / "test" / f"{s.name}.csv" for s in TEST_DRIVES]
    run(hdrd("simulate", "--benchmark", "train", "--out", str(W / "train")), cmds)
    run(hdrd("simulate", "--benchmark", "test", "--out", str(W / "test")), cmds)
    run(
        hdrd(
            "evaluate", *map(str, train_files), "--method", "hdr+", "--json", str(W / "train.json")
        ),
        cmds,
    )
    run(
        hdrd("evaluate", *map(str, test_files), "--method", "hdr+", "--json", str(W / "test.json")),
        cmds,
    )
    cli = {k: evaluate_json(W / f"{k}.json") for k in ("train", "test")}
    real: list[tuple[str, str, dict[str, Any]]] = []
    if DATA.is_dir():
        run([sys.executable, "tools/convert_real.py", "all", "--out-dir", str(W / "real")], cmds)
        sl, cm = W / "real" / "smartloc_berlin.csv", W / "real" / "comma2k19.csv"
        for label, bias_args, f, out in (
            (
                "smartLoc Berlin, bias 0 (the car's sensor taken as zeroed)",
                ["--bias", "0"],
                sl,
                "sl0",
            ),
            (
                f"smartLoc Berlin, bias {SMARTLOC_FIT_BIAS_DPS:+g} deg/s (best static bias in hindsight)",
                ["--bias", str(SMARTLOC_FIT_BIAS_DPS)],
                sl,
                "sl1",
            ),
            (
                "comma2k19, bias = Android's estimate",
                ["--bias", str(COMMA_ANDROID_BIAS_DPS)],
                cm,
                "cm0",
            ),
            (
                "comma2k19, bias from its first second (moving!)",
                ["--calibrate-seconds", "1"],
                cm,
                "cm1",
            ),
        ):
            run(
                hdrd(
                    "evaluate",
                    str(f),
                    *bias_args,
                    "--method",
                    "hdr+",
                    "--json",
                    str(W / "real" / f"{out}.json"),
                ),
                cmds,
            )
            real.append((label, " ".join(bias_args), evaluate_json(W / "real" / f"{out}.json")))

    # In-process: the same drives (prepared as hdrd evaluate does) and more routes per type.
    print("preparing drive sets ...", flush=True)
    from hdrd.io.drivelog import read_drive

    sets: dict[str, tuple[list[PreparedDrive], int]] = {
        "train": ([prepare_drive(read_drive(f)) for f in train_files], len(TRAIN_DRIVES)),
        "test": ([prepare_drive(read_drive(f)) for f in test_files], len(TEST_DRIVES)),
        "train types": (
            [prepare_drive(d) for d in routes(TRAIN_DRIVES, args.routes)],
            len(TRAIN_DRIVES),
        ),
        "test types": (
            [prepare_drive(d) for d in routes(TEST_DRIVES, args.routes)],
            len(TEST_DRIVES),
        ),
    }
    hdr_ref = {
        k: np.array([ne(p, hdr_batch(p.steps.u).yaw) for p in ps]) for k, (ps, _) in sets.items()
    }
    table: list[tuple[str, list[tuple[Variant, dict[str, SetScores]]]]] = []
    for group, vs in variants():
        rows = []
        for v in vs:
            print(f"  {v.label}", flush=True)
            rows.append((v, {k: score(v, ps, hdr_ref[k], t) for k, (ps, t) in sets.items()}))
        table.append((group, rows))
    # The in-process HDR+ row must be what `hdrd evaluate --method hdr+` printed.
    plus_row = next(r for g, rs in table for v, r in rs if v.label == "**HDR+ (defaults)**")
    for k in ("train", "test"):
        got = [d["NE_psi_hdr+"] for d in cli[k]["drives"]]
        if not np.allclose(got, plus_row[k].values, rtol=1e-9, atol=1e-12):
            raise SystemExit(
                f"in-process HDR+ differs from hdrd evaluate on {k}: {got} vs {plus_row[k].values}"
            )

    print("calibration study ...", flush=True)
    more = {
        k: [replace(s, seed=s.seed + 1000 * j) for j in range(1, args.routes + 1) for s in specs]
        for k, specs in (("train types", TRAIN_DRIVES), ("test types", TEST_DRIVES))
    }
    cal_a = {
        "train": calibration_rows([read_drive(f) for f in train_files]),
        "test": calibration_rows([read_drive(f) for f in test_files]),
        **{k: calibration_rows([generate(s) for s in specs]) for k, specs in more.items()},
    }
    cal_b = {
        "train": drive_off_rows(TRAIN_DRIVES),
        "test": drive_off_rows(TEST_DRIVES),
        **{k: drive_off_rows(specs) for k, specs in more.items()},
    }
    perfect = {
        "train": perfect_gyro([read_drive(f) for f in train_files]),
        "test": perfect_gyro([read_drive(f) for f in test_files]),
    }
    us_step, us_batch = step_cost(sets["train"][0][5])

    real_diag = real_diagnostics(W / "real") if real else []
    section = render(
        args, cmds, cli, table, sets, real, cal_a, cal_b, us_step, us_batch, wq, real_diag, perfect
    )
    print(section)
    if not args.no_write:
        write_section(section)
        print(f"wrote {RESULTS.relative_to(REPO)} ({SECTION})")
    return 0


def render(
    args: argparse.Namespace,
    cmds: list[str],
    cli: dict[str, dict[str, Any]],
    table: list[tuple[str, list[tuple[Variant, dict[str, SetScores]]]]],
    sets: dict[str, tuple[list[PreparedDrive], int]],
    real: list[tuple[str, str, dict[str, Any]]],
    cal_a: dict[str, dict[str, list[float]]],
    cal_b: dict[str, tuple[dict[str, list[float]], int]],
    us_step: float,
    us_batch: float,
    wq: str,
    real_diag: list[tuple[str, str, dict[str, float]]],
    perfect: dict[str, dict[str, list[float]]],
) -> str:
    L: list[str] = [SECTION, ""]
    L.append(
        f"Generated by `python bench/hdrplus.py` ({time.strftime('%Y-%m-%d')}, {machine()}; "
        f"--routes {args.routes}). It runs these commands (outputs in `{wq}`), then the ablation "
        "and calibration study in-process on the same drives:"
    )
    L += ["", "```sh"]
    L += [c.replace(str(Path(args.workdir)), "$W") for c in cmds]
    L += ["```", ""]
    L.append(
        "**Held out.** HDR+'s parameters (its core's i_c, τ, Θw, c1, c2 and its bias model's "
        "variances and gate) were tuned on the nine *training* drive types only: a random search "
        "on more routes of those nine types (seeds `spec.seed + 1000 j`), refined and rounded by "
        "hand (`python bench/hdrplus.py --tune N` repeats that kind of search). The five *test* "
        "drives, and the extra routes of the five test types, were never searched; they are "
        "evaluated here with the parameters fixed. (Disclosure: in the very first exploration, "
        "before HDR+ existed, a few prototype gating variants of paper HDR were also printed on "
        "the five test drives; none is part of HDR+ and no parameter came from them. One "
        "parameter was changed after seeing a real recording: see the discussion.) Paper HDR "
        "runs with Table III throughout."
    )
    L.append("")

    # Headline: per drive, from hdrd evaluate's JSON.
    L.append("### Held-out test drives and the training drives (`hdrd evaluate --method hdr+`)")
    L.append("")
    L.append("| set | drive | Td min | NEψ none | NEψ paper HDR | NEψ HDR+ | HDR+ / HDR |")
    L.append("|---|---|---|---|---|---|---|")
    for k in ("test", "train"):
        for d in cli[k]["drives"]:
            L.append(
                f"| {k} | {d['name']} | {d['duration_min']:.1f} | {fm(d['NE_psi_raw'])} | "
                f"{fm(d['NE_psi_hdr'])} | {fm(d['NE_psi_hdr+'])} | {d['NE_psi_hdr+'] / d['NE_psi_hdr']:.2f} |"
            )
        m = cli[k]["mean"]
        ratios = [d["NE_psi_hdr+"] / d["NE_psi_hdr"] for d in cli[k]["drives"]]
        L.append(
            f"| **{k} mean** | | | **{fm(m['NE_psi_raw'])}** | **{fm(m['NE_psi_hdr'])}** | "
            f"**{fm(m['NE_psi_hdr+'])}** | **{m['NE_psi_hdr+'] / m['NE_psi_hdr']:.2f}** "
            f"(HDR / HDR+ = {m['NE_psi_hdr'] / m['NE_psi_hdr+']:.2f}×; worst drive {max(ratios):.2f}) |"
        )
    L.append("")
    L.append(
        f"More routes of each type (`--routes {args.routes}`: {args.routes} per type; mean NEψ, "
        "and the type where HDR+ did worst relative to HDR, as a ratio of the type's mean NEψ):"
    )
    L.append("")
    L.append(
        "| drive types | drives | NEψ none | NEψ paper HDR | NEψ HDR+ | HDR / HDR+ | worst type (HDR+ / HDR) |"
    )
    L.append("|---|---|---|---|---|---|---|")
    refs = {v.label: r for g, rs in table for v, r in rs}
    for k in ("test types", "train types"):
        none_, hdr_, plus_ = (
            refs[x][k]
            for x in (
                "no correction (static bias only)",
                "paper HDR, Table III",
                "**HDR+ (defaults)**",
            )
        )
        wt, wn = plus_.worst_type
        L.append(
            f"| {k} | {len(sets[k][0])} | {fm(none_.mean)} | {fm(hdr_.mean)} | {fm(plus_.mean)} | "
            f"{hdr_.mean / plus_.mean:.2f}× | {wt:.2f} ({wn}) |"
        )
    L.append("")
    L.append("Per drive type (mean NEψ over its routes):")
    L.append("")
    L.append("| type | set | NEψ paper HDR | NEψ HDR+ | HDR+ / HDR |")
    L.append("|---|---|---|---|---|")
    for k in ("test types", "train types"):
        h, q = refs["paper HDR, Table III"][k], refs["**HDR+ (defaults)**"][k]
        for t in range(h.types):
            mh, mq = float(np.mean(h.values[t :: h.types])), float(np.mean(q.values[t :: q.types]))
            L.append(f"| {h.names[t]} | {k} | {fm(mh)} | {fm(mq)} | {mq / mh:.2f} |")
    L.append("")

    # Ablation.
    L.append("### Ablation: every idea, on training and held-out drives")
    L.append("")
    L.append(
        "Mean NEψ (deg/min) per set; *worst* = the largest NEψ(row) / NEψ(paper HDR) over the "
        "single drives (train, test) or over the drive types' means (the route sets). The bold "
        "row: the defaults. A row that is worse than the row it modifies did not help."
    )
    L.append("")
    L.append(
        "| row | train (9) | test (5) | worst drive train / test | train types | test types | worst type train / test |"
    )
    L.append("|---|---|---|---|---|---|---|")
    for group, rows in table:
        L.append(f"| *{group}* | | | | | | |")
        for v, r in rows:
            wd = f"{r['train'].worst_drive[0]:.2f} / {r['test'].worst_drive[0]:.2f}"
            wts = f"{r['train types'].worst_type[0]:.2f} / {r['test types'].worst_type[0]:.2f}"
            L.append(
                f"| {v.label} | {fm(r['train'].mean)} | {fm(r['test'].mean)} | {wd} | "
                f"{fm(r['train types'].mean)} | {fm(r['test types'].mean)} | {wts} |"
            )
    L.append("")

    L.append(
        "The same drives with a *perfect* gyro (the true rate, bias 0; scored from 30 s on): "
        "whatever error a method shows here it made itself, by taking real motion for drift. "
        "Mean NEψ, deg/min:"
    )
    L.append("")
    L.append("| method | train (9) | test (5) |")
    L.append("|---|---|---|")
    for key in perfect["train"]:
        L.append(
            f"| {key} | {fm(float(np.mean(perfect['train'][key])))} | "
            f"{fm(float(np.mean(perfect['test'][key])))} |"
        )
    L.append("")

    # Calibration.
    L.append("### A 1 s start-up calibration plus standstill re-calibration vs a 30 s one")
    L.append("")
    L.append(
        "**A — the benchmark's drives** (30 s standstill after power-on, then driving): every "
        "row is scored on the same steps, from 30 s on; the 1 s rows use the mean of the first "
        "second as eps0 and run from power-on, so HDR+ sees the remaining 29 s of standstill as "
        "a stop. Mean NEψ, deg/min:"
    )
    L.append("")
    cal_cols = ("train", "test", "train types", "test types")
    head = (
        f"| method | train (9) | test (5) | train types ({args.routes} routes each) | test types |"
    )
    L.append(head)
    L.append("|---|---|---|---|---|")
    for key in cal_a["train"]:
        L.append(
            f"| {key} | " + " | ".join(fm(float(np.mean(cal_a[c][key]))) for c in cal_cols) + " |"
        )
    L.append("")
    L.append(
        "**B — drive off after 1 s** (the same routes, legs, temperature profiles and gyro "
        "with only 1 s of standstill after power-on; HDR+ can re-calibrate only at the stops "
        f"during the drive: {cal_b['train'][1]} standstill steps in the nine, "
        f"{cal_b['test'][1]} in the five, {cal_b['train types'][1]} and {cal_b['test types'][1]} "
        "in the route sets). The 30 s reference rows are given the bias a 30 s "
        "calibration at power-on would have measured (the gyro output minus its scaled true rate, "
        "averaged over the first 30 s: known in simulation only). Mean NEψ, deg/min:"
    )
    L.append("")
    L.append(head)
    L.append("|---|---|---|---|---|")
    for key in cal_b["train"][0]:
        L.append(
            f"| {key} | "
            + " | ".join(fm(float(np.mean(cal_b[c][0][key]))) for c in cal_cols)
            + " |"
        )
    L.append("")

    # Real recordings.
    L.append("### Real recordings (`../shared/data/`, converted by `tools/convert_real.py`)")
    L.append("")
    if not real:
        L.append("Skipped: ../shared/data/ is not present on this machine.")
    else:
        L.append(
            "| recording | bias | Td min | Eψ none | Eψ paper HDR | Eψ HDR+ | NEψ none | NEψ HDR | NEψ HDR+ |"
        )
        L.append("|---|---|---|---|---|---|---|---|---|")
        for label, bias, doc in real:
            d = doc["drives"][0]
            L.append(
                f"| {label} | `{bias}` | {d['duration_min']:.1f} | {fm(d['E_psi_raw'], 2)}° | {fm(d['E_psi_hdr'], 2)}° | "
                f"{fm(d['E_psi_hdr+'], 2)}° | {fm(d['NE_psi_raw'])} | {fm(d['NE_psi_hdr'])} | {fm(d['NE_psi_hdr+'])} |"
            )
    L.append("")
    if real_diag:
        L.append(
            "Post hoc, to explain the table (nothing was chosen from it): HDR+ on the same "
            "recordings with inputs withheld or with a vaguer prior on the given bias "
            "(`bias_p0` = 2.6e-3 (deg/s)², the accuracy of a 1 s calibration, instead of a "
            "30 s one's 8e-5). Eψ in degrees:"
        )
        L.append("")
        L.append("| recording | bias | " + " | ".join(real_diag[0][2]) + " |")
        L.append("|---|---|" + "---|" * len(real_diag[0][2]))
        for label, bias, cols in real_diag:
            L.append(
                f"| {label} | `{bias}` | "
                + " | ".join(f"{fm(v, 2)}°" for v in cols.values())
                + " |"
            )
        L.append("")
    L.append(
        f"Cost: `hdrplus.step` {us_step:.1f} µs per step (the daemon runs one per second), "
        f"`hdrplus.run_batch` {us_batch:.1f} µs per step (highway1, best of 3)."
    )
    L.append("")
    L.append(DISCUSSION.strip())
    L.append("")
    L.append(CITY_STUDY.strip())
    L.append("")
    return "\n".join(L) + "\n"


DISCUSSION = """
### Discussion

Written by hand from the run above (everything is seeded: a re-run gives the same tables
unless the code changes; if it did, re-read the numbers before these words). Design and
equations: docs/hdrplus.md.

- **Held-out result.** On the five test drives mean NEψ goes from 0.397 deg/min (paper HDR,
  Table III) to 0.159 with HDR+, 2.5× lower (no correction: 1.80); on 60 further drives of the
  five test types (12 routes each, never searched) from 0.298 to 0.199, 1.50×; on the training
  side 1.90× (the nine) and 1.54× (108 routes of their types). Every drive *type* is better on
  average (HDR+ / HDR between 0.38 and 0.80, test types 0.43-0.80), most on curving highways
  (highway2, highwaymix, highway3: 0.34-0.43), least in the city (city3 type 0.80).
- **Not every single drive.** HDR+ is worse than paper HDR on the test drive city3 (0.066 ->
  0.181, 2.8×) and on the training drive rural1 (1.17×). city3 is paper HDR's luckiest drive:
  over 12 other routes of its type HDR averages 0.306, not 0.066, and HDR+ 0.245. A single
  drive's NEψ is a noisy number (its errors are a few degrees that random-walk; HDR's binary
  increments make it chaotic: the same route with other gyro noise moves HDR's NEψ by ±30-50 %),
  so "no worse than HDR by more than 10 % on any drive" holds here per drive type, not per drive.
- **What does the work** (ablation): a ~9× smaller HDR increment (i_c 0.0048 instead of
  0.0422 deg/s) *together with* the slow Kalman bias model fed by straight driving. Neither
  alone: the retuned core alone is no better than HDR on the route sets (0.247 / 0.242), and
  straight-driving measurements beside the paper's large increment are worse (0.314 / 0.384).
  HDR's own response to real motion (sway, curve entries below Θw) is most of its error on
  these drives: fed a *perfect* gyro it still scores 0.240 (train) and 0.411 (test) deg/min,
  about all it scores with the simulated CRS03-04, where no correction scores 0.087 / 0.063.
  A small increment makes fewer such mistakes (HDR+ 0.135 / 0.165 on the perfect gyro), and
  the bias model, a long average of the straight stretches, follows the slow drift that the
  small increment alone could not.
- **Temperature model:** a small gain (route sets 0.170 -> 0.164, 0.206 -> 0.199). In this
  simulator the bias is an exact function of the logged temperature plus small random terms,
  so this is an upper bound; on a real board the temperature sensor sits beside, not inside,
  the gyro. Without temperature HDR+ uses a faster-forgetting bias model (`bias_q_no_temp`).
- **Standstill updates:** neutral on NEψ in the simulator (route sets 0.157 without vs 0.164
  with, 0.201 vs 0.199): at a simulated stop the gyro sees pure noise, which HDR's integrator
  and the bias model already average correctly. Kept for what they guarantee — the yaw does
  not move while the car stands, and the bias is re-measured where the true rate is exactly
  zero — and for the short calibration (below). Gyro-only detection (speed unknown) is *off* by
  default: the simulator has no engine vibration or road noise, so quiet straight driving
  looks exactly like a stop and the detector takes sway for bias (route sets 0.157 -> 0.197);
  on a real car the spread may separate them, which this simulator cannot show.
- **Not kept:** the speed gate (I frozen below 3 m/s: neutral, 0.164 -> 0.165), the hold-off
  after turns (worse, 0.177), the adaptive increment (max(i_c, sd of the bias model): worse,
  0.238 — larger steps undo what the small increment gains).
- **Withheld inputs.** With neither speed nor temperature HDR+ still scores 0.164 / 0.208 on
  the route sets (HDR 0.253 / 0.298): it needs neither. Withholding the speed only switches
  the standstill updates off (the default gate is off), hence identical rows.
- **One parameter chosen after seeing a held-out result** (disclosed): the first version used
  a stop from its first zero-speed step. On smartLoc Berlin that made HDR+ worse than no
  correction (9.8° vs 8.7°): the recording's three zero-speed steps are rolling halts between
  manoeuvres, in which the car still yaws and the speed's and gyro's blocks do not line up; the
  simulator's stops are perfectly still. Stops now count from their third step
  (`standstill.steps_speed = 3`), which was neutral on the training types (0.162 -> 0.164) and
  costs on the test drives (0.135 -> 0.159; test types 0.192 -> 0.199); smartLoc is therefore
  not held out for this one choice.
- **1 s vs 30 s calibration.** (A) With the benchmark's 30 s standstill, a 1 s calibration plus
  re-calibration lands within 1-2 % of a 30 s one (route sets 0.166 vs 0.164, 0.196 vs 0.199);
  without the standstill updates 0.177 / 0.202. (B) Driving off after 1 s, HDR+ is within 4-9 %
  of what it does with the bias a 30 s standstill would have given (0.161 vs 0.155, 0.200 vs
  0.183); here the bias model re-learns eps0 from straight driving and the standstill updates
  add little (0.164 / 0.198 without). Paper HDR itself hardly cares (0.257 vs 0.253 in A): its
  integrator removes a 1 s calibration's ~0.05 deg/s error within a few steps. So the paper's
  closing remark holds for both; for HDR+ the 30 s wait buys a few per cent.
- **Real recordings.** smartLoc Berlin (4.7 min, slow urban, an automotive sensor with almost
  no drift): HDR+ 6.5° vs paper HDR 12.8° vs none 8.7° with the sensor taken as zeroed, 2.0°
  vs 10.3° vs 1.8° with the best bias in hindsight — HDR+ moves far less than HDR on this
  curve-after-curve drive, helps with the zero bias and costs 0.3° with the hindsight one.
  comma2k19 (1 min, nearly straight, phone gyro): HDR+ 0.63° vs HDR 0.31° vs none 1.13° with
  Android's bias estimate — better than nothing, worse than HDR: one minute is too short for
  HDR+'s slow bias model, while HDR's 9× larger increment removes the residual bias in
  seconds. Neither recording has a temperature, and both are far shorter than the drift HDR+
  is built for; they show conventions and robustness, not its benefit.
"""


CITY_STUDY = """
### Why HDR+ gains least in the city (a study on training routes; nothing kept)

The question: test drive city3 is the one drive where HDR+ is clearly worse than paper HDR
(0.181 vs 0.066 deg/min), and downtown driving is HDR+'s weakest type on average. Studied on
*training* routes only: the nine drives, their 108 extra routes, and 48 new routes with seeds
that no test spec uses (24 downtown routes of the `city` profile, 18 min; 12 suburbs, 22 min;
12 suburbs/highway/city, 30 min; seeds 70001/80001/90001 + 37 j, the training drives'
temperature profiles in turn). On the 24 new downtown routes paper HDR scores 0.223 and HDR+
0.208 deg/min (0.93; on suburbs 0.61, on the mixed routes 0.57).

**What the error is.** Diagnostics on the same routes (scripts not kept; the numbers are
seeded): fed a *perfect* gyro, HDR+ scores 0.148 on the downtown routes against 0.085 for no
correction (GPS-truth noise), and with the core's integrator I switched off 0.083: the
self-inflicted part is the integrator's. With the drift removed from the simulated gyro (its
121 s moving-average error subtracted, white noise left) HDR+ scores 0.172 against 0.100 for
no correction and 0.208 with the drift: about two thirds of HDR+'s excess error downtown is
I reacting to real motion, one third following the temperature drift. Regenerating 12 of these
routes with less sway (a diagnosis, not an evaluation; the benchmark's simulator is
unchanged) moves the perfect-gyro score 0.124 -> 0.100 -> 0.081 for sway 0.5 -> 0.25 -> 0
deg: the downtown profile's sway (0.5 deg heading wiggle with a 2 s correlation time, four
times the highway's rate) makes the sign of the low-passed rate a coin toss often enough for
I to wander (its standard deviation while driving 0.016 deg/s, correlation time ~30 s). Steps within 4 s of a
turn push I against the turn (the turn's ramp is taken for drift: net -0.10 to -0.20 deg/s
of increments per drive, against the turn's sign), but freezing I around the true turns
(an oracle gate from the simulated truth, ±2 to ±5 steps) did not help on average.
At a stop HDR+ folds I into b with a variance of only i_c² and the stop's precise
measurements then move b only part of the way: the wander I had at that moment becomes part
of b until the next stop. Paper HDR, by contrast, does comparatively well downtown (0.209
with the drift removed, against 0.644 in the suburbs): short sharp corners are far above Θw,
so its turn switch closes cleanly.

**What was tried** (a prototype of HDR+'s loop with each change, `python bench/hdrplus.py
--city-study train`; it reproduces HDR+'s defaults bit for bit). Mean NEψ, deg/min; *all* =
the 165 training drives; then the new routes by type, and the training types whose mean got
worse than the defaults':

| row | all (165) | new city (24) | new suburbs (12) | new mixed (12) | city1 type | city2 type | the nine | training types worse |
|---|---|---|---|---|---|---|---|---|
| paper HDR | 0.285 | 0.223 | 0.610 | 0.363 | 0.171 | 0.283 | 0.290 | |
| **HDR+ (defaults)** | **0.188** | **0.208** | **0.371** | **0.207** | **0.129** | **0.178** | **0.152** | |
| stop: I folded into b, P_bb += 2e-4 (not i_c²) | 0.185 | 0.205 | 0.355 | 0.211 | 0.131 | 0.167 | 0.142 | new mixed +2 %, city1 +2 %, mixed +1 %, highway1 +6 % |
| stop: I folded into b, P_bb += 1e-3 | 0.183 | 0.203 | 0.335 | 0.212 | 0.135 | 0.164 | 0.129 | new mixed +2 %, city1 +5 %, mixed +3 %, rural2 +2 %, highway1 +6 % |
| stop: I folded into b, P_bb += i_c² + 4 I² | 0.184 | 0.204 | 0.350 | 0.209 | 0.131 | 0.164 | 0.143 | new mixed +1 %, city1 +2 %, mixed +2 %, highway2 +2 % |
| stop: I folded as a Kalman measurement (b and k share it) | 0.202 | 0.223 | 0.398 | 0.287 | 0.153 | 0.236 | 0.156 | 8 of the 12 types (city1 +19 %, city2 +33 %, new mixed +39 %) |
| stop: I discarded, P_bb += 3e-4 | 0.179 | 0.193 | 0.328 | 0.200 | 0.134 | 0.162 | 0.145 | city1 +4 %, rural2 +0.5 %, highway1 +2 % |
| stop: I discarded, P_bb += 1e-3 | 0.179 | 0.190 | 0.325 | 0.198 | 0.134 | 0.158 | 0.135 | city1 +4 %, rural2 +2 %, highway1 +4 % |
| + windowed straight measurement (mean u of 10 gated steps, r 0.01) | 0.183 | 0.202 | 0.330 | 0.193 | 0.138 | 0.193 | 0.154 | city1 +7 %, mixed +1 %, highway1 +14 %, highwaymix +2 %, city2 +8 %, the nine +1 % |
| + windowed (10 steps, r 0.003) and i_c 0.0025 | 0.170 | 0.201 | 0.252 | 0.182 | 0.131 | 0.190 | 0.151 | city1 +2 %, highway1 +6 %, highwaymix +6 %, city2 +7 % |

The ideas: (1) a stop should reset what I wandered to rather than keep it — the stop itself
measures the bias to ~0.01 deg/s in 20 s, so the fold's variance should be I's wander, not one
increment, or I should be dropped; (2) sway is a heading *wiggle* that integrates back to zero,
so the mean rate over 10 straight steps measures the bias far better than 10 single steps
(sd ~0.07 vs ~0.35 deg/s each), and a better bias model lets the increment shrink. Each but the Kalman fold helps
the training mean by 2-10 % and the new downtown routes by at most 9 % (0.208 -> 0.190), but
every one makes at least one training type worse (city1 in every row, by 2-19 %), so by this
study's rule (no training type worse) none was kept; hdrd/ is unchanged. The increment's
wander downtown is the sign controller doing its job on a noisier signal: what would remove
it is a decision signal that averages the sway away without smearing the corners, which no
variant here achieved without costing elsewhere.

**Held out, evaluated once** after the rows above were settled (the five test drives, mean,
and 12 routes of each test type; `--city-study held-out`; no row was changed afterwards):

| row | all (65) | test (5) | city3 type | suburbs2 type | rural3 type | highway3 type | mixed2 type |
|---|---|---|---|---|---|---|---|
| paper HDR | 0.306 | 0.397 | 0.306 | 0.451 | 0.199 | 0.209 | 0.328 |
| **HDR+ (defaults)** | **0.196** | **0.159** | **0.245** | **0.302** | **0.153** | **0.090** | **0.203** |
| stop: I folded, P_bb += 2e-4 | 0.197 | 0.166 | 0.241 | 0.311 | 0.152 | 0.091 | 0.201 |
| stop: I folded, P_bb += 1e-3 | 0.197 | 0.156 | 0.230 | 0.331 | 0.149 | 0.093 | 0.198 |
| stop: I folded, P_bb += i_c² + 4 I² | 0.194 | 0.156 | 0.236 | 0.311 | 0.149 | 0.090 | 0.198 |
| stop: I folded as a Kalman measurement | 0.233 | 0.217 | 0.250 | 0.390 | 0.158 | 0.087 | 0.285 |
| stop: I discarded, P_bb += 3e-4 | 0.192 | 0.144 | 0.238 | 0.318 | 0.142 | 0.090 | 0.191 |
| stop: I discarded, P_bb += 1e-3 | 0.194 | 0.150 | 0.230 | 0.332 | 0.143 | 0.092 | 0.193 |
| + windowed straight measurement (10, 0.01) | 0.191 | 0.149 | 0.245 | 0.301 | 0.137 | 0.089 | 0.198 |
| + windowed (10, 0.003), i_c 0.0025 | 0.187 | 0.147 | 0.238 | 0.275 | 0.125 | 0.083 | 0.228 |

Held out the picture is the same: gains of at most 5 % over all 65 (9 % on the five test
drives' mean), the city3 type at best
0.245 -> 0.230 (HDR 0.306), and a worse type in most rows. None would have made the single
drive city3 (HDR's luckiest: 0.066) no worse than paper HDR; that criterion holds per drive
type, not per drive (see the discussion above).

**Later, an ensemble (session 2; prototype scripts not kept).** Averaging HDR+'s heading
with that of a second, linear estimator (no sign controller: a Kalman bias model with a fast
random walk, q = 1e-4 (deg/s)²/s, fed by the stops, the single straight steps and the mean
rate of every 10 consecutive straight steps, gated at 3 σ) lowered mean NEψ on the 165
training drives above by 6 % (geometric mean of per-drive ratios 0.94) and on 480 further
training-type routes by 9 % (0.188 -> 0.172), with rural2 and highway1 worse by 6-8 %. Held
out, evaluated once: the 65 drives 0.196 -> 0.180 (four of the five test types better,
highway3 0.090 -> 0.094), but the five test drives' mean worse (0.159 -> 0.180), city3
unchanged (0.184), and the share of held-out drives more than 10 % worse than paper HDR
unchanged (25 %). Not kept: a second estimator for a gain that does not reach the per-drive
criterion and does not hold on the test drives.

Also tried on training routes only (prototype scripts not kept; none reached a held-out look):
dropping I at a stop instead of folding it into b (learns the temperature coefficient, 0.008
instead of 0.005 deg/s/°C, but within noise on 480 further training-type routes: geometric
mean of per-drive ratios 1.007 ± 0.012); a process noise raised when the straight-driving
innovations stay one-sided (no gain); a search minimising the share of single drives worse
than 1.1 × paper HDR (0.261 -> 0.188 on the 165 search drives, 0.198 -> 0.192 on the 480:
no real change); sign decisions on the mean of 3-20 straight steps instead of every step
(worse by 8-18 %).

**Session 3: a speed-aware core and a blend with paper HDR** (`python bench/hdrplus.py
--city-study train`, training routes only; neither reached a held-out look). Paper HDR does
comparatively well downtown, so two ways to borrow from it: switch HDR+'s core to the paper's
Table III core (or a 3× larger increment) while the car is slow — the issue's "speed-aware
gating" — or publish a weighted mean of paper HDR's and HDR+'s yaw, which bounds how much
worse than HDR a drive can get (|e| ≤ w |e_HDR| + (1 − w) |e_HDR+| at every step). Mean NEψ,
deg/min, as in the table above; last column: share of the 165 drives more than 10 % worse
than paper HDR:

| row | all (165) | new city (24) | new suburbs (12) | new mixed (12) | city1 type | city2 type | the nine | groups worse than the defaults | drives > 1.1 × HDR |
|---|---|---|---|---|---|---|---|---|---|
| **HDR+ (defaults)** | **0.188** | **0.208** | **0.371** | **0.207** | **0.129** | **0.178** | **0.152** | | **26 %** |
| core: paper Table III below 8 m/s | 0.329 | 0.441 | 0.640 | 0.460 | 0.394 | 0.463 | 0.347 | 13 of 13 (city1 +205 %) | 48 % |
| core: paper Table III below 8 m/s (speed low-passed 60 s) | 0.253 | 0.357 | 0.374 | 0.387 | 0.170 | 0.386 | 0.271 | 12 of 13 (new mixed +87 %) | 38 % |
| core: i_c 0.015 below 8 m/s (speed low-passed 60 s) | 0.211 | 0.260 | 0.344 | 0.267 | 0.185 | 0.245 | 0.189 | 10 of 13 (city1 +43 %) | 29 % |
| blend: 0.3 × paper HDR + 0.7 × HDR+ | 0.196 | 0.203 | 0.374 | 0.239 | 0.126 | 0.185 | 0.180 | 9 of 13 (new mixed +15 %) | 18 % |
| blend: 0.5 × paper HDR + 0.5 × HDR+ | 0.213 | 0.204 | 0.421 | 0.271 | 0.132 | 0.205 | 0.209 | 11 of 13 (new mixed +31 %) | 15 % |

A larger increment while slow makes the city *worse* (new downtown routes 0.208 -> 0.26-0.44):
beside the bias model the paper's increment over-corrects, and paper HDR's good city score
belongs to its whole loop, not to its increment. The blend lowers the share of single drives
worse than 1.1 × paper HDR (26 % -> 18 % -> 15 %) only by taking on HDR's own error
everywhere else (mean 0.188 -> 0.196 -> 0.213; 9-11 of the 13 groups worse). Neither kept.

The standstill updates, once more: the ablation above shows HDR+ *without* them passing the
five test drives (worst 0.93 × HDR, city3 included). On training routes they are neutral
(NEψ without / with, geometric mean of per-drive ratios: 0.98 ± 0.04 on the 165, 1.01 ± 0.02
on 480 further training-type routes), so switching them off would be a choice made on the
test drives; they stay on.
"""


def write_section(section: str) -> None:
    """Replace this script's section of RESULTS.md (or append it), leaving the rest alone."""
    from _common import replace_section  # bench/ is on sys.path when run as a script

    replace_section(SECTION, section)


if __name__ == "__main__":
    sys.exit(main())
