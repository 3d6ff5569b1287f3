"""The drift reducers by name: the one registry the daemon, replay, evaluate and the CLI use.

A :class:`Method` holds three things:

- ``step(state, input, settings) -> (state, output)``: one step T, the form the daemon's
  pipeline runs once per closed block. Every method shares one state,
  :class:`hdrd.hdrplus.PlusState` (HDR+ carries the paper's :class:`hdrd.hdr.HdrState` inside
  as its core), so a method switched on SIGHUP continues the same heading; and one input,
  :class:`hdrd.hdrplus.PlusInput` (u = block mean - eps0 in deg/s CCW, the samples' spread,
  speed, temperature, T), of which each method reads what it uses.
- ``batch(inputs, settings) -> yaw``: the same recursion over a whole drive's
  :class:`StepInputs` from the initial state, the fast form for offline tools; bit-identical
  to looping ``step`` (tests/test_methods.py).
- ``settings(context) -> settings``: how its settings follow from what the caller knows
  (:class:`SettingsContext`: the configured HDR parameters, HDR+'s configured base, the
  gyro's samples per step, the calibration record). HDR+'s are derived in one function,
  :func:`plus_settings`, for the daemon, replay and evaluate alike.

A new drift reducer is one more entry in :data:`REGISTRY`. Pure; no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, Generic, TypeVar

import numpy as np
import numpy.typing as npt

from hdrd import hdr, hdrplus
from hdrd.calibrate import BiasRecord
from hdrd.hdr import HdrOutput, HdrParams
from hdrd.hdrplus import GyroNoise, HdrPlusParams, PlusInput, PlusOutput, PlusState
from hdrd.zupt import CalibrationNoise

__all__ = [
    "REGISTRY",
    "Method",
    "SettingsContext",
    "StepInputs",
    "StepOutput",
    "calibration_of",
    "get",
    "names",
    "plus_settings",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
S = TypeVar("S")
StepOutput = HdrOutput | PlusOutput
"""What a step publishes: omega, yaw, I, W, R, r, filtered (HDR+ adds its bias model's)."""


@dataclass(frozen=True)
class StepInputs:
    """A drive's steps as arrays, one element per step taken (a step without samples is not
    a step: it has no element, and the yaw holds across it).

    u: block mean of the raw rate minus the static bias, deg/s CCW (Eqs. 2, 11). t_end: end
    of each step, s since the drive log's first sample. T: step period, s. bias_dps: the static
    bias removed, deg/s. n_samples: samples averaged in each step. speed: mean speed in each
    step, m/s (NaN where unknown), None if the log has none. temp_c: mean temperature in each
    step, deg C (NaN where unknown), or None. omega_std: standard deviation of the raw samples
    within each step, deg/s (0 for a single sample). bias_var: variance of the static bias
    estimate, (deg/s)^2 (sample variance / samples of the calibration window; NaN if the bias
    was given).
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

    def input(self, i: int) -> PlusInput:
        """Step i as the daemon's pipeline hands it to a method's ``step``."""

        def at(a: FloatArray | None) -> float:
            return math.nan if a is None else float(a[i])

        return PlusInput(
            float(self.u[i]), at(self.omega_std), at(self.speed), at(self.temp_c), self.T
        )


@dataclass(frozen=True)
class SettingsContext:
    """What a method's settings are derived from.

    hdr: the configured HDR parameters (``hdr.*``; T is the step period, s). plus: HDR+'s
    base settings (its defaults with the config's ``standstill.*`` applied). samples_per_step:
    samples averaged in one step, from the gyro's own sample rate (None = unknown). bias: the
    calibration record behind the static bias (None, or n = 0, when the bias was given).
    noise: the gyro's error model when known (configured grade, recorded parameters).
    quant_step_dps: the gyro's output step, deg/s, when known.
    """

    hdr: HdrParams = HdrParams()
    plus: HdrPlusParams = HdrPlusParams()
    samples_per_step: float | None = None
    bias: BiasRecord | None = None
    noise: GyroNoise | None = None
    quant_step_dps: float | None = None


def calibration_of(
    bias: BiasRecord | None, samples_per_step: float | None
) -> CalibrationNoise | None:
    """What a start-up calibration record says about the gyro's noise at standstill
    (:class:`hdrd.zupt.CalibrationNoise`): var(eps0) = std^2 / n, a step's mean's variance
    std^2 / (samples per step), and whether the window sat on one output code (std 0: a
    coarse ADC whose noise is below its step). None without a measured record (n < 2)."""
    if bias is None or bias.n < 2 or not math.isfinite(bias.std_dps):
        return None
    per = samples_per_step if samples_per_step is not None and samples_per_step > 0 else 1.0
    var = bias.std_dps * bias.std_dps
    return CalibrationNoise(var / bias.n, var / per, math.nan, per, 1 if var == 0.0 else 0)


def plus_settings(
    base: HdrPlusParams,
    T: float,
    samples_per_step: float | None = None,
    bias: BiasRecord | None = None,
    noise: GyroNoise | None = None,
    quant_step_dps: float | None = None,
) -> HdrPlusParams:
    """HDR+'s settings for this gyro and this drive: the one place they are derived.

    base: HDR+'s configured settings (its own core, tuned with its extras; the configured
    ``hdr.*`` parameters are not used). T: the step period, s, given to the core. Samples per
    step (the gyro's sample rate times T; a 1 Hz gyro has 1) turns a step's spread into the
    variance of its mean at a standstill. bias: the start-up calibration record (its noise:
    :func:`calibration_of`; a given bias has none, and base.bias_p0 stays). noise: the gyro's
    error model when known (a configured grade, or parameters recorded by ``hdrd calibrate``).
    quant_step_dps: the gyro's output step, deg/s, when known (the ADC's LSB; for a recorded
    log, the lattice of its values). :meth:`hdrd.hdrplus.HdrPlusParams.fitted` does the rest.
    """
    p = base.with_(hdr=replace(base.hdr, T=T))
    if samples_per_step is not None and samples_per_step > 0:
        p = p.with_(standstill=replace(p.standstill, samples_per_step=float(samples_per_step)))
    return p.fitted(calibration_of(bias, samples_per_step), noise, quant_step_dps)


@dataclass(frozen=True)
class Method(Generic[S]):
    """One drift reducer (see the module docstring). ``bias_model``: the method refines the
    static bias itself and detects standstill, so the pipeline publishes the corrected bias and
    the ``zupt`` flag."""

    name: str
    summary: str
    step: Callable[[PlusState, PlusInput, S], tuple[PlusState, StepOutput]]
    batch: Callable[[StepInputs, S], FloatArray]
    settings: Callable[[SettingsContext], S]
    bias_model: bool = False


# -- none: static bias removal only ------------------------------------------------------------


def _hdr_step(state: PlusState, inp: PlusInput, params: HdrParams) -> tuple[PlusState, StepOutput]:
    core, out = hdr.step(state.core, inp.u, params)
    return state._replace(core=core), out


def _none_batch(steps: StepInputs, params: HdrParams) -> FloatArray:
    # psi_i = psi_{i-1} + u_i * T (Eq. 3 with I = 0). A sequential cumsum: bit-identical to
    # hdr.step with I frozen at 0 (tests/test_methods.py).
    return np.cumsum(steps.u * params.T)


def _none_settings(ctx: SettingsContext) -> HdrParams:
    return replace(ctx.hdr, enabled=False)


# -- hdr: the paper --------------------------------------------------------------------------


def _hdr_batch(steps: StepInputs, params: HdrParams) -> FloatArray:
    return hdr.run_batch(steps.u, params).yaw


def _hdr_settings(ctx: SettingsContext) -> HdrParams:
    return ctx.hdr


# -- hdr+ ------------------------------------------------------------------------------------


def _plus_step(
    state: PlusState, inp: PlusInput, params: HdrPlusParams
) -> tuple[PlusState, StepOutput]:
    return hdrplus.step(state, inp, params)


def _plus_batch(steps: StepInputs, params: HdrPlusParams) -> FloatArray:
    return hdrplus.run_batch(
        steps.u, steps.omega_std, steps.speed, steps.temp_c, steps.T, params
    ).yaw


def _plus_settings(ctx: SettingsContext) -> HdrPlusParams:
    return plus_settings(
        ctx.plus, ctx.hdr.T, ctx.samples_per_step, ctx.bias, ctx.noise, ctx.quant_step_dps
    )


REGISTRY: dict[str, Method[Any]] = {
    m.name: m
    for m in (
        Method("none", "static bias removal only", _hdr_step, _none_batch, _none_settings),
        Method("hdr", "the paper's HDR (Table III)", _hdr_step, _hdr_batch, _hdr_settings),
        Method(
            "hdr+",
            "HDR with standstill re-calibration and a bias model",
            _plus_step,
            _plus_batch,
            _plus_settings,
            bias_model=True,
        ),
    )
}
"""Drift reducers by name (``hdr.method``, ``--method``)."""


def names() -> tuple[str, ...]:
    """The registered methods' names, in registry order."""
    return tuple(REGISTRY)


def get(name: str) -> Method[Any]:
    """The method called ``name``; ValueError naming the allowed ones."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r} (allowed: {', '.join(REGISTRY)})") from None
