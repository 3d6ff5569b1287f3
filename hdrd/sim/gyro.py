"""The gyro's error model: named physical effects composed into a :class:`GyroModel`.

Pure: :meth:`GyroModel.apply` maps the true yaw rate (deg/s, + = CCW) to what the gyro and its
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
import os
from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt
import yaml

from hdrd.core.sensor import SensorModel

__all__ = [
    "DEFAULT_START_MODEL",
    "EFFECTS",
    "EFFECT_NAMES",
    "Bandwidth",
    "BiasInstability",
    "Effect",
    "GyroModel",
    "MotionOffset",
    "Quantization",
    "RateRandomWalk",
    "STREAMS",
    "Saturation",
    "ScaleAsymmetry",
    "ScaleFactor",
    "StaticBias",
    "TemperatureBias",
    "TimeOffset",
    "WarmupTransient",
    "WhiteNoise",
    "ar1",
    "crs03_default_model",
    "effect_from_dict",
    "load_model",
    "save_model",
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
class _Ctx:
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

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:  # pragma: no cover - abstract
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

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
        return np.interp(ctx.t - self.delay_s, ctx.t, x)


@dataclass(frozen=True)
class ScaleFactor(Effect):
    """Gain error: measured = (1 + error) * true (error dimensionless, 0.01 = 1 %)."""

    name: ClassVar[str] = "scale_factor"
    order: ClassVar[int] = 1
    error: float = 0.0

    def __post_init__(self) -> None:
        _gain(self.name, "error", self.error)

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
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

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
        return np.where(x > 0, (1.0 + self.pos_error) * x, (1.0 + self.neg_error) * x)


@dataclass(frozen=True)
class StaticBias(Effect):
    """Constant null offset, deg/s (+ = reads CCW at rest). The paper's eps0 (Eq. 2)."""

    name: ClassVar[str] = "static_bias"
    order: ClassVar[int] = 3
    bias_dps: float = 0.0

    def __post_init__(self) -> None:
        _finite(self.name, "bias_dps", self.bias_dps)

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
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

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
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

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
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

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
        if ctx.speed_mps is None:
            raise ValueError("motion_offset needs the vehicle's speed (speed_mps) for every sample")
        v = ctx.speed_mps
        return x + np.where(self.moving(v), self.offset_dps + self.coeff_dps_per_mps * v, 0.0)


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

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
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

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
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

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
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

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
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

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
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

    def apply(self, x: FloatArray, ctx: _Ctx) -> FloatArray:
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
}
"""The random stream of each effect (:meth:`GyroModel.apply`): a number fixed per effect and
never reused, apart from the order of application, so that a new effect (given the next
number) leaves every other effect's noise, and so every earlier simulated output, unchanged."""


def _param_names(cls: type[Effect]) -> list[str]:
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
    return [p for p in _param_names(cls) if p not in optional]


def effect_from_dict(d: dict[str, Any]) -> Effect:
    """One effect from ``{name: ..., <param>: <value>, ...}``; ValueError naming what is wrong."""
    if not isinstance(d, dict):
        raise ValueError(f"an effect must be a mapping with a 'name', got {d!r}")  # noqa: TRY004 - a bad model is a ValueError
    name = d.get("name")
    if name not in EFFECTS:
        raise ValueError(f"unknown effect name {name!r} (known: {', '.join(EFFECT_NAMES)})")
    cls = EFFECTS[name]
    params = {k: v for k, v in d.items() if k != "name"}
    allowed = _param_names(cls)
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        raise ValueError(
            f"effect {name}: unknown parameter(s) {', '.join(unknown)} (allowed: {', '.join(allowed)})"
        )
    missing = [p for p in _required(cls) if p not in params]
    if missing:
        raise ValueError(f"effect {name}: missing parameter(s) {', '.join(missing)}")
    for k, v in params.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{name}.{k}: {v!r} is not a number")  # noqa: TRY004 - a bad model is a ValueError
    return cls(**{k: float(v) for k, v in params.items()})


# -- the model -------------------------------------------------------------------------------


@dataclass(frozen=True)
class GyroModel:
    """A set of effects (at most one of each name), applied in the fixed physical order."""

    effects: tuple[Effect, ...] = ()

    def __post_init__(self) -> None:
        effects = tuple(self.effects)
        for e in effects:
            if not isinstance(e, Effect) or type(e) not in EFFECTS.values():
                raise ValueError(f"not a gyro effect: {e!r}")
        names = [e.name for e in effects]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"effect(s) listed more than once: {', '.join(dup)}")
        object.__setattr__(self, "effects", tuple(sorted(effects, key=lambda e: e.order)))

    def names(self) -> list[str]:
        """Effect names in the order they apply."""
        return [e.name for e in self.effects]

    def __contains__(self, name: object) -> bool:
        return any(e.name == name for e in self.effects)

    def get(self, name: str) -> Effect | None:
        """The effect of that name, or None if the model lacks it (ValueError: unknown name)."""
        _check_name(name)
        for e in self.effects:
            if e.name == name:
                return e
        return None

    def with_effect(self, effect: Effect) -> GyroModel:
        """A copy with ``effect`` added, or replacing the one of the same name."""
        return GyroModel(tuple(e for e in self.effects if e.name != effect.name) + (effect,))

    def without(self, name: str) -> GyroModel:
        """A copy without the effect ``name`` (unchanged if absent; ValueError: unknown name)."""
        _check_name(name)
        return GyroModel(tuple(e for e in self.effects if e.name != name))

    def to_dict(self) -> dict[str, list[dict[str, Any]]]:
        """``{"effects": [{"name": ..., <param>: <value>}, ...]}`` in physical order."""
        return {"effects": [{"name": e.name, **e.params()} for e in self.effects]}

    @classmethod
    def from_dict(cls, data: Any) -> GyroModel:
        """Inverse of :meth:`to_dict`; ValueError naming unknown effects or parameters."""
        if not isinstance(data, dict) or "effects" not in data:
            raise ValueError("a gyro model must be a mapping with an 'effects' list")
        extra = sorted(set(data) - {"effects"})
        if extra:
            raise ValueError(
                f"unknown key(s) in gyro model: {', '.join(map(str, extra))} (allowed: effects)"
            )
        items = data["effects"]
        if items is None:
            items = []
        if not isinstance(items, list):
            raise ValueError("'effects' must be a list of {name: ..., <param>: ...} mappings")  # noqa: TRY004 - a bad model is a ValueError
        unknown = [
            str(d.get("name"))
            for d in items
            if isinstance(d, dict) and d.get("name") not in EFFECTS
        ]
        if unknown:
            raise ValueError(
                f"unknown effect name(s): {', '.join(unknown)} (known: {', '.join(EFFECT_NAMES)})"
            )
        return cls(tuple(effect_from_dict(d) for d in items))

    def apply(
        self,
        t_s: npt.ArrayLike,
        omega_true_dps: npt.ArrayLike,
        temp_c: npt.ArrayLike | None,
        rng: np.random.Generator,
        speed_mps: npt.ArrayLike | None = None,
    ) -> FloatArray:
        """The gyro's output (deg/s, + = CCW, bias included) for the true rate at times t_s.

        t_s: strictly increasing sample times, s (power-on = t_s[0]). temp_c: temperature per
        sample, deg C (NaN gaps are interpolated; None is allowed without temperature_bias).
        speed_mps: the vehicle's speed per sample, m/s (NaN gaps interpolated; None is allowed
        without motion_offset). Randomness comes from ``rng`` only (one draw seeds a separate
        stream per effect, :data:`STREAMS`, so adding or removing an effect leaves the others'
        noise unchanged).
        """
        t = np.asarray(t_s, dtype=np.float64)
        x = np.array(omega_true_dps, dtype=np.float64)
        n = int(t.shape[0])
        if t.ndim != 1 or x.shape != t.shape:
            raise ValueError(
                f"t_s and omega_true_dps must be 1-D of equal length ({t.shape} vs {x.shape})"
            )
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(x))):
            raise ValueError("t_s and omega_true_dps must be finite")
        if n > 1 and np.any(np.diff(t) <= 0):
            raise ValueError("t_s must be strictly increasing")
        temp = _per_sample("temp_c", temp_c, n)
        speed = _per_sample("speed_mps", speed_mps, n)
        base = int(rng.integers(0, 2**63 - 1))
        if n == 0:
            return x
        dt = np.empty(n)
        if n > 1:
            dt[1:] = np.diff(t)
            dt[0] = float(np.median(dt[1:]))
        else:
            dt[0] = 1.0
        t0 = t - t[0]
        for e in self.effects:
            ctx = _Ctx(t0, dt, temp, np.random.default_rng([base, STREAMS[e.name]]), speed)
            x = e.apply(x, ctx)
        return x


def _check_name(name: str) -> None:
    if name not in EFFECTS:
        raise ValueError(f"unknown effect name {name!r} (known: {', '.join(EFFECT_NAMES)})")


def _per_sample(what: str, values: npt.ArrayLike | None, n: int) -> FloatArray | None:
    """A column of one value per sample (a scalar: the same for all), NaN gaps interpolated;
    None if absent or all NaN."""
    if values is None:
        return None
    arr = np.array(values, dtype=np.float64)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.shape != (n,):
        raise ValueError(f"{what} must have one value per sample ({arr.shape} vs {n})")
    ok = np.isfinite(arr)
    if ok.all():
        return arr
    if not ok.any():
        return None
    idx = np.arange(n)
    return np.interp(idx, idx[ok], arr[ok])


# -- defaults and files -------------------------------------------------------------------------


def crs03_default_model() -> GyroModel:
    """A CRS03-04-like gyro on a 16-bit ADC (values plausible for the part, not a datasheet):

    - static bias 1.0 deg/s (the paper measured eps0 = 1.432 deg/s on its unit);
    - warm-up transient 0.02 deg/s settling with tau 90 s after power-on;
    - temperature coefficient 0.008 deg/s/degC at 25 degC, -0.0001 deg/s/degC^2 (steeper when
      cold: 0.012 deg/s/degC at 5 degC): a cabin warming from 5 to 21 degC moves the bias by
      ~0.17 deg/s, the paper's Sec. 5 explanation of its large uncorrected errors (the bias
      over -40..85 degC stays within the part's +/-3 deg/s);
    - bias instability 0.01 deg/s, tau 300 s, and rate random walk 3e-4 deg/s/sqrt(s): in-run
      drift well inside the specified < 1.1 deg/min (0.018 deg/s, 66 deg/h);
    - white noise 0.05 deg/s/sqrt(Hz) (ARW 3 deg/sqrt(h); 0.16 deg/s rms at 10 Hz);
    - scale factor error 0.5 %; bandwidth 10 Hz; saturation +/-200 deg/s;
    - 16-bit ADC quantization, 0.00763 deg/s (hdrd.core.sensor.SensorModel().lsb_dps).
    """
    return GyroModel(
        (
            ScaleFactor(error=0.005),
            StaticBias(bias_dps=1.0),
            WarmupTransient(amplitude_dps=0.02, tau_s=90.0),
            TemperatureBias(coeff_dps_per_c=0.008, ref_temp_c=25.0, quad_dps_per_c2=-0.0001),
            BiasInstability(sigma_dps=0.01, tau_s=300.0),
            RateRandomWalk(k_dps_per_sqrt_s=3e-4),
            WhiteNoise(density_dps_per_rthz=0.05),
            Bandwidth(cutoff_hz=10.0),
            Saturation(limit_dps=200.0),
            Quantization(step_dps=SensorModel().lsb_dps),
        )
    )


DEFAULT_START_MODEL = GyroModel((StaticBias(bias_dps=1.0), WhiteNoise(density_dps_per_rthz=0.05)))
"""The model-gap workflow's starting model: static bias + white noise (CRS03-04-like values)."""


def load_model(path: str | os.PathLike[str]) -> GyroModel:
    """Read a model YAML ``{effects: [{name: static_bias, bias_dps: 0.3}, ...]}``.

    Read as hdrd reads its configuration (:mod:`hdrd.io.files`): a regular file of at most
    1 MiB, YAML nested at most 32 deep. Raises ValueError naming the file and what is wrong,
    in one line (OSError if it cannot be read)."""
    from hdrd.io.files import MAX_CONFIG_BYTES, InputFileError, load_yaml, read_limited

    try:
        text = read_limited(path, MAX_CONFIG_BYTES).decode("utf-8")
    except InputFileError as exc:
        raise ValueError(f"{path}: cannot be read: {exc}") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not UTF-8 text") from None
    try:
        data = load_yaml(text)
    except InputFileError as exc:
        at = f" at {exc.where}" if exc.where else ""
        raise ValueError(f"{path}: not valid YAML{at}: {exc}") from None
    try:
        return GyroModel.from_dict(data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    except (TypeError, OverflowError) as exc:  # a key or value of a type no model has
        raise ValueError(f"{path}: not a gyro model ({type(exc).__name__}: {exc})") from None


def save_model(model: GyroModel, path: str | os.PathLike[str]) -> None:
    """Write a model YAML that :func:`load_model` reads back equal."""
    text = (
        "# hdrd gyro error model (docs/gyro-model.md): rates deg/s, + = CCW; times s; temps degC\n"
        + yaml.safe_dump(model.to_dict(), sort_keys=False, default_flow_style=None)
    )
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)
