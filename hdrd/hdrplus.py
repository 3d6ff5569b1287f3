"""HDR+: the paper's HDR kept as a core, under a Kalman model of the bias that adapts to the gyro.

Pure: no I/O, no clock. One step per period T on the same input as HDR, u_i = block mean of
the raw rate minus the start-up static bias eps0 (paper Eqs. 2, 11), deg/s, + = CCW, plus
what HDR does not use: the spread of the raw samples within the block, the vehicle speed and
the board temperature (each NaN when unknown). docs/hdrplus.md has the reasoning and the
measurements behind every default.

1. **Bias model** (:mod:`hdrd.zupt`): a Kalman filter of bias(temp) = eps0 + b + k (temp -
   t_ref) and of c, the offset between what a stop reads and the bias while driving (a
   quantised gyro reads the same code at every stop). Its prior comes from the start-up
   calibration (var(eps0) + the quantisation step's q^2/12); its process noise from the
   gyro's error model (:class:`hdrd.gyronoise.GyroNoise`: a grade, or parameters recorded by
   ``hdrd calibrate``) or, for a gyro nobody described, learned online (below). The HDR core
   runs on u_c = u - b - k (temp - t_ref).
2. **The core's increment follows the bias uncertainty**: i_c = ``ic_alpha`` x the bias
   model's standard deviation at this temperature (capped at ``i_c_max``). With a known error
   model whose bias wanders less within a road's curve than real roads curve
   (``ic_drift_ratio``), the binary increment is off: on such a gyro it only straightens
   real gentle curves.
3. **Standstill (zero-rate) updates**: a step detected as standstill (from the speed, or the
   gyro alone when enabled; and its level within ``stop_gate_sigma`` of what the model
   expects at rest) publishes omega = 0, folds I into b and measures b + c.
4. **Straight-driving measurements**: a step on which the turn switch lets I move (W = 1) and
   whose corrected rate is within ``straight_gate_dps`` measures b with variance
   ``straight_r`` (the road's own yaw wander makes it a noisy one).
5. **The random walk of an unknown gyro** (``q_adapt_steps`` > 0, without a temperature):
   it starts at ``bias_q_no_temp``; each stop's
   mean, against a bias anchored on stops alone, says how far the bias moved since the last
   (clean evidence: no road in it); until the first such stop, windows of straight steps say
   it (contaminated by gentle curves, so each may raise it only so much).

With every extra switched off (:meth:`HdrPlusParams.paper`) HDR+ is bit-identical to paper
HDR. Two forms with bit-identical results: :func:`step` (immutable :class:`PlusState`) for
the daemon, composed of :func:`hdrd.hdr.step` and :mod:`hdrd.zupt`'s functions, and
:func:`run_batch` over arrays for offline tools, the same recursion inlined on local floats
(tests/test_hdrplus.py holds the two to the same bits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from hdrd import hdr, zupt
from hdrd.gyronoise import GyroNoise
from hdrd.hdr import INITIAL_STATE, HdrParams, HdrState
from hdrd.zupt import INITIAL_BIAS, BiasState, CalibrationNoise, StandstillParams

__all__ = [
    "INITIAL_ADAPT",
    "INITIAL_PLUS_STATE",
    "PLUS_CORE",
    "AdaptState",
    "GyroNoise",
    "HdrPlusParams",
    "PlusInput",
    "PlusOutput",
    "PlusState",
    "PlusTrace",
    "run_batch",
    "step",
]

PLUS_CORE = HdrParams(i_c=0.0048, tau=0.5, theta_w=0.45, c1=0.14, c2=0.88)
"""HDR+'s core parameters (the fixed increment i_c applies only with ``ic_alpha = 0``)."""


@dataclass(frozen=True, slots=True)
class HdrPlusParams:
    """HDR+ tunables. Every extra has an off switch; :meth:`paper` turns them all off."""

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
    from the driving bias by about a quantisation step (q^2/12; default: the CRS03-04 on a
    16-bit ADC). 0: stops measure the driving bias itself."""
    quant_step_dps: float = 0.00763
    """The gyro's output step q, deg/s: a stop's block mean is trusted to q^2/12 at best."""
    block_var: float = math.nan
    """Variance of one step's mean at standstill, (deg/s)^2 (from the calibration; NaN =
    unknown): the floor of a stop measurement's variance and the scale of the stop gate."""
    bias_q: float = 1e-6
    """Random walk of the bias left unexplained by the temperature model, (deg/s)^2/s."""
    bias_q_no_temp: float = 3e-7
    """The same when the temperature is unknown, (deg/s)^2/s: the start value of the online
    estimate when ``q_adapt_steps`` > 0."""
    q_adapt_steps: int = 30
    """Without a temperature, learn the bias random walk online (0 = off: the error model is
    known). Until the first stop-based estimate, every this many straight steps the squared
    mean of (u - the model's bias at the window's start) beyond what the road's scatter
    explains, per second elapsed, is blended into the estimate."""
    q_adapt_gain: float = 0.2
    """Weight of each straight window in the online estimate (exponential forgetting)."""
    q_adapt_kappa: float = 2.0
    """Inflation of a window mean's variance for the road's correlated yaw wander (sway)."""
    q_min: float = 1e-8
    """Floor of the online estimate, (deg/s)^2/s."""
    q_adapt_max_rise: float = 10.0
    """One straight window may raise the estimate at most this many times (a single curving
    window is not a drifting gyro; a sustained drift still raises it geometrically)."""
    q_stop_gain: float = 0.3
    """Weight of each stop in the online estimate: the stop's mean against the stop-only
    anchor, beyond their variances, per second since the last stop."""
    q_stop_max_rise: float = 100.0
    """One stop may raise the estimate at most this many times."""
    q_white_ratio: float = 0.0
    """:meth:`fitted` without an error model: the online estimate starts at this times the
    calibration's white noise density squared (N^2 = a step's standstill variance x T)...
    (0 = off, the start is ``bias_q_no_temp``: 0.03 helped every simulated grade but hurt
    the real judging drives, where a running engine's vibration, not the gyro's own noise,
    sets the standstill noise; docs/hdrplus.md)"""
    q_start_min: float = 1e-8
    """... but no lower than this, (deg/s)^2/s ..."""
    q_start_max: float = 1e-4
    """... and no higher than this, (deg/s)^2/s."""
    temp_model: bool = True
    """Learn the temperature coefficient k (when a temperature is given)."""
    temp_coeff_sd: float = 0.01
    """Prior standard deviation of k, deg/s/degC (prior mean 0)."""
    straight_r: float = 0.27
    """Variance of a straight-driving bias measurement, (deg/s)^2 (swaying, slow curves);
    0 switches these measurements off."""
    straight_gate_dps: float = 0.93
    """Largest |u_c + I| of a step used as a straight-driving measurement, deg/s."""
    ic_alpha: float = 0.1
    """The core's increment is ic_alpha x the bias model's standard deviation at this
    temperature, deg/s (capped at i_c_max); 0 = the fixed hdr.i_c."""
    i_c_max: float = 0.008
    """Largest increment, deg/s."""
    ic_drift_ratio: float = 0.0
    """The increment is 0 while the random walk in force over ``road_tau_s`` is below this
    times ``road_var``: the bias moves less within a curve than real roads curve (0 = off;
    :meth:`fitted` sets it with a known error model)."""
    road_var: float = 0.0025
    """Variance of the yaw rate of gentle real-road curvature that passes the turn switch,
    (deg/s)^2 (a Gauss-Markov rate of 0.05 deg/s sd ...)"""
    road_tau_s: float = 120.0
    """... and this correlation time, s: the level at which straight driving on real roads
    misleads a bias estimate by 0.025 deg/s per drive, as on the real tuning drives)."""
    stop_gate_sigma: float = 4.0
    """A standstill step's corrected level must be within this many standard deviations of
    what the model expects at rest (block_var + the bias variance + i_c^2): a turn that a
    stale speed calls standstill is not taken for the bias (0 = off; needs block_var)."""
    model: str = "defaults"
    """Which error model the settings were fitted to (published by the daemon): ``defaults``,
    ``calibration`` (the start-up window's noise; the random walk learned online), or the
    known model's source (``grade NAME``, ``recorded``, ``config``)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("hdr", "standstill", "model"):
                continue
            if f.type in ("bool", bool):
                object.__setattr__(self, f.name, bool(v))
            elif f.type in ("int", int):
                if int(v) < 0:
                    raise ValueError(f"{f.name} must be >= 0, got {v!r}")
                object.__setattr__(self, f.name, int(v))
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
        for name in ("q_adapt_gain", "q_stop_gain"):
            if getattr(self, name) > 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)!r}")

    @classmethod
    def paper(cls, hdr: HdrParams | None = None) -> HdrPlusParams:
        """Every extra off: bit-identical to :func:`hdrd.hdr.step` with ``hdr``
        (default: the paper's Table III)."""
        return cls(
            hdr=HdrParams() if hdr is None else hdr,
            standstill=StandstillParams(enabled=False),
            temp_model=False,
            straight_r=0.0,
            ic_alpha=0.0,
            q_adapt_steps=0,
            stop_offset_var=0.0,
            model="paper",
        )

    def with_(self, **kw: object) -> HdrPlusParams:
        """A copy with some fields replaced (``hdr`` and ``standstill`` by whole objects)."""
        return replace(self, **kw)  # type: ignore[arg-type]

    def fitted(
        self,
        calibration: CalibrationNoise | None = None,
        noise: GyroNoise | None = None,
        quant_step_dps: float | None = None,
    ) -> HdrPlusParams:
        """These settings fitted to one gyro and its start-up calibration.

        calibration: the calibration window's noise (:func:`hdrd.zupt.calibration_noise`):
        samples per step, the step's standstill variance (block_var), bias_p0 = var(eps0).
        noise: the gyro's error model when known (a grade preset, the config's, or the
        parameters recorded beside the bias): the bias random walk (K^2 + 2 sigma^2 / tau;
        without a temperature plus a warm-up), no online learning, the prior on k, and the
        increment off where it would only straighten gentle curves. Without it, the online
        estimate may start from the calibration's white noise (``q_white_ratio``, off).
        quant_step_dps: the output step q when known otherwise (the ADC's LSB; for a log,
        the lattice of its values); else the calibration's, else the noise model's. The stop
        offset's variance is q^2/12. Unknown pieces keep their current values.
        """
        p = self
        q = math.nan
        for cand in (
            quant_step_dps,
            calibration.quant_step_dps if calibration is not None else None,
            noise.quant_step_dps if noise is not None else None,
        ):
            if cand is not None and math.isfinite(cand) and cand > 0:
                q = float(cand)
                break
        if math.isfinite(q):
            p = p.with_(quant_step_dps=q, stop_offset_var=q * q / 12.0)
        if calibration is not None:
            ss = replace(p.standstill, samples_per_step=max(1.0, calibration.samples_per_step))
            p = p.with_(standstill=ss, model="calibration")
            if math.isfinite(calibration.block_var) and calibration.block_var >= 0:
                p = p.with_(block_var=calibration.block_var)
                if p.q_white_ratio > 0.0:
                    white2 = calibration.block_var * p.hdr.T  # N^2: a step's variance x T
                    start = min(max(p.q_white_ratio * white2, p.q_start_min), p.q_start_max)
                    p = p.with_(bias_q_no_temp=start)
            if math.isfinite(calibration.bias_var) and calibration.bias_var >= 0:
                p = p.with_(bias_p0=calibration.bias_var)
        if noise is not None and noise.known():
            qt, qnt = noise.bias_q(), noise.bias_q_no_temp()
            p = p.with_(bias_q_no_temp=qnt, q_adapt_steps=0, ic_drift_ratio=0.01)
            p = p.with_(bias_q=qt if math.isfinite(qt) else qnt, model=noise.source)
            if math.isfinite(noise.temp_coeff_dps_per_c):
                p = p.with_(temp_coeff_sd=max(noise.temp_coeff_dps_per_c, 1e-5))
        return p


class PlusInput(NamedTuple):
    """One step's input. NaN marks an unknown spread, speed or temperature."""

    u: float
    """Block mean raw rate minus the start-up static bias eps0, deg/s CCW."""
    spread_dps: float
    """Standard deviation of the raw samples within the block, deg/s."""
    speed_mps: float
    """Vehicle speed, m/s (NaN: gyro-only standstill detection, if enabled)."""
    temp_c: float
    """Board temperature, degC."""
    T: float
    """Step length, s (normally hdr.T)."""


class AdaptState(NamedTuple):
    """The online estimate of the bias random walk (used without a temperature).

    q: the estimate, (deg/s)^2/s (NaN until the first step sets it from the parameters).
    Straight windows: n, steps in the open window; total, square, sums of (u - beta) and its
    square over them, deg/s and (deg/s)^2; beta, the model's bias at the window's start
    (b - I), deg/s; span, seconds since the window opened. Stops: anchor, the bias relative
    to eps0 measured by stops alone, deg/s, and anchor_var its variance, (deg/s)^2 (NaN until
    the first step); since, seconds driven since the anchor was last measured; run_z,
    run_w, the open stop's inverse-variance weighted sums; stops, stop estimates made.
    """

    q: float = math.nan
    n: int = 0
    total: float = 0.0
    square: float = 0.0
    beta: float = 0.0
    span: float = 0.0
    anchor: float = 0.0
    anchor_var: float = math.nan
    since: float = 0.0
    run_z: float = 0.0
    run_w: float = 0.0
    stops: int = 0


INITIAL_ADAPT = AdaptState()


class PlusState(NamedTuple):
    """State carried between steps. Immutable.

    core: the paper HDR state (x, I, yaw, r, s, n). bias: the bias model (:mod:`hdrd.zupt`).
    still: consecutive standstill-candidate steps. adapt: the online estimate of the bias
    random walk.
    """

    core: HdrState = INITIAL_STATE
    bias: BiasState = INITIAL_BIAS
    still: int = 0
    adapt: AdaptState = INITIAL_ADAPT


INITIAL_PLUS_STATE = PlusState()


class PlusOutput(NamedTuple):
    """What one step publishes.

    omega: corrected yaw rate, deg/s CCW (0 at standstill). yaw: deg CCW since start. I: the
    core's integrator applied in this step, deg/s. W, R, r, filtered: as :class:`hdrd.hdr.HdrOutput`
    (W = 0 at standstill). bias_corr_dps: the learned correction to eps0 at this step's
    temperature, deg/s (published bias = eps0 + bias_corr). standstill: this step was a
    zero-rate update. bias_sd_dps: standard deviation of b, deg/s. temp_coeff_dps_per_c: k.
    i_c_dps: the core's increment in force, deg/s. bias_q: the bias random walk in force,
    (deg/s)^2/s.
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


# -- the step, composed of the paper's step and the bias model's functions ----------------------


def _increment(var_t: float, q_i: float, params: HdrPlusParams) -> float:
    """The core's increment, deg/s (module docstring, 2)."""
    if params.ic_alpha > 0.0:
        inc = min(params.i_c_max, params.ic_alpha * math.sqrt(var_t if var_t > 0.0 else 0.0))
    else:
        inc = params.hdr.i_c
    if params.ic_drift_ratio > 0.0 and q_i * params.road_tau_s < (
        params.ic_drift_ratio * params.road_var
    ):
        inc = 0.0
    return inc


def _stop_estimate(ad: AdaptState, q2: float, params: HdrPlusParams) -> AdaptState:
    """A stop ended: its mean against the stop-only anchor updates the random walk estimate
    (what their difference exceeds of their variances, per second driven between them),
    then the anchor."""
    q_hat = ad.q
    z = ad.run_z / ad.run_w
    rv = 1.0 / ad.run_w + q2
    nu = z - ad.anchor
    stops = ad.stops
    if ad.since > 0.0:
        stops += 1
        q_obs = nu * nu - ad.anchor_var - rv
        q_obs = (q_obs if q_obs > 0.0 else 0.0) / ad.since
        if q_obs > params.q_stop_max_rise * q_hat:
            q_obs = params.q_stop_max_rise * q_hat
        q_hat = (1.0 - params.q_stop_gain) * q_hat + params.q_stop_gain * q_obs
        if q_hat < params.q_min:
            q_hat = params.q_min
    v = ad.anchor_var + q_hat * ad.since
    g = v / (v + rv)
    return ad._replace(
        q=q_hat,
        anchor=ad.anchor + g * nu,
        anchor_var=v - g * v,
        since=0.0,
        run_z=0.0,
        run_w=0.0,
        stops=stops,
    )


def _window(ad: AdaptState, u: float, beta: float, T: float, params: HdrPlusParams) -> AdaptState:
    """One straight step of u (deg/s) in the open window (opened with the model's bias beta,
    deg/s, and T s when empty); a full window updates the random walk estimate."""
    n, total, square, span = ad.n, ad.total, ad.square, ad.span
    if n == 0:
        span = T
    else:
        beta = ad.beta
    z = u - beta
    total += z
    square += z * z
    n += 1
    q_hat = ad.q
    if n >= params.q_adapt_steps:
        m = total / n
        var_in = square / n - m * m
        excess = m * m - params.q_adapt_kappa * (var_in if var_in > 1e-6 else 1e-6) / n
        q_obs = (excess if excess > 0.0 else 0.0) / span
        if q_obs > params.q_adapt_max_rise * q_hat:
            q_obs = params.q_adapt_max_rise * q_hat
        q_hat = (1.0 - params.q_adapt_gain) * q_hat + params.q_adapt_gain * q_obs
        if q_hat < params.q_min:
            q_hat = params.q_min
        n, total, square, span = 0, 0.0, 0.0, 0.0
    return ad._replace(q=q_hat, n=n, total=total, square=square, beta=beta, span=span)


def step(
    state: PlusState, inp: PlusInput, params: HdrPlusParams = HdrPlusParams()
) -> tuple[PlusState, PlusOutput]:
    """Advance HDR+ by one step of inp.T seconds. Pure.

    The paper's step (:func:`hdrd.hdr.step`) on the corrected rate with the increment the
    bias uncertainty justifies, and the bias model's functions (:mod:`hdrd.zupt`); the same
    recursion as :func:`run_batch`, to the bit."""
    T, u, sp, v, te = float(inp.T), float(inp.u), float(inp.spread_dps), inp.speed_mps, inp.temp_c
    v, te = float(v), float(te)
    q2 = params.quant_step_dps * params.quant_step_dps / 12.0
    bias = zupt.init_bias(
        state.bias, params.bias_p0 + q2, params.temp_coeff_sd, params.stop_offset_var
    )
    ad = state.adapt
    if math.isnan(ad.q):
        ad = ad._replace(q=params.bias_q_no_temp)
    if math.isnan(ad.anchor_var):
        ad = ad._replace(anchor_var=params.bias_p0 + q2)
    learn = params.q_adapt_steps > 0
    have_temp = params.temp_model and not math.isnan(te)
    if have_temp and math.isnan(bias.t_ref):
        bias = bias._replace(t_ref=te)
    dT = te - bias.t_ref if have_temp else 0.0
    q_i = params.bias_q if have_temp else (ad.q if learn else params.bias_q_no_temp)
    bias = zupt.predict(bias, q_i, T)
    if ad.n:
        ad = ad._replace(span=ad.span + T)
    uc = u - zupt.correction(bias, dT)
    inc = _increment(bias.p_bb + dT * (2.0 * bias.p_bk + dT * bias.p_kk), q_i, params)
    core = state.core
    level = uc + core.I
    cand, need = zupt.standstill_candidate(level, sp, v, params.standstill)
    if cand and params.stop_gate_sigma > 0.0 and not math.isnan(params.block_var):
        hv = bias.p_bb + 2.0 * bias.p_bc + bias.p_cc
        cand = abs(level) <= params.stop_gate_sigma * math.sqrt(
            params.block_var + (hv if hv > 0.0 else 0.0) + inc * inc
        )
    still = state.still + 1 if cand else 0
    zero_rate = cand and still >= need
    if learn and ad.run_w > 0.0 and not zero_rate:
        ad = _stop_estimate(ad, q2, params)
    if zero_rate:
        # Zero-rate update: the true rate is 0, so u measures what a stop reads, b + c.
        # I is folded into b first (omega = u - b + I = u - (b - I)).
        bias = bias._replace(b=bias.b - core.I)
        if still == need:  # I, a sum of +-i_c steps, is only known to about one increment
            bias = bias._replace(p_bb=bias.p_bb + inc * inc)
        rv = zupt.block_mean_variance(sp, params.standstill)
        if not math.isnan(params.block_var) and params.block_var > rv:
            rv = params.block_var
        if learn:
            ad = ad._replace(run_z=ad.run_z + u / rv, run_w=ad.run_w + 1.0 / rv)
        bias = zupt.update(bias, u, rv + q2, dT, stop=True)
        new_core = core._replace(x=0.0, I=0.0, r=1, s=0, n=core.n + 1)
        out = PlusOutput(0.0, core.yaw, 0.0, 0, 1.0, 1, 0.0, zupt.correction(bias, dT), True,
                         math.sqrt(bias.p_bb), bias.k, inc, q_i)  # fmt: skip
        return PlusState(new_core, bias, still, ad), out
    new_core, o = hdr.step(core, uc, replace(params.hdr, T=T, i_c=inc))
    if params.straight_r > 0.0 and o.W and abs(o.omega) <= params.straight_gate_dps:
        if learn and not have_temp and ad.stops == 0:
            ad = _window(ad, u, bias.b - core.I, T, params)
        bias = zupt.update(bias, u, params.straight_r, dT, stop=False)
    if learn:
        ad = ad._replace(since=ad.since + T)
    out = PlusOutput(o.omega, o.yaw, o.I, o.W, o.R, o.r, o.filtered, zupt.correction(bias, dT),
                     False, math.sqrt(bias.p_bb), bias.k, inc, q_i)  # fmt: skip
    return PlusState(new_core, bias, still, ad), out


# -- the batch form: the same recursion on local floats ----------------------------------------


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
    final: PlusState


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

    :func:`step` looped, inlined on local floats (the recursion is sequential): about 8x
    faster. Any change here must be made in :func:`step` and its helpers too.
    """
    uu = np.asarray(u, dtype=np.float64)
    n = uu.shape[0]
    u_l = uu.tolist()
    spread_l = _column(spread, n, "spread")
    speed_l = _column(speed, n, "speed")
    temp_l = _column(temp, n, "temp")
    T_l = _column(params.hdr.T if T is None else T, n, "T")
    o_omega, o_yaw, o_I, o_R, o_y = (np.empty(n) for _ in range(5))
    o_corr, o_sd, o_k, o_ic, o_q = (np.empty(n) for _ in range(5))
    o_W = np.empty(n, np.int8)
    o_r = np.empty(n, np.int64)
    o_still = np.empty(n, np.bool_)

    hp = params.hdr
    ss = params.standstill
    tau, theta_w, c1, c2, i_c_fixed = hp.tau, hp.theta_w, hp.c1, hp.c2, hp.i_c
    lowpass, turn_switch, attenuator, enabled = (
        hp.lowpass,
        hp.turn_switch,
        hp.attenuator,
        hp.enabled,
    )
    temp_model, q_t, q_nt = params.temp_model, params.bias_q, params.bias_q_no_temp
    straight_r, straight_gate = params.straight_r, params.straight_gate_dps
    ic_alpha, ic_max = params.ic_alpha, params.i_c_max
    drift_ratio, road = params.ic_drift_ratio, params.road_tau_s
    drift_floor = params.ic_drift_ratio * params.road_var
    a_steps, a_gain, a_kappa, q_min = (
        params.q_adapt_steps,
        params.q_adapt_gain,
        params.q_adapt_kappa,
        params.q_min,
    )
    a_rise, s_gain, s_rise = params.q_adapt_max_rise, params.q_stop_gain, params.q_stop_max_rise
    learn = a_steps > 0
    q2 = params.quant_step_dps * params.quant_step_dps / 12.0
    block_var, gate_sigma = params.block_var, params.stop_gate_sigma
    use_gate = gate_sigma > 0.0 and not math.isnan(block_var)
    ss_on, ss_speed, ss_spread, ss_level, ss_n_speed = (
        ss.enabled,
        ss.speed_mps,
        ss.spread_dps,
        ss.level_dps,
        ss.steps_speed,
    )
    ss_gyro, g_spread, g_level, ss_n_gyro = (
        ss.gyro_only,
        ss.gyro_spread_dps,
        ss.gyro_level_dps,
        ss.steps_gyro,
    )
    floor2, nsamp = ss.noise_floor_dps * ss.noise_floor_dps, ss.samples_per_step
    # The prior: the calibration's noise and, on top, its quantisation (it cannot see the
    # bias better than the output step allows), and the standstill offset's variance.
    bias0 = zupt.init_bias(
        state.bias, params.bias_p0 + q2, params.temp_coeff_sd, params.stop_offset_var
    )
    b, k, p_bb, p_bk, p_kk, t_ref, c, p_bc, p_cc, p_ck = bias0
    core = state.core
    x, I, yaw, r, s_prev, n0 = core.x, core.I, core.yaw, core.r, core.s, core.n
    still = state.still
    ad = state.adapt
    q_hat = q_nt if math.isnan(ad.q) else ad.q
    w_n, w_sum, w_sq, w_beta, w_span = ad.n, ad.total, ad.square, ad.beta, ad.span
    an_a, an_v, an_dt, run_z, run_w, stops = (
        ad.anchor,
        params.bias_p0 + q2 if math.isnan(ad.anchor_var) else ad.anchor_var,
        ad.since,
        ad.run_z,
        ad.run_w,
        ad.stops,
    )
    isnan, sqrt, pow_ = math.isnan, math.sqrt, math.pow

    for i in range(n):
        T_i = T_l[i]
        ui = u_l[i]
        te = temp_l[i]
        have_temp = temp_model and not isnan(te)
        if have_temp and isnan(t_ref):
            t_ref = te
        dT = te - t_ref if have_temp else 0.0
        q_i = q_t if have_temp else (q_hat if learn else q_nt)
        p_bb = p_bb + q_i * T_i
        if w_n:
            w_span += T_i
        uc = ui - (b + k * dT)
        # the bias variance at this temperature, and the core's increment it justifies
        var_t = p_bb + dT * (2.0 * p_bk + dT * p_kk)
        if ic_alpha > 0.0:
            inc = min(ic_max, ic_alpha * sqrt(var_t if var_t > 0.0 else 0.0))
        else:
            inc = i_c_fixed
        if drift_ratio > 0.0 and q_i * road < drift_floor:
            inc = 0.0
        sp = spread_l[i]
        v = speed_l[i]
        # zupt.standstill_candidate, inline, then the gate on the level
        level = uc + I
        if not ss_on:
            cand, need = False, ss_n_speed
        elif not isnan(v):
            cand = v <= ss_speed and not sp > ss_spread and abs(level) <= ss_level
            need = ss_n_speed
        elif ss_gyro and not isnan(sp):
            cand = sp <= g_spread and abs(level) <= g_level
            need = ss_n_gyro
        else:
            cand, need = False, ss_n_gyro
        if cand and use_gate:
            hv = p_bb + 2.0 * p_bc + p_cc
            cand = abs(level) <= gate_sigma * sqrt(
                block_var + (hv if hv > 0.0 else 0.0) + inc * inc
            )
        still = still + 1 if cand else 0
        zero_rate = cand and still >= need
        if learn and run_w > 0.0 and not zero_rate:
            # _stop_estimate, inline
            z = run_z / run_w
            rvs = 1.0 / run_w + q2
            nu = z - an_a
            if an_dt > 0.0:
                stops += 1
                q_obs = nu * nu - an_v - rvs
                q_obs = (q_obs if q_obs > 0.0 else 0.0) / an_dt
                if q_obs > s_rise * q_hat:
                    q_obs = s_rise * q_hat
                q_hat = (1.0 - s_gain) * q_hat + s_gain * q_obs
                if q_hat < q_min:
                    q_hat = q_min
            vv = an_v + q_hat * an_dt
            g_ = vv / (vv + rvs)
            an_a = an_a + g_ * nu
            an_v = vv - g_ * vv
            an_dt, run_z, run_w = 0.0, 0.0, 0.0
        if zero_rate:
            b = b - I
            if still == need:
                p_bb = p_bb + inc * inc
            s_ = ss_spread if isnan(sp) else sp
            rv = (s_ * s_ + floor2) / nsamp
            if not isnan(block_var) and block_var > rv:
                rv = block_var
            if learn:
                run_z = run_z + ui / rv
                run_w = run_w + 1.0 / rv
            b, c, k, p_bb, p_bc, p_bk, p_cc, p_ck, p_kk = _update(
                b, c, k, p_bb, p_bc, p_bk, p_cc, p_ck, p_kk, ui, rv + q2, dT, 1.0
            )
            x, I, r, s_prev = 0.0, 0.0, 1, 0
            o_omega[i] = 0.0
            o_yaw[i] = yaw
            o_I[i] = 0.0
            o_W[i] = 0
            o_R[i] = 1.0
            o_r[i] = 1
            o_y[i] = 0.0
            o_corr[i] = b + k * dT
            o_still[i] = True
            o_sd[i] = sqrt(p_bb)
            o_k[i] = k
            o_ic[i] = inc
            o_q[i] = q_i
            continue
        # The paper's step (hdrd.hdr.step, same operations in the same order) on u_c.
        x = (T_i * uc + tau * x) / (T_i + tau) if lowpass else uc
        y = x + I
        omega = uc + I
        yaw = yaw + omega * T_i
        s = 1 if y > 0.0 else (-1 if y < 0.0 else 0)
        r = r + 1 if s == s_prev else 1
        R = (1.0 + c1) / (1.0 + c1 * pow_(r, c2)) if attenuator else 1.0
        W = 1 if (not turn_switch or abs(y) <= theta_w) else 0
        I_next = I - s * W * R * inc if enabled else 0.0
        if straight_r > 0.0 and W and abs(omega) <= straight_gate:
            if learn and not have_temp and stops == 0:
                # _window, inline: the online estimate from windows of straight steps
                if w_n == 0:
                    w_beta = b - I
                    w_span = T_i
                z = ui - w_beta
                w_sum += z
                w_sq += z * z
                w_n += 1
                if w_n >= a_steps:
                    m = w_sum / w_n
                    var_in = w_sq / w_n - m * m
                    excess = m * m - a_kappa * (var_in if var_in > 1e-6 else 1e-6) / w_n
                    q_obs = (excess if excess > 0.0 else 0.0) / w_span
                    if q_obs > a_rise * q_hat:
                        q_obs = a_rise * q_hat
                    q_hat = (1.0 - a_gain) * q_hat + a_gain * q_obs
                    if q_hat < q_min:
                        q_hat = q_min
                    w_n, w_sum, w_sq, w_span = 0, 0.0, 0.0, 0.0
            b, c, k, p_bb, p_bc, p_bk, p_cc, p_ck, p_kk = _update(
                b, c, k, p_bb, p_bc, p_bk, p_cc, p_ck, p_kk, ui, straight_r, dT, 0.0
            )
        if learn:
            an_dt += T_i
        o_omega[i] = omega
        o_yaw[i] = yaw
        o_I[i] = I
        o_W[i] = W
        o_R[i] = R
        o_r[i] = r
        o_y[i] = y
        o_corr[i] = b + k * dT
        o_still[i] = False
        o_sd[i] = sqrt(p_bb)
        o_k[i] = k
        o_ic[i] = inc
        o_q[i] = q_i
        I = I_next
        s_prev = s
    outs = (o_omega, o_yaw, o_I, o_W, o_R, o_r, o_y, o_corr, o_still, o_sd, o_k, o_ic, o_q)
    if n == 0:  # nothing ran: not even the prior is set
        return PlusTrace(*outs, state)
    final = PlusState(
        HdrState(x=x, I=I, yaw=yaw, r=r, s=s_prev, n=n0 + n),
        BiasState(b, k, p_bb, p_bk, p_kk, t_ref, c, p_bc, p_cc, p_ck),
        still,
        AdaptState(q_hat, w_n, w_sum, w_sq, w_beta, w_span, an_a, an_v, an_dt, run_z, run_w, stops),
    )
    return PlusTrace(*outs, final)


def _update(
    b: float,
    c: float,
    k: float,
    p_bb: float,
    p_bc: float,
    p_bk: float,
    p_cc: float,
    p_ck: float,
    p_kk: float,
    z: float,
    r: float,
    dT: float,
    hs: float,
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """:func:`hdrd.zupt.update` on plain floats (same operations); hs = 1 at a stop."""
    ph0 = p_bb + hs * p_bc + dT * p_bk
    ph1 = p_bc + hs * p_cc + dT * p_ck
    ph2 = p_bk + hs * p_ck + dT * p_kk
    s = ph0 + hs * ph1 + dT * ph2 + r
    k0 = ph0 / s
    k1 = ph1 / s
    k2 = ph2 / s
    innov = z - (b + hs * c + k * dT)
    return (
        b + k0 * innov,
        c + k1 * innov,
        k + k2 * innov,
        p_bb - k0 * ph0,
        p_bc - k0 * ph1,
        p_bk - k0 * ph2,
        p_cc - k1 * ph1,
        p_ck - k1 * ph2,
        p_kk - k2 * ph2,
    )
