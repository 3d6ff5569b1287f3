#!/usr/bin/env python3
"""HDR+ vs paper HDR on held-out drives, every idea's ablation, and the 1 s vs 30 s calibration.

    python bench/hdrplus.py [--workdir /tmp/hdrd-hdrplus] [--routes 12] [--no-write]
    python bench/hdrplus.py --tune 300 [--seed 0]     # the training-set search (no write)
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
3. Rewrites its own section of bench/RESULTS.md (Accuracy: simulated drives), leaving every
   other section as it is.

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
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from _common import (
    fmt,
    machine_line,
    ne_psi,
    oracle_yaw,
    paper_plus,
    plus_with,
    put_section,
    run_recorded,
    share_worse,
    true_gyro_error,
    type_means,
)

from hdrd.analysis.evaluate import PreparedDrive, prepare_drive
from hdrd.analysis.metrics import e_psi
from hdrd.core.hdr import HdrParams
from hdrd.core.hdr import run_batch as hdr_batch
from hdrd.core.hdrplus import INITIAL_PLUS_STATE, HdrPlusParams, run_batch, step
from hdrd.core.methods import MethodSetup, plus_settings
from hdrd.core.plusparams import PLUS_CORE
from hdrd.core.standstill import StandstillParams
from hdrd.core.steps import StepInput
from hdrd.io.drivelog import DriveLog
from hdrd.sim.benchmark import TEST_DRIVES, TRAIN_DRIVES, VARIANTS, DriveSpec, generate
from hdrd.sim.drive import simulate_legs

RESULTS = REPO / "bench" / "RESULTS.md"
SECTION = "## Beyond the paper: HDR+ and standstill re-calibration (held-out)"
DATA = REPO.parent / "shared" / "data"
SMARTLOC_FIT_BIAS_DPS = 0.053  # as bench/tables.py: least-squares bias of the whole run
COMMA_ANDROID_BIAS_DPS = -3.9167  # Android's own estimate, in hdrd's CCW convention
PAPER = HdrParams()


# -- running the user's commands ------------------------------------------------------------


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


def yaw_of(v: Variant, prep: PreparedDrive) -> np.ndarray:
    s = prep.steps
    if v.kind == "none":
        return np.cumsum(s.u * s.T)
    if v.kind == "hdr":
        return hdr_batch(s.u, PAPER).yaw
    assert v.params is not None
    q = prep.quant_step_dps if prep.quant_step_dps > 0 else None
    # as hdrd evaluate fits HDR+ to the drive (hdrd.core.methods.plus_settings)
    ctx = MethodSetup(HdrParams(T=s.T), v.params, prep.samples_per_step, prep.bias, q)
    p = plus_settings(ctx)
    return run_batch(
        s.u,
        s.omega_std,
        s.speed if v.speed else None,
        s.temp_c if v.temp else None,
        s.T,
        p,
    ).yaw


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
        """The drive type whose mean NEψ is the largest multiple of paper HDR's, and that
        multiple."""
        mine, hdr = type_means(self.values, self.names), type_means(self.hdr, self.names)
        kind = max(mine, key=lambda k: mine[k] / hdr[k])
        return mine[kind] / hdr[kind], kind


def score(v: Variant, preps: Sequence[PreparedDrive], hdr: np.ndarray, types: int) -> SetScores:
    vals = np.array([ne_psi(p, yaw_of(v, p)) for p in preps])
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


def truth_bias_30s(log: DriveLog) -> float:
    """What a 30 s standstill calibration at power-on would have measured, known only in
    simulation: the mean over the first 30 s of the gyro output minus its scaled true rate."""
    w = log.t < log.t[0] + 30.0
    return float(np.mean(true_gyro_error(log)[w]))


# -- the rows ---------------------------------------------------------------------------------


def variants() -> list[tuple[str, list[Variant]]]:
    P = HdrPlusParams()
    paper = paper_plus()
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
                    paper_plus(PLUS_CORE),
                    temp=False,
                ),
                Variant(
                    "+ standstill zero-rate updates (speed)",
                    "plus",
                    paper.with_(standstill=P.standstill),
                    temp=False,
                ),
                Variant(
                    "+ standstill + temperature model",
                    "plus",
                    paper.with_(standstill=P.standstill),
                ),
                Variant(
                    "+ straight-driving bias measurements",
                    "plus",
                    plus_with(paper, straight_r=P.tuning.straight_r),
                    temp=False,
                ),
                Variant(
                    "+ straight measurements + temperature model",
                    "plus",
                    plus_with(paper, straight_r=P.tuning.straight_r),
                ),
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
                    "HDR+ without straight-driving measurements",
                    "plus",
                    plus_with(P, straight_r=0.0),
                ),
                Variant("HDR+ without the temperature model", "plus", P, temp=False),
                Variant("HDR+ with the paper's core (Table III)", "plus", P.with_(hdr=PAPER)),
                Variant(
                    "HDR+ with the fixed increment (i_c 0.0048, not 0.1 x the bias sd)",
                    "plus",
                    plus_with(P, ic_alpha=0.0),
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
        add("HDR, 30 s calibration", ne_psi(p30, hdr_batch(p30.steps.u).yaw))
        add("HDR, 1 s calibration", ne_psi(p1, hdr_batch(p1.steps.u).yaw, drop))
        add("HDR+, 30 s calibration", ne_psi(p30, yaw_of(Variant("", "plus", P), p30)))
        add(
            "HDR+, 1 s calibration + standstill re-calibration",
            ne_psi(p1, yaw_of(Variant("", "plus", P), p1), drop),
        )
        add(
            "HDR+ without standstill updates, 1 s calibration",
            ne_psi(p1, yaw_of(Variant("", "plus", no_ss), p1), drop),
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
            ne_psi(pb, hdr_batch(pb.steps.u).yaw, drop),
        )
        add(
            "HDR+, bias of a 30 s standstill (known in simulation only)",
            ne_psi(pb, yaw_of(Variant("", "plus", plus_with(P, bias_p0=0.155**2 / 300)), pb), drop),
        )
        add("HDR, 1 s calibration", ne_psi(p1, hdr_batch(p1.steps.u).yaw, drop))
        add(
            "HDR+, 1 s calibration + standstill re-calibration",
            ne_psi(p1, yaw_of(Variant("", "plus", P), p1), drop),
        )
        add(
            "HDR+ without standstill updates, 1 s calibration",
            ne_psi(p1, yaw_of(Variant("", "plus", no_ss), p1), drop),
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
            ("HDR+, bias_p0 2.6e-3", Variant("", "plus", plus_with(P, bias_p0=2.6e-3))),
        ):
            yaw = yaw_of(v, prep)
            cols[name] = float(e_psi(yaw, prep.truth, prep.k, prep.align_n))
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
            out.setdefault(label, []).append(ne_psi(prep, yaw_of(v, prep), 30))
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
    hdr = np.array([ne_psi(p, hdr_batch(p.steps.u).yaw) for p in preps])

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
            "straight_r": lu(0.003, 0.3),
            "straight_gate_dps": lu(0.05, 2.0),
            "bias_p0": lu(1e-5, 1e-2),
            "temp_coeff_sd": lu(0.002, 0.03),
        }
        P = plus_with(None, hdr=HdrParams(**core), **extra)  # type: ignore[arg-type]
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


# -- single drives: how often HDR+ (or anything) is worse than paper HDR on one drive -----------

SINGLE_SECTION = "## HDR+ vs paper HDR on single drives (how often one drive is worse)"
SINGLE_FIRST_ROUTE = 13
"""Routes j = 13.. of each type (seeds spec.seed + 1000 j): none of them was used by the tuning
(j = 1..12 at most) or any study above."""


def _single_drive(spec: DriveSpec) -> tuple[str, float, float, float, float]:
    log = generate(spec)
    prep = prepare_drive(log)
    plus = Variant("", "plus", HdrPlusParams())
    return (
        spec.name,
        ne_psi(prep, np.cumsum(prep.steps.u * prep.steps.T)),
        ne_psi(prep, hdr_batch(prep.steps.u, PAPER).yaw),
        ne_psi(prep, yaw_of(plus, prep)),
        ne_psi(prep, oracle_yaw(log, prep)),
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
            f"({time.strftime('%Y-%m-%d')}, {machine_line()}): {n_routes} new routes of each drive "
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
                f_plus = share_worse(v[:, 2], v[:, 1])
                f_orc = share_worse(v[:, 3], v[:, 1])
                p_plus *= 1.0 - f_plus
                type_ratios.append(float(v[:, 2].mean() / v[:, 1].mean()))
                p_orc *= 1.0 - f_orc
                L.append(
                    f"| {set_name} | {t} | {int(m.sum())} | {fmt(float(v[:, 0].mean()))} | "
                    f"{fmt(float(v[:, 1].mean()))} | {fmt(float(v[:, 2].mean()))} | "
                    f"{fmt(float(v[:, 3].mean()))} | {f_plus:.0%} | {f_orc:.0%} |"
                )
            L.append(
                f"| **{set_name}** | all | {a.shape[0]} | **{fmt(float(a[:, 0].mean()))}** | "
                f"**{fmt(float(a[:, 1].mean()))}** | **{fmt(float(a[:, 2].mean()))}** | "
                f"**{fmt(float(a[:, 3].mean()))}** | **{share_worse(a[:, 2], a[:, 1]):.0%}** | "
                f"**{share_worse(a[:, 3], a[:, 1]):.0%}** |"
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
        put_section("sim", text)
        print(f"wrote {RESULTS.relative_to(REPO)} ({SINGLE_SECTION})")


# -- formatting -------------------------------------------------------------------------------


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
    if args.tune:
        tune(args.tune, args.seed, args.routes)
        return 0

    W = Path(args.workdir)
    W.mkdir(parents=True, exist_ok=True)
    cmds: list[str] = []
    wq = shlex.quote(str(W))
    train_files = [W / "train" / f"{s.name}.csv" for s in TRAIN_DRIVES]
    test_files = [W / "test" / f"{s.name}.csv" for s in TEST_DRIVES]
    run_recorded(hdrd("simulate", "--benchmark", "train", "--out", str(W / "train")), cmds)
    run_recorded(hdrd("simulate", "--benchmark", "test", "--out", str(W / "test")), cmds)
    run_recorded(
        hdrd(
            "evaluate", *map(str, train_files), "--method", "hdr+", "--json", str(W / "train.json")
        ),
        cmds,
    )
    run_recorded(
        hdrd("evaluate", *map(str, test_files), "--method", "hdr+", "--json", str(W / "test.json")),
        cmds,
    )
    cli = {k: evaluate_json(W / f"{k}.json") for k in ("train", "test")}
    real: list[tuple[str, str, dict[str, Any]]] = []
    if DATA.is_dir():
        run_recorded(
            [sys.executable, "tools/convert_real.py", "all", "--out-dir", str(W / "real")], cmds
        )
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
        ):
            run_recorded(
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
        k: np.array([ne_psi(p, hdr_batch(p.steps.u).yaw) for p in ps])
        for k, (ps, _) in sets.items()
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
        put_section("sim", section)
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
        f"Generated by `python bench/hdrplus.py` ({time.strftime('%Y-%m-%d')}, {machine_line()}; "
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
                f"| {k} | {d['name']} | {d['duration_min']:.1f} | {fmt(d['NE_psi_raw'])} | "
                f"{fmt(d['NE_psi_hdr'])} | {fmt(d['NE_psi_hdr+'])} | {d['NE_psi_hdr+'] / d['NE_psi_hdr']:.2f} |"
            )
        m = cli[k]["mean"]
        ratios = [d["NE_psi_hdr+"] / d["NE_psi_hdr"] for d in cli[k]["drives"]]
        L.append(
            f"| **{k} mean** | | | **{fmt(m['NE_psi_raw'])}** | **{fmt(m['NE_psi_hdr'])}** | "
            f"**{fmt(m['NE_psi_hdr+'])}** | **{m['NE_psi_hdr+'] / m['NE_psi_hdr']:.2f}** "
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
            f"| {k} | {len(sets[k][0])} | {fmt(none_.mean)} | {fmt(hdr_.mean)} | {fmt(plus_.mean)} | "
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
            L.append(f"| {h.names[t]} | {k} | {fmt(mh)} | {fmt(mq)} | {mq / mh:.2f} |")
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
                f"| {v.label} | {fmt(r['train'].mean)} | {fmt(r['test'].mean)} | {wd} | "
                f"{fmt(r['train types'].mean)} | {fmt(r['test types'].mean)} | {wts} |"
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
            f"| {key} | {fmt(float(np.mean(perfect['train'][key])))} | "
            f"{fmt(float(np.mean(perfect['test'][key])))} |"
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
            f"| {key} | " + " | ".join(fmt(float(np.mean(cal_a[c][key]))) for c in cal_cols) + " |"
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
            + " | ".join(fmt(float(np.mean(cal_b[c][0][key]))) for c in cal_cols)
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
                f"| {label} | `{bias}` | {d['duration_min']:.1f} | {fmt(d['E_psi_raw'], 2)}° | {fmt(d['E_psi_hdr'], 2)}° | "
                f"{fmt(d['E_psi_hdr+'], 2)}° | {fmt(d['NE_psi_raw'])} | {fmt(d['NE_psi_hdr'])} | {fmt(d['NE_psi_hdr+'])} |"
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
                + " | ".join(f"{fmt(v, 2)}°" for v in cols.values())
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
- **Not kept:** the speed gate (I frozen below 3 m/s: neutral, 0.164 -> 0.165) and the
  hold-off after turns (worse, 0.177), both retired from this script with their rows (last
  recorded 2026-12-01, "Retired results" in bench/RESULTS.md); the adaptive increment (max(i_c, sd of the bias model): worse,
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


if __name__ == "__main__":
    sys.exit(main())
