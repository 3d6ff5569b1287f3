"""HDR+: the paper's HDR kept as a core, under a Kalman model of the bias that adapts to the gyro.

Pure: no I/O, no clock. One step per period T on the same input as HDR, u_i = block mean of
the raw rate minus the start-up static bias eps0 (paper Eqs. 2, 11), deg/s, + = CCW, plus
what HDR does not use: the spread of the raw samples within the block, the vehicle speed and
the board temperature (each NaN when unknown). docs/hdrplus.md has the reasoning and the
measurements behind every default.

1. **Bias model** (:mod:`hdrd.core.biasbank`): Kalman filters of the bias b, the standstill offset
   c, the temperature coefficient k, the road's gentle curvature r and the heading error the
   bias estimate has caused. The HDR core runs on u_c = u - (b + k (temp - t_ref)).
   - With a temperature, or with the gyro's error model known (a grade, parameters recorded
     by ``hdrd calibrate``), one filter, whose random walk is the model's.
   - Without either (the default for an unknown recording), a *bank* of two: a *stable* gyro
     and a *drifting* one, weighed by evidence: how well each predicted every stop's reading
     and every straight step. The correction is their weighted mean; the heading is
     corrected when a stop (or the road) moves the estimate.
2. **The core's increment follows the bias uncertainty**: i_c = ``ic_alpha`` x the bias sd
   (capped at ``i_c_max``). With the bank, only while the evidence says the gyro drifts (on a
   stable gyro the binary increment only straightens real gentle curves); with a known model,
   only when its bias wanders more within a road's curve than real roads curve.
3. **Standstill (zero-rate) updates**: a step detected as standstill (from the speed, or the
   gyro alone when enabled; its level within ``stop_gate_sigma`` of what the model allows at
   rest) publishes omega = 0, folds I into b and measures b + c.
4. **Straight-driving measurements**: a step on which the turn switch lets I move (W = 1)
   and whose corrected rate is within ``straight_gate_dps`` measures b + r.

With every extra switched off (:meth:`HdrPlusParams.paper`) HDR+ is bit-identical to paper
HDR. :func:`step` (immutable :class:`PlusState`, the daemon's) and :func:`run_batch` (arrays,
evaluate's) run the same code (:class:`_Run`), so they agree to the bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from hdrd.core import biasbank as bb
from hdrd.core.biasbank import INITIAL_BANK, BankState, Filter
from hdrd.core.gyronoise import GyroNoise
from hdrd.core.hdr import INITIAL_STATE, HdrParams, HdrState, kernel
from hdrd.core.standstill import (
    CalibrationNoise,
    StandstillParams,
    block_mean_variance,
    standstill_candidate,
)
from hdrd.core.steps import StepInput

__all__ = [
    "FULL",
    "INITIAL_PLUS_STATE",
    "PLUS_CORE",
    "Ablation",
    "GyroNoise",
    "HdrPlusParams",
    "PlusOutput",
    "PlusState",
    "PlusTrace",
    "run_batch",
    "step",
]

PLUS_CORE = HdrParams(i_c=0.0048, tau=0.5, theta_w=0.45, c1=0.14, c2=0.88)
"""HDR+'s core parameters (the fixed increment i_c applies only with ``ic_alpha = 0``)."""


@dataclass(frozen=True, slots=True)
class Ablation:
    """The switches of HDR+'s ideas, which benchmarks and tests vary one at a time (the daemon
    always runs :data:`FULL`). Each is a branch in the filter; :meth:`HdrPlusParams.paper`
    turns them all off."""

    temp_model: bool = True
    """Learn the temperature coefficient k (when a temperature is given)."""
    heading_fix: bool = True
    """With the bank, correct the heading for the bias error a measurement reveals (by the
    covariance of the heading error and the bias)."""
    straight_r: float = 0.05
    """Variance of a straight-driving measurement beyond the road state, (deg/s)^2 (sway);
    0 switches these measurements off."""
    ic_alpha: float = 0.1
    """The core's increment is ic_alpha x the bias sd at this temperature, deg/s (capped at
    ``i_c_max``); 0 = the fixed hdr.i_c."""
    drift_prior: float = 0.3
    """Weight of "drifting" at start (the increment is off until the evidence exceeds 0.5)."""
    moved_prior: float = 0.0
    """With the bank (no temperature), a third filter, *moved*: the bias at rest as stable as
    the stable filter's (q_stable) and the driving bias free to sit ``moved_offset_var`` off
    it (a motion-dependent bias the stops cannot show); its weight at start (the stable
    filter's is 1 - drift_prior - it). 0: off (two filters)."""
    moved_offset_var: float = 0.01
    """The moved filter's motion offset prior variance, (deg/s)^2."""
    moved_q: float = 0.0
    """With the bank, the second filter's bias random walk instead of ``q_drifting``,
    (deg/s)^2/s: with ``motion_offset_var`` it is a *moved* hypothesis (the bias at rest as
    stable as the first's, the driving bias free) rather than a drifting one. 0: off."""
    road_lat_acc: float = 0.0
    """The road's gentle curves as a lateral acceleration, m/s^2: with the speed v known
    (above ``ROAD_MIN_SPEED``), the road rate's variance is road_floor_dps^2 + (a / v)^2 (in
    deg/s): at speed a residual rate is more likely bias, in town a curve. 0: road_var
    whatever the speed."""
    road_floor_dps: float = 0.013
    """The road rate's spread at any speed with ``road_lat_acc``, deg/s."""
    motion_offset_var: float = 0.0
    """Prior variance of a *motion offset*, (deg/s)^2: how far the bias while driving may sit
    from what the stops read (vibration rectification, g-sensitivity), added to the
    standstill offset's F of the drifting (or only) filter; the stable filter keeps F. 0: off
    (bench/RESULTS.md, "HDR+ round two: ideas tried", has why it is not on)."""

    def __post_init__(self) -> None:
        for name in (
            "straight_r", "ic_alpha", "motion_offset_var", "moved_q", "road_lat_acc",
            "road_floor_dps", "moved_prior", "moved_offset_var",
        ):  # fmt: skip
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be a number >= 0, got {v!r}")
            object.__setattr__(self, name, v)
        object.__setattr__(self, "temp_model", bool(self.temp_model))
        object.__setattr__(self, "heading_fix", bool(self.heading_fix))
        prior = float(self.drift_prior)
        if not 0.0 < prior < 1.0:
            raise ValueError(f"drift_prior must be in (0, 1), got {self.drift_prior!r}")
        if not prior + self.moved_prior < 1.0:
            raise ValueError(
                f"drift_prior + moved_prior must be below 1, got {prior + self.moved_prior!r}"
            )
        object.__setattr__(self, "drift_prior", prior)


FULL = Ablation()
"""Every idea on: what the daemon runs."""


@dataclass(frozen=True, slots=True)
class HdrPlusParams:
    """HDR+'s settings: the gyro's error model as fitted to it and its calibration
    (:meth:`fitted`), and the filter's constants. The experiments' switches are apart, in
    :attr:`ablation`; :meth:`paper` turns every extra off."""

    hdr: HdrParams = PLUS_CORE
    """The HDR core (i_c deg/s, tau s, theta_w deg/s, c1, c2, T s; paper Table III names)."""
    standstill: StandstillParams = field(default_factory=StandstillParams)
    """Standstill detection and the variance of a standstill measurement."""
    bias_p0: float = 8e-5
    """Variance of the start-up eps0 from the calibration's noise, (deg/s)^2 (sample variance /
    samples; default: 30 s of a CRS03-04 at 10 Hz). The prior variance of b is this plus
    q^2/12 (``quant_step_dps``) plus the standstill offset's variance."""
    stop_offset_var: float = 4.9e-6
    """Prior variance F of the standstill offset c, (deg/s)^2: what a stop reads may differ
    from the driving bias by about a quantisation step (q^2/12) and, for a gyro of unknown
    error model, by ``offset_white_ratio`` x its standstill noise density (:meth:`fitted`).
    0: stops measure the driving bias itself."""
    quant_step_dps: float = 0.00763
    """The gyro's output step q, deg/s: a stop's block mean is trusted to q^2/12 at best."""
    block_var: float = math.nan
    """Variance of one step's mean at standstill, (deg/s)^2 (from the calibration; NaN =
    unknown): the floor of a stop measurement's variance and the scale of the stop gate."""
    bias_q: float = 1e-6
    """Random walk of the bias left unexplained by the temperature model, (deg/s)^2/s."""
    bias_q_no_temp: float = 3e-7
    """The same without a temperature when the bank is off (a known error model's)."""
    bank: bool = True
    """Without a temperature, weigh a stable and a drifting bias by evidence (off: one filter
    of ``bias_q_no_temp``; :meth:`fitted` turns it off for a known error model)."""
    q_stable: float = 1e-8
    """The stable gyro's bias random walk, (deg/s)^2/s (0.006 deg/s over an hour)."""
    q_drifting: float = 1e-5
    """The drifting gyro's, (deg/s)^2/s (a 0.1 deg/s warm-up within 15 minutes)."""
    drift_odds_max: float = 4.6
    """The log-odds of "drifting" stay within +-this (1 % .. 99 %): later evidence can always
    turn the bank round."""
    stop_floor_dps: float = 0.02
    """A stop's reading is allowed this much error, deg/s, in both filters' innovation
    variance when it is weighed as evidence (a start-up calibration error is a constant, not a
    drift)."""
    offset_white_ratio: float = 0.5
    """:meth:`fitted` without an error model: the standstill offset's sd is this times the
    calibration's white noise density N (deg/s/sqrt(Hz): a step's standstill variance x T): a
    gyro that is noisy at rest (a running engine's vibration, a coarse part) is not trusted to
    read the driving bias at a stop."""
    temp_coeff_sd: float = 0.01
    """Prior standard deviation of k, deg/s/degC (prior mean 0)."""
    straight_gate_dps: float = 0.93
    """Largest |u_c + I| of a step used as a straight-driving measurement, deg/s."""
    road_var: float = 0.0025
    """Variance of the road's yaw rate that passes for straight driving, (deg/s)^2 (gentle
    curvature: a Gauss-Markov rate of 0.05 deg/s sd ...)"""
    road_tau_s: float = 120.0
    """... and this correlation time, s: straight driving on real roads misleads a bias
    estimate by 0.025 deg/s per drive, as on the real tuning drives)."""
    i_c_max: float = 0.008
    """Largest increment, deg/s."""
    ic_drift_ratio: float = 0.0
    """Without the bank, the increment is 0 while the random walk over ``road_tau_s`` is below
    this times ``road_var`` (0 = off; :meth:`fitted` sets it with a known error model)."""
    stop_gate_sigma: float = 4.0
    """A standstill step's corrected level must be within this many standard deviations of
    what the model allows at rest (block_var + the bias variance + i_c^2 + gate_floor_dps^2): a
    turn that a stale speed calls standstill is not taken for the bias (0 = off; without
    block_var, the step's own spread stands for it)."""
    gate_floor_dps: float = 0.03
    """The stop gate allows at least this much bias error, deg/s (a start-up calibration that
    missed the bias by 0.02 deg/s must not shut its own correction out)."""
    ablation: Ablation = FULL
    """Experiments: each idea's switch (:class:`Ablation`); only benchmarks and tests change
    it."""
    model: str = "defaults"
    """Which error model the settings were fitted to (published by the daemon): ``defaults``,
    ``calibration`` (the start-up window's noise; the bank weighs the evidence), or the known
    model's source (``grade NAME``, ``recorded``, ``config``)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("hdr", "standstill", "model", "ablation"):
                continue
            if f.type in ("bool", bool):
                object.__setattr__(self, f.name, bool(v))
            elif f.name == "block_var":
                v = float(v)
                if not (math.isnan(v) or (math.isfinite(v) and v >= 0.0)):
                    raise ValueError(f"{f.name} must be a number >= 0 or NaN, got {v!r}")
                object.__setattr__(self, f.name, v)
            else:
                v = float(v)
                if not (math.isfinite(v) and v >= 0.0):
                    raise ValueError(f"{f.name} must be a number >= 0, got {v!r}")
                object.__setattr__(self, f.name, v)

    @classmethod
    def paper(cls, hdr: HdrParams | None = None) -> HdrPlusParams:
        """Every extra off: bit-identical to :func:`hdrd.core.hdr.step` with ``hdr``
        (default: the paper's Table III)."""
        return cls(
            hdr=HdrParams() if hdr is None else hdr,
            standstill=StandstillParams(enabled=False),
            bank=False,
            stop_offset_var=0.0,
            ablation=Ablation(temp_model=False, heading_fix=False, straight_r=0.0, ic_alpha=0.0),
            model="paper",
        )

    def with_(self, **kw: object) -> HdrPlusParams:
        """A copy with some fields replaced (``hdr``, ``standstill`` and ``ablation`` by whole
        objects)."""
        return replace(self, **kw)  # type: ignore[arg-type]

    def ablated(self, **kw: object) -> HdrPlusParams:
        """A copy with some of :class:`Ablation`'s switches replaced (benchmarks, tests)."""
        return replace(self, ablation=replace(self.ablation, **kw))  # type: ignore[arg-type]

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
        parameters recorded beside the bias): one filter whose random walk is the model's
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
            p = p.with_(quant_step_dps=q, stop_offset_var=q * q / 12.0)
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
        p = self.with_(standstill=ss, model="calibration")
        if math.isfinite(calibration.block_var) and calibration.block_var >= 0:
            p = p.with_(block_var=calibration.block_var)
            if not known:
                white2 = calibration.block_var * p.hdr.T  # N^2: a step's variance x T
                off = p.stop_offset_var + p.offset_white_ratio**2 * white2
                p = p.with_(stop_offset_var=off)
        if math.isfinite(calibration.bias_var) and calibration.bias_var >= 0:
            p = p.with_(bias_p0=calibration.bias_var)
        return p

    def _with_model(self, noise: GyroNoise) -> HdrPlusParams:
        """:meth:`fitted`'s known error model part: one filter of the model's random walk,
        the prior on k, the increment off where it would only straighten gentle curves."""
        qt, qnt = noise.bias_q(), noise.bias_q_no_temp()
        p = self.with_(bias_q_no_temp=qnt, bank=False, ic_drift_ratio=0.01)
        p = p.with_(bias_q=qt if math.isfinite(qt) else qnt, model=noise.source)
        if math.isfinite(noise.temp_coeff_dps_per_c):
            p = p.with_(temp_coeff_sd=max(noise.temp_coeff_dps_per_c, 1e-5))
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


class PlusState(NamedTuple):
    """State carried between steps. Immutable.

    core: the paper HDR state (x, I, yaw, r, s, n). bank: the bias model
    (:class:`hdrd.core.biasbank.BankState`). still: consecutive standstill-candidate steps.
    """

    core: HdrState = INITIAL_STATE
    bank: BankState = INITIAL_BANK
    still: int = 0


INITIAL_PLUS_STATE = PlusState()


class PlusOutput(NamedTuple):
    """What one step publishes.

    omega: corrected yaw rate, deg/s CCW (0 at standstill). yaw: deg CCW since start (with the
    heading correction of this step). I: the core's integrator applied in this step, deg/s.
    W, R, r, filtered: as :class:`hdrd.core.hdr.HdrOutput` (W = 0 at standstill). bias_corr_dps:
    the learned correction to eps0 at this step's temperature, deg/s (published bias = eps0 +
    bias_corr). standstill: this step was a zero-rate update. bias_sd_dps: its standard
    deviation, deg/s. temp_coeff_dps_per_c: k. i_c_dps: the core's increment in force, deg/s.
    bias_q: the bias random walk in force (the bank's weighted), (deg/s)^2/s. drift_weight:
    the weight of "drifting" (1 without the bank). heading_fix_deg: the heading correction
    made in this step, deg CCW.
    """

    omega: float
    yaw: float
    I: float
    W: int
    R: float
    r: int
    filtered: float
    bias_corr_dps: float
    standstill: bool
    bias_sd_dps: float
    temp_coeff_dps_per_c: float
    i_c_dps: float
    bias_q: float
    drift_weight: float
    heading_fix_deg: float


# -- one step, shared by both forms: the filter's phases ---------------------------------------


class _Mix(NamedTuple):
    """The bias correction in force for a step (after predict, before the measurements).

    w1: weight of the drifting filter (1 without the bank's mixture). corr0, corr1: each
    filter's correction b + k dT, deg/s; corr: their weighted mean, subtracted from u. inc:
    the core's increment, deg/s. q1: the drifting (or only) filter's random walk,
    (deg/s)^2/s. mixing: the bank weighs its filters in this step. wm, corrm: the moved
    filter's weight and correction (0 without it; the stable filter's weight is 1 - w1 - wm).
    """

    w1: float
    corr0: float
    corr1: float
    corr: float
    inc: float
    q1: float
    mixing: bool
    wm: float = 0.0
    corrm: float = 0.0


def _increment(var_t: float, q_i: float, params: HdrPlusParams) -> float:
    """The core's increment without the bank, deg/s (module docstring, 2)."""
    ab = params.ablation
    if ab.ic_alpha > 0.0:
        inc = min(params.i_c_max, ab.ic_alpha * math.sqrt(var_t if var_t > 0.0 else 0.0))
    else:
        inc = params.hdr.i_c
    if params.ic_drift_ratio > 0.0 and q_i * params.road_tau_s < (
        params.ic_drift_ratio * params.road_var
    ):
        inc = 0.0
    return inc


ROAD_MIN_SPEED = 1.0
"""Below this speed, m/s, the road's rate variance is road_var (a/v grows without bound)."""


def _road_var(params: HdrPlusParams, v: float) -> float:
    """The road rate's variance at speed v m/s, (deg/s)^2 (``Ablation.road_lat_acc``)."""
    acc = params.ablation.road_lat_acc
    if acc <= 0.0 or not v >= ROAD_MIN_SPEED:
        return params.road_var
    rate = math.degrees(acc / v)
    return params.ablation.road_floor_dps**2 + rate * rate


class _Run:
    """The filter on mutable locals: :func:`step` runs one step of it from a state,
    :func:`run_batch` many. :meth:`advance` calls the phases in order (predict, mixture,
    standstill test, then a standstill or a driving update, heading fix, output); each phase
    is a method below. Any change here changes both forms alike."""

    def __init__(self, state: PlusState, p: HdrPlusParams) -> None:
        self.p = p
        c = state.core
        self.x, self.I, self.yaw, self.r, self.s, self.n = c.x, c.I, c.yaw, c.r, c.s, c.n
        self.still = state.still
        self.need = 0  # consecutive candidates the current standstill test asks for
        k = state.bank
        q2 = p.quant_step_dps * p.quant_step_dps / 12.0
        self.q2 = q2
        init = self.prior(0.0)
        f1 = k.drifting
        if f1 is None:
            mo = p.ablation.motion_offset_var
            f1 = self.prior(mo) if mo > 0.0 else init
        self.x1, self.P1 = list(f1.x), list(f1.P)
        f0 = (init if k.stable is None else k.stable) if p.bank else None
        self.x0 = list(f0.x) if f0 is not None else []
        self.P0 = list(f0.P) if f0 is not None else []
        lo = k.log_odds
        ab = p.ablation
        prior, mp = ab.drift_prior, ab.moved_prior
        self.moved_on = p.bank and mp > 0.0
        self.xm: list[float] = []
        self.Pm: list[float] = []
        self.lo_m = k.moved_log_odds
        if self.moved_on:
            fm = self.prior(ab.moved_offset_var) if k.moved is None else k.moved
            self.xm, self.Pm = list(fm.x), list(fm.P)
            rest = 1.0 - prior - mp
            if math.isnan(lo):
                lo = math.log(prior / rest)
            if math.isnan(self.lo_m):
                self.lo_m = math.log(mp / rest)
        self.log_odds = math.log(prior / (1.0 - prior)) if math.isnan(lo) else lo
        self.t_ref = k.t_ref

    def prior(self, motion_offset_var: float) -> Filter:
        """A filter's prior after the start-up calibration (:func:`hdrd.core.biasbank.prior`),
        the driving bias free to sit ``motion_offset_var`` further off the stops'."""
        p = self.p
        f = p.stop_offset_var + motion_offset_var
        return bb.prior(p.bias_p0 + self.q2, f, p.temp_coeff_sd**2, p.road_var)

    def state(self) -> PlusState:
        core = HdrState(x=self.x, I=self.I, yaw=self.yaw, r=self.r, s=self.s, n=self.n)
        stable = Filter(tuple(self.x0), tuple(self.P0)) if self.p.bank else None
        moved = Filter(tuple(self.xm), tuple(self.Pm)) if self.moved_on else None
        bank = BankState(
            Filter(tuple(self.x1), tuple(self.P1)), stable, self.log_odds, self.t_ref, moved,
            self.lo_m,
        )  # fmt: skip
        return PlusState(core, bank, self.still)

    def filters(self) -> list[tuple[list[float], list[float]]]:
        """The filters that take every measurement: the drifting one, and the stable one
        when the bank is on."""
        if self.moved_on:
            return [(self.x1, self.P1), (self.x0, self.P0), (self.xm, self.Pm)]
        if self.p.bank:
            return [(self.x1, self.P1), (self.x0, self.P0)]
        return [(self.x1, self.P1)]

    def advance(self, u: float, sp: float, v: float, te: float, T: float) -> PlusOutput:
        """One step of T seconds: u deg/s CCW, the samples' spread sp deg/s, speed v m/s,
        temperature te degC (NaN = unknown)."""
        dT, have_temp = self.temperature(te)
        mix = self.predict(T, dT, have_temp, v)
        zero = self.standstill_test(u - mix.corr, sp, v, mix)
        if zero:
            out = self.standstill_update(u, sp, dT, mix)
        else:
            out = self.driving_update(u, T, dT, mix)
        heading = self.heading_fix(mix) if mix.mixing and self.p.ablation.heading_fix else 0.0
        m = self.p.drift_odds_max
        self.log_odds = min(max(self.log_odds, -m), m)
        if self.moved_on:
            self.lo_m = min(max(self.lo_m, -m), m)
        return self.output(out, zero, dT, mix, heading)

    # -- the phases ------------------------------------------------------------------------

    def temperature(self, te: float) -> tuple[float, bool]:
        """(dT, a temperature is used): degC above the first one seen, 0 without."""
        have_temp = self.p.ablation.temp_model and not math.isnan(te)
        if have_temp and math.isnan(self.t_ref):
            self.t_ref = te
        return (te - self.t_ref if have_temp else 0.0), have_temp

    def predict(self, T: float, dT: float, have_temp: bool, v: float = math.nan) -> _Mix:
        """Let T pass (the random walks, the road's decay) and weigh the bank: the correction
        and the core's increment in force for this step."""
        p, x1, P1 = self.p, self.x1, self.P1
        q1 = p.bias_q if have_temp else (p.q_drifting if p.bank else p.bias_q_no_temp)
        if p.bank and not have_temp and p.ablation.moved_q > 0.0:
            q1 = p.ablation.moved_q  # the second filter is "moved", not "drifting"
        a = math.exp(-T / p.road_tau_s) if p.road_var > 0.0 else 1.0
        road_q = _road_var(p, v) * (1.0 - a * a)
        bb.predict(x1, P1, q1, T, a, road_q)
        if p.bank:
            bb.predict(self.x0, self.P0, p.q_stable, T, a, road_q)
        if self.moved_on:
            bb.predict(self.xm, self.Pm, p.q_stable, T, a, road_q)
        corr1 = bb.bias_at(x1, dT)
        if p.bank and not have_temp:
            if self.moved_on:
                return self._mix3(dT, corr1, q1)
            w1 = 1.0 / (1.0 + math.exp(-self.log_odds))
            corr0 = bb.bias_at(self.x0, dT)
            corr = (1.0 - w1) * corr0 + w1 * corr1
            return _Mix(w1, corr0, corr1, corr, self.bank_increment(w1), q1, True)
        inc = _increment(bb.bias_var_at(P1, dT), q1, p)
        return _Mix(1.0, corr1, corr1, corr1, inc, q1, False)

    def _mix3(self, dT: float, corr1: float, q1: float) -> _Mix:
        """The bank's mixture with the moved filter (:meth:`predict`): weights from the
        log-odds of drifting and of moved, each against stable."""
        e1, em = math.exp(self.log_odds), math.exp(self.lo_m)
        w0 = 1.0 / (1.0 + e1 + em)
        w1, wm = e1 * w0, em * w0
        corr0 = bb.bias_at(self.x0, dT)
        corrm = bb.bias_at(self.xm, dT)
        corr = w0 * corr0 + w1 * corr1 + wm * corrm
        return _Mix(w1, corr0, corr1, corr, self.bank_increment(w1), q1, True, wm, corrm)

    def bank_increment(self, w1: float) -> float:
        """The core's increment with the bank, deg/s: ``ic_alpha`` x the drifting filter's
        bias sd (capped at ``i_c_max``) while "drifting" weighs at least 0.5, else 0."""
        p, v1 = self.p, self.P1[bb.BB]
        sd1 = math.sqrt(v1 if v1 > 0.0 else 0.0)
        return min(p.i_c_max, p.ablation.ic_alpha * sd1) if w1 >= 0.5 else 0.0

    def standstill_test(self, uc: float, sp: float, v: float, mix: _Mix) -> bool:
        """Is this step a zero-rate update? A standstill candidate (:func:`hdrd.core.standstill.
        standstill_candidate`) whose corrected level is within ``stop_gate_sigma`` of what
        the model allows at rest, for ``steps_speed`` (or ``steps_gyro``) steps running."""
        p = self.p
        level = uc + self.I
        cand, need = standstill_candidate(level, sp, v, p.standstill)
        if cand and p.stop_gate_sigma > 0.0:
            hv = bb.stop_var(self.P1)
            if mix.mixing:
                hv = max(hv, bb.stop_var(self.P0)) + (mix.corr1 - mix.corr0) ** 2
                if self.moved_on:
                    spread = max(abs(mix.corrm - mix.corr0), abs(mix.corrm - mix.corr1))
                    hv = max(hv, bb.stop_var(self.Pm) + spread * spread)
            bv = p.block_var
            if math.isnan(bv):  # no calibration (a given bias): this step's own spread
                bv = block_mean_variance(sp, p.standstill)
            allow = bv + (hv if hv > 0.0 else 0.0) + mix.inc * mix.inc
            allow += p.gate_floor_dps**2
            cand = abs(level) <= p.stop_gate_sigma * math.sqrt(allow)
        self.still = self.still + 1 if cand else 0
        self.need = need
        return cand and self.still >= need

    def standstill_update(
        self, u: float, sp: float, dT: float, mix: _Mix
    ) -> tuple[float, float, int, float, int, float]:
        """A zero-rate update: the true rate is 0, so u measures what a stop reads, b + c.
        I is folded into b first (omega = u - b + I = u - (b - I)); I, a sum of +-i_c steps,
        is only known to about one increment. The core restarts; omega = 0 is published."""
        p = self.p
        rv = block_mean_variance(sp, p.standstill)
        if not math.isnan(p.block_var) and p.block_var > rv:
            rv = p.block_var
        first = self.still == self.need
        evidence = []
        for x, P in self.filters():
            x[bb.B] -= self.I
            if first:
                P[bb.BB] += mix.inc * mix.inc
            evidence.append(bb.update(x, P, 1.0, dT, 0.0, u, rv + self.q2))
        if mix.mixing:
            # Which filter predicted the stop's reading better (both allow a calibration
            # error: stop_floor_dps).
            (nu1, s1), (nu0, s0) = evidence[:2]
            f2 = p.stop_floor_dps**2
            self.log_odds += bb.log_evidence(nu1, s1 + f2, nu0, s0 + f2)
            if self.moved_on:
                num, sm = evidence[2]
                self.lo_m += bb.log_evidence(num, sm + f2, nu0, s0 + f2)
        self.x, self.I, self.r, self.s, self.n = 0.0, 0.0, 1, 0, self.n + 1
        return 0.0, 0.0, 0, 1.0, 1, 0.0

    def driving_update(
        self, u: float, T: float, dT: float, mix: _Mix
    ) -> tuple[float, float, int, float, int, float]:
        """The paper's step (:func:`hdrd.core.hdr.kernel`) on u_c = u - the correction, with the
        increment in force; then, on a straight step, a measurement of b + r."""
        p = self.p
        if mix.mixing and p.ablation.heading_fix:
            bb.heading_predict(self.P1, T, dT)
            bb.heading_predict(self.P0, T, dT)
            if self.moved_on:
                bb.heading_predict(self.Pm, T, dT)
        I_out = self.I
        x, self.I, self.yaw, r, s, W, R, y, omega = kernel(
            u - mix.corr, self.x, I_out, self.yaw, self.r, self.s, mix.inc, T, p.hdr
        )
        self.x, self.r, self.s, self.n = x, r, s, self.n + 1
        straight_r = p.ablation.straight_r
        if straight_r > 0.0 and W and abs(omega) <= p.straight_gate_dps:
            evidence = [bb.update(x_, P_, 0.0, dT, 1.0, u, straight_r) for x_, P_ in self.filters()]
            if mix.mixing:  # which filter predicted this step (and its road) better
                (nu1, s1), (nu0, s0) = evidence[:2]
                self.log_odds += bb.log_evidence(nu1, s1, nu0, s0)
                if self.moved_on:
                    num, sm = evidence[2]
                    self.lo_m += bb.log_evidence(num, sm, nu0, s0)
        return omega, I_out, W, R, r, y

    def heading_fix(self, mix: _Mix) -> float:
        """Correct the yaw by the heading error the measurements revealed (the bank's
        weighted psi), deg CCW; psi restarts at 0."""
        w1 = mix.w1
        heading = (1.0 - w1 - mix.wm) * self.x0[bb.PSI] + w1 * self.x1[bb.PSI]
        if self.moved_on:
            heading += mix.wm * self.xm[bb.PSI]
            self.xm[bb.PSI] = 0.0
        self.yaw += heading
        self.x0[bb.PSI] = 0.0
        self.x1[bb.PSI] = 0.0
        return heading

    def output(
        self,
        core: tuple[float, float, int, float, int, float],
        zero: bool,
        dT: float,
        mix: _Mix,
        heading: float,
    ) -> PlusOutput:
        """What is published: the core's output and the bias model after this step."""
        x1, w1 = self.x1, mix.w1
        b1 = bb.bias_at(x1, dT)
        v1 = bb.bias_var_at(self.P1, dT)
        if mix.mixing:
            bc, var_b, kc, q_in = self.mixture(dT, mix, b1, v1)
        else:
            bc, var_b, kc, q_in = b1, v1, x1[bb.K], mix.q1
        sd = math.sqrt(var_b if var_b > 0.0 else 0.0)
        omega, I_out, W, R, r, y = core
        return PlusOutput(omega, self.yaw, I_out, W, R, r, y, bc, zero, sd, kc, mix.inc, q_in,
                          w1, heading)  # fmt: skip

    def mixture(
        self, dT: float, mix: _Mix, b1: float, v1: float
    ) -> tuple[float, float, float, float]:
        """:meth:`output`'s bank mixture over its filters (stable, drifting, and moved when
        on): the bias correction, its variance (within and between the filters), k and the
        random walk in force."""
        p, w1, wm = self.p, mix.w1, mix.wm
        w0 = 1.0 - w1 - wm
        x0, x1 = self.x0, self.x1
        b0, v0 = bb.bias_at(x0, dT), bb.bias_var_at(self.P0, dT)
        bc = w0 * b0 + w1 * b1
        if self.moved_on:
            bm, vm = bb.bias_at(self.xm, dT), bb.bias_var_at(self.Pm, dT)
            bc += wm * bm
        var_b = w0 * (v0 + (b0 - bc) ** 2) + w1 * (v1 + (b1 - bc) ** 2)
        kc = w0 * x0[bb.K] + w1 * x1[bb.K]
        q_in = w0 * p.q_stable + w1 * mix.q1
        if self.moved_on:
            var_b += wm * (vm + (bm - bc) ** 2)
            kc += wm * self.xm[bb.K]
            q_in += wm * p.q_stable
        return bc, var_b, kc, q_in


def step(
    state: PlusState, inp: StepInput, params: HdrPlusParams = HdrPlusParams()
) -> tuple[PlusState, PlusOutput]:
    """Advance HDR+ by one step of inp.T seconds. Pure (the same code as :func:`run_batch`)."""
    run = _Run(state, params)
    out = run.advance(
        float(inp.u), float(inp.spread_dps), float(inp.speed_mps), float(inp.temp_c), float(inp.T)
    )
    return run.state(), out


# -- the batch form ---------------------------------------------------------------------------


@dataclass(frozen=True)
class PlusTrace:
    """Every step's output of a batch run, as arrays (one element per step)."""

    omega: npt.NDArray[np.float64]
    yaw: npt.NDArray[np.float64]
    I: npt.NDArray[np.float64]
    W: npt.NDArray[np.int8]
    R: npt.NDArray[np.float64]
    r: npt.NDArray[np.int64]
    filtered: npt.NDArray[np.float64]
    bias_corr_dps: npt.NDArray[np.float64]
    standstill: npt.NDArray[np.bool_]
    bias_sd_dps: npt.NDArray[np.float64]
    temp_coeff_dps_per_c: npt.NDArray[np.float64]
    i_c_dps: npt.NDArray[np.float64]
    bias_q: npt.NDArray[np.float64]
    drift_weight: npt.NDArray[np.float64]
    heading_fix_deg: npt.NDArray[np.float64]
    final: PlusState


_DTYPES: tuple[type[np.generic], ...] = (
    *(np.float64,) * 3,
    np.int8,
    np.float64,
    np.int64,
    np.float64,
    np.float64,
    np.bool_,
    *(np.float64,) * 6,
)
"""The dtypes of :class:`PlusTrace`'s arrays, in the order of :class:`PlusOutput`."""


def _column(v: npt.ArrayLike | None, n: int, name: str) -> list[float]:
    if v is None:
        return [math.nan] * n
    a = np.asarray(v, dtype=np.float64)
    if a.ndim == 0:
        return [float(a)] * n
    if a.shape != (n,):
        raise ValueError(f"{name} must have one value per step ({a.shape} vs {n})")
    return a.tolist()


def run_batch(
    u: npt.ArrayLike,
    spread: npt.ArrayLike | None = None,
    speed: npt.ArrayLike | None = None,
    temp: npt.ArrayLike | None = None,
    T: npt.ArrayLike | None = None,
    params: HdrPlusParams = HdrPlusParams(),
    state: PlusState = INITIAL_PLUS_STATE,
) -> PlusTrace:
    """Run HDR+ over arrays of steps: u (deg/s), spread (deg/s), speed (m/s), temp (degC),
    each per step or None (unknown throughout), T a scalar or per step (None: params.hdr.T).
    :func:`step` looped, without building a state between steps (the same code)."""
    uu = np.asarray(u, dtype=np.float64)
    n = uu.shape[0]
    cols = (
        uu.tolist(),
        _column(spread, n, "spread"),
        _column(speed, n, "speed"),
        _column(temp, n, "temp"),
        _column(params.hdr.T if T is None else T, n, "T"),
    )
    if n == 0:  # nothing ran: not even the prior is set
        return PlusTrace(*(np.empty(0, dt) for dt in _DTYPES), final=state)  # type: ignore[misc, arg-type]
    run = _Run(state, params)
    rows = [run.advance(*row) for row in zip(*cols, strict=True)]
    outs: list[npt.NDArray[np.generic]] = [
        np.array(col, dtype=dt) for col, dt in zip(zip(*rows, strict=True), _DTYPES, strict=True)
    ]
    return PlusTrace(*outs, final=run.state())  # type: ignore[misc, arg-type]
