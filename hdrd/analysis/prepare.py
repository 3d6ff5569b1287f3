"""A drive log made ready for evaluation, exactly as the daemon would have run it. Pure.

One path from samples to steps: the log's samples go through the daemon's own block code
and stepper, not a re-implementation of them:

1. times: t (s) -> integer microseconds since the log's first sample (``round``); raw omega
   (deg/s), temperature (deg C) and, per step, the mean of the log's speed (m/s);
2. blocks: :meth:`hdrd.core.resample.BlockAverager.feed_many` then ``flush`` (the last, partial
   block is a step, as at the end of a replay); a step without samples is
   :class:`hdrd.core.resample.Missing`: no step, the yaw holds, nothing is evaluated there;
3. the static bias and the steps: :class:`hdrd.daemon.pipeline.Stepper`, the daemon's per-block
   stepper with its start-up window (:class:`hdrd.core.calibrate.StartupWindow`): it measures the
   bias over the window's steps, starts again after a window that shows motion, then hands
   each block's input (u = block mean - eps0, spread, speed, temperature, T) to the method;
4. where the bias comes from, per drive (:func:`plan_calibration`): ``bias`` when given;
   else ``calibrate_seconds`` (the first S s as the daemon's start-up window); else the log's
   own ``lead_in_s`` (metadata: seconds of standstill at the start); else the first standstill
   found from the speed (at or below :data:`STANDSTILL_SPEED_MPS`, at least
   :data:`STANDSTILL_MIN_S`, at most :data:`STANDSTILL_MAX_S`); else, when the log has no
   speed, the first window that passes the standstill test on the gyro alone. A standstill
   found after the log's start begins the drive there (the daemon started then).

The drive starts where the calibration ends (0 with a given bias); Td (Eq. 13) is the time
from there to the end of the last step. ``hdrd replay`` of a capture holding the same samples
publishes the same yaw at every step (tests/test_onepath.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.analysis.metrics import align_index, truth_at
from hdrd.analysis.signcheck import NO_CHECK, SignCheck, check_sign
from hdrd.core.angles import wrap180
from hdrd.core.calibrate import (
    BiasRecord,
    CalibrationLimits,
    MotionDetected,
    estimate_bias,
    given_bias,
)
from hdrd.core.hdr import HdrParams
from hdrd.core.methods import MethodSetup, StepInputs
from hdrd.core.resample import Block, BlockAverager, Missing
from hdrd.core.standstill import quantization_step
from hdrd.daemon.stepper import PipelineConfig, Stepper
from hdrd.errors import HdrdError
from hdrd.io.files.drivelog import DriveLog

__all__ = [
    "DEFAULTS",
    "DEFAULT_LIMITS",
    "PAPER_PARAMS",
    "STANDSTILL_MAX_S",
    "STANDSTILL_MIN_S",
    "STANDSTILL_SPEED_MPS",
    "TRUTH_MAX_GAP_S",
    "CalibrationPlan",
    "EvaluationError",
    "PreparedDrive",
    "method_settings",
    "plan_calibration",
    "prepare_drive",
    "step_log",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

TRUTH_MAX_GAP_S = 2.0
"""Truth is interpolated between fixes at most this far apart (1 Hz GPS with one fix lost)."""
STANDSTILL_SPEED_MPS = 0.3
"""A sample at or below this speed, m/s, is standing still (GPS speed at rest jitters by a few
tenths of a m/s; HDR+'s standstill detection uses the same)."""
STANDSTILL_MIN_S = 6.0
"""Shortest standstill a per-drive calibration window is found in, s (at 1 Hz, the six samples
the standstill test's noise-scaled checks need)."""
STANDSTILL_MAX_S = 30.0
"""Longest window taken from a found standstill, s (the paper's Tbias)."""
ALIGN_S = 10.0
"""Where the truth is a course over ground, the gyro is aligned over the first this many
seconds of straight driving at speed, s (:func:`alignment`)."""
ALIGN_MIN_SPEED_MPS = 5.0
"""... at or above this speed, m/s (the GPS aiding's: a course below it is noise) ..."""
ALIGN_MAX_TURN_DPS = 1.0
"""... with the truth turning by at most this from step to step, deg/s."""
DEFAULT_LIMITS = CalibrationLimits()
"""The standstill test's default thresholds (the daemon's ``calibration.*`` defaults)."""
PAPER_PARAMS = HdrParams()
"""The paper's Table III parameters (HDR's defaults)."""
DEFAULTS = MethodSetup()
"""The built-in configuration's setup of the methods (Table III, HDR+'s defaults, no grade,
standstill on; :func:`hdrd.config.method_setup` of a configuration)."""


class EvaluationError(HdrdError, ValueError):
    """A drive that cannot be evaluated; the message names the drive and says why."""


@dataclass(frozen=True)
class CalibrationPlan:
    """Where one drive's static bias comes from (see :func:`plan_calibration`).

    bias_dps: the given bias, or None (measured by the start-up window). start: the sample at
    which the daemon starts (0 = the log's first; a standstill found later starts the drive
    there). window_s: the start-up window's length, s (None with a given bias). source: what
    was used, for the reader: ``given``, ``first S s``, ``lead-in S s``, ``speed standstill
    ...``, ``gyro standstill ...``.
    """

    bias_dps: float | None
    start: int
    window_s: float | None
    source: str


@dataclass(frozen=True)
class PreparedDrive:
    """A drive reduced to what the metrics need: per-step inputs and truth at step ends.

    steps: the steps after the calibration (t_end in s since the log's first sample). truth:
    compass heading, deg CW, at each step end (NaN where unknown). k, align_n: the step where
    the gyro is aligned to the truth, and over how many steps (:func:`alignment`). duration_min: Td of Eq. 13. bias_source: where the bias came from
    (:class:`CalibrationPlan`). bias_std_dps: spread of the calibration samples, deg/s (NaN if
    given). missing_steps: steps without samples after the start (not evaluated). start_s:
    where the evaluated drive starts, s after the log's first sample (the end of the
    calibration window, 0 if the bias was given). bias: the calibration record (None if
    given). samples_per_step: samples in the first step, as the daemon derives its methods'
    settings from (the gyro's sample rate times T). calibration_attempts: start-up windows
    measured (more than one: the first ones showed motion). quant_step_dps: the output step
    of the log's raw rates, deg/s (the lattice of its values, :func:`hdrd.core.standstill.
    quantization_step`; 0 = not quantised or not seen): a recorded log's analogue of the LSB
    the daemon knows of its ADC.
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
    bias: BiasRecord | None = None
    samples_per_step: float | None = None
    calibration_attempts: int = 0
    quant_step_dps: float = 0.0
    sign: SignCheck = NO_CHECK
    """How the log's rate follows its truth heading over the turns (a flipped sign, a wrong
    unit: :mod:`hdrd.analysis.signcheck`)."""
    align_n: int = 1
    """Steps the gyro is aligned over from k (:func:`alignment`; 1: at k itself)."""


# -- where the bias comes from -------------------------------------------------------------


def _t_us(t: FloatArray) -> IntArray:
    """Sample times as integer microseconds since the first sample (the device clock's unit)."""
    return np.rint((t - t[0]) * 1e6).astype(np.int64)


def _lead_in_s(log: DriveLog) -> float | None:
    try:
        v = float(log.meta.get("lead_in_s", ""))
    except ValueError:
        return None
    return v if math.isfinite(v) and v > 0 else None


def _whole_steps(seconds: float, T: float) -> float:
    """The longest whole number of steps of T within ``seconds``, s (0 if none fits)."""
    return math.floor(seconds / T + 1e-9) * T


def _standstill_from_speed(log: DriveLog, T: float) -> tuple[int, float] | None:
    """(first sample, window s) of the first run of samples at standstill by the speed that
    holds at least STANDSTILL_MIN_S of whole steps; None if there is none."""
    runs = _still_runs(log, T)
    return runs[0] if runs else None


def _still_runs(log: DriveLog, T: float) -> list[tuple[int, float]]:
    """(first sample, window s) of every run of samples at standstill by the speed that holds
    at least STANDSTILL_MIN_S of whole steps (at most STANDSTILL_MAX_S of it), in order."""
    assert log.speed is not None
    still = np.isfinite(log.speed) & (log.speed <= STANDSTILL_SPEED_MPS)
    t = log.t
    dt = float(np.median(np.diff(t))) if len(log) > 1 else 0.0
    edges = np.flatnonzero(np.diff(np.concatenate(([0], still.astype(np.int8), [0]))))
    out = []
    for i, j in zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True):
        covered = float(t[j - 1] - t[i]) + dt  # the last sample stands for one interval
        window = _whole_steps(min(covered, STANDSTILL_MAX_S), T)
        if window >= STANDSTILL_MIN_S:
            out.append((i, window))
    return out


def _standstill_from_gyro(
    log: DriveLog, T: float, limits: CalibrationLimits
) -> tuple[int, float] | None:
    """(first sample, window s) of the first window that passes the standstill test on the
    raw rate alone: from each step edge in turn, the longest of 30, 20, 10 and 6 s (whole
    steps) that passes; None if none does. A gyro cannot tell a stop from a smooth straight
    road: with a speed in the log, :func:`_standstill_from_speed` is used instead."""
    t_us = _t_us(log.t)
    T_us = round(T * 1_000_000)
    w = log.omega
    n = w.shape[0]
    lengths = sorted(
        {_whole_steps(s, T) for s in (STANDSTILL_MAX_S, 20.0, 10.0, STANDSTILL_MIN_S)},
        reverse=True,
    )
    lengths = [s for s in lengths if s >= STANDSTILL_MIN_S]
    # Cheap screens first (spread and level from running sums, the values centred for
    # precision): only windows that pass them take the full test.
    c = w - float(np.median(w))
    s1 = np.concatenate(([0.0], np.cumsum(c)))
    s2 = np.concatenate(([0.0], np.cumsum(c * c)))
    block = t_us // T_us
    # each block's first sample (a block without samples starts where the next one does)
    starts = np.flatnonzero(np.diff(block, prepend=block[0] - 1))
    for i in starts.tolist():
        if i >= n:
            break
        for length in lengths:
            end_us = int(t_us[i]) + round(length * 1_000_000)
            j = int(np.searchsorted(t_us, end_us, side="left"))
            m = j - i
            if m < 2 or j >= n:  # the drive must go on after its calibration window
                continue
            mean = (s1[j] - s1[i]) / m
            var = max((s2[j] - s2[i]) / m - mean * mean, 0.0) * m / (m - 1)
            if var > limits.max_std_dps**2:
                continue
            try:
                estimate_bias(w[i:j], limits=limits)
            except MotionDetected:
                continue
            return i, length
    return None


def plan_calibration(
    log: DriveLog,
    bias: float | None = None,
    calibrate_seconds: float | None = None,
    T: float = 1.0,
    limits: CalibrationLimits = DEFAULT_LIMITS,
) -> CalibrationPlan:
    """Where the drive's static bias comes from: ``bias``, else ``calibrate_seconds``, else
    the log's ``lead_in_s``, else the first standstill found from the speed, else (no speed
    in the log) from the gyro. EvaluationError if none applies."""
    name = log.name or "drive"
    if bias is not None:
        if not math.isfinite(bias):
            raise EvaluationError(f"{name}: bias {bias!r} is not a finite number")
        return CalibrationPlan(float(bias), 0, None, "given")
    if calibrate_seconds is not None:
        window = _whole_steps(calibrate_seconds, T) if calibrate_seconds > 0 else 0.0
        if not window > 0:
            raise EvaluationError(
                f"{name}: calibration window must hold at least one step of {T:g} s, got "
                f"{calibrate_seconds!r}"
            )
        return CalibrationPlan(None, 0, window, f"first {window:g} s")
    lead = _lead_in_s(log)
    if lead is not None and _whole_steps(lead, T) > 0:
        window = _whole_steps(lead, T)
        return CalibrationPlan(None, 0, window, f"lead-in {window:g} s")
    has_speed = log.speed is not None and bool(np.isfinite(log.speed).any())
    found = _standstill_from_speed(log, T) if has_speed else _standstill_from_gyro(log, T, limits)
    kind = "speed" if has_speed else "gyro"
    if found is None:
        raise EvaluationError(
            f"{name}: no standstill of at least {STANDSTILL_MIN_S:g} s found from the {kind} to "
            "measure the static bias; give it with --bias DPS or --calibrate-seconds S"
        )
    i, window = found
    at = float(log.t[i] - log.t[0])
    return CalibrationPlan(None, i, window, f"{kind} standstill {window:g} s at {at:g} s")


# -- the steps ------------------------------------------------------------------------------


@dataclass
class _Stepped:
    """What the stepper made of a log: the blocks stepped after the calibration and their
    inputs, the calibration's outcome."""

    blocks: list[Block]
    u: list[float]
    spread: list[float]
    speed: list[float]
    temp: list[float]
    missing: int
    start_s: float
    stepper: Stepper


def _speed_per_block(t_us: IntArray, speed: FloatArray, T_us: int) -> dict[int, float]:
    """Block index -> mean of the finite speeds in the block (NaN for a block without any),
    m/s, for the blocks that have samples: memory follows the samples, not the time they
    span."""
    blocks, idx = np.unique(t_us // T_us, return_inverse=True)
    ok = np.isfinite(speed)
    sums = np.bincount(idx[ok], weights=speed[ok], minlength=blocks.shape[0])
    counts = np.bincount(idx[ok], minlength=blocks.shape[0])
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    return dict(zip(blocks.tolist(), mean.tolist()))


def step_log(log: DriveLog, config: PipelineConfig, t_us: IntArray | None = None) -> _Stepped:
    """Run a log's samples through the daemon's BlockAverager and Stepper (module docstring,
    steps 1-3). config: T (``params.T``), the bias (``bias_dps``) or the start-up window
    (``startup_s``, ``limits``). t_us: the samples' times in integer us from the first
    (default: from ``log.t``)."""
    if t_us is None:
        t_us = _t_us(log.t)
    omega = log.omega
    n = omega.shape[0]
    temp = np.full(n, np.nan) if log.temp_c is None else log.temp_c
    avg = BlockAverager(config.params.T)
    items = avg.feed_many(t_us, omega, temp)
    items.extend((n, b) for b in avg.flush())  # the end of input closes the last block
    speed = None if log.speed is None else _speed_per_block(t_us, log.speed, avg.T_us)
    stepper = Stepper(config)
    out = _Stepped([], [], [], [], [], 0, 0.0, stepper)
    prev = 0
    for pos, item in items:
        if stepper.calibrating:  # the samples fed before this block closed, as the daemon's
            stepper.window.add_many(omega[prev:pos], temp[prev:pos])
        prev = pos
        if isinstance(item, Missing):
            if not stepper.calibrating:
                out.missing += item.count
            continue
        was_calibrating = stepper.calibrating
        if speed is not None:
            v = speed[item.index]
            stepper.speed_mps = None if math.isnan(v) else v
        inp = stepper.prepare(item)
        if inp is None:
            if was_calibrating and not stepper.calibrating:
                out.start_s = item.t_end  # the drive starts when the calibration ends
            continue
        out.blocks.append(item)
        out.u.append(inp.u)
        out.spread.append(inp.spread_dps)
        out.speed.append(inp.speed_mps)
        out.temp.append(inp.temp_c)
    return out


def _later_standstills(
    log: DriveLog, plan: CalibrationPlan, T: float, limits: CalibrationLimits
) -> list[CalibrationPlan]:
    """Where else the bias may be measured when the planned window showed motion (a phone
    handled while the car stood, a car manoeuvring slowly in its lead-in): each later stop by
    the speed whose raw rate passes the standstill test, in order; without a speed, the
    first window the gyro alone passes. None for a window the user gave
    (``--calibrate-seconds``) or a bias given."""
    if plan.bias_dps is not None or plan.source.startswith("first "):
        return []
    has_speed = log.speed is not None and bool(np.isfinite(log.speed).any())
    if not has_speed:
        found = _standstill_from_gyro(log, T, limits)
        runs = [found] if found is not None and found[0] > plan.start else []
    else:
        runs = [(i, w) for i, w in _still_runs(log, T) if i > plan.start]
    out = []
    for i, window in runs:
        j = int(np.searchsorted(log.t, log.t[i] + window, side="left"))
        try:
            estimate_bias(log.omega[i:j], limits=limits)
        except MotionDetected:
            continue
        at = float(log.t[i] - log.t[0])
        kind = "speed" if has_speed else "gyro"
        why = f"{kind} standstill {window:g} s at {at:g} s; the {plan.source} showed motion"
        out.append(CalibrationPlan(None, i, window, why))
    return out


def _calibration_failure(name: str, plan: CalibrationPlan, stepper: Stepper) -> str:
    window = f"the {plan.window_s:g} s start-up window"
    if stepper.window.attempts == 0:
        return f"{name}: the log ends before {window} ({plan.source}) is complete"
    reasons = [f["reason"] for e, f in stepper.events if e == "calibration_rejected"]
    return (
        f"{name}: cannot measure the static bias: {window} ({plan.source}) showed motion in "
        f"all {stepper.window.attempts} attempts (last: {reasons[-1]}); give it with --bias DPS"
    )


def _usable_rows(log: DriveLog, name: str, T: float) -> tuple[DriveLog, FloatArray]:
    """The log without its rows marked valid = 0 (as if dropped: a time gap; a lead-in that
    lost its first rows is shortened in the metadata), checked: at least 2 rows, some truth
    heading, T > 0 s; and its truth heading."""
    if log.valid is not None:
        kept = log.counted()
        if len(kept) == 0:
            raise EvaluationError(f"{name}: every row has valid = 0; nothing to evaluate")
        lead = _lead_in_s(log)
        if lead is not None and kept.t[0] > log.t[0]:  # the lead-in lost its first rows
            left = lead - float(kept.t[0] - log.t[0])
            kept = replace(kept, meta={**kept.meta, "lead_in_s": f"{max(left, 0.0)!r}"})
        log = kept
    n_rows = len(log)
    if n_rows < 2:
        raise EvaluationError(f"{name}: only {n_rows} sample(s); a drive needs at least 2")
    if log.heading_truth is None or not np.isfinite(log.heading_truth).any():
        raise EvaluationError(f"{name}: no truth heading (column heading_truth is absent or empty)")
    if not T > 0:
        raise EvaluationError(f"{name}: step period T must be > 0 s, got {T!r}")
    return log, log.heading_truth


def _stepped_after_calibration(
    log: DriveLog, name: str, plan: CalibrationPlan, T: float, limits: CalibrationLimits
) -> tuple[_Stepped, float]:
    """The drive stepped from the plan's start, with its bias measured or given (else
    EvaluationError: why not, or too few steps left), and where it starts after the log's
    first row, s."""
    drive = log.slice(plan.start) if plan.start else log
    offset = float(drive.t[0] - log.t[0])
    config = PipelineConfig(
        startup_s=plan.window_s if plan.window_s is not None else 1.0,
        limits=limits,
        setup=MethodSetup(method="none", hdr=HdrParams(T=T), bias=given_bias(plan.bias_dps)),
    )
    t_us = _t_us(log.t)[plan.start :]
    stepped = step_log(drive, config, t_us - t_us[0])
    if stepped.stepper.bias is None:
        raise EvaluationError(_calibration_failure(name, plan, stepped.stepper))
    if len(stepped.blocks) < 2:
        raise EvaluationError(
            f"{name}: nothing left to evaluate after the calibration ({plan.source}): "
            f"{len(stepped.blocks)} step(s) of {T:g} s; at least 2 are needed"
        )
    return stepped, offset


def _calibrated(
    log: DriveLog, name: str, plan: CalibrationPlan, T: float, limits: CalibrationLimits
) -> tuple[CalibrationPlan, _Stepped, float]:
    """:func:`_stepped_after_calibration` on the plan, else on the first of
    :func:`_later_standstills` whose bias can be measured (the plan used returned with it);
    the plan's error if none."""
    try:
        return (plan, *_stepped_after_calibration(log, name, plan, T, limits))
    except EvaluationError as first:
        for later in _later_standstills(log, plan, T, limits):
            try:
                return (later, *_stepped_after_calibration(log, name, later, T, limits))
            except EvaluationError:
                continue
        raise first from None


def _step_inputs(
    log: DriveLog,
    stepped: _Stepped,
    t_end: FloatArray,
    T: float,
    rec: BiasRecord,
    measured: bool,
) -> StepInputs:
    """The methods' inputs of a stepped drive; ``measured``: the bias ``rec`` was measured on
    the drive (its variance of the mean is known), not given."""
    return StepInputs(
        u=np.array(stepped.u),
        t_end=t_end,
        T=T,
        bias_dps=rec.bias_dps,
        n_samples=np.array([b.n for b in stepped.blocks], np.int64),
        speed=None if log.speed is None else np.array(stepped.speed),
        temp_c=None if log.temp_c is None else np.array(stepped.temp),
        omega_std=np.array(stepped.spread),
        bias_var=rec.std_dps * rec.std_dps / rec.n if measured else math.nan,
    )


def prepare_drive(
    log: DriveLog,
    bias: float | None = None,
    calibrate_seconds: float | None = None,
    T: float = 1.0,
    truth_max_gap_s: float = TRUTH_MAX_GAP_S,
    limits: CalibrationLimits = DEFAULT_LIMITS,
) -> PreparedDrive:
    """Bias, steps and truth at step ends for one drive (see the module docstring).

    bias: static bias eps0 in deg/s; None = measured per drive (:func:`plan_calibration`,
    ``calibrate_seconds`` first). limits: the standstill test's thresholds. Raises
    EvaluationError if the log is too short, has no truth heading at all, or its bias cannot
    be measured.
    """
    name = log.name or "drive"
    log, heading_truth = _usable_rows(log, name, T)
    plan = plan_calibration(log, bias, calibrate_seconds, T, limits)
    plan, stepped, offset = _calibrated(log, name, plan, T, limits)
    stepper = stepped.stepper
    rec = stepper.bias
    assert rec is not None
    measured = plan.bias_dps is None
    t_end = np.array([b.t_end for b in stepped.blocks]) + offset
    start_s = stepped.start_s + offset
    truth = truth_at(log.t - log.t[0], heading_truth, t_end, truth_max_gap_s)
    if align_index(np.zeros(t_end.shape[0]), truth) is None:
        raise EvaluationError(
            f"{name}: no truth heading at any step end after the start (fixes further than "
            f"{truth_max_gap_s:g} s apart, or only during calibration)"
        )
    steps = _step_inputs(log, stepped, t_end, T, rec, measured)
    exact = log.omega_truth is not None and bool(np.isfinite(log.omega_truth).any())
    k, align_n = alignment(truth, steps.speed, T, exact)
    source = plan.source
    if measured and stepper.window.attempts > 1:
        source = (
            f"{plan.window_s:g} s to {start_s:g} s ({stepper.window.attempts - 1} rejected, "
            f"{plan.source})"
        )
    return PreparedDrive(
        name=name,
        steps=steps,
        truth=truth,
        k=k,
        align_n=align_n,
        duration_min=(float(t_end[-1]) - start_s) / 60.0,
        bias_source=source,
        bias_std_dps=rec.std_dps if measured else math.nan,
        missing_steps=stepped.missing,
        start_s=start_s,
        bias=rec if measured else None,
        samples_per_step=stepper.samples_per_step,
        calibration_attempts=stepper.window.attempts,
        quant_step_dps=quantization_step(log.omega),
        sign=check_sign(log.t, log.omega, heading_truth),
    )


def alignment(
    truth: FloatArray, speed: FloatArray | None, T: float, exact: bool
) -> tuple[int, int]:
    """(k, n): the step the gyro is aligned to the truth at, and over how many steps
    (:func:`hdrd.analysis.metrics.reference`).

    An exact truth (a simulated drive, an INS: the log has ``omega_truth``) aligns at its first
    value, n = 1. A course over ground is noisy and meaningless at walking pace, and a first
    fix often falls at 2 m/s in a turn: it aligns over the first :data:`ALIGN_S` of straight
    driving at speed (every step with a truth, a speed of at least
    :data:`ALIGN_MIN_SPEED_MPS` where the log has one, and the truth turning by at most
    :data:`ALIGN_MAX_TURN_DPS`); where no such stretch exists, at the first value too.
    """
    first = align_index(np.zeros(truth.shape[0]), truth)
    assert first is not None
    n = max(2, int(round(ALIGN_S / T)))
    if exact or truth.shape[0] < n:
        return first, 1
    ok = np.isfinite(truth)
    if speed is not None:
        ok &= np.nan_to_num(speed, nan=-1.0) >= ALIGN_MIN_SPEED_MPS
    turn = np.abs(wrap180(np.diff(truth))) <= ALIGN_MAX_TURN_DPS * T
    good = ok[1:] & ok[:-1] & turn  # step j+1 straight after step j
    run = 0
    for j in range(first, good.shape[0]):
        run = run + 1 if good[j] else 0
        if run >= n - 1:
            return j + 2 - n, n
    return first, 1


def method_settings(prep: PreparedDrive, method: str, setup: MethodSetup = DEFAULTS) -> Any:
    """A method's settings for a prepared drive, derived as the daemon derives them: the
    setup with this drive's samples per step, calibration record and output step."""
    q = prep.quant_step_dps if prep.quant_step_dps > 0 else None
    drive = replace(setup, method=method).for_drive(prep.samples_per_step, prep.bias, q)
    return drive.settings()
