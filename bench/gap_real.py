#!/usr/bin/env python3
"""The simulated-versus-real gap on the real moving drives: what the simulator lacked there,
measured on the tuning drives, and the gap before and after the simulator got it.

    python bench/gap_real.py [--workdir /tmp/hdrd-gap-real] [--no-write]

1. As a process, the commands a user runs: ``python tools/convert_real.py all --out-dir DIR``,
   then ``python -m hdrd gap DRIVE.csv --report R.json`` on every moving drive of at least
   :data:`MIN_MINUTES` (truth: the GNSS course).
2. On the *tuning* drives only (bench/real.py's split: DrivePlotR odd drive numbers), what the
   simulator's values for that recording are measured from (bench/recordings.py):
   the noise inside stops, the course's latency (``time_offset``), the bias's random walk
   while driving, the course's noise; and the scale factor with the latency in the model
   (reported: it is not established, so the profile keeps the grade's). The script checks that the
   profile's values are these measurements (it stops if they differ by more than rounding).
3. On every moving drive: the gap (docs/model-gap.md, section 8) of the simulator's model for
   the recording's gyro *as given* (the grade preset bench/real.py configures for the
   hardware: phone for DrivePlotR, tactical for rtklib, automotive for smartLoc), mean and sd
   over six seeds, before (the preset at the log's rate) and after (the recording's profile,
   bench/recordings.py's :func:`log_rate_model`), and what ``hdrd gap --model`` still names
   from the after model. Recordings without tuning drives (rtklib, smartLoc) have no after.
4. Rewrites its own section of bench/RESULTS.md (Model gap).

The judging drives (DrivePlotR even drive numbers, rtklib drive 0708, smartLoc) were run once,
after the profile's values were fixed from the tuning drives.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from _common import machine_line, put_section
from real import TUNING, drive_set, grade_of
from recordings import Recording, log_rate_model, point_sampled_sd

from hdrd.analysis.gap import GapError, prepare, run_gap
from hdrd.analysis.gap.candidates import evaluate_candidate
from hdrd.analysis.gap.data import GapData, stop_interior
from hdrd.analysis.gap.fit import Fit, Fitter, fit_model
from hdrd.analysis.gap.metric import gap_metric
from hdrd.core.grades import Grade
from hdrd.io.files.drivelog import read_drive
from hdrd.sim.effects import Quantization, RateRandomWalk, TimeOffset, WhiteNoise
from hdrd.sim.grades import grade_model
from hdrd.sim.gyro import DEFAULT_START_MODEL, GyroModel

SECTION = "## Model gap on the real moving drives: what the simulator lacked, before and after"
MIN_MINUTES = 4.5
"""Drives shorter than this, min, are listed, not analysed (a few blocks say little)."""
SEEDS = (0, 1000, 1001, 1002, 1003, 1004)
"""The gap's seeds: hdrd gap's own six (its seed, then the seed-to-seed ones)."""
PROFILE_OF = {"nds": "driveplotr"}
"""The recording profile of each recording (by name prefix); others have none."""


def profile_of(name: str) -> str | None:
    return next((p for k, p in PROFILE_OF.items() if name.startswith(k)), None)


def before_model(name: str, hz: float) -> GyroModel:
    """The simulator's model of the recording's gyro before this work: the grade preset
    bench/real.py configures for the hardware, at the log's rate (what ``hdrd simulate
    --grade G --hz HZ`` makes), without its temperature effect (no log has a temperature)."""
    del hz  # the grade's effects act at whatever rate the log has
    return grade_model(grade_of(name), 0).without("temperature_bias")


# -- 1. the user's commands ----------------------------------------------------------------------


def convert(workdir: Path) -> Path:
    out = workdir / "real"
    cmd = [sys.executable, str(REPO / "tools" / "convert_real.py"), "all", "--out-dir", str(out)]
    subprocess.run(cmd, check=True, cwd=REPO, capture_output=True, text=True)
    return out


def hdrd_gap(csv: Path, report: Path, model: Path | None = None) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "hdrd", "gap", str(csv), "--report", str(report)]
    if model is not None:
        cmd += ["--model", str(model)]
    env = {**os.environ, "PYTHONPATH": str(REPO)}  # this tree's hdrd, as the tests run it
    subprocess.run(cmd, check=True, cwd=REPO, capture_output=True, text=True, env=env)
    return dict(json.loads(report.read_text()))


def named(rep: dict[str, Any]) -> str:
    steps = [s["effect"] for s in rep["steps"]]
    rej = sorted({r["effect"] for r in rep["rejected"]} - set(steps))
    out = " -> ".join(steps) if steps else "nothing"
    if rej:
        out += f" (significant, not added: {', '.join(rej)})"
    return out


# -- 2. measurements on the tuning drives ---------------------------------------------------------


@dataclass
class Measure:
    """What one tuning drive shows (rates deg/s)."""

    name: str
    minutes: float
    stop_sd: float  # sd per sample inside stops, as hdrd gap reads it (white + ADC step)
    delay_s: float
    delay_dbic: float
    scale: float
    scale_se: float  # nan: the fit gained nothing (no information)
    rrw: float
    rrw_dbic: float
    rrw_sig: bool
    course_sd_deg: float  # the heading noise at the fixes fitted with the profile's model
    bias_moving: float  # the static bias hdrd gap fits while driving (with the latency)
    bias_stopped: float  # the mean rate inside the stops (nan: no stop)
    blocks: tuple[np.ndarray, np.ndarray] = field(
        repr=False, default=(np.zeros(0), np.zeros((0, 4)))
    )
    """The block residual with the latency in the model (deg/s) and its regressors per block:
    speed (m/s), longitudinal and lateral acceleration and |lateral| (m/s**2)."""


def _base(data: GapData) -> GyroModel:
    m = DEFAULT_START_MODEL
    if data.lattice is not None:
        m = m.with_effect(Quantization(step_dps=data.lattice.step_dps))
    return m


def _trimmed_mean(x: np.ndarray, q: float) -> float:
    """Mean of x without the values further than 5 robust sd from the median (a stop where
    the phone was handled), nan when empty."""
    if x.shape[0] == 0:
        return math.nan
    med = float(np.median(x))
    mad = max(float(np.median(np.abs(x - med))), q)
    return float(np.mean(x[np.abs(x - med) <= 5.0 * 1.4826 * mad]))


def measure(data: GapData) -> Measure:
    f = Fitter(data)
    base = fit_model(data, _base(data))
    q = base.noise.q_step
    stop_sd = math.sqrt(base.noise.white_var + q * q / 12.0)
    to = evaluate_candidate(f, base, "time_offset")
    te = to.fit.model.get("time_offset")
    assert isinstance(te, TimeOffset)
    lag: Fit = fit_model(data, _base(data).with_effect(TimeOffset(delay_s=te.delay_s)))
    sf = evaluate_candidate(f, lag, "scale_factor")
    err = float(getattr(sf.fit.model.get("scale_factor"), "error", math.nan))
    se = abs(err) / math.sqrt(2.0 * sf.dlnl) if sf.dlnl > 1e-6 and err != 0.0 else math.nan
    rw = evaluate_candidate(f, lag, "rate_random_walk")
    k = float(getattr(rw.fit.model.get("rate_random_walk"), "k_dps_per_sqrt_s", math.nan))
    prof = fit_model(data, log_rate_model("driveplotr", 0))
    course_sd = math.sqrt(prof.noise.extra_var / 2.0) * data.block_s
    stops = stop_interior(data)
    assert data.speed is not None
    v = data.block_mean(np.nan_to_num(data.speed))
    w = data.btruth
    bt = data.bt[data.bvalid]
    a_long = np.gradient(v, bt) if v.shape[0] > 2 else np.zeros_like(v)
    a_lat = np.radians(w) * v
    e = f.ebar - lag.dbar
    sb = lag.model.get("static_bias")
    return Measure(
        name=data.name,
        minutes=data.duration_s / 60.0,
        stop_sd=stop_sd,
        delay_s=te.delay_s,
        delay_dbic=to.dbic,
        scale=err,
        scale_se=se,
        rrw=k,
        rrw_dbic=rw.dbic,
        rrw_sig=rw.significant,
        course_sd_deg=course_sd,
        bias_moving=float(getattr(sb, "bias_dps", math.nan)),
        bias_stopped=_trimmed_mean(data.omega[stops], q),
        blocks=(e, np.column_stack([v, a_long, a_lat, np.abs(a_lat)])),
    )


@dataclass(frozen=True)
class Pooled:
    stop_sd: float
    white: float  # installed density at the sensor, deg/s/sqrt(Hz)
    latency_s: float
    scale: float
    scale_se: float
    scale_median: float
    scale_chi2: float  # of the per-drive scales about their mean, against their own se
    scale_n: int
    rrw: float
    rrw_from: int
    course_sd_deg: float


def pool(ms: list[Measure], profile: str) -> Pooled:
    r = Recording.from_table(profile)
    g = Grade.from_table(r.grade)
    sd = statistics.median(m.stop_sd for m in ms)
    sd_noq = math.sqrt(max(sd * sd - r.quant_step_dps**2 / 12.0, 0.0))
    white = (
        r.white_dps_per_rthz
        * sd_noq
        / point_sampled_sd(r.white_dps_per_rthz, g.bandwidth_hz, r.sensor_hz)
    )
    inf = [m for m in ms if math.isfinite(m.scale_se) and m.scale_se > 0]
    w = np.array([1.0 / m.scale_se**2 for m in inf])
    s = np.array([m.scale for m in inf])
    sig = [m.rrw for m in ms if m.rrw_sig]
    return Pooled(
        stop_sd=sd,
        white=white,
        latency_s=-statistics.median(m.delay_s for m in ms),
        scale=float(np.sum(w * s) / np.sum(w)),
        scale_se=float(1.0 / math.sqrt(np.sum(w))),
        scale_median=float(np.median(s)),
        scale_chi2=float(np.sum(w * (s - np.sum(w * s) / np.sum(w)) ** 2)),
        scale_n=len(inf),
        rrw=statistics.median(sig) if sig else 0.0,
        rrw_from=len(sig),
        course_sd_deg=statistics.median(m.course_sd_deg for m in ms),
    )


REGRESSORS = (
    "speed, per m/s",
    "longitudinal acceleration, per m/s²",
    "lateral acceleration, per m/s²",
    "|lateral acceleration|, per m/s²",
)


def motion_regression(ms: list[Measure]) -> list[tuple[str, float, float]]:
    """Does the residual while driving follow the motion (a speed- or acceleration-correlated
    bias, g-sensitivity)? Ordinary least squares of the block residual (the latency in the
    model) on :data:`REGRESSORS`, with an intercept per drive (its bias), pooled over the
    tuning drives: (regressor, coefficient deg/s per unit, its se). The se is ordinary least
    squares' (the residual's neighbouring blocks are correlated: a rough figure)."""
    ys, xs = [], []
    for j, m in enumerate(ms):
        e, x = m.blocks
        dummies = np.zeros((e.shape[0], len(ms)))
        dummies[:, j] = 1.0
        ys.append(e)
        xs.append(np.hstack([dummies, x]))
    y, x = np.concatenate(ys), np.vstack(xs)
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    res = y - x @ beta
    s2 = float(res @ res) / (y.shape[0] - x.shape[1])
    se = np.sqrt(np.diag(s2 * np.linalg.pinv(x.T @ x)))
    k = len(ms)
    return [(REGRESSORS[i], float(beta[k + i]), float(se[k + i])) for i in range(len(REGRESSORS))]


def check_profile(p: Pooled, profile: str) -> list[str]:
    """The profile's values against the measurements: rounding only (say what differs)."""
    r = Recording.from_table(profile)
    pairs = [
        ("white_dps_per_rthz", r.white_dps_per_rthz, p.white, 0.05),
        ("rrw_dps_per_sqrt_s", r.rrw_dps_per_sqrt_s, p.rrw, 0.05),
        ("gps_latency_s", r.gps_latency_s, p.latency_s, 0.05),
        ("gps_course_sd_deg", r.gps_course_sd_deg, p.course_sd_deg, 0.05),
    ]
    return [
        f"{k}: profile {v:.4g}, measured {m:.4g}"
        for k, v, m, rel in pairs
        if not (abs(v - m) <= rel * abs(m) + 1e-12)
    ]


# -- 3. the gap before and after -----------------------------------------------------------------


def gap_as_given(data: GapData, model: GyroModel) -> tuple[float, float]:
    """The gap of ``model`` as given (docs/model-gap.md, section 8), mean and sd over
    :data:`SEEDS`; the truth's noise is the one nuisance fitted (with the model refitted, as
    ``hdrd gap``'s ``gap_as_given`` takes it)."""
    tv = fit_model(data, model).noise.extra_var
    gaps = [gap_metric(data, model, s, None, tv).gap for s in SEEDS]
    return statistics.mean(gaps), statistics.stdev(gaps)


def delta_bic(data: GapData, before: GyroModel, after: GyroModel) -> float:
    """BIC of ``after`` minus that of ``before``, each refitted to the log (``hdrd gap``'s
    likelihood: negative = the log is better explained by ``after``)."""
    return fit_model(data, after).bic - fit_model(data, before).bic


def ladder(name: str) -> list[tuple[str, GyroModel]]:
    """The before model with the profile's changes added one at a time (cumulative), the last
    rung being bench/recordings.py's :func:`log_rate_model`: what each change does to the gap."""
    prof = profile_of(name)
    if prof is None:
        return []
    r = Recording.from_table(prof)
    g = Grade.from_table(r.grade)
    m0 = before_model(name, r.log_hz)
    m1 = m0.with_effect(Quantization(step_dps=r.quant_step_dps))
    sd = point_sampled_sd(r.white_dps_per_rthz, g.bandwidth_hz, r.sensor_hz)
    m2 = m1.with_effect(WhiteNoise(density_dps_per_rthz=sd / math.sqrt(r.log_hz)))
    m3 = m2.with_effect(RateRandomWalk(k_dps_per_sqrt_s=r.rrw_dps_per_sqrt_s))
    m4 = log_rate_model(prof, 0)
    return [
        ("before: the grade preset", m0),
        ("+ the log's ADC step", m1),
        ("+ point samples of the installed sensor noise", m2),
        ("+ the bias's random walk while driving", m3),
        ("+ the course's latency (time_offset): the profile", m4),
    ]


@dataclass
class Row:
    name: str
    set: str
    minutes: float
    user: str  # what hdrd gap names from its default start
    user_gap: tuple[float, float]
    before: tuple[float, float]
    after: tuple[float, float] | None
    still: str  # what hdrd gap still names from the after model
    rungs: list[float] = field(default_factory=list)  # mean gap at each rung of ladder()
    dbic: float = math.nan  # BIC(profile) - BIC(preset), both refitted


def analyse(csv: Path, workdir: Path) -> Row | None:
    log = read_drive(csv, csv.stem)
    name = log.name or csv.stem
    try:
        data = prepare(log)
    except GapError:
        return None
    if data.duration_s / 60.0 < MIN_MINUTES:
        return None
    rep = hdrd_gap(csv, workdir / f"{name}.gap.json")
    before = gap_as_given(data, before_model(name, data.fs_hz))
    prof = profile_of(name)
    after = None
    rungs: list[float] = []
    dbic = math.nan
    still = "n/a (no tuning drive of this recording)"
    if prof is not None:
        m = log_rate_model(prof, 0)
        after = gap_as_given(data, m)
        rungs = [gap_as_given(data, lm)[0] for _, lm in ladder(name)[1:-1]]
        dbic = delta_bic(data, before_model(name, data.fs_hz), m)
        res = run_gap(data, m)
        steps = [s.effect for s in res.steps]
        rej = sorted({r["effect"] for r in res.rejected} - set(steps))
        still = (" -> ".join(steps) if steps else "nothing") + (
            f" (significant, not added: {', '.join(rej)})" if rej else ""
        )
    return Row(
        name=name,
        set=drive_set(name),
        minutes=data.duration_s / 60.0,
        user=named(rep),
        user_gap=(rep["gap_initial"], rep["gap_final"]),
        before=before,
        after=after,
        still=still,
        rungs=[before[0], *rungs, after[0]] if after is not None else [],
        dbic=dbic,
    )


# -- 4. the section ---------------------------------------------------------------------------------


def fmt(g: tuple[float, float] | None) -> str:
    return "n/a" if g is None else f"{g[0]:.3g} ± {g[1]:.2g}"


def _head(machine: str) -> list[str]:
    """How the section was made, and the tuning drives' table head."""
    return [
        SECTION,
        "",
        f"Generated by `python bench/gap_real.py` ({machine}). It runs `python tools/convert_real.py "
        "all --out-dir DIR` and `python -m hdrd gap DRIVE.csv --report R.json` on every moving "
        f"drive of at least {MIN_MINUTES:g} min (truth: the GNSS course), then in-process the "
        "measurements and gaps below. Split (bench/real.py, fixed before any result): tuning = "
        "DrivePlotR odd drive numbers; judging = DrivePlotR even numbers, rtklib drive 0708, "
        "smartLoc. The profile's values (bench/recordings.py) come from the tuning drives "
        "only; the judging drives were run once, after they were fixed.",
        "",
        "**Tuning drives: what they show** (rates deg/s; `hdrd gap`'s fits with the log's "
        "ADC step in the model; scale and random walk with the course latency in the model):",
        "",
        "| drive | min | sd per sample in stops | time_offset s (dBIC) | scale error (± se) | random walk K deg/s/√s (dBIC) | course noise at the fixes, deg | bias driving / in stops, deg/s |",
        "|---|---|---|---|---|---|---|---|",
    ]


def _measure_row(m: Measure) -> str:
    se = f" ± {m.scale_se:.3f}" if math.isfinite(m.scale_se) else " (no information)"
    return (
        f"| {m.name} | {m.minutes:.1f} | {m.stop_sd:.3f} | {m.delay_s:+.2f} ({m.delay_dbic:+.0f}) "
        f"| {m.scale:+.3f}{se} | {m.rrw:.2g} ({m.rrw_dbic:+.1f}"
        f"{', significant' if m.rrw_sig else ''}) | {m.course_sd_deg:.2f} "
        f"| {m.bias_moving:+.3f} / {m.bias_stopped:+.3f} |"
    )


def _pooled(ms: list[Measure], p: Pooled) -> list[str]:
    """The pooled measurements beside the profile's values, the motion regression, and the
    gap table's head."""
    r = Recording.from_table("driveplotr")
    return [
        "",
        f"Pooled: sd in stops {p.stop_sd:.3f} deg/s per sample (median) -> installed white noise "
        f"{p.white:.4f} deg/s/√Hz at a 100 Hz sensor of 32 Hz bandwidth (profile "
        f"{r.white_dps_per_rthz}); course latency {p.latency_s:.2f} s (median; profile "
        f"{r.gps_latency_s}); random walk {p.rrw:.3g} deg/s/√s (median of the {p.rrw_from} "
        f"drives where it is significant; profile {r.rrw_dps_per_sqrt_s}); course noise "
        f"{p.course_sd_deg:.2f} deg (median; profile {r.gps_course_sd_deg}). Scale error: "
        f"inverse-variance mean {p.scale:+.4f} ± {p.scale_se:.4f}, but the {p.scale_n} drives "
        f"scatter about it with chi² {p.scale_chi2:.0f} on {p.scale_n - 1} degrees of freedom "
        f"(median {p.scale_median:+.3f}): a gain that differs from drive to drive, or a fit "
        "whose se is too small; not established, so the profile keeps the grade's 1 %.",
        "",
        "Does the residual while driving follow the motion? Pooled over the tuning drives, an "
        "intercept (bias) per drive, ordinary least squares on the blocks (se rough: "
        "neighbouring blocks are correlated): "
        + "; ".join(f"{lab} {b:+.4f} ± {e:.4f} deg/s" for lab, b, e in motion_regression(ms))
        + ".",
        "",
        "**The gap, simulated versus real** (docs/model-gap.md, section 8: mean ± sd over six "
        "seeds, each model *as given*; before = the grade preset bench/real.py configures for "
        "the hardware, at the log's rate, without its temperature effect; after = the "
        "recording's profile as its log sees it, bench/recordings.py's `log_rate_model`, the "
        "course latency as a `time_offset`; dBIC: the profile against the preset, both refitted, by `hdrd gap`'s likelihood):",
        "",
        "| set | drive | min | `hdrd gap` names (default start) | its gap initial -> final | gap before | gap after | dBIC after - before | `hdrd gap --model` after still names |",
        "|---|---|---|---|---|---|---|---|---|",
    ]


def _gap_row(w: Row) -> str:
    return (
        f"| {w.set} | {w.name} | {w.minutes:.1f} | {w.user} | {w.user_gap[0]:.3g} -> "
        f"{w.user_gap[1]:.3g} | {fmt(w.before)} | {fmt(w.after)} | "
        f"{'n/a' if math.isnan(w.dbic) else f'{w.dbic:+.0f}'} | {w.still} |"
    )


def _ladder_rows(rows: list[Row]) -> list[str]:
    """The ladder's table: the gap's mean per change, tuning and judging drives apart (none
    without a drive that climbed it)."""
    labels = [lab for lab, _ in ladder("nds_drive01")]
    sets = [(s, [w for w in rows if w.set == s and w.rungs]) for s in ("tune", "judge")]
    sets = [(s, ws) for s, ws in sets if ws]
    if not sets:
        return []
    out = [
        "",
        "What each change does (the gap's mean over the DrivePlotR drives, each change added "
        "to the ones above it):",
        "",
        "| model | "
        + " | ".join(f"{len(ws)} {'tuning' if s == 'tune' else 'judging'} drives" for s, ws in sets)
        + " |",
        "|---|" + "---|" * len(sets),
    ]
    for i, lab in enumerate(labels):
        vals = [statistics.mean(w.rungs[i] for w in ws) for _, ws in sets]
        out.append(f"| {lab} | " + " | ".join(f"{v:.3g}" for v in vals) + " |")
    return out


def section(ms: list[Measure], p: Pooled, rows: list[Row], skipped: list[str], machine: str) -> str:
    """The section: how it was made, the tuning drives' measurements, pooled, the gap per drive
    and per change of the model, what was not analysed."""
    out = _head(machine)
    out += [_measure_row(m) for m in ms]
    out += _pooled(ms, p)
    out += [_gap_row(w) for w in rows]
    out += _ladder_rows(rows)
    if skipped:
        out += ["", "Not analysed: " + "; ".join(skipped) + "."]
    return "\n".join(out) + "\n"


def _tuning_measures(csvs: list[Path]) -> tuple[list[Measure], list[str]]:
    """The tuning drives' measurements, and the drives skipped (with why)."""
    ms: list[Measure] = []
    skipped: list[str] = []
    for csv in csvs:
        name = csv.stem
        if name not in TUNING or profile_of(name) != "driveplotr":
            continue
        try:
            data = prepare(read_drive(csv, name))
        except GapError as e:
            skipped.append(f"{name} ({e})")
            continue
        if data.duration_s / 60.0 < MIN_MINUTES:
            skipped.append(f"{name} ({data.duration_s / 60.0:.1f} min)")
            continue
        ms.append(measure(data))
        print(ms[-1], flush=True)
    return ms, skipped


def _gap_rows(csvs: list[Path], args: argparse.Namespace, skipped: list[str]) -> list[Row]:
    """Each drive's gap row (tuning drives first); a drive too short joins ``skipped``."""
    rows: list[Row] = []
    for csv in csvs:
        if args.tuning_only and csv.stem not in TUNING:
            continue
        row = analyse(csv, args.workdir)
        if row is None:
            if csv.stem not in {s.split(" ")[0] for s in skipped}:
                skipped.append(f"{csv.stem} (shorter than {MIN_MINUTES:g} min of truth)")
            continue
        rows.append(row)
        print(row, flush=True)
    rows.sort(key=lambda w: (w.set != "tune", w.name))
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/hdrd-gap-real"))
    ap.add_argument("--no-write", action="store_true", help="print, do not touch RESULTS.md")
    ap.add_argument("--tuning-only", action="store_true", help="measure on the tuning drives only")
    args = ap.parse_args(argv)
    data_dir = Path(os.environ.get("HDRD_REAL_DATA") or REPO.parent / "shared" / "data")
    if not data_dir.is_dir():
        print(f"bench/gap_real.py: {data_dir} is absent: nothing to do", file=sys.stderr)
        return 1
    args.workdir.mkdir(parents=True, exist_ok=True)
    machine = machine_line()
    real = convert(args.workdir)
    csvs = sorted(real.glob("*.csv"))
    ms, skipped = _tuning_measures(csvs)
    p = pool(ms, "driveplotr")
    print(p)
    differ = check_profile(p, "driveplotr")
    if differ:
        print("the profile's values are not the tuning drives' measurements:", file=sys.stderr)
        for d in differ:
            print("  " + d, file=sys.stderr)
        return 1
    rows = _gap_rows(csvs, args, skipped)
    text = section(ms, p, rows, skipped, machine)
    print(text)
    if not args.no_write:
        put_section("gap", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
