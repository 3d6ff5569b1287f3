"""HDR+'s settings, in three parts: what one gyro's error model and start-up calibration set
(:class:`GyroFit`, fitted by :meth:`HdrPlusParams.fitted`), the bank of hypotheses (data:
:class:`hdrd.core.biasbank.Hypothesis`), and the filter's constants (:class:`Tuning`; the
daemon runs :data:`TUNING`, chosen on tuning data as bench/RESULTS.md records; benchmarks
override them). The filter itself is :mod:`hdrd.core.hdrplus`. Pure.

Units: rates deg/s, + = counter-clockwise seen from above; variances (deg/s)^2; random walks
(deg/s)^2/s; temperature degC; time s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

from hdrd.core.biasbank import Hypothesis
from hdrd.core.gyronoise import GyroNoise
from hdrd.core.hdr import HdrParams
from hdrd.core.standstill import CalibrationNoise, StandstillParams

__all__ = [
    "DEFAULTS",
    "DEFAULT_BANK",
    "DRIFT_PRIOR",
    "PLUS_CORE",
    "TUNING",
    "GyroFit",
    "HdrPlusParams",
    "Tuning",
    "one_model",
]

PLUS_CORE = HdrParams(i_c=0.0048, tau=0.5, theta_w=0.45, c1=0.14, c2=0.88)
"""HDR+'s core parameters (the fixed increment i_c applies only with ``ic_alpha = 0``)."""

DRIFT_PRIOR = 0.3
"""Weight of "drifting" at start (the increment is off until the evidence exceeds 0.5)."""

DEFAULT_BANK = (
    Hypothesis("stable", 1e-8, 1.0 - DRIFT_PRIOR),  # 0.006 deg/s over an hour
    Hypothesis("drifting", 1e-5, DRIFT_PRIOR),  # a 0.1 deg/s warm-up within 15 minutes
)
"""The bank for a gyro of unknown error model: a stable and a drifting bias, (deg/s)^2/s."""


def one_model(q: float, name: str = "model") -> tuple[Hypothesis]:
    """A bank of one: a known error model whose bias random walk is q, (deg/s)^2/s."""
    return (Hypothesis(name, q, 1.0),)


def _check_numbers(obj: object, skip: tuple[str, ...] = ()) -> None:
    """Every float field of a frozen record finite and >= 0 (block_var may be NaN)."""
    for f in fields(obj):  # type: ignore[arg-type]
        if f.name in skip:
            continue
        v = float(getattr(obj, f.name))
        if f.name == "block_var" and math.isnan(v):
            pass
        elif not (math.isfinite(v) and v >= 0.0):
            raise ValueError(f"{f.name} must be a number >= 0, got {getattr(obj, f.name)!r}")
        object.__setattr__(obj, f.name, v)


@dataclass(frozen=True, slots=True)
class Tuning:
    """HDR+'s constants, chosen once on tuning data (bench/RESULTS.md says which): the
    daemon always runs :data:`TUNING`; only benchmarks and tests override them."""

    straight_r: float = 0.05
    """Variance of a straight-driving measurement beyond the road state, (deg/s)^2 (sway);
    0 switches these measurements off."""
    straight_gate_dps: float = 0.93
    """Largest |u_c + I| of a step used as a straight-driving measurement, deg/s."""
    road_var: float = 0.0025
    """Variance of the road's yaw rate that passes for straight driving, (deg/s)^2 (gentle
    curvature: a Gauss-Markov rate of 0.05 deg/s sd ..."""
    road_tau_s: float = 120.0
    """... and this correlation time, s: straight driving on real roads misleads a bias
    estimate by 0.025 deg/s per drive, as on the real tuning drives)."""
    ic_alpha: float = 0.1
    """The core's increment is ic_alpha x the bias sd at this temperature, deg/s (capped at
    ``i_c_max``); 0 = the core's fixed i_c."""
    i_c_max: float = 0.008
    """Largest increment, deg/s."""
    drift_odds_max: float = 4.6
    """Each member's log-odds stay within +-this (1 % .. 99 % for two): later evidence can
    always turn the bank round."""
    stop_floor_dps: float = 0.02
    """A stop's reading is allowed this much error, deg/s, in every member's innovation
    variance when it is weighed as evidence (a start-up calibration error is a constant, not
    a drift)."""
    offset_white_ratio: float = 0.5
    """:meth:`HdrPlusParams.fitted` without an error model: the standstill offset's sd is this
    times the calibration's white noise density N (deg/s/sqrt(Hz): a step's standstill
    variance x T): a gyro that is noisy at rest is not trusted to read the driving bias at a
    stop."""
    stop_gate_sigma: float = 4.0
    """A standstill step's corrected level must be within this many standard deviations of
    what the model allows at rest (block_var + the bias variance + i_c^2 + gate_floor_dps^2): a
    turn that a stale speed calls standstill is not taken for the bias (0 = off; without
    block_var, the step's own spread stands for it)."""
    gate_floor_dps: float = 0.03
    """The stop gate allows at least this much bias error, deg/s (a start-up calibration that
    missed the bias by 0.02 deg/s must not shut its own correction out)."""
    turn_err: float = 0.01
    """Once the heading is aligned to GPS: the heading error a turn adds, as a share of the
    angle turned (1 sigma; a scale factor's error): how far a course after a turn may
    correct it."""

    def __post_init__(self) -> None:
        _check_numbers(self)


TUNING = Tuning()
"""The constants the daemon runs."""


@dataclass(frozen=True, slots=True)
class GyroFit:
    """What one gyro's error model and its start-up calibration set
    (:meth:`HdrPlusParams.fitted`); the defaults are a CRS03-04's."""

    bias_p0: float = 8e-5
    """Variance of the start-up eps0 from the calibration's noise, (deg/s)^2 (sample variance /
    samples; default: 30 s of a CRS03-04 at 10 Hz). The prior variance of b is this plus
    q^2/12 (``quant_step_dps``) plus the standstill offset's variance."""
    stop_offset_var: float = 4.9e-6
    """Prior variance F of the standstill offset c, (deg/s)^2: what a stop reads may differ
    from the driving bias by about a quantisation step (q^2/12) and, for a gyro of unknown
    error model, by ``offset_white_ratio`` x its standstill noise density. 0: stops measure
    the driving bias itself."""
    quant_step_dps: float = 0.00763
    """The gyro's output step q, deg/s: a stop's block mean is trusted to q^2/12 at best."""
    block_var: float = math.nan
    """Variance of one step's mean at standstill, (deg/s)^2 (from the calibration; NaN =
    unknown): the floor of a stop measurement's variance and the scale of the stop gate."""
    bias_q: float = 1e-6
    """Random walk of the bias left unexplained by the temperature model, (deg/s)^2/s."""
    temp_coeff_sd: float = 0.01
    """Prior standard deviation of k, deg/s/degC (prior mean 0)."""
    ic_drift_ratio: float = 0.0
    """With a bank of one, the increment is 0 while its random walk over ``road_tau_s`` is
    below this times ``road_var`` (0 = off; set with a known error model)."""
    model: str = "defaults"
    """Which error model the settings were fitted to (published by the daemon): ``defaults``,
    ``calibration`` (the start-up window's noise; the bank weighs the evidence), or the known
    model's source (``grade NAME``, ``recorded``, ``config``)."""

    def __post_init__(self) -> None:
        _check_numbers(self, skip=("model",))


@dataclass(frozen=True, slots=True)
class HdrPlusParams:
    """HDR+'s settings: the HDR core, standstill detection, what the gyro's fit sets, the
    bank of hypotheses, and the constants (see the module docstring)."""

    hdr: HdrParams = PLUS_CORE
    """The HDR core (i_c deg/s, tau s, theta_w deg/s, c1, c2, T s; paper Table III names)."""
    standstill: StandstillParams = field(default_factory=StandstillParams)
    """Standstill detection and the variance of a standstill measurement."""
    fit: GyroFit = GyroFit()
    """What the gyro's error model and calibration set."""
    bank: tuple[Hypothesis, ...] = DEFAULT_BANK
    """The hypotheses, from the most stable to the most drifting."""
    tuning: Tuning = TUNING
    """The filter's constants."""

    def __post_init__(self) -> None:
        if not self.bank:
            raise ValueError("the bank needs at least one hypothesis")
        object.__setattr__(self, "bank", tuple(self.bank))

    @property
    def model(self) -> str:
        """The error model the settings were fitted to (:attr:`GyroFit.model`)."""
        return self.fit.model

    def with_(self, **kw: object) -> HdrPlusParams:
        """A copy with some fields replaced (each by a whole object)."""
        return replace(self, **kw)  # type: ignore[arg-type]

    def with_fit(self, **kw: object) -> HdrPlusParams:
        """A copy with some of :class:`GyroFit`'s fields replaced."""
        return replace(self, fit=replace(self.fit, **kw))  # type: ignore[arg-type]

    def fitted(
        self,
        calibration: CalibrationNoise | None = None,
        noise: GyroNoise | None = None,
        quant_step_dps: float | None = None,
    ) -> HdrPlusParams:
        """These settings fitted to one gyro and its start-up calibration.

        calibration: the calibration window's noise (:func:`hdrd.core.standstill.calibration_noise`):
        samples per step, the step's standstill variance (block_var), bias_p0 = var(eps0).
        noise: the gyro's error model when known (a grade preset, the config's, or the
        parameters recorded beside the bias): a bank of one whose random walk is the model's
        (K^2 + 2 sigma^2 / tau; without a temperature plus a warm-up), the prior on k, and the
        increment off where it would only straighten gentle curves. Without it, the bank, and
        a standstill offset of ``offset_white_ratio`` x the calibration's white noise.
        quant_step_dps: the output step q when known otherwise (the ADC's LSB; for a log, the
        lattice of its values); else the calibration's, else the noise model's. The stop
        offset's variance is q^2/12 (+ the above). Unknown pieces keep their current values.
        """
        p = self
        q = _output_step(quant_step_dps, calibration, noise)
        if math.isfinite(q):
            p = p.with_fit(quant_step_dps=q, stop_offset_var=q * q / 12.0)
        known = noise is not None and noise.known()
        if calibration is not None:
            p = p._with_calibration(calibration, known)
        if noise is not None and known:
            p = p._with_model(noise)
        return p

    def _with_calibration(self, calibration: CalibrationNoise, known: bool) -> HdrPlusParams:
        """:meth:`fitted`'s calibration part: samples per step, block_var, bias_p0, and
        without a known error model the standstill offset's white-noise part."""
        ss = replace(self.standstill, samples_per_step=max(1.0, calibration.samples_per_step))
        p = self.with_(standstill=ss).with_fit(model="calibration")
        if math.isfinite(calibration.block_var) and calibration.block_var >= 0:
            p = p.with_fit(block_var=calibration.block_var)
            if not known:
                white2 = calibration.block_var * p.hdr.T  # N^2: a step's variance x T
                off = p.fit.stop_offset_var + p.tuning.offset_white_ratio**2 * white2
                p = p.with_fit(stop_offset_var=off)
        if math.isfinite(calibration.bias_var) and calibration.bias_var >= 0:
            p = p.with_fit(bias_p0=calibration.bias_var)
        return p

    def _with_model(self, noise: GyroNoise) -> HdrPlusParams:
        """:meth:`fitted`'s known error model part: a bank of one of the model's random walk,
        the prior on k, the increment off where it would only straighten gentle curves."""
        qt, qnt = noise.bias_q(), noise.bias_q_no_temp()
        p = self.with_(bank=one_model(qnt))
        p = p.with_fit(bias_q=qt if math.isfinite(qt) else qnt, ic_drift_ratio=0.01)
        p = p.with_fit(model=noise.source)
        if math.isfinite(noise.temp_coeff_dps_per_c):
            p = p.with_fit(temp_coeff_sd=max(noise.temp_coeff_dps_per_c, 1e-5))
        return p


def _output_step(
    given: float | None, calibration: CalibrationNoise | None, noise: GyroNoise | None
) -> float:
    """The output step q, deg/s: the one given, else the calibration's, else the noise
    model's; NaN when none is known."""
    for cand in (
        given,
        calibration.quant_step_dps if calibration is not None else None,
        noise.quant_step_dps if noise is not None else None,
    ):
        if cand is not None and math.isfinite(cand) and cand > 0:
            return float(cand)
    return math.nan


DEFAULTS = HdrPlusParams()
"""HDR+'s settings before any fit: a CRS03-04's defaults, the two-member bank, :data:`TUNING`."""
