"""The drift reducers by name: the one registry the daemon, replay, evaluate and the CLI use.

A method (:class:`Method`) is a small object with six operations:

- ``initial_state(yaw)``: its state at start, the yaw (deg CCW) carried in, so that a method
  switched on SIGHUP continues the same heading (:meth:`Method.yaw` reads it back out);
- ``step(state, input, settings) -> (state, output)``: one step T, the form the daemon's
  pipeline runs once per closed block, on the one input every method takes,
  :class:`hdrd.core.steps.StepInput` (u = block mean - eps0 in deg/s CCW, the samples' spread,
  speed, temperature, T), of which each reads what it uses;
- ``batch(inputs, settings) -> yaw``: the same recursion over a whole drive's
  :class:`hdrd.core.steps.StepInputs` from the initial state, the fast form for offline tools;
  bit-identical to looping ``step`` (tests/test_methods.py);
- ``settings(context) -> settings``: how its settings follow from what the caller knows
  (:class:`MethodSetup`: the configured HDR parameters, HDR+'s configured base, the
  gyro's samples per step, the calibration record, its error model). HDR+'s are derived in
  one function, :func:`plus_settings`, for the daemon, replay and evaluate alike;
- ``publish(output, settings) -> Published``: the message fields of a step's output.

A new drift reducer is one more entry in :data:`REGISTRY`. Pure; no I/O.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, replace
from typing import Any, Generic, NamedTuple, TypeVar

import numpy as np
import numpy.typing as npt

from hdrd.core import hdr, hdrplus
from hdrd.core.calibrate import BiasRecord
from hdrd.core.gyronoise import GyroNoise, noise_in_force
from hdrd.core.hdr import INITIAL_STATE, HdrOutput, HdrParams, HdrState
from hdrd.core.hdrplus import INITIAL_PLUS_STATE, PlusOutput, PlusState
from hdrd.core.plusparams import PlusParams
from hdrd.core.standstill import CalibrationNoise
from hdrd.core.steps import StepInput, StepInputs

__all__ = [
    "REGISTRY",
    "Method",
    "Published",
    "MethodSetup",
    "StepInput",
    "StepInputs",
    "StepOutput",
    "calibration_of",
    "error_model",
    "get",
    "hdr_settings",
    "names",
    "plus_settings",
]

FloatArray = npt.NDArray[np.float64]
S = TypeVar("S")
P = TypeVar("P")
StepOutput = HdrOutput | PlusOutput
"""What a step publishes: omega, yaw, I, W, R, r, filtered (HDR+ adds its bias model's)."""


class Published(NamedTuple):
    """A step's output as message fields (docs/protocol.md): what every method says of the
    heading and the bias, in one shape.

    core: omega and yaw, then the paper's controller I, W, R, r where the method has them (HDR+
    has W only: 1 on a step it took for straight road); the heading is the pipeline's. extra:
    the method's own fields after the bias (HDR+: zupt, model, bias_sd, motion_offset).
    bias_corr_dps: what the method adds to the static bias eps0, deg/s (the published bias is
    eps0 + this). standstill: the step was a zero-rate update (status ``standstill``).
    heading_sd_deg: the heading's standard deviation, deg (NaN: the method does not know it).
    """

    core: dict[str, float | int]
    extra: dict[str, float | int | str]
    bias_corr_dps: float = 0.0
    standstill: bool = False
    heading_sd_deg: float = math.nan


@dataclass(frozen=True)
class MethodSetup:
    """One drift reducer's setup, typed: built once from the configuration, the bias file and
    the sensor (:func:`hdrd.config.method_setup`) and used alike by the daemon, replay and
    evaluate; each derives the method's settings from it (:meth:`settings`), with what a
    drive adds (:meth:`for_drive`: the gyro's samples per step, a calibration measured at
    start, a recorded log's output step).

    From the configuration: method, ``hdr.method``; hdr, the HDR parameters (``hdr.*``; T is
    the step period, s); i_c_auto, ``hdr.i_c: auto`` (HDR's increment follows a known error
    model's drift, :func:`hdr_settings`); grade, ``gyro.grade`` (``none``: no preset);
    given_noise, the ``gyro.*`` noise parameters given (name, value; 0 = not given);
    standstill and standstill_from_gyro, ``standstill.enabled`` and ``standstill.from_gyro``.
    plus: HDR+'s base settings (its defaults; benchmarks override them).

    From the bias file and the sensor, and the drive: bias, the static bias and the record
    behind it (None: measured at start-up; a given bias: :meth:`hdrd.core.calibrate.
    BiasRecord.given`, n = 0; a bias file's record carries the error model ``hdrd calibrate``
    measured); quant_step_dps, the gyro's output step, deg/s (the ADC's LSB; for a recorded
    log, the lattice of its values), None = unknown; samples_per_step, samples averaged in
    one step (the gyro's sample rate times T; None = unknown). learned: what the unit's trips
    taught of it (the daemon's unit state file, :mod:`hdrd.io.files.unitstate`; None: nothing).
    """

    hdr: HdrParams = HdrParams()
    plus: PlusParams = PlusParams()
    samples_per_step: float | None = None
    bias: BiasRecord | None = None
    quant_step_dps: float | None = None
    i_c_auto: bool = True
    grade: str = "none"
    given_noise: tuple[tuple[str, float], ...] = ()
    standstill: bool = True
    standstill_from_gyro: bool = False
    method: str = "hdr"
    learned: GyroNoise | None = None

    def for_drive(
        self,
        samples_per_step: float | None,
        bias: BiasRecord | None,
        quant_step_dps: float | None = None,
    ) -> MethodSetup:
        """This setup with what a drive shows: its samples per step, the bias in force (a
        calibration measured at start, or the one given), its output step when known
        otherwise than the setup's (a recorded log's lattice)."""
        q = self.quant_step_dps if quant_step_dps is None else quant_step_dps
        return replace(self, samples_per_step=samples_per_step, bias=bias, quant_step_dps=q)

    def settings(self) -> Any:
        """The method's settings for this setup (:meth:`Method.settings`)."""
        return get(self.method).settings(self)


def calibration_of(
    bias: BiasRecord | None, samples_per_step: float | None
) -> CalibrationNoise | None:
    """What a start-up calibration record says about the gyro's noise at standstill
    (:class:`hdrd.core.standstill.CalibrationNoise`): var(eps0) = std^2 / n, a step's mean's variance
    std^2 / (samples per step), and whether the window sat on one output code (std 0: a
    coarse ADC whose noise is below its step). None without a measured record (n < 2)."""
    if bias is None or bias.n < 2 or not math.isfinite(bias.std_dps):
        return None
    per = samples_per_step if samples_per_step is not None and samples_per_step > 0 else 1.0
    var = bias.std_dps * bias.std_dps
    return CalibrationNoise(var / bias.n, var / per, math.nan, per, 1 if var == 0.0 else 0)


def error_model(setup: MethodSetup) -> GyroNoise | None:
    """The gyro's error model when known (:func:`hdrd.core.gyronoise.noise_in_force`: recorded
    by ``hdrd calibrate`` in the bias file, else the ``gyro.*`` parameters given, else the
    grade's); None when nothing is known."""
    recorded = setup.bias.noise if setup.bias is not None else None
    return noise_in_force(setup.grade, dict(setup.given_noise), recorded, setup.learned)


I_C_WINDOW_S = 30.0
"""HDR's increment with a known error model is at most the bias's drift over this long, s:
sqrt(Q x 30 s), Q the model's random walk without a temperature (K^2 + 2 sigma^2 / tau + a
warm-up). For the CRS03-04 grade 0.024 deg/s (Table III: 0.0422), the automotive grade
0.016, the tactical grade 0.0016; a phone's drift is above Table III's, which stays. Chosen on
simulated tuning routes of every grade (bench/RESULTS.md,
Real drives, "What tuned what")."""


def hdr_settings(setup: MethodSetup) -> HdrParams:
    """The paper's HDR parameters for this gyro: the configured ``hdr.*`` (Table III by
    default); with ``hdr.i_c: auto`` and the gyro's error model known
    (:func:`error_model`), i_c = min(hdr.i_c, sqrt(Q x :data:`I_C_WINDOW_S`)), Q its bias random
    walk without a temperature, (deg/s)^2/s: a gyro whose bias barely moves is not "corrected"
    by a binary increment meant for a CRS03-04's drift, which only straightens real curves.
    Without a known model Table III stays (the start-up calibration shows the white noise, not
    how the bias drifts)."""
    p = setup.hdr
    if not setup.i_c_auto:
        return p
    noise = error_model(setup)
    if noise is None or not noise.known():
        return p
    drift = math.sqrt(max(noise.bias_q_no_temp(), 0.0) * I_C_WINDOW_S)
    return p if drift >= p.i_c else replace(p, i_c=drift)


def plus_settings(setup: MethodSetup) -> PlusParams:
    """HDR+'s settings for this gyro and this drive: the one place they are derived (the
    daemon, replay and evaluate all come here).

    From setup (:class:`MethodSetup`): HDR+'s base settings with ``standstill.*`` applied
    (its own core, tuned with its extras; the configured ``hdr.*`` parameters are not used
    but for T, the step period); the samples per step (a 1 Hz gyro has 1), which turn a
    step's spread into the variance of its mean at a standstill; the calibration record's
    noise (:func:`calibration_of`; a given bias has none, and the base's bias_p0 stays); the
    gyro's error model when known (:func:`hdrd.core.gyronoise.noise_in_force`: recorded by
    ``hdrd calibrate``, else the ``gyro.*`` parameters given, else the grade's); the output
    step (the ADC's LSB; for a recorded log, the lattice of its values).
    :meth:`hdrd.core.plusparams.PlusParams.fitted` fits the bank to them.
    """
    base = setup.plus
    ss = replace(base.standstill, enabled=setup.standstill, gyro_only=setup.standstill_from_gyro)
    p = base.with_(T=setup.hdr.T, standstill=ss)
    n = setup.samples_per_step
    if n is not None and n > 0:
        p = p.with_(standstill=replace(p.standstill, samples_per_step=float(n)))
    return p.fitted(calibration_of(setup.bias, n), error_model(setup), setup.quant_step_dps)


class Method(ABC, Generic[S, P]):
    """One drift reducer (see the module docstring); subclasses define the operations.
    ``owns_heading``: the method owns the heading and the bias: it takes each GPS course as a
    measurement of its heading (the aiding aligns it once and then hands it the courses) and
    publishes its own bias; the others' heading is aligned by the aiding, whose learning moves
    their static bias."""

    name: str = ""
    summary: str = ""
    owns_heading: bool = False

    @abstractmethod
    def initial_state(self, yaw: float = 0.0) -> S:
        """The state at start, with ``yaw`` deg CCW carried in."""

    @abstractmethod
    def yaw(self, state: S) -> float:
        """The yaw of a state, deg CCW since start."""

    @abstractmethod
    def step(self, state: S, inp: StepInput, settings: P) -> tuple[S, StepOutput]:
        """One step T."""

    @abstractmethod
    def batch(self, steps: StepInputs, settings: P) -> FloatArray:
        """The yaw of every step of a drive from the initial state, deg CCW."""

    @abstractmethod
    def settings(self, setup: MethodSetup) -> P:
        """The settings for this gyro and drive."""

    def heading_sd(self, steps: StepInputs, settings: P) -> FloatArray | None:
        """The standard deviation of every step's yaw (so heading), deg, for a method that
        estimates it (HDR+); None for one that does not."""
        return None

    def publish(self, out: StepOutput, settings: P) -> Published:
        """A step's output as message fields."""
        return Published(_core_fields(out), {})


def _core_fields(o: StepOutput) -> dict[str, float | int]:
    assert isinstance(o, HdrOutput)  # the paper's controller: its fields
    return {"omega": o.omega, "yaw": o.yaw, "I": o.I, "W": o.W, "R": o.R, "r": o.r}


class _Hdr(Method[HdrState, HdrParams]):
    """The paper's HDR (Table III by default)."""

    name = "hdr"
    summary = "the paper's HDR (Table III)"

    def initial_state(self, yaw: float = 0.0) -> HdrState:
        return INITIAL_STATE._replace(yaw=yaw)

    def yaw(self, state: HdrState) -> float:
        return state.yaw

    def step(
        self, state: HdrState, inp: StepInput, settings: HdrParams
    ) -> tuple[HdrState, StepOutput]:
        return hdr.step(state, inp.u, settings)

    def batch(self, steps: StepInputs, settings: HdrParams) -> FloatArray:
        return hdr.run_batch(steps.u, settings).yaw

    def settings(self, setup: MethodSetup) -> HdrParams:
        return hdr_settings(setup)


class _None(_Hdr):
    """Static bias removal only: the paper's HDR with I frozen at 0."""

    name = "none"
    summary = "static bias removal only"

    def batch(self, steps: StepInputs, settings: HdrParams) -> FloatArray:
        # psi_i = psi_{i-1} + u_i * T (Eq. 3 with I = 0). A sequential cumsum: bit-identical
        # to hdr.step with I frozen at 0 (tests/test_methods.py).
        return np.cumsum(steps.u * settings.T)

    def settings(self, setup: MethodSetup) -> HdrParams:
        return replace(setup.hdr, enabled=False)


class _Plus(Method[PlusState, PlusParams]):
    """HDR+ (:mod:`hdrd.core.hdrplus`)."""

    name = "hdr+"
    summary = "HDR with standstill re-calibration and a bias model"
    owns_heading = True

    def initial_state(self, yaw: float = 0.0) -> PlusState:
        return INITIAL_PLUS_STATE._replace(yaw=yaw)

    def yaw(self, state: PlusState) -> float:
        if state.xs:
            return float(sum(m * x[hdrplus.YAW] for m, x in zip(state.mu, state.xs)))
        return state.yaw

    def step(
        self, state: PlusState, inp: StepInput, settings: PlusParams
    ) -> tuple[PlusState, StepOutput]:
        return hdrplus.step(state, inp, settings)

    def batch(self, steps: StepInputs, settings: PlusParams) -> FloatArray:
        return self._run(steps, settings).yaw

    def heading_sd(self, steps: StepInputs, settings: PlusParams) -> FloatArray:
        return self._run(steps, settings).heading_sd_deg

    @staticmethod
    def _run(steps: StepInputs, settings: PlusParams) -> hdrplus.PlusTrace:
        return hdrplus.run_batch(
            steps.u, steps.omega_std, steps.speed, steps.temp_c, steps.T, settings
        )

    def settings(self, setup: MethodSetup) -> PlusParams:
        return plus_settings(setup)

    def publish(self, out: StepOutput, settings: PlusParams) -> Published:
        assert isinstance(out, PlusOutput)
        core: dict[str, float | int] = {
            "omega": out.omega,
            "yaw": out.yaw,
            "W": int(out.straight >= 0.5),
        }
        extra: dict[str, float | int | str] = {
            "zupt": int(out.standstill),
            "model": settings.model,  # the error model in force
            "bias_sd": out.bias_sd_dps,
            "motion_offset": out.offset_dps,
        }
        return Published(core, extra, out.bias_corr_dps, out.standstill, out.heading_sd_deg)


REGISTRY: dict[str, Method[Any, Any]] = {m.name: m for m in (_None(), _Hdr(), _Plus())}
"""Drift reducers by name (``hdr.method``, ``--method``)."""


def names() -> tuple[str, ...]:
    """The registered methods' names, in registry order."""
    return tuple(REGISTRY)


def get(name: str) -> Method[Any, Any]:
    """The method called ``name``; ValueError naming the allowed ones."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r} (allowed: {', '.join(REGISTRY)})") from None
