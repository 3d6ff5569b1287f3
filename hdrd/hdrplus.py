"""HDR+: the paper's HDR with standstill re-calibration, a slow bias model and speed gating.

Pure: no I/O, no clock. One step per period T on the same input as HDR, u_i = block mean of
the raw rate minus the start-up static bias eps0 (paper Eqs. 2, 11), deg/s, + = CCW, plus
what HDR does not use: the spread of the raw samples within the block, the vehicle speed and
the board temperature (each NaN when unknown). What it adds to the paper (docs/hdrplus.md
has the reasoning and the measurements behind every default):

1. **Bias model** (:mod:`hdrd.zupt`): bias(temp) = eps0 + b + k (temp - t_ref), a two-state
   Kalman filter. The HDR core runs on u_c = u - b - k (temp - t_ref), so the paper's
   integrator I only has to remove what the model misses.
2. **Standstill re-calibration (zero-rate update)**: a step detected as standstill
   (:func:`hdrd.zupt.standstill_candidate`; from the speed, or from the gyro alone when
   enabled) publishes omega = 0 (the yaw does not move), folds I into b and measures the bias
   with the block's own variance (a long, quiet stop weighs most). The core's low-pass filter
   and repetition counter restart after it.
3. **Straight-driving bias measurements**: a step on which the turn switch lets I move
   (W = 1), and whose corrected rate is within ``straight_gate_dps``, is also a (noisy:
   ``straight_r``) measurement of the bias, since the true rate of a straight drive averages
   zero. Unlike I, which moves by a fixed increment, these refine b and k slowly, the way a
   long average would; they are what lets the model learn k while the cabin warms.
4. **Speed gating**: below ``gate_speed_mps`` (manoeuvring, turning at a junction) I does not
   move; ``holdoff_steps`` keeps it frozen for a few steps after the turn switch opened.

The core is :mod:`hdrd.hdr`'s step with the same operations in the same order: with every
extra switched off (:meth:`HdrPlusParams.paper`) HDR+ is bit-identical to paper HDR. Its
default core parameters (``hdr``) differ from the paper's Table III: they were tuned together
with the extras on simulated training drives (bench/hdrplus.py; never on the test drives).

Two forms with bit-identical results: :func:`step` (immutable :class:`PlusState`) for the
daemon, :func:`run_batch` over arrays for offline tools.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from hdrd import zupt
from hdrd.hdr import INITIAL_STATE, HdrParams, HdrState
from hdrd.zupt import INITIAL_BIAS, BiasState, StandstillParams

__all__ = [
    "INITIAL_PLUS_STATE",
    "PLUS_CORE",
    "HdrPlusParams",
    "PlusInput",
    "PlusOutput",
    "PlusState",
    "PlusTrace",
    "run_batch",
    "step",
]

PLUS_CORE = HdrParams(i_c=0.0048, tau=0.5, theta_w=0.45, c1=0.14, c2=0.88)
"""HDR+'s core parameters, tuned with the extras on the simulated training drives."""


@dataclass(frozen=True, slots=True)
class HdrPlusParams:
    """HDR+ tunables. Every extra has an off switch; :meth:`paper` turns them all off."""

    hdr: HdrParams = PLUS_CORE
    """The HDR core (i_c deg/s, tau s, theta_w deg/s, c1, c2, T s; paper Table III names)."""
    standstill: StandstillParams = field(default_factory=StandstillParams)
    """Standstill detection and the variance of a standstill measurement."""
    bias_p0: float = 8e-5
    """Prior variance of b at start, (deg/s)^2: how well the start-up eps0 is trusted
    (a 1 s calibration of a 0.16 deg/s-noisy gyro at 10 Hz: about (0.05 deg/s)^2 = 2.5e-3)."""
    bias_q: float = 7e-8
    """Random walk of the bias left unexplained by the temperature model, (deg/s)^2/s."""
    bias_q_no_temp: float = 4e-5
    """The same when the temperature is unknown (the model cannot explain warming), (deg/s)^2/s."""
    temp_model: bool = True
    """Learn the temperature coefficient k (when a temperature is given)."""
    temp_coeff_sd: float = 0.01
    """Prior standard deviation of k, deg/s/degC (prior mean 0)."""
    straight_r: float = 0.27
    """Variance of a straight-driving bias measurement, (deg/s)^2 (swaying, slow curves);
    0 switches these measurements off."""
    straight_gate_dps: float = 0.93
    """Largest |u_c + I| of a step used as a straight-driving measurement, deg/s."""
    gate_speed_mps: float = 0.0
    """Below this known speed, m/s, I does not move and no straight measurement is taken
    (0 = off)."""
    holdoff_steps: int = 0
    """Steps after the turn switch opened (|y| > theta_w) during which I stays frozen."""
    adapt_gain: float = 0.0
    """Adaptive increment: I moves by max(i_c, adapt_gain * sd) per step (capped at
    i_c_max), sd the bias model's standard deviation at this temperature, deg/s
    (dimensionless; 0 = off, always i_c)."""
    i_c_max: float = 0.0422
    """Largest adaptive increment, deg/s (default: the paper's i_c)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("hdr", "standstill"):
                continue
            if f.type in ("bool", bool):
                object.__setattr__(self, f.name, bool(v))
            elif f.type in ("int", int):
                if int(v) < 0:
                    raise ValueError(f"{f.name} must be >= 0, got {v!r}")
                object.__setattr__(self, f.name, int(v))
            else:
                v = float(v)
                if not (math.isfinite(v) and v >= 0.0):
                    raise ValueError(f"{f.name} must be a number >= 0, got {v!r}")
                object.__setattr__(self, f.name, v)

    @classmethod
    def paper(cls, hdr: HdrParams | None = None) -> HdrPlusParams:
        """Every extra off: bit-identical to :func:`hdrd.hdr.step` with ``hdr``
        (default: the paper's Table III)."""
        return cls(
            hdr=HdrParams() if hdr is None else hdr,
            standstill=StandstillParams(enabled=False),
            temp_model=False,
            straight_r=0.0,
            gate_speed_mps=0.0,
            holdoff_steps=0,
            adapt_gain=0.0,
        )

    def with_(self, **kw: object) -> HdrPlusParams:
        """A copy with some fields replaced (``hdr`` and ``standstill`` by whole objects)."""
        return replace(self, **kw)  # type: ignore[arg-type]


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


class PlusState(NamedTuple):
    """State carried between steps. Immutable.

    core: the paper HDR state (x, I, yaw, r, s, n). bias: the bias model (:mod:`hdrd.zupt`).
    still: consecutive standstill-candidate steps. hold: hold-off steps left.
    """

    core: HdrState = INITIAL_STATE
    bias: BiasState = INITIAL_BIAS
    still: int = 0
    hold: int = 0


INITIAL_PLUS_STATE = PlusState()


class PlusOutput(NamedTuple):
    """What one step publishes.

    omega: corrected yaw rate, deg/s CCW (0 at standstill). yaw: deg CCW since start. I: the
    core's integrator applied in this step, deg/s. W, R, r, filtered: as :class:`hdrd.hdr.HdrOutput`
    (W = 0 at standstill and while gated). bias_corr_dps: the learned correction to eps0 at this
    step's temperature, deg/s (published bias = eps0 + bias_corr). standstill: this step was a
    zero-rate update. bias_sd_dps: standard deviation of b, deg/s. temp_coeff_dps_per_c: k.
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


def step(
    state: PlusState, inp: PlusInput, params: HdrPlusParams = HdrPlusParams()
) -> tuple[PlusState, PlusOutput]:
    """Advance HDR+ by one step of inp.T seconds. Pure."""
    hp = params.hdr
    T = float(inp.T)
    u = float(inp.u)
    temp = float(inp.temp_c)
    bias = zupt.init_bias(state.bias, params.bias_p0, params.temp_coeff_sd)
    have_temp = params.temp_model and not math.isnan(temp)
    if have_temp and math.isnan(bias.t_ref):
        bias = bias._replace(t_ref=temp)
    dT = temp - bias.t_ref if have_temp else 0.0
    bias = zupt.predict(bias, params.bias_q if have_temp else params.bias_q_no_temp, T)
    uc = u - zupt.correction(bias, dT)
    core = state.core
    spread = float(inp.spread_dps)
    speed = float(inp.speed_mps)

    cand, need = zupt.standstill_candidate(uc + core.I, spread, speed, params.standstill)
    still = state.still + 1 if cand else 0
    if cand and still >= need:
        # Zero-rate update: the true rate is 0, so u measures the bias itself. I is folded
        # into b first (omega = u - b + I = u - (b - I)), then b and k are refined.
        bias = bias._replace(b=bias.b - core.I)
        if still == need:
            # I, a sum of +-i_c steps, is only known to about one increment: the bias the
            # core tracked while driving is that uncertain when a stop begins.
            bias = bias._replace(p_bb=bias.p_bb + hp.i_c * hp.i_c)
        bias = zupt.update(bias, u, zupt.block_mean_variance(spread, params.standstill), dT)
        new_core = HdrState(x=0.0, I=0.0, yaw=core.yaw, r=1, s=0, n=core.n + 1)
        out = PlusOutput(
            omega=0.0,
            yaw=core.yaw,
            I=0.0,
            W=0,
            R=1.0,
            r=1,
            filtered=0.0,
            bias_corr_dps=zupt.correction(bias, dT),
            standstill=True,
            bias_sd_dps=math.sqrt(bias.p_bb),
            temp_coeff_dps_per_c=bias.k,
        )
        return PlusState(new_core, bias, still, 0), out

    # The paper's step (hdrd.hdr.step, same operations in the same order) on u_c.
    if hp.lowpass:
        x = (T * uc + hp.tau * core.x) / (T + hp.tau)
    else:
        x = uc
    I = core.I
    y = x + I
    omega = uc + I
    yaw = core.yaw + omega * T
    s = 1 if y > 0.0 else (-1 if y < 0.0 else 0)
    r = core.r + 1 if s == core.s else 1
    R = (1.0 + hp.c1) / (1.0 + hp.c1 * math.pow(r, hp.c2)) if hp.attenuator else 1.0
    W = 1 if (not hp.turn_switch or abs(y) <= hp.theta_w) else 0
    hold = state.hold
    if params.holdoff_steps:
        if not abs(y) <= hp.theta_w:
            hold = params.holdoff_steps
        elif hold > 0:
            W = 0
            hold -= 1
    if params.gate_speed_mps > 0.0 and speed < params.gate_speed_mps:
        W = 0
    i_c = hp.i_c
    if params.adapt_gain > 0.0:
        sd = math.sqrt(bias.p_bb + dT * (2.0 * bias.p_bk + dT * bias.p_kk))
        i_c = min(params.i_c_max, max(i_c, params.adapt_gain * sd))
    I_next = I - s * W * R * i_c if hp.enabled else 0.0
    if params.straight_r > 0.0 and W and abs(uc + I) <= params.straight_gate_dps:
        bias = zupt.update(bias, u, params.straight_r, dT)
    out = PlusOutput(
        omega=omega,
        yaw=yaw,
        I=I,
        W=W,
        R=R,
        r=r,
        filtered=y,
        bias_corr_dps=zupt.correction(bias, dT),
        standstill=False,
        bias_sd_dps=math.sqrt(bias.p_bb),
        temp_coeff_dps_per_c=bias.k,
    )
    return PlusState(
        HdrState(x=x, I=I_next, yaw=yaw, r=r, s=s, n=core.n + 1), bias, still, hold
    ), out


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

    Bit-identical to calling :func:`step` in a loop: the same operations in the same order,
    written out with local floats (the recursion is sequential; tuning needs the speed).
    """
    uu = np.asarray(u, dtype=np.float64)
    n = uu.shape[0]
    u_l = uu.tolist()
    spread_l = _column(spread, n, "spread")
    speed_l = _column(speed, n, "speed")
    temp_l = _column(temp, n, "temp")
    T_l = _column(params.hdr.T if T is None else T, n, "T")
    o_omega = np.empty(n)
    o_yaw = np.empty(n)
    o_I = np.empty(n)
    o_W = np.empty(n, np.int8)
    o_R = np.empty(n)
    o_r = np.empty(n, np.int64)
    o_y = np.empty(n)
    o_corr = np.empty(n)
    o_still = np.empty(n, np.bool_)
    o_sd = np.empty(n)
    o_k = np.empty(n)

    hp = params.hdr
    ss = params.standstill
    tau, theta_w, c1, c2, i_c = hp.tau, hp.theta_w, hp.c1, hp.c2, hp.i_c
    lowpass, turn_switch, attenuator, enabled = (
        hp.lowpass,
        hp.turn_switch,
        hp.attenuator,
        hp.enabled,
    )
    temp_model, q_t, q_nt = params.temp_model, params.bias_q, params.bias_q_no_temp
    straight_r, straight_gate = params.straight_r, params.straight_gate_dps
    gate_speed, holdoff = params.gate_speed_mps, params.holdoff_steps
    adapt_gain, i_c_max = params.adapt_gain, params.i_c_max
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
    bias0 = zupt.init_bias(state.bias, params.bias_p0, params.temp_coeff_sd)
    b, k, p_bb, p_bk, p_kk, t_ref = bias0
    core = state.core
    x, I, yaw, r, s_prev, n0 = core.x, core.I, core.yaw, core.r, core.s, core.n
    still, hold = state.still, state.hold
    isnan, sqrt, pow_ = math.isnan, math.sqrt, math.pow

    for i in range(n):
        T_i = T_l[i]
        ui = u_l[i]
        te = temp_l[i]
        have_temp = temp_model and not isnan(te)
        if have_temp and isnan(t_ref):
            t_ref = te
        dT = te - t_ref if have_temp else 0.0
        p_bb = p_bb + (q_t if have_temp else q_nt) * T_i
        uc = ui - (b + k * dT)
        sp = spread_l[i]
        v = speed_l[i]
        # zupt.standstill_candidate, inline
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
        still = still + 1 if cand else 0
        if cand and still >= need:
            b = b - I
            if still == need:
                p_bb = p_bb + i_c * i_c
            s_ = ss_spread if isnan(sp) else sp
            b, k, p_bb, p_bk, p_kk = _update(
                b, k, p_bb, p_bk, p_kk, ui, (s_ * s_ + floor2) / nsamp, dT
            )
            x, I, r, s_prev, hold = 0.0, 0.0, 1, 0, 0
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
            continue
        x = (T_i * uc + tau * x) / (T_i + tau) if lowpass else uc
        y = x + I
        omega = uc + I
        yaw = yaw + omega * T_i
        s = 1 if y > 0.0 else (-1 if y < 0.0 else 0)
        r = r + 1 if s == s_prev else 1
        R = (1.0 + c1) / (1.0 + c1 * pow_(r, c2)) if attenuator else 1.0
        W = 1 if (not turn_switch or abs(y) <= theta_w) else 0
        if holdoff:
            if not abs(y) <= theta_w:
                hold = holdoff
            elif hold > 0:
                W = 0
                hold -= 1
        if gate_speed > 0.0 and v < gate_speed:
            W = 0
        inc = i_c
        if adapt_gain > 0.0:
            sd = sqrt(p_bb + dT * (2.0 * p_bk + dT * p_kk))
            inc = min(i_c_max, max(inc, adapt_gain * sd))
        I_next = I - s * W * R * inc if enabled else 0.0
        if straight_r > 0.0 and W and abs(uc + I) <= straight_gate:
            b, k, p_bb, p_bk, p_kk = _update(b, k, p_bb, p_bk, p_kk, ui, straight_r, dT)
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
        I = I_next
        s_prev = s
    if n == 0:  # as a loop of step() that never ran: not even the prior is set
        return PlusTrace(o_omega, o_yaw, o_I, o_W, o_R, o_r, o_y, o_corr, o_still, o_sd, o_k, state)
    final = PlusState(
        HdrState(x=x, I=I, yaw=yaw, r=r, s=s_prev, n=n0 + n),
        BiasState(b, k, p_bb, p_bk, p_kk, t_ref),
        still,
        hold,
    )
    return PlusTrace(o_omega, o_yaw, o_I, o_W, o_R, o_r, o_y, o_corr, o_still, o_sd, o_k, final)


def _update(
    b: float, k: float, p_bb: float, p_bk: float, p_kk: float, z: float, r: float, dT: float
) -> tuple[float, float, float, float, float]:
    """:func:`hdrd.zupt.update` on plain floats (same operations)."""
    ph0 = p_bb + dT * p_bk
    ph1 = p_bk + dT * p_kk
    s = ph0 + dT * ph1 + r
    k0 = ph0 / s
    k1 = ph1 / s
    innov = z - (b + k * dT)
    return b + k0 * innov, k + k1 * innov, p_bb - k0 * ph0, p_bk - k0 * ph1, p_kk - k1 * ph1
