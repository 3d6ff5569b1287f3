#!/usr/bin/env python3
"""Real drives: none / paper HDR / HDR+ with a start-up calibration from each drive's own
standstill, per drive, on a tuning and a judging set fixed before any result was seen.

    python bench/real.py [--workdir /tmp/hdrd-real] [--no-write]

1. As a process, the command a user runs: ``python tools/convert_real.py all --out-dir DIR``
   (every recording of ../shared/data/; the script stops with a message if it is absent).
2. In-process, per drive: the start-up calibration (below), then ``none`` (static bias
   removal only), ``hdr`` (paper HDR, Table III) and ``hdr+`` exactly as ``hdrd evaluate
   --method hdr+`` runs them (:data:`hdrd.analysis.evaluate.METHODS`), and the reference
   "best constant bias in hindsight": the single bias that minimises the drive's Eψ with no
   other correction (Eψ is convex in it: a golden-section search). NEψ and Eψ per drive, means
   per set, and how often each method is worse than bias removal.
3. Rewrites its own section of bench/RESULTS.md, leaving every other section as it is.

**The split** (written here before any method was run on these drives; see :data:`TUNING`):
tuning = the DrivePlotR drives with an *odd* drive number, and comma2k19; judging = the
DrivePlotR drives with an *even* number, rtklib drive 0708 and smartLoc Berlin. Only tuning
drives may inform a parameter or a design choice; the judging drives are evaluated.

**Start-up calibration** (:func:`startup_window`; a thin helper of this script, to be replaced
by ``hdrd evaluate``'s own per-drive calibration once it has one): the log's ``lead_in_s``
(its start-up standstill, tools/convert_real.py) when it has one, else the first standstill
found from the speed: a run of rows with speed <= 0.3 m/s whose gyro rate, averaged over 1 s,
stays within 0.5 deg/s of the run's median (a car creeping or turning with a lagging speed is
not standing), with 2 s dropped at its start (a stop is not still at once) and a margin at its
end (1 s, or 3 s on logs sampled at 2 Hz or less, whose GPS speed lags). The calibration
averages the first min(standstill, 30 s) of it (``hdrd evaluate --calibrate-seconds S`` on the
log from that point on; the paper's Tbias is 30 s); the scored drive starts where the
calibration ends, so a drive that first stops after 10 minutes is scored from that stop on.
A log without any standstill of at least 3 s is listed, not scored; so is a drive whose scored
part is shorter than 5 minutes (:data:`MIN_SCORED_MIN`: on a short drive Eψ / Td is noise).
"""

from __future__ import annotations

import argparse
import math
import shlex
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from _common import machine_line, replace_section

from hdrd.analysis.evaluate import (
    METHODS,
    PAPER_PARAMS,
    PLUS_DEFAULTS,
    EvaluationError,
    PreparedDrive,
    prepare_drive,
)
from hdrd.analysis.metrics import e_psi
from hdrd.drivelog import DriveLog, read_drive
from hdrd.hdrplus import HdrPlusParams
from hdrd.zupt import CalibrationNoise, calibration_noise, quantization_step

SECTION = "## Real drives: none / paper HDR / HDR+ with a start-up calibration per drive"
DATA = REPO.parent / "shared" / "data"

TUNING: frozenset[str] = frozenset(
    {"comma2k19"}
    | {f"nds_drive{d:02d}" for d in (1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 23, 25, 31, 33)}
)
"""Drives that may tune (DrivePlotR odd drive numbers, comma2k19). Fixed before any result."""
JUDGING: frozenset[str] = frozenset(
    {"rtklib_drive0708", "smartloc_berlin"}
    | {f"nds_drive{d:02d}" for d in (2, 4, 6, 8, 10, 12, 14, 16, 18, 24, 28, 30, 32, 34)}
)
"""Drives that only judge (DrivePlotR even drive numbers, rtklib, smartLoc)."""

MAX_CALIBRATE_S = 30.0
"""Longest start-up calibration, s (the paper's Tbias)."""
MIN_STANDSTILL_S = 3.0
"""Shortest standstill used for a calibration, s."""
MIN_SCORED_MIN = 5.0
"""Drives whose scored part is shorter than this, min, are listed but not scored."""
STILL_SPEED_MPS = 0.3
STILL_RATE_DEV_DPS = 0.5


def drive_set(name: str) -> str:
    """ "tune" or "judge" (ValueError for a drive in neither: the split must be explicit)."""
    if name in TUNING:
        return "tune"
    if name in JUDGING:
        return "judge"
    raise ValueError(f"{name}: in neither the tuning nor the judging set")


# -- the start-up calibration (to be replaced by hdrd evaluate's per-drive calibration) ----


def _moving_mean(t: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    c = np.concatenate(([0.0], np.cumsum(x)))
    lo = np.searchsorted(t, t - window_s / 2, side="left")
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    return np.asarray((c[hi] - c[lo]) / np.maximum(hi - lo, 1))


@dataclass(frozen=True)
class Window:
    """A start-up calibration: rows from ``start`` on, the first ``seconds`` averaged.
    ``source``: "lead-in" (the log's lead_in_s) or "stop at N s" (the first standstill)."""

    start: int
    seconds: float
    source: str


def startup_window(log: DriveLog) -> Window | None:
    """The start-up calibration of a log (see the module docstring), or None without one."""
    t = log.t
    if "lead_in_s" in log.meta:
        lead = float(log.meta["lead_in_s"])
        if lead >= MIN_STANDSTILL_S:
            return Window(0, min(lead, MAX_CALIBRATE_S), "lead-in")
    if log.speed is None:
        return None
    w = _moving_mean(t, log.omega, 1.0)
    margin = 3.0 if log.rate_hz <= 2.0 else 1.0
    still = np.isfinite(log.speed) & (log.speed <= STILL_SPEED_MPS)
    i = 0
    n = len(log)
    while i < n:
        if not still[i]:
            i += 1
            continue
        j = i
        while j < n and still[j]:
            j += 1
        # rows i..j-1 stand still by the speed; drop 2 s at the start, check the gyro
        a = int(np.searchsorted(t, t[i] + 2.0))
        if a < j:
            med = float(np.median(w[a:j]))
            bad = np.flatnonzero(np.abs(w[a:j] - med) > STILL_RATE_DEV_DPS)
            end = a + int(bad[0]) if bad.shape[0] else j
            t_end = (t[end] if end < n else t[-1]) - margin
            length = math.floor(t_end - t[a])
            if length >= MIN_STANDSTILL_S:
                return Window(
                    a, min(float(length), MAX_CALIBRATE_S), f"stop at {t[a] - t[0]:.0f} s"
                )
        i = j
    return None


def prepare(log: DriveLog, win: Window) -> PreparedDrive:
    """``hdrd evaluate --calibrate-seconds S`` on the log from the window's first row."""
    part = log.slice(win.start) if win.start else log
    return prepare_drive(part, bias=None, calibrate_seconds=win.seconds)


def fit_plus(log: DriveLog, win: Window | None, T: float = 1.0) -> HdrPlusParams:
    """HDR+'s settings for this gyro, as :meth:`hdrd.hdrplus.HdrPlusParams.fitted` derives
    them: from the calibration window's noise (samples per step, a step's standstill
    variance, var(eps0)) and the output step seen over the whole recording (a property of
    the sensor). Without a window: samples per step from the log's rate. (To be replaced by
    evaluate's own call of ``fitted`` once it has one.)"""
    q = quantization_step(log.omega)
    if win is None:
        cal = CalibrationNoise(math.nan, math.nan, q, max(1.0, log.rate_hz * T))
    else:
        part = log.slice(win.start) if win.start else log
        w = part.t < part.t[0] + win.seconds
        cal = calibration_noise(part.omega[w], part.t[w], T)
    return PLUS_DEFAULTS.fitted(cal, None, q if q > 0 else None)


# -- scoring --------------------------------------------------------------------------------

YawFn = Callable[[PreparedDrive, HdrPlusParams], np.ndarray]


def method_yaw(method: str) -> YawFn:
    """A method as ``hdrd evaluate`` runs it (paper Table III for hdr; HDR+ with the drive's
    fitted settings, its prior the calibration's variance)."""
    return lambda prep, plus: METHODS[method](prep.steps, PAPER_PARAMS, plus)


def best_constant_bias(prep: PreparedDrive) -> tuple[float, float]:
    """(bias correction delta, deg/s; Eψ, deg) minimising Eψ of u - delta without any other
    correction: a grid over +-1 deg/s in steps of 0.002 deg/s, then a golden-section search
    in the best grid cell's neighbourhood (Eψ wraps each error to +-180 deg, so it is not
    convex in delta far from the optimum)."""
    s = prep.steps
    t = np.arange(1, s.u.shape[0] + 1) * s.T
    base = np.cumsum(s.u * s.T)

    def f(d: float) -> float:
        return float(e_psi(base - d * t, prep.truth, prep.k))

    grid = np.arange(-1.0, 1.0 + 1e-9, 0.002)
    vals = [f(float(d)) for d in grid]
    i = int(np.argmin(vals))
    lo, hi = float(grid[max(i - 1, 0)]), float(grid[min(i + 1, grid.shape[0] - 1)])
    g = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - g * (hi - lo), lo + g * (hi - lo)
    fa, fb = f(a), f(b)
    for _ in range(30):
        if fa < fb:
            hi, b, fb = b, a, fa
            a = hi - g * (hi - lo)
            fa = f(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + g * (hi - lo)
            fb = f(b)
    d = 0.5 * (lo + hi)
    best = min((f(d), d), (vals[i], float(grid[i])))
    return best[1], best[0]


@dataclass(frozen=True)
class RealDrive:
    """One converted drive with its calibration (None: not scorable) and why not."""

    name: str
    set: str
    log: DriveLog
    window: Window | None
    prep: PreparedDrive | None
    plus: HdrPlusParams
    note: str = ""

    @property
    def scored(self) -> bool:
        return self.prep is not None and not self.note


def load_drives(folder: Path) -> list[RealDrive]:
    """Every converted log in ``folder`` with its start-up calibration."""
    out = []
    for f in sorted(folder.glob("*.csv")):
        log = read_drive(f)
        name = log.name or f.stem
        win = startup_window(log)
        prep: PreparedDrive | None = None
        note = ""
        if win is None:
            note = "no standstill of 3 s or more"
        else:
            try:
                prep = prepare(log, win)
            except EvaluationError as e:
                note = f"calibration refused: {e}"
            if prep is not None and prep.duration_min < MIN_SCORED_MIN:
                note = f"scored part {prep.duration_min:.1f} min < {MIN_SCORED_MIN:g}"
        plus = fit_plus(log, win)
        out.append(RealDrive(name, drive_set(name), log, win, prep, plus, note))
    return out


def scores(prep: PreparedDrive, plus: HdrPlusParams, methods: dict[str, YawFn]) -> dict[str, float]:
    """Eψ (deg) of each method on one prepared drive."""
    return {m: float(e_psi(fn(prep, plus), prep.truth, prep.k)) for m, fn in methods.items()}


DEFAULT_METHODS: dict[str, YawFn] = {
    "none": method_yaw("none"),
    "hdr": method_yaw("hdr"),
    "hdr+": method_yaw("hdr+"),
}


# -- the report -------------------------------------------------------------------------------


def run(cmd: list[str], shown: list[str]) -> None:
    text = " ".join(shlex.quote(c) for c in cmd).replace(sys.executable, "python")
    print(f"$ {text}", flush=True)
    shown.append(text)
    p = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, check=False)
    if p.returncode != 0:
        sys.stderr.write(p.stdout + p.stderr)
        raise SystemExit(f"command failed ({p.returncode}): {text}")


def _f(v: float, d: int = 3) -> str:
    return f"{v:.{d}f}" if math.isfinite(v) else "–"


def table(
    drives: Sequence[RealDrive], methods: Sequence[str]
) -> tuple[str, dict[str, dict[str, float]]]:
    """The per-drive table and the per-set means of NEψ (and counts)."""
    head = (
        "| set | drive | Td min | calibration | eps0 deg/s | best const. bias deg/s | "
        + " | ".join(f"Eψ {m}" for m in methods)
        + " | Eψ best const. | "
        + " | ".join(f"NEψ {m}" for m in methods)
        + " | NEψ best const. |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    per_set: dict[str, dict[str, list[float]]] = {}
    skipped = []
    for d in sorted(drives, key=lambda d: (d.set != "judge", d.name)):
        if not d.scored:
            skipped.append(d)
            continue
        assert d.prep is not None and d.window is not None
        e = scores(d.prep, d.plus, {m: DEFAULT_METHODS[m] for m in methods})
        delta, e_best = best_constant_bias(d.prep)
        td = d.prep.duration_min
        lines.append(
            f"| {d.set} | {d.name} | {td:.1f} | {d.window.seconds:g} s, {d.window.source} | "
            f"{d.prep.steps.bias_dps:+.4f} | {d.prep.steps.bias_dps + delta:+.4f} | "
            + " | ".join(f"{e[m]:.2f}°" for m in methods)
            + f" | {e_best:.2f}° | "
            + " | ".join(_f(e[m] / td) for m in methods)
            + f" | {_f(e_best / td)} |"
        )
        s = per_set.setdefault(d.set, {})
        for m in methods:
            s.setdefault(m, []).append(e[m] / td)
            s.setdefault(f"E {m}", []).append(e[m])
        s.setdefault("best", []).append(e_best / td)
    means = {k: {m: float(np.mean(v)) for m, v in s.items()} for k, s in per_set.items()}
    for k, s in per_set.items():
        none = np.array(s["none"])
        for m in methods:
            if m == "none":
                continue
            v = np.array(s[m])
            ev, en = np.array(s[f"E {m}"]), np.array(s["E none"])
            worse = (v > 1.1 * none) & (ev - en > 0.5)
            means[k][f"worse {m}"] = float(np.count_nonzero(worse))
            means[k][f"better {m}"] = float(np.count_nonzero(v < none))
        means[k]["n"] = float(none.shape[0])
    if skipped:
        lines.append("")
        lines.append(
            "Not scored: "
            + "; ".join(
                f"{d.name} ({d.set}: {d.note})" for d in sorted(skipped, key=lambda d: d.name)
            )
            + "."
        )
    return "\n".join(lines), means


GIVEN_MIN_MIN = 4.5
"""Drives without a usable standstill but at least this long, min, get a row in the
given-bias table."""


def hindsight_prep(log: DriveLog) -> PreparedDrive | None:
    """The whole log with its best constant bias in hindsight given (``--bias``), or None."""
    try:
        prep0 = prepare_drive(log, bias=0.0)
    except EvaluationError:
        return None
    delta, _ = best_constant_bias(prep0)
    return prepare_drive(log, bias=delta)


def given_table(drives: Sequence[RealDrive], methods: Sequence[str]) -> str:
    """Drives without a start-up calibration, evaluated with their hindsight bias given:
    whatever a method does here beyond bias removal is what it adds to a perfect static bias."""
    head = (
        "| set | drive | Td min | given bias deg/s | "
        + " | ".join(f"Eψ {m}" for m in methods)
        + " | "
        + " | ".join(f"NEψ {m}" for m in methods)
        + " |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for d in sorted(drives, key=lambda d: (d.set != "judge", d.name)):
        if d.prep is not None or d.log.duration_s < 60.0 * GIVEN_MIN_MIN:
            continue
        prep = hindsight_prep(d.log)
        if prep is None:
            continue
        e = scores(prep, fit_plus(d.log, None), {m: DEFAULT_METHODS[m] for m in methods})
        td = prep.duration_min
        lines.append(
            f"| {d.set} | {d.name} | {td:.1f} | {prep.steps.bias_dps:+.4f} | "
            + " | ".join(f"{e[m]:.2f}°" for m in methods)
            + " | "
            + " | ".join(_f(e[m] / td) for m in methods)
            + " |"
        )
    return "\n".join(lines)


def summary(means: dict[str, dict[str, float]], methods: Sequence[str]) -> str:
    head = (
        "| set | drives | "
        + " | ".join(f"mean NEψ {m}" for m in methods)
        + " | mean NEψ best const. | "
        + " | ".join(
            f"{m}: better than none / > 1.1x none and +0.5° worse" for m in methods if m != "none"
        )
        + " |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for k in ("judge", "tune"):
        if k not in means:
            continue
        s = means[k]
        n = int(s["n"])
        lines.append(
            f"| {'judging' if k == 'judge' else 'tuning'} | {n} | "
            + " | ".join(_f(s[m]) for m in methods)
            + f" | {_f(s['best'])} | "
            + " | ".join(
                f"{int(s[f'better {m}'])} / {int(s[f'worse {m}'])}" for m in methods if m != "none"
            )
            + " |"
        )
    return "\n".join(lines)


DISCUSSION = """
**What tuned what.** HDR+'s settings (docs/hdrplus.md) were chosen on simulated training routes
and on the *tuning* drives above; HDR+ is fitted to each drive from its own calibration window
and output step (`HdrPlusParams.fitted`, through this script's `fit_plus` until `hdrd evaluate`
does it). **Disclosure:** one setting, the limit on how fast the online random walk may rise
(`q_adapt_max_rise`), was added after the judging drives had been seen (rtklib drive 0708 was
1.11° -> 2.17° before it, 1.65° after; the judging mean 2.970 before, 2.972 after); it was then
measured on the training data only. These judging numbers are therefore not fully held out.

**Reading** (written by hand from the run above; re-read the tables if the code changed).
HDR+ does not reach the issue's real-drive targets here: its judging mean (2.97 deg/min) is
0.90 of bias removal's (3.29; the target is 0.67) and below paper HDR's (3.10); three of seven
judging drives are more than 10 % and 0.5° worse than bias removal (DrivePlotR 8 and 18,
rtklib), against four for paper HDR. On rtklib drive 0708, a tactical-grade IMU with an
exact start-up calibration (the best constant bias in hindsight is the calibrated one), any
correction can only hurt: HDR+ adds 0.54° over 8.6 minutes, paper HDR 2.3°. The DrivePlotR
logs are 1 Hz point samples of a phone gyro in 1/16 deg/s steps: aliasing of turns and a
scale-factor error of 3-17 % against the GPS course (measured on the tuning drives) dominate
their heading error, which no bias estimate removes (the best constant bias in hindsight still
leaves 1.2-1.6 deg/min), and their GPS speed lags, so standstill steps include the first
seconds of pulling away. On the 2.4-hour drive 30 with its hindsight bias given, HDR+ doubles
the error (26.7° -> 52.3°): over hours, straight-road measurements on a real road with
systematic gentle curvature move the bias model (the simulator's roads do not). smartLoc with
its hindsight bias: 1.42° -> 1.46° (paper HDR 9.14°).
"""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workdir", default="/tmp/hdrd-real")
    ap.add_argument("--no-write", action="store_true", help="print only")
    ap.add_argument(
        "--tuning-only",
        action="store_true",
        help="score and print the tuning drives only (no write): for development",
    )
    a = ap.parse_args(argv)
    if not DATA.is_dir():
        print(f"bench/real.py: {DATA} is absent: no real drives to score", file=sys.stderr)
        return 1
    work = Path(a.workdir)
    folder = work / "real"
    shown: list[str] = []
    run([sys.executable, "tools/convert_real.py", "all", "--out-dir", str(folder)], shown)
    drives = load_drives(folder)
    if a.tuning_only:
        drives = [d for d in drives if d.set == "tune"]
        a.no_write = True
    methods = ("none", "hdr", "hdr+")
    tab, means = table(drives, methods)
    summ = summary(means, methods)
    given = given_table(drives, methods)
    print(summ)
    print(tab)
    print(given)
    body = f"""{SECTION}

Generated by `python bench/real.py` ({machine_line()}). It runs:

```sh
{chr(10).join(shown)}
```

then, per converted log, the start-up calibration and the methods in-process, exactly as
`hdrd evaluate --calibrate-seconds S --method hdr+` on the log from the calibration's first row
(S and that row per drive in the table; paper HDR with Table III, HDR+ with its defaults).

**Split, fixed before any method ran on these drives** (bench/real.py `TUNING`, `JUDGING`):
tuning = DrivePlotR drives with an odd drive number and comma2k19; judging = DrivePlotR
drives with an even number, rtklib drive 0708 and smartLoc Berlin. Calibration: each log's
start-up standstill (`lead_in_s`) or else its first standstill found from the speed (2 s dropped
at its start, a 1 s / 3 s margin at its end), averaged for at most 30 s; the drive is scored
from the end of the calibration. Drives without a 3 s standstill, or with less than 5 minutes
left to score, are listed, not scored. *Best const.*: the one constant bias that minimises the
drive's Eψ with no other correction (known only in hindsight: a reference, not a method).
"Worse" counts a drive whose NEψ exceeds 1.1 × bias removal's by more than 0.5° of Eψ.

{summ}

Per drive (Eψ in degrees, NEψ in deg/min):

{tab}

Drives without a usable standstill (at least {GIVEN_MIN_MIN:g} minutes long), evaluated whole
with their best constant bias in hindsight *given* (`hdrd evaluate --bias B`): not a realistic
calibration, but what a method adds to (or takes from) a perfect static bias:

{given}

{DISCUSSION.strip()}
"""
    if not a.no_write:
        replace_section(SECTION, body)
        print(f"wrote the section {SECTION!r} of bench/RESULTS.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
