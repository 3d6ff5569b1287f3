"""The gyro's error effects, each a named physical effect with its parameters; composed into a
model by :class:`hdrd.sim.gyro.GyroModel`.

Pure: a model (:meth:`hdrd.sim.gyro.GyroModel.apply`) maps the true yaw rate (deg/s, + = CCW) to what the gyro and its
ADC report, drawing randomness only from the generator it is given. Every effect is a frozen
dataclass whose fields are its parameters in physical units (docs/gyro-model.md):

==================== ================================================================ ==========
name                 parameters                                                      adds
==================== ================================================================ ==========
time_offset          delay_s (s; measured lags truth by this much)                    lag
scale_factor         error (-; measured = (1 + error) * true)                         gain
scale_asymmetry      pos_error, neg_error (-; gain error for true > 0 / true < 0)     gain
static_bias          bias_dps (deg/s)                                                 bias
warmup_transient     amplitude_dps (deg/s), tau_s (s): amplitude*exp(-t/tau)          bias
temperature_bias     coeff_dps_per_c (deg/s/degC), ref_temp_c (degC),                 bias
                     quad_dps_per_c2 (deg/s/degC^2, optional)
motion_offset        offset_dps (deg/s), coeff_dps_per_mps (deg/s per m/s, opt.):     bias
                     offset + coeff*v while the speed v > moving_mps (m/s, opt. 0.5)
bias_instability     sigma_dps (deg/s), tau_s (s): first-order Gauss-Markov           bias
rate_random_walk     k_dps_per_sqrt_s (deg/s/sqrt(s)): random walk of the bias        bias
white_noise          density_dps_per_rthz (deg/s/sqrt(Hz)): angle random walk         noise
bandwidth            cutoff_hz (Hz): first-order low-pass; output_noise_dps_per_rthz  filter
                     (deg/s/sqrt(Hz), opt.): white noise after it
saturation           limit_dps (deg/s): output clipped to +/- limit                   clip
quantization         step_dps (deg/s): output rounded to a multiple of step           ADC
==================== ================================================================ ==========

The effects apply in that fixed physical order whatever order a model lists them in: the
sensing element sees the (delayed) true rate, multiplies it by its gain, adds its bias terms
and noise; its output amplifier has a finite bandwidth and rails; the ADC quantises last.
Time t in the effects is time since power-on, taken as the first sample's time (``t - t[0]``).
Every effect draws from a random stream of its own, numbered once and for all (:data:`STREAMS`).

Noise conventions (IEEE Std 952 coefficients, so that the Allan deviation reads them back):
white noise of density N gives samples of standard deviation N / sqrt(dt) and an Allan deviation
N / sqrt(tau) (N at tau = 1 s); a rate random walk K gives K * sqrt(tau / 3); a Gauss-Markov
bias of sigma, tau_c has variance sigma**2 and correlation exp(-|dt| / tau_c).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from hdrd.core.sensor import SensorModel
from hdrd.errors import clipped
from hdrd.sim.gyrolimits import limit_problem

__all__ = [
    "Bandwidth",
    "BiasInstability",
    "Context",
    "EFFECTS",
    "EFFECT_NAMES",
    "Effect",
    "MotionOffset",
    "Quantization",
    "RateRandomWalk",
    "STREAMS",
    "Saturation",
    "ScaleAsymmetry",
    "ScaleFactor",
    "StaticBias",
    "StopOffset",
    "TemperatureBias",
    "TimeOffset",
    "WarmupTransient",
    "WhiteNoise",
    "ar1",
    "effect_from_dict",
    "param_names",
]

FloatArray = npt.NDArray[np.float64]


def _finite(effect: str, name: str, value: float) -> None:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ValueError(f"{effect}.{name}: {value!r} is not a finite number")


def _positive(effect: str, name: str, value: float) -> None:
    _finite(effect, name, value)
    if value <= 0:
        raise ValueError(f"{effect}.{name}: {value!r} must be > 0")


def _nonneg(effect: str, name: str, value: float) -> None:
    _finite(effect, name, value)
    if value < 0:
        raise ValueError(f"{effect}.{name}: {value!r} must be >= 0")


def _gain(effect: str, name: str, value: float) -> None:
    _finite(effect, name, value)
    if value <= -1:
        raise ValueError(f"{effect}.{name}: {value!r} must be > -1 (a gain of 1 + error > 0)")


# -- fast first-order recursion ----------------------------------------------------------

_SPAN = 500.0  # e-folds per block: exp(+-540) stays inside float64's range
_STEP_CAP = 40.0  # a step of > 40 time constants forgets the past to < 5e-18: treat as 40


def ar1(decay: FloatArray, u: FloatArray, x0: float) -> FloatArray:
    """x[0] = x0; x[k] = exp(-decay[k]) * x[k-1] + u[k] for k >= 1 (decay[0], u[0] unused).

    ``decay[k]`` = (t[k] - t[k-1]) / tau, so non-uniform sampling is exact. Vectorised with the
    cumulative-sum form x[k] = exp(-g[k]) * (x0 + sum_j u[j] * exp(g[j])), g = cumsum(decay),
    restarted every few hundred e-folds so that the exponentials stay finite and accurate.
    """
    n = int(u.shape[0])
    x = np.empty(n, dtype=np.float64)
    if n == 0:
        return x
    x[0] = x0
    if n == 1:
        return x
    d = np.minimum(np.asarray(decay[1:], dtype=np.float64), _STEP_CAP)
    g = np.cumsum(d)  # g[i] belongs to sample i + 1
    block = np.floor(g / _SPAN).astype(np.int64)
    starts = np.concatenate(([0], np.flatnonzero(np.diff(block)) + 1, [n - 1]))
    carry = float(x0)
    uu = u[1:]
    for a, b in itertools.pairwise(starts):
        g0 = g[a - 1] if a > 0 else 0.0
        gr = g[a:b] - g0
        e = np.exp(gr)
        seg = (carry + np.cumsum(uu[a:b] * e)) / e
        x[a + 1 : b + 1] = seg
        carry = float(seg[-1])
    return x


# -- the effects ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Context:
    """What every effect may use: time since power-on (s), sample steps (s), temperature (C),
    the vehicle's speed (m/s; None: not known)."""

    t: FloatArray
    dt: FloatArray
    temp_c: FloatArray | None
    rng: np.random.Generator
    speed_mps: FloatArray | None = None


@dataclass(frozen=True)
class Effect:
    """Base of all effects. ``name`` is the YAML/report name; ``order`` the physical order."""

    name: ClassVar[str] = ""
    order: ClassVar[int] = 0

    def params(self) -> dict[str, float]:
        """The parameters in physical units, as in YAML."""
        return {k: float(v) for k, v in asdict(self).items()}

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:  # pragma: no cover - abstract
        raise NotImplementedError


@dataclass(frozen=True)
class TimeOffset(Effect):
    """The measurement lags the truth by ``delay_s`` seconds (negative: leads); linear
    interpolation of the true rate, held constant beyond the ends."""

    name: ClassVar[str] = "time_offset"
    order: ClassVar[int] = 0
    delay_s: float = 0.0

    def __post_init__(self) -> None:
        _finite(self.name, "delay_s", self.delay_s)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        return np.interp(ctx.t - self.delay_s, ctx.t, x)


@dataclass(frozen=True)
class ScaleFactor(Effect):
    """Gain error: measured = (1 + error) * true (error dimensionless, 0.01 = 1 %)."""

    name: ClassVar[str] = "scale_factor"
    order: ClassVar[int] = 1
    error: float = 0.0

    def __post_init__(self) -> None:
        _gain(self.name, "error", self.error)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        return (1.0 + self.error) * x


@dataclass(frozen=True)
class ScaleAsymmetry(Effect):
    """Sign-dependent gain: measured = (1 + pos_error) * true for true > 0 (left turns),
    (1 + neg_error) * true for true < 0 (right turns). Dimensionless."""

    name: ClassVar[str] = "scale_asymmetry"
    order: ClassVar[int] = 2
    pos_error: float = 0.0
    neg_error: float = 0.0

    def __post_init__(self) -> None:
        _gain(self.name, "pos_error", self.pos_error)
        _gain(self.name, "neg_error", self.neg_error)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        return np.where(x > 0, (1.0 + self.pos_error) * x, (1.0 + self.neg_error) * x)


@dataclass(frozen=True)
class StaticBias(Effect):
    """Constant null offset, deg/s (+ = reads CCW at rest). The paper's eps0 (Eq. 2)."""

    name: ClassVar[str] = "static_bias"
    order: ClassVar[int] = 3
    bias_dps: float = 0.0

    def __post_init__(self) -> None:
        _finite(self.name, "bias_dps", self.bias_dps)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        return x + self.bias_dps


@dataclass(frozen=True)
class WarmupTransient(Effect):
    """Bias settling after power-on: + amplitude_dps * exp(-t / tau_s), t since power-on."""

    name: ClassVar[str] = "warmup_transient"
    order: ClassVar[int] = 4
    amplitude_dps: float = 0.0
    tau_s: float = 60.0

    def __post_init__(self) -> None:
        _finite(self.name, "amplitude_dps", self.amplitude_dps)
        _positive(self.name, "tau_s", self.tau_s)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        return x + self.amplitude_dps * np.exp(-ctx.t / self.tau_s)


@dataclass(frozen=True)
class TemperatureBias(Effect):
    """Bias that depends on temperature T (the log's temp_c, deg C)::

        + coeff_dps_per_c * (T - ref_temp_c) + quad_dps_per_c2 * (T - ref_temp_c)**2

    coeff_dps_per_c is the bias change per deg C at the reference temperature (deg/s/degC)."""

    name: ClassVar[str] = "temperature_bias"
    order: ClassVar[int] = 5
    coeff_dps_per_c: float = 0.0
    ref_temp_c: float = 25.0
    quad_dps_per_c2: float = 0.0

    def __post_init__(self) -> None:
        _finite(self.name, "coeff_dps_per_c", self.coeff_dps_per_c)
        _finite(self.name, "ref_temp_c", self.ref_temp_c)
        _finite(self.name, "quad_dps_per_c2", self.quad_dps_per_c2)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        if ctx.temp_c is None:
            raise ValueError("temperature_bias needs a temperature (temp_c) for every sample")
        d = ctx.temp_c - self.ref_temp_c
        return x + self.coeff_dps_per_c * d + self.quad_dps_per_c2 * d * d


@dataclass(frozen=True)
class MotionOffset(Effect):
    """Bias that differs between standstill and driving (vibration rectification,
    g-sensitivity): while the vehicle's speed v (m/s) is above moving_mps the gyro reads::

        + offset_dps + coeff_dps_per_mps * v

    and nothing at or below it, so a bias measured at a stop misses it while driving. The
    effect needs the speed of every sample (``GyroModel.apply(..., speed_mps=...)``):
    ValueError without it, as temperature_bias without a temperature."""

    name: ClassVar[str] = "motion_offset"
    order: ClassVar[int] = 6
    offset_dps: float = 0.0
    moving_mps: float = 0.5
    coeff_dps_per_mps: float = 0.0

    def __post_init__(self) -> None:
        _finite(self.name, "offset_dps", self.offset_dps)
        _nonneg(self.name, "moving_mps", self.moving_mps)
        _finite(self.name, "coeff_dps_per_mps", self.coeff_dps_per_mps)

    def moving(self, speed_mps: FloatArray) -> npt.NDArray[np.bool_]:
        """Samples taken while the vehicle moves: speed above moving_mps."""
        return np.asarray(speed_mps > self.moving_mps)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        if ctx.speed_mps is None:
            raise ValueError("motion_offset needs the vehicle's speed (speed_mps) for every sample")
        v = ctx.speed_mps
        return x + np.where(self.moving(v), self.offset_dps + self.coeff_dps_per_mps * v, 0.0)


@dataclass(frozen=True)
class StopOffset(Effect):
    """Each stop reads its own bias: while the speed v (m/s) is at or below moving_mps, the
    gyro reads an offset drawn anew for every such run of samples (every stop, the standstill
    at power-on too) from N(0, sd_dps), deg/s; nothing while moving. Real stops read 0.005-0.04
    deg/s off a still-good driving bias (idling, a slope, the engine's vibration). Needs the
    speed of every sample, as motion_offset does."""

    name: ClassVar[str] = "stop_offset"
    order: ClassVar[int] = 6
    sd_dps: float = 0.0
    moving_mps: float = 0.5

    def __post_init__(self) -> None:
        _nonneg(self.name, "sd_dps", self.sd_dps)
        _nonneg(self.name, "moving_mps", self.moving_mps)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        if ctx.speed_mps is None:
            raise ValueError("stop_offset needs the vehicle's speed (speed_mps) for every sample")
        still = np.asarray(ctx.speed_mps <= self.moving_mps)
        starts = still & ~np.concatenate(([False], still[:-1]))
        run = np.cumsum(starts)  # the stop each sample belongs to (1, 2, ...)
        offsets = np.concatenate(
            ([0.0], ctx.rng.normal(0.0, self.sd_dps, int(run[-1]) if run.shape[0] else 0))
        )
        return x + np.where(still, offsets[run], 0.0)


@dataclass(frozen=True)
class BiasInstability(Effect):
    """First-order Gauss-Markov bias: stationary standard deviation sigma_dps (deg/s),
    correlation time tau_s (s); exact discretisation b[k] = a b[k-1] + sigma sqrt(1 - a^2) w,
    a = exp(-dt / tau). Its Allan deviation peaks near 0.62 sigma at tau ~ 1.9 tau_s."""

    name: ClassVar[str] = "bias_instability"
    order: ClassVar[int] = 7
    sigma_dps: float = 0.0
    tau_s: float = 300.0

    def __post_init__(self) -> None:
        _nonneg(self.name, "sigma_dps", self.sigma_dps)
        _positive(self.name, "tau_s", self.tau_s)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        decay = ctx.dt / self.tau_s
        a = np.exp(-np.minimum(decay, _STEP_CAP))
        w = ctx.rng.standard_normal((x.shape[0],))
        drive = self.sigma_dps * np.sqrt(1.0 - a * a) * w
        return x + ar1(decay, drive, self.sigma_dps * float(w[0]))


@dataclass(frozen=True)
class RateRandomWalk(Effect):
    """Bias random walk from zero at power-on: b[k] = b[k-1] + k_dps_per_sqrt_s * sqrt(dt) * w
    (deg/s/sqrt(s)); Allan deviation K * sqrt(tau / 3)."""

    name: ClassVar[str] = "rate_random_walk"
    order: ClassVar[int] = 8
    k_dps_per_sqrt_s: float = 0.0

    def __post_init__(self) -> None:
        _nonneg(self.name, "k_dps_per_sqrt_s", self.k_dps_per_sqrt_s)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        steps = self.k_dps_per_sqrt_s * np.sqrt(ctx.dt) * ctx.rng.standard_normal((x.shape[0],))
        steps[0] = 0.0
        return x + np.cumsum(steps)


@dataclass(frozen=True)
class WhiteNoise(Effect):
    """White rate noise of density density_dps_per_rthz (deg/s/sqrt(Hz) = deg/sqrt(s): the angle
    random walk coefficient N). Sample standard deviation N / sqrt(dt); Allan deviation N at 1 s."""

    name: ClassVar[str] = "white_noise"
    order: ClassVar[int] = 9
    density_dps_per_rthz: float = 0.0

    def __post_init__(self) -> None:
        _nonneg(self.name, "density_dps_per_rthz", self.density_dps_per_rthz)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        sd = self.density_dps_per_rthz / np.sqrt(ctx.dt)
        return x + sd * ctx.rng.standard_normal((x.shape[0],))


@dataclass(frozen=True)
class Bandwidth(Effect):
    """Low-pass of the sensor's output, cutoff_hz (Hz, -3 dB; CRS03-04: 10 Hz): ``sections``
    equal first-order sections (default 1; 1 .. 4), each exact for a rate held over each
    sample step: y[k] = a y[k-1] + (1 - a) x[k], a = exp(-2 pi f_s dt), f_s = cutoff /
    sqrt(2**(1/sections) - 1) so that the whole filter is 3 dB down at cutoff_hz; starts
    settled (y[0] = x[0]). Optional output_noise_dps_per_rthz (deg/s/sqrt(Hz), default 0):
    white noise added after the low-pass (the output stage's and the ADC's own), sample sd
    N_out / sqrt(dt): what the low-pass leaves of the sensor's noise at high frequency is not
    all there is."""

    name: ClassVar[str] = "bandwidth"
    order: ClassVar[int] = 10
    cutoff_hz: float = 10.0
    output_noise_dps_per_rthz: float = 0.0
    sections: int = 1

    def __post_init__(self) -> None:
        _positive(self.name, "cutoff_hz", self.cutoff_hz)
        _nonneg(self.name, "output_noise_dps_per_rthz", self.output_noise_dps_per_rthz)
        n = self.sections
        if isinstance(n, bool) or not isinstance(n, (int, float)) or n not in (1, 2, 3, 4):
            raise ValueError(f"{self.name}.sections: {n!r} must be 1, 2, 3 or 4")
        object.__setattr__(self, "sections", int(n))

    def params(self) -> dict[str, float]:
        """The parameters; the output noise only when there is one, the sections only when
        more than one (a model written before they existed reads and writes back the same)."""
        out = super().params()
        if self.output_noise_dps_per_rthz == 0.0:
            del out["output_noise_dps_per_rthz"]
        if self.sections == 1:
            del out["sections"]
        else:
            out["sections"] = self.sections
        return out

    def section_hz(self) -> float:
        """Each section's cutoff, Hz (the cutoff itself for one section)."""
        if self.sections == 1:
            return self.cutoff_hz
        return self.cutoff_hz / math.sqrt(2.0 ** (1.0 / self.sections) - 1.0)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        decay = 2.0 * math.pi * self.section_hz() * ctx.dt
        a = np.exp(-np.minimum(decay, _STEP_CAP))
        y = x
        for _ in range(self.sections):
            y = ar1(decay, (1.0 - a) * y, float(y[0]))
        if self.output_noise_dps_per_rthz > 0.0:
            sd = self.output_noise_dps_per_rthz / np.sqrt(ctx.dt)
            y = y + sd * ctx.rng.standard_normal((x.shape[0],))
        return y


@dataclass(frozen=True)
class Saturation(Effect):
    """Output clipped to +/- limit_dps (deg/s; CRS03-04: 200 deg/s)."""

    name: ClassVar[str] = "saturation"
    order: ClassVar[int] = 11
    limit_dps: float = 200.0

    def __post_init__(self) -> None:
        _positive(self.name, "limit_dps", self.limit_dps)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        return np.clip(x, -self.limit_dps, self.limit_dps)


@dataclass(frozen=True)
class Quantization(Effect):
    """ADC resolution: output rounded to the nearest multiple of step_dps (deg/s; the CRS03-04
    on a 16-bit 5 V ADC: 5 V / 2**16 / (10 mV/(deg/s)) = 0.00763 deg/s, hdrd.core.sensor lsb_dps).
    Zero rate sits on a code (null at exactly half scale). Applied last, after every noise, as
    a real ADC rounds what reaches it: noise of less than about half a step at its input
    leaves a gyro at rest on one code (undithered), more dithers it and the output's mean is
    the input's."""

    name: ClassVar[str] = "quantization"
    order: ClassVar[int] = 12
    step_dps: float = SensorModel().lsb_dps

    def __post_init__(self) -> None:
        _positive(self.name, "step_dps", self.step_dps)

    def apply(self, x: FloatArray, ctx: Context) -> FloatArray:
        return self.step_dps * np.round(x / self.step_dps)


EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in sorted(
        (
            TimeOffset,
            ScaleFactor,
            ScaleAsymmetry,
            StaticBias,
            WarmupTransient,
            TemperatureBias,
            MotionOffset,
            StopOffset,
            BiasInstability,
            RateRandomWalk,
            WhiteNoise,
            Bandwidth,
            Saturation,
            Quantization,
        ),
        key=lambda c: c.order,
    )
}
"""Every effect class by name, in the physical order of application."""

EFFECT_NAMES: tuple[str, ...] = tuple(EFFECTS)

STREAMS: dict[str, int] = {
    "time_offset": 0,
    "scale_factor": 1,
    "scale_asymmetry": 2,
    "static_bias": 3,
    "warmup_transient": 4,
    "temperature_bias": 5,
    "bias_instability": 6,
    "rate_random_walk": 7,
    "white_noise": 8,
    "bandwidth": 9,
    "saturation": 10,
    "quantization": 11,
    "motion_offset": 12,
    "stop_offset": 13,
}
"""The random stream of each effect (:meth:`GyroModel.apply`): a number fixed per effect and
never reused, apart from the order of application, so that a new effect (given the next
number) leaves every other effect's noise, and so every earlier simulated output, unchanged."""


def param_names(cls: type[Effect]) -> list[str]:
    return [f.name for f in fields(cls)]


def _required(cls: type[Effect]) -> list[str]:
    # Every parameter is required in a file except the documented optional ones.
    optional = {
        "quad_dps_per_c2",
        "moving_mps",
        "coeff_dps_per_mps",
        "output_noise_dps_per_rthz",
        "sections",
    }
    return [p for p in param_names(cls) if p not in optional]


def effect_from_dict(d: dict[str, Any]) -> Effect:
    """One effect from ``{name: ..., <param>: <value>, ...}``, every parameter within what a
    gyro can have (:data:`hdrd.sim.gyrolimits.LIMITS`); ValueError naming what is wrong."""
    if not isinstance(d, dict):
        raise ValueError(f"an effect must be a mapping with a 'name', got {d!r}")  # noqa: TRY004 - a bad model is a ValueError
    name = d.get("name")
    if not isinstance(name, str) or name not in EFFECTS:  # a list or a mapping is no name
        raise ValueError(
            f"unknown effect name {clipped(repr(name), 80)} (known: {', '.join(EFFECT_NAMES)})"
        )
    cls = EFFECTS[name]
    params = {k: v for k, v in d.items() if k != "name"}
    allowed = param_names(cls)
    unknown = sorted(str(k) for k in params if k not in allowed)
    if unknown:
        raise ValueError(
            f"effect {name}: unknown parameter(s) {', '.join(unknown)} (allowed: {', '.join(allowed)})"
        )
    missing = [p for p in _required(cls) if p not in params]
    if missing:
        raise ValueError(f"effect {name}: missing parameter(s) {', '.join(missing)}")
    values = _numbers(name, params)
    effect = cls(**values)  # its own rules first (> 0, ...)
    for k, v in values.items():  # then what a gyro can have
        if (problem := limit_problem(name, k, v)) is not None:
            raise ValueError(problem)
    return effect


def _numbers(name: str, params: dict[str, Any]) -> dict[str, float]:
    """An effect's parameters as floats; ValueError naming one that is not a number."""
    for k, v in params.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{name}.{k}: {clipped(repr(v), 80)} is not a number")
    return {k: float(v) for k, v in params.items()}


# -- the model -------------------------------------------------------------------------------
