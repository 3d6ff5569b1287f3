"""Evaluation against ground truth: the paper's Table II for any drive logs.

Pure core (:func:`prepare_drive`, :func:`evaluate_prepared`, :func:`evaluate_drive`,
:func:`summarize`, :func:`to_json`, :func:`format_table`) and the ``hdrd evaluate`` edge
(:func:`main`).

How a drive log becomes Table II numbers:

1. Static bias eps0 (deg/s): given, or the mean of the first S seconds of the log (paper:
   "Each experiment started by measuring the static bias drift, eps0, while the vehicle was
   standing still for about 20 seconds"), refused if those samples show motion
   (:func:`hdrd.calibrate.estimate_bias`).
2. The raw rate is block-averaged to steps of T (paper: 1 s, Eq. 11) with
   :func:`hdrd.resample.block_average_seconds`: step i holds the samples with t in
   [t0 + iT, t0 + (i+1)T). Only complete steps are kept: n = floor((t_last - t0 + dt) / T),
   dt the median sample period. A step without samples (a gap in the log) repeats the
   previous step's rate and is counted in ``missing_steps``.
3. The drive starts where the calibration ends: when the bias is measured over the first S
   seconds, the steps before ceil(S / T) are dropped (the daemon, too, calibrates and then
   runs HDR); when the bias is given, the whole log is the drive.
4. u_i = block mean - eps0 (Eqs. 2, 11) goes through each method (``none``: static bias
   only; ``hdr``: :func:`hdrd.hdr.run_batch` with the given parameters) from yaw 0 at the
   drive's start, giving the yaw at each step's END, t0 + (i+1)T; ``hdr+``:
   :func:`hdrd.hdrplus.run_batch` with its own defaults (only T taken from the parameters),
   also given each step's sample spread, speed and temperature.
5. The truth heading is sampled at those same step ends (:func:`hdrd.analysis.metrics.truth_at`,
   interpolating between fixes at most 2 s apart), the yaw is aligned to the truth at the
   first step end where truth exists, and Eψ (Eq. 12) is the mean |error| over the step ends
   where truth exists.
6. Td, the drive's duration in minutes for NEψ (Eq. 13), is (number of drive steps) * T / 60:
   the time from the drive's start (end of calibration) to the last complete step.

Methods are dispatched through :data:`METHODS` (name -> function of the per-step inputs, the
HDR parameters and HDR+'s settings, returning yaw), the one place a new drift reducer is
registered.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.analysis.metrics import align_index, e_psi, gyro_heading, improvement, ne_psi, truth_at
from hdrd.calibrate import MotionDetected, estimate_bias
from hdrd.drivelog import DriveLog
from hdrd.hdr import HdrParams, run_batch
from hdrd.hdrplus import PLUS_CORE, HdrPlusParams
from hdrd.hdrplus import run_batch as run_plus
from hdrd.resample import block_average_seconds

__all__ = [
    "METHODS",
    "DriveResult",
    "EvaluationError",
    "MethodFn",
    "PreparedDrive",
    "StepInputs",
    "evaluate_drive",
    "evaluate_prepared",
    "format_table",
    "main",
    "method_key",
    "prepare_drive",
    "summarize",
    "to_json",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

PAPER_PARAMS = HdrParams()
"""The paper's Table III parameters (HDR's defaults)."""
PLUS_DEFAULTS = HdrPlusParams()
"""HDR+'s own settings (its extras at their defaults; the core is set per drive's T)."""
DEFAULT_CALIBRATE_S = 30.0
"""Default calibration window, s (paper Sec. 2: Tbias = 30 s)."""
TRUTH_MAX_GAP_S = 2.0
"""Truth is interpolated between fixes at most this far apart (1 Hz GPS with one fix lost)."""


class EvaluationError(ValueError):
    """A drive that cannot be evaluated; the message names the drive and says why."""


@dataclass(frozen=True)
class StepInputs:
    """Everything a drift reducer may use, one element per step T.

    u: block mean of the raw rate minus the static bias, deg/s CCW (Eqs. 2, 11). t_end: end
    of each step, s since the log's first sample. T: step period, s. bias_dps: the static bias
    removed, deg/s. n_samples: samples averaged in each step (0 = gap, u held from the step
    before). speed: mean speed in each step, m/s (NaN where unknown), None if the log has none.
    temp_c: mean temperature in each step, deg C, or None. omega_std: standard deviation of the
    raw samples within each step, deg/s (0 for a single sample), for standstill detection.
    bias_var: variance of the static bias estimate, (deg/s)^2 (sample variance / samples of
    the calibration window; NaN if the bias was given).
    """

    u: FloatArray
    t_end: FloatArray
    T: float
    bias_dps: float
    n_samples: IntArray
    speed: FloatArray | None = None
    temp_c: FloatArray | None = None
    omega_std: FloatArray | None = None
    bias_var: float = math.nan


MethodFn = Callable[[StepInputs, HdrParams, HdrPlusParams], FloatArray]
"""A drift reducer: per-step inputs, the HDR parameters and HDR+'s settings (the config's
``standstill.*``; only hdr+ reads them) -> yaw at each step end, deg CCW."""


def _yaw_none(steps: StepInputs, params: HdrParams, plus: HdrPlusParams) -> FloatArray:
    # Static bias removal only: psi_i = psi_{i-1} + u_i * T (Eq. 3 with I = 0). Sequential
    # cumsum: bit-identical to run_batch(u, HdrParams.off()).yaw.
    return np.cumsum(steps.u * params.T)


def _yaw_hdr(steps: StepInputs, params: HdrParams, plus: HdrPlusParams) -> FloatArray:
    return run_batch(steps.u, params).yaw


def _yaw_hdrplus(steps: StepInputs, params: HdrParams, plus: HdrPlusParams) -> FloatArray:
    # HDR+ runs with its own core (tuned together with its extras), at the drive's T; its
    # prior on the bias is how well the calibration measured it, when it was measured.
    plus = plus.with_(hdr=replace(PLUS_CORE, T=params.T))
    if math.isfinite(steps.bias_var):
        plus = plus.with_(bias_p0=steps.bias_var)
    return run_plus(steps.u, steps.omega_std, steps.speed, steps.temp_c, steps.T, plus).yaw


METHODS: dict[str, MethodFn] = {"none": _yaw_none, "hdr": _yaw_hdr, "hdr+": _yaw_hdrplus}
"""Drift reducers by name (``--method``). ``none`` is the "without HDR" column of Table II."""


def method_key(method: str) -> str:
    """The suffix of a method's JSON keys: ``none`` -> ``raw`` (Table II's "without HDR")."""
    return "raw" if method == "none" else method


@dataclass(frozen=True)
class PreparedDrive:
    """A drive reduced to what the metrics need: per-step inputs and truth at step ends.

    truth: compass heading, deg CW, at each step end (NaN where unknown). k: the step where
    the gyro is aligned to the truth. duration_min: Td of Eq. 13. bias_source: "given" or
    "first S s". bias_std_dps: spread of the calibration samples, deg/s (NaN if given).
    start_s: where the evaluated drive starts, s after the log's first sample (the end of
    the calibration window, 0 if the bias was given).
    """

    name: str
    steps: StepInputs
    truth: FloatArray
    k: int
    duration_min: float
    bias_source: str
    bias_std_dps: float
    missing_steps: int
    start_s: float = 0.0


@dataclass(frozen=True)
class DriveResult:
    """Table II's row for one drive, plus the traces the plots draw.

    e_psi, ne_psi: Eψ (deg) and NEψ (deg/min) per method name. improvement: Eψ(none) /
    Eψ(primary), the primary method being the last one evaluated. heading: the aligned gyro
    heading per method, deg CW, continuous (not wrapped), at each step end.
    """

    name: str
    duration_min: float
    bias_dps: float
    bias_source: str
    n_steps: int
    n_compared: int
    missing_steps: int
    methods: tuple[str, ...]
    e_psi: dict[str, float]
    ne_psi: dict[str, float]
    t_end: FloatArray = field(repr=False)
    truth: FloatArray = field(repr=False)
    heading: dict[str, FloatArray] = field(repr=False)

    @property
    def primary(self) -> str:
        return self.methods[-1]

    @property
    def improvement(self) -> float:
        return improvement(self.e_psi["none"], self.e_psi[self.primary])

    def improvement_of(self, method: str) -> float:
        return improvement(self.e_psi["none"], self.e_psi[method])


def _step_means(t: FloatArray, t0: float, values: FloatArray, n_steps: int, T: float) -> FloatArray:
    """Mean of the finite values in each step (NaN for a step without any), same edges as
    :func:`hdrd.resample.block_means`."""
    T_us = round(T * 1_000_000)
    idx = np.rint((t - t0) * 1e6).astype(np.int64) // T_us
    ok = np.isfinite(values) & (idx < n_steps)
    sums = np.bincount(idx[ok], weights=values[ok], minlength=n_steps)[:n_steps]
    counts = np.bincount(idx[ok], minlength=n_steps)[:n_steps]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


def prepare_drive(
    log: DriveLog,
    bias: float | None = None,
    calibrate_seconds: float = DEFAULT_CALIBRATE_S,
    T: float = 1.0,
    truth_max_gap_s: float = TRUTH_MAX_GAP_S,
) -> PreparedDrive:
    """Bias, step averages and truth at step ends for one drive (see the module docstring).

    bias: static bias eps0 in deg/s; None = measure it over the first ``calibrate_seconds``.
    Raises EvaluationError if the log is too short, has no truth heading at all, or its
    calibration window shows motion.
    """
    name = log.name or "drive"
    n_rows = len(log)
    if n_rows < 2:
        raise EvaluationError(f"{name}: only {n_rows} sample(s); a drive needs at least 2")
    if log.heading_truth is None or not np.isfinite(log.heading_truth).any():
        raise EvaluationError(f"{name}: no truth heading (column heading_truth is absent or empty)")
    t = log.t
    t0 = float(t[0])
    dt = float(np.median(np.diff(t)))
    n_steps = math.floor((float(t[-1]) - t0 + dt) / T + 1e-9)
    if n_steps < 2:
        raise EvaluationError(
            f"{name}: {t[-1] - t0 + dt:.2f} s long; at least 2 steps of {T:g} s needed"
        )

    if bias is None:
        if not calibrate_seconds > 0:
            raise EvaluationError(
                f"{name}: calibration window must be > 0 s, got {calibrate_seconds!r}"
            )
        win = t < t0 + calibrate_seconds
        try:
            rec = estimate_bias(log.omega[win], t[win])
        except MotionDetected as e:
            raise EvaluationError(
                f"{name}: cannot measure the static bias over the first {calibrate_seconds:g} s: "
                f"{e}; give it with --bias DPS"
            ) from None
        bias_dps, bias_source, bias_std = (
            rec.bias_dps,
            f"first {calibrate_seconds:g} s",
            rec.std_dps,
        )
        bias_var = rec.std_dps * rec.std_dps / rec.n
    else:
        if not math.isfinite(bias):
            raise EvaluationError(f"{name}: bias {bias!r} is not a finite number")
        bias_dps, bias_source, bias_std = float(bias), "given", math.nan
        bias_var = math.nan

    idx, means, counts = block_average_seconds(t, log.omega, T)
    keep = idx < n_steps
    idx, means, counts = idx[keep], means[keep], counts[keep]
    n_samples = np.zeros(n_steps, np.int64)
    n_samples[idx] = counts
    # A gap repeats the last known rate (a better guess of the rotation than zero); a gap at
    # the start takes the first known one.
    filled = np.full(n_steps, np.nan)
    filled[idx] = means
    have = np.flatnonzero(n_samples > 0)
    pos = np.maximum.accumulate(np.where(n_samples > 0, np.arange(n_steps), -1))
    pos = np.where(pos < 0, have[0], pos)
    raw = filled[pos]
    u = raw - bias_dps

    sq = _step_means(t, t0, log.omega * log.omega, n_steps, T)
    mean_full = _step_means(t, t0, log.omega, n_steps, T)
    var = np.maximum(sq - mean_full * mean_full, 0.0)
    omega_std = np.where(n_samples > 0, np.sqrt(var), np.nan)
    speed = None if log.speed is None else _step_means(t, t0, log.speed, n_steps, T)
    temp = None if log.temp_c is None else _step_means(t, t0, log.temp_c, n_steps, T)

    t_end = (np.arange(n_steps, dtype=np.float64) + 1.0) * T
    truth = truth_at(t - t0, log.heading_truth, t_end, truth_max_gap_s)
    # The drive starts when the calibration ends (the daemon, too, calibrates, then runs).
    first = math.ceil(calibrate_seconds / T - 1e-9) if bias is None else 0
    if n_steps - first < 2:
        raise EvaluationError(
            f"{name}: nothing left to evaluate after the {calibrate_seconds:g} s calibration window"
        )
    sl = slice(first, None)
    k = align_index(np.zeros(n_steps - first), truth[sl])
    if k is None:
        raise EvaluationError(
            f"{name}: no truth heading at any step end after the start (fixes further than "
            f"{truth_max_gap_s:g} s apart, or only during calibration)"
        )
    steps = StepInputs(
        u[sl],
        t_end[sl],
        T,
        bias_dps,
        n_samples[sl],
        None if speed is None else speed[sl],
        None if temp is None else temp[sl],
        omega_std[sl],
        bias_var,
    )
    return PreparedDrive(
        name=name,
        steps=steps,
        truth=truth[sl],
        k=k,
        duration_min=(n_steps - first) * T / 60.0,
        bias_source=bias_source,
        bias_std_dps=bias_std,
        missing_steps=int(np.count_nonzero(n_samples[sl] == 0)),
        start_s=first * T,
    )


def _methods(methods: Sequence[str]) -> tuple[str, ...]:
    out = ["none"] + [m for m in methods if m != "none"]
    unknown = [m for m in out if m not in METHODS]
    if unknown:
        raise EvaluationError(
            f"method {unknown[0]!r} is not available (available: {', '.join(METHODS)})"
        )
    return tuple(dict.fromkeys(out))


def evaluate_prepared(
    prep: PreparedDrive,
    params: HdrParams = PAPER_PARAMS,
    methods: Sequence[str] = ("none", "hdr"),
    plus: HdrPlusParams = PLUS_DEFAULTS,
) -> DriveResult:
    """Eψ and NEψ of each method on a prepared drive. ``none`` is always evaluated (first).
    ``plus``: HDR+'s settings besides its core (default: HDR+'s defaults)."""
    ms = _methods(methods)
    if params.T != prep.steps.T:
        raise EvaluationError(
            f"{prep.name}: params.T = {params.T} s but the drive was stepped at {prep.steps.T} s"
        )
    e: dict[str, float] = {}
    ne: dict[str, float] = {}
    heading: dict[str, FloatArray] = {}
    for m in ms:
        yaw = METHODS[m](prep.steps, params, plus)
        e[m] = float(e_psi(yaw, prep.truth, prep.k))
        ne[m] = float(ne_psi(e[m], prep.duration_min))
        heading[m] = gyro_heading(yaw, prep.truth, prep.k)
    return DriveResult(
        name=prep.name,
        duration_min=prep.duration_min,
        bias_dps=prep.steps.bias_dps,
        bias_source=prep.bias_source,
        n_steps=int(prep.steps.u.shape[0]),
        n_compared=int(np.count_nonzero(np.isfinite(prep.truth))),
        missing_steps=prep.missing_steps,
        methods=ms,
        e_psi=e,
        ne_psi=ne,
        t_end=prep.steps.t_end,
        truth=prep.truth,
        heading=heading,
    )


def evaluate_drive(
    log: DriveLog,
    params: HdrParams = PAPER_PARAMS,
    bias: float | None = None,
    calibrate_seconds: float = DEFAULT_CALIBRATE_S,
    methods: Sequence[str] = ("none", "hdr"),
) -> DriveResult:
    """Table II's row for one drive log: Eψ (Eq. 12) and NEψ (Eq. 13) per method.

    bias: static bias eps0, deg/s; None = measured over the first ``calibrate_seconds`` s
    (EvaluationError if they show motion).
    """
    prep = prepare_drive(log, bias, calibrate_seconds, params.T)
    return evaluate_prepared(prep, params, methods)


def _mean_std(values: Sequence[float]) -> tuple[float, float]:
    a = np.asarray(values, dtype=np.float64)
    if a.shape[0] == 0:
        return math.nan, math.nan
    mean = float(np.mean(a))
    # The paper's sigma of the nine improvements (7.57) is the sample standard deviation.
    std = float(np.std(a, ddof=1)) if a.shape[0] > 1 else math.nan
    return mean, std


@dataclass(frozen=True)
class Summary:
    """The "average of all drives" row: means over drives, as the paper's bottom line.

    improvement_std: sample standard deviation of the per-drive improvements (paper: σ).
    """

    n: int
    duration_min: float
    total_min: float
    e_psi: dict[str, float]
    ne_psi: dict[str, float]
    improvement: float
    improvement_std: float
    improvement_of: dict[str, tuple[float, float]]


def summarize(results: Sequence[DriveResult]) -> Summary:
    """Mean Eψ, mean NEψ per method, and the mean (and σ) of the per-drive improvements."""
    if not results:
        raise ValueError("no drives to summarize")
    ms = results[0].methods
    e = {m: float(np.mean([r.e_psi[m] for r in results])) for m in ms}
    ne = {m: float(np.mean([r.ne_psi[m] for r in results])) for m in ms}
    imp_of = {m: _mean_std([r.improvement_of(m) for r in results]) for m in ms}
    imp, std = imp_of[ms[-1]]
    durations = [r.duration_min for r in results]
    return Summary(
        len(results), float(np.mean(durations)), float(np.sum(durations)), e, ne, imp, std, imp_of
    )


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def to_json(results: Sequence[DriveResult]) -> dict[str, Any]:
    """``{"drives": [{"name", "duration_min", "E_psi_raw", "E_psi_<m>", "NE_psi_raw",
    "NE_psi_<m>", "improvement"}], "mean": {same keys except name}}``.

    With the default methods (none, hdr) the keys are exactly those of issue 5:
    E_psi_raw, E_psi_hdr, NE_psi_raw, NE_psi_hdr. With ``--method none`` alone, E_psi_none and
    NE_psi_none repeat the raw values (issue 9 names keys E_psi_<method>). ``improvement`` is Eψ(raw) / Eψ(primary
    method); when more than one method besides ``none`` is evaluated, ``improvement_<m>`` is
    added for each. Non-finite numbers (an improvement over a zero error) are null. The mean
    row's duration_min is the mean duration.
    """
    summary = summarize(results)
    ms = results[0].methods
    extra = [m for m in ms if m != "none"]

    def row(r: DriveResult | None) -> dict[str, Any]:
        d: dict[str, Any] = {}
        if r is not None:
            d["name"] = r.name
        d["duration_min"] = _num(r.duration_min if r else summary.duration_min)
        for m in ms:
            d[f"E_psi_{method_key(m)}"] = _num(r.e_psi[m] if r else summary.e_psi[m])
        for m in ms:
            d[f"NE_psi_{method_key(m)}"] = _num(r.ne_psi[m] if r else summary.ne_psi[m])
        if list(ms) == ["none"]:  # --method none: issue 9's E_psi_<method> spelling too
            d["E_psi_none"], d["NE_psi_none"] = d["E_psi_raw"], d["NE_psi_raw"]
        d["improvement"] = _num(r.improvement if r else summary.improvement)
        if len(extra) > 1:
            for m in extra:
                d[f"improvement_{m}"] = _num(
                    r.improvement_of(m) if r else summary.improvement_of[m][0]
                )
        return d

    return {"drives": [row(r) for r in results], "mean": row(None)}


def _fmt(v: float, digits: int) -> str:
    return f"{v:.{digits}f}" if math.isfinite(v) else ("inf" if v == math.inf else "-")


def format_table(results: Sequence[DriveResult]) -> str:
    """A Table II-like text table: one row per drive and the mean row (improvement with σ)."""
    ms = results[0].methods
    name_w = max(12, *(len(r.name) for r in results))
    head = f"{'drive':<{name_w}} {'min':>6} {'bias dps':>9}"
    for m in ms:
        head += f" {'Epsi ' + method_key(m):>10}"
    for m in ms:
        head += f" {'NEpsi ' + method_key(m):>11}"
    head += f" {'improvement':>12}"
    lines = [head, "-" * len(head)]
    for r in results:
        line = f"{r.name:<{name_w}} {r.duration_min:>6.1f} {r.bias_dps:>9.4f}"
        for m in ms:
            line += f" {_fmt(r.e_psi[m], 2):>10}"
        for m in ms:
            line += f" {_fmt(r.ne_psi[m], 3):>11}"
        line += f" {_fmt(r.improvement, 1) + 'x':>12}"
        lines.append(line)
    s = summarize(results)
    lines.append("-" * len(head))
    line = f"{'mean (' + str(s.n) + ')':<{name_w}} {s.duration_min:>6.1f} {'':>9}"
    for m in ms:
        line += f" {_fmt(s.e_psi[m], 2):>10}"
    for m in ms:
        line += f" {_fmt(s.ne_psi[m], 3):>11}"
    line += f" {_fmt(s.improvement, 1) + 'x':>12}"
    if math.isfinite(s.improvement_std):
        line += f" (σ {s.improvement_std:.2f})"
    lines.append(line)
    lines.append(
        f"total duration {s.total_min:.1f} min ({s.total_min / 60:.2f} h); "
        f"improvement = Epsi raw / Epsi {method_key(ms[-1])}; Epsi in deg, NEpsi in deg/min"
    )
    return "\n".join(lines)


# -- the command-line edge --------------------------------------------------------------


def _err(msg: str) -> None:
    print(f"hdrd evaluate: error: {msg}", file=sys.stderr)


def load_drives(paths: Sequence[str]) -> list[DriveLog]:
    """Read drive logs; EvaluationError with a one-line message on any unreadable file."""
    from hdrd.drivelog import DriveLogError, read_drive

    logs = []
    for p in paths:
        try:
            logs.append(read_drive(p))
        except FileNotFoundError:
            raise EvaluationError(f"{p}: no such file") from None
        except IsADirectoryError:
            raise EvaluationError(f"{p}: is a directory, expected a drive log CSV") from None
        except (OSError, UnicodeDecodeError) as e:
            raise EvaluationError(f"{p}: cannot be read: {e.__class__.__name__}: {e}") from None
        except DriveLogError as e:
            raise EvaluationError(str(e)) from None
    return logs


def main(args: argparse.Namespace) -> int:
    """``hdrd evaluate DRIVE.csv... [--calibrate-seconds S | --bias DPS] [--json FILE]
    [--plot FILE.png] [--config PATH] [--method none|hdr|hdr+]``."""
    from hdrd.config import EX_CONFIG, ConfigError, load_config
    from hdrd.daemon import plus_params

    try:
        cfg, _ = load_config(args.config)
    except ConfigError as e:
        print(f"hdrd evaluate: {e}", file=sys.stderr)
        return EX_CONFIG
    if args.plot:
        from hdrd.analysis.plots import plotting_unavailable

        problem = plotting_unavailable()
        if problem:  # said before the work, not after it
            _err(problem)
            return 1
    plus = plus_params(cfg)
    method = args.method or cfg.hdr.method
    params = cfg.hdr.params
    calibrate_s = (
        args.calibrate_seconds if args.calibrate_seconds is not None else DEFAULT_CALIBRATE_S
    )
    try:
        # HDR+ is shown beside the paper's HDR it improves on.
        methods = _methods(["hdr", method] if method == "hdr+" else [method])
        logs = load_drives(args.drives)
        results = [
            evaluate_prepared(
                prepare_drive(log, args.bias, calibrate_s, params.T), params, methods, plus
            )
            for log in logs
        ]
    except EvaluationError as e:
        _err(str(e))
        return 1
    print(format_table(results))
    if args.json:
        try:
            from hdrd.calibrate import atomic_write_json

            atomic_write_json(args.json, to_json(results))
        except OSError as e:
            _err(f"cannot write {args.json}: {e.strerror or e}")
            return 1
    if args.plot:
        from hdrd.analysis.plots import plot_evaluation, plot_to_file

        problem = plot_to_file(lambda path: plot_evaluation(results, path), args.plot)
        if problem:
            _err(problem)
            return 1
    return 0
