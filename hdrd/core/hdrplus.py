"""HDR+: one estimator that owns the heading and the bias, pure.

A bank of Kalman filters (:class:`hdrd.core.kalman.Bank`, an interacting multiple model), one
per kind of unit (:class:`hdrd.core.plusparams.Hypothesis`), each over the same states:

- ``YAW``: the yaw, deg CCW since start (the heading published is heading0 - yaw);
- ``BIAS``: the driving bias minus the start-up static bias eps0 (paper Eq. 2), deg/s;
- ``OFFSET``: the bias at rest minus the driving bias, deg/s: what a stop reads that driving
  does not (a motion offset, with the sign turned; the output's rounding at rest);
- ``STOP``: this stop's own offset, deg/s (each stop reads a little differently);
- ``ROAD``: the yaw rate of the road's gentle curves on a straight step, deg/s;
- ``TEMP``: the bias's temperature coefficient, deg/s/degC (while a temperature is known).

One step of T seconds on u = block mean - eps0 (deg/s CCW, Eqs. 2, 11): time passes (the yaw
integrates u minus the driving bias, except at a stop, where the vehicle does not turn);
then each measurement is an update of every member with its own row h and variance R, and
weighs the members by how well each predicted it:

- a *stop* (a zero-rate update: :func:`hdrd.core.standstill.standstill_candidate` for
  ``steps_speed`` steps running, and the step's level within the stop gate) measures
  BIAS + OFFSET + STOP (+ TEMP dT);
- a step of *driving* that is not a stop measures BIAS + ROAD (+ TEMP dT) -- the paper's
  heuristic that roads are mostly straight, as a likelihood that knows roads curve: a
  straight step (``ROAD_MODEL.p_straight``) or a curve, each step weighted by which it looks like;
- a *GPS course* (from the aiding stage, at the end of the step before) measures YAW; the
  heading aligned anew restarts YAW's error at the course's variance.

The calibration window is the prior: BIAS + OFFSET is eps0's error (var(eps0)), OFFSET the
member's motion offset prior plus what the output's rounding hides at rest. Published: the
combined yaw and its sd (``heading_sd``), omega = u - the driving bias (0 at a stop), the
driving bias's correction and its sd, the rest offset. docs/hdrplus.md has the reasoning and
says which effect enters which state.

:func:`step` (immutable :class:`PlusState`, the daemon's) and :func:`run_batch` (arrays,
evaluate's) run the same code (:class:`_Estimator`), so they agree to the bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from hdrd.core.kalman import Bank, Filter, Row, log_likelihood
from hdrd.core.plusparams import (
    DEFAULTS,
    EVIDENCE_WEIGHT,
    GATE_FLOOR_DPS,
    ROAD_MODEL,
    STOP_FLOOR_DPS,
    STOP_GATE_SIGMA,
    SWITCH_P,
    TURN_ERR,
    PlusParams,
)
from hdrd.core.standstill import block_mean_variance, standstill_candidate
from hdrd.core.steps import StepInput, per_step

__all__ = [
    "BIAS",
    "INITIAL_PLUS_STATE",
    "OFFSET",
    "PlusOutput",
    "PlusParams",
    "PlusState",
    "PlusTrace",
    "YAW",
    "motion_offset",
    "prior_filters",
    "run_batch",
    "step",
]

YAW, BIAS, OFFSET, STOP, ROAD, TEMP = range(6)
N_STATES = 6

_H_YAW = ((YAW, 1.0),)
_H_BIAS = ((BIAS, 1.0),)
_H_OFFSET = ((OFFSET, 1.0),)


class PlusState(NamedTuple):
    """State carried between steps. Immutable.

    xs, Ps: each member's state and covariance (tuples); empty before the first step (the
    prior is built then, from the settings). mu: the members' probabilities. still:
    consecutive standstill-candidate steps. in_stop: the last step was a stop. t_ref: the
    first temperature seen, degC (NaN: none yet). u_prev: the last step's input, deg/s (NaN
    before one). yaw: the yaw published at the last step, deg CCW (what a GPS course's
    measurement is relative to). aided: the heading has been aligned to a GPS course.
    stop_n, stop_mean, stop_m2: the readings of the stop in progress (count, mean deg/s, sum
    of squared deviations (deg/s)^2: Welford's), how much they scatter from step to step.
    """

    xs: tuple[tuple[float, ...], ...] = ()
    Ps: tuple[tuple[tuple[float, ...], ...], ...] = ()
    mu: tuple[float, ...] = ()
    still: int = 0
    in_stop: bool = False
    t_ref: float = math.nan
    u_prev: float = math.nan
    yaw: float = 0.0
    aided: bool = False
    stop_n: int = 0
    stop_mean: float = 0.0
    stop_m2: float = 0.0


INITIAL_PLUS_STATE = PlusState()


class PlusOutput(NamedTuple):
    """What one step publishes.

    omega: the corrected yaw rate, deg/s CCW (0 at a stop). yaw: deg CCW since start.
    heading_sd_deg: the yaw's (so the heading's) standard deviation, deg. bias_corr_dps: the
    driving bias's correction to eps0 at this step's temperature, deg/s (published bias =
    eps0 + this). bias_sd_dps: its sd. offset_dps: the estimated motion offset (driving bias
    minus rest bias), deg/s. standstill: this step was a zero-rate update. straight: the
    weight with which the step counted as straight road (0 at a stop or a course). weights:
    each member's probability after the step.
    """

    omega: float
    yaw: float
    heading_sd_deg: float
    bias_corr_dps: float
    bias_sd_dps: float
    offset_dps: float
    standstill: bool
    straight: float
    weights: tuple[float, ...]


def prior_filters(p: PlusParams, yaw: float = 0.0) -> list[Filter]:
    """Each member's filter at the end of the start-up calibration (module docstring)."""
    out = []
    for h in p.bank:
        x = [0.0] * N_STATES
        P = [[0.0] * N_STATES for _ in range(N_STATES)]
        x[YAW] = yaw
        x[OFFSET] = -h.offset_dps  # rest minus driving
        x[BIAS] = h.offset_dps
        vc = h.offset_sd_dps**2 + p.quant_var
        P[OFFSET][OFFSET] = vc
        P[BIAS][BIAS] = vc + p.bias_p0
        P[BIAS][OFFSET] = P[OFFSET][BIAS] = -vc
        P[ROAD][ROAD] = ROAD_MODEL.sd_dps**2
        P[TEMP][TEMP] = p.temp_coeff_sd**2
        out.append(Filter(x, P))
    return out


class _Estimator:
    """The estimator on mutable members: :func:`step` runs one step of it from a state,
    :func:`run_batch` many; the phases are its methods."""

    def __init__(self, state: PlusState, p: PlusParams) -> None:
        self.p = p
        m = len(p.bank)
        if len(state.xs) == m:
            fs = [Filter(x, P) for x, P in zip(state.xs, state.Ps)]
            mu = list(state.mu)
        else:  # the first step, or a bank of another size (a reconfigured daemon)
            fs = prior_filters(p, state.yaw)
            mu = [h.prior for h in p.bank]
            total = sum(mu)
            mu = [w / total for w in mu]
        self.tilt = [h.share / h.prior for h in p.bank]  # decision -> population weights
        s = SWITCH_P if m > 1 else 0.0
        M = [[1.0 - s if i == j else s / (m - 1) for j in range(m)] for i in range(m)]
        self.bank = Bank(fs, mu, M)
        self.still, self.in_stop = state.still, state.in_stop
        self.t_ref, self.u_prev = state.t_ref, state.u_prev
        self.yaw, self.aided = state.yaw, state.aided
        self.stop_n, self.stop_mean, self.stop_m2 = state.stop_n, state.stop_mean, state.stop_m2
        self.road_a = math.exp(-p.T / ROAD_MODEL.tau_s)
        self.road_q = ROAD_MODEL.sd_dps**2 * (1.0 - self.road_a**2)

    def state(self) -> PlusState:
        fs = self.bank.filters
        return PlusState(
            tuple(tuple(f.x) for f in fs),
            tuple(tuple(tuple(r) for r in f.P) for f in fs),
            tuple(self.bank.mu),
            self.still,
            self.in_stop,
            self.t_ref,
            self.u_prev,
            self.yaw,
            self.aided,
            self.stop_n,
            self.stop_mean,
            self.stop_m2,
        )

    def advance(
        self,
        u: float,
        spread: float,
        speed: float,
        temp_c: float,
        T: float,
        course_err: float = math.nan,
        course_var: float = math.nan,
        reset: bool = False,
    ) -> PlusOutput:
        """One step of T seconds: u deg/s CCW, the samples' spread deg/s, speed m/s, temp_c
        degC (NaN = unknown); a GPS course's measurement of the heading error at the end of
        the step before (course_err deg, variance course_var deg^2; NaN: none), the heading
        aligned anew before it (reset)."""
        dtemp = self.temperature(temp_c)
        loglik = [0.0] * len(self.bank.filters)
        measured = course_err == course_err
        if reset or measured:
            self.course(course_err, course_var, reset, loglik)
        self.bank.transition()
        h_bias = ((BIAS, 1.0), (TEMP, dtemp))
        corr = self.bank.mean(h_bias)
        zero = self.standstill_test(u - corr, spread, speed, dtemp) and self.p.measure
        self.predict(u, spread, T, dtemp, corr, zero)
        straight = 0.0
        if zero:
            self.stop_update(u, spread, dtemp, loglik)
        elif not measured and self.p.measure:
            straight = self.road_update(u, dtemp, loglik)
        ew = EVIDENCE_WEIGHT
        self.bank.weigh([ew * ll for ll in loglik])
        self.u_prev = u
        return self.output(u, dtemp, zero, straight)

    # -- the phases ----------------------------------------------------------------------

    def temperature(self, temp_c: float) -> float:
        """degC above the first temperature seen; 0 without one."""
        if temp_c != temp_c:
            return 0.0
        if self.t_ref != self.t_ref:
            self.t_ref = temp_c
        return temp_c - self.t_ref

    def course(
        self, course_err: float, course_var: float, reset: bool, loglik: list[float]
    ) -> None:
        """A GPS course at the end of the step before: the true yaw was the published one plus
        course_err (the published heading minus the course; compass degrees turn the other way);
        reset: the heading was aligned anew, its error restarts at the course's variance."""
        var = course_var if course_var > 0.0 else 0.0
        if reset:
            for f in self.bank.filters:
                for i in range(N_STATES):
                    f.P[YAW][i] = f.P[i][YAW] = 0.0
                f.P[YAW][YAW] = var
                f.x[YAW] = self.yaw
            self.aided = True
        if course_err == course_err and self.aided and var > 0.0:
            z = self.yaw + course_err
            for k, f in enumerate(self.bank.filters):
                inn = f.update(z, _H_YAW, var)
                loglik[k] += log_likelihood(inn.nu, inn.S)

    def standstill_test(self, level: float, spread: float, speed: float, dtemp: float) -> bool:
        """A zero-rate update? A standstill candidate (:func:`hdrd.core.standstill.
        standstill_candidate`) whose corrected level is within ``STOP_GATE_SIGMA`` of what the
        bank allows at rest, for ``steps_speed`` (or ``steps_gyro``) steps running."""
        p = self.p
        cand, need = standstill_candidate(level, spread, speed, p.standstill)
        if cand:
            rest = ((BIAS, 1.0), (OFFSET, 1.0), (TEMP, dtemp))
            allow = self.bank.var(rest) + p.stop_scatter_dps**2 + GATE_FLOOR_DPS**2
            bvar = (
                p.block_var
                if p.block_var == p.block_var
                else block_mean_variance(spread, p.standstill)
            )
            cand = abs(level - self.bank.mean(_H_OFFSET)) <= STOP_GATE_SIGMA * math.sqrt(
                allow + bvar
            )
        self.still = self.still + 1 if cand else 0
        return cand and self.still >= need

    def predict(
        self, u: float, spread: float, T: float, dtemp: float, corr: float, zero: bool
    ) -> None:
        """Let T pass in every member: the driving bias's random walk, the road's decay, and
        -- unless the vehicle stands -- the yaw integrating u minus the bias, with the noise
        of what the bias does not explain (module docstring)."""
        p = self.p
        a = self.road_a if T == p.T else math.exp(-T / ROAD_MODEL.tau_s)
        q_road = self.road_q if T == p.T else ROAD_MODEL.sd_dps**2 * (1.0 - a * a)
        rows: dict[int, Row] = {ROAD: ((ROAD, a),)}
        q_yaw = 0.0
        if not zero:
            rows[YAW] = ((YAW, 1.0), (BIAS, -T), (TEMP, -T * dtemp))
            q_yaw = self.heading_noise(u - corr, u, spread, T)
        new_stop = zero and not self.in_stop
        self.in_stop = zero
        if new_stop or not zero:
            self.stop_n, self.stop_mean, self.stop_m2 = 0, 0.0, 0.0
        for h, f in zip(self.p.bank, self.bank.filters):
            if h.drift_tau_s < math.inf:  # a bounded wander about the member's offset
                ab = math.exp(-T / h.drift_tau_s)
                f.x[BIAS] -= h.offset_dps
                f.predict(
                    {**rows, BIAS: ((BIAS, ab),)},
                    (
                        (BIAS, BIAS, h.drift_q * h.drift_tau_s / 2.0 * (1.0 - ab * ab)),
                        (ROAD, ROAD, q_road),
                        (YAW, YAW, q_yaw),
                    ),
                )
                f.x[BIAS] += h.offset_dps
            else:
                f.predict(
                    rows, ((BIAS, BIAS, h.drift_q * T), (ROAD, ROAD, q_road), (YAW, YAW, q_yaw))
                )
            if not zero:
                f.x[YAW] += T * u
            if new_stop:  # each stop reads with an offset of its own
                for i in range(N_STATES):
                    f.P[STOP][i] = f.P[i][STOP] = 0.0
                f.x[STOP] = 0.0
                f.P[STOP][STOP] = p.stop_scatter_dps**2

    def heading_noise(self, u_corr: float, u: float, spread: float, T: float) -> float:
        """What a step of driving adds to the yaw's variance beside the bias, deg^2: the rate
        noise integrated (a step's variance at rest x T^2), ``TURN_ERR`` of the angle turned,
        a turn's onset between samples that a point-sampled gyro misses (the rate's change
        x T / (2 x samples per step)), and a bias wander too fast to follow."""
        p = self.p
        bvar = p.block_var
        if bvar != bvar:
            bvar = block_mean_variance(spread, p.standstill) if spread == spread else 0.0
        turned = TURN_ERR * u_corr * T
        q = bvar * T * T + turned * turned + p.heading_q * T
        if self.u_prev == self.u_prev:
            onset = (u - self.u_prev) * T / (2.0 * p.standstill.samples_per_step)
            q += onset * onset
        return q

    def stop_update(self, u: float, spread: float, dtemp: float, loglik: list[float]) -> None:
        """A zero-rate update: u measures what a stop reads, BIAS + OFFSET + STOP (+ TEMP
        dtemp), of a step's variance at rest: the largest of the calibration's, the step's own
        spread's, how the stop's readings scatter from step to step so far (the samples of a
        band-limited gyro and an idling engine's vibration are correlated within a step), and
        ``STOP_FLOOR_DPS``^2 -- which a stop's first steps, before they show their scatter,
        take times four."""
        p = self.p
        self.stop_n += 1
        d = u - self.stop_mean
        self.stop_mean += d / self.stop_n
        self.stop_m2 += d * (u - self.stop_mean)
        floor = STOP_FLOOR_DPS**2
        r_var = max(
            block_mean_variance(spread, p.standstill), floor if self.stop_n >= 3 else 4.0 * floor
        )
        if p.block_var == p.block_var and p.block_var > r_var:
            r_var = p.block_var
        if self.stop_n >= 3:
            r_var = max(r_var, self.stop_m2 / (self.stop_n - 1))
        h = ((BIAS, 1.0), (OFFSET, 1.0), (STOP, 1.0), (TEMP, dtemp))
        for k, f in enumerate(self.bank.filters):
            inn = f.update(u, h, r_var)
            loglik[k] += log_likelihood(inn.nu, inn.S)

    def road_update(self, u: float, dtemp: float, loglik: list[float]) -> float:
        """A step of driving: u measures BIAS + ROAD (+ TEMP dtemp) if the road is straight, with
        ``sway_var``; a curve adds ``curve_var``. Each member weighs the two by its own
        innovation and updates as far as the step looks straight; the mixture's likelihood
        is its evidence. Returns the bank's weight of "straight"."""
        road = ROAD_MODEL
        h = ((BIAS, 1.0), (ROAD, 1.0), (TEMP, dtemp))
        ls0 = math.log(road.p_straight)
        lc0 = math.log(1.0 - road.p_straight) if road.p_straight < 1.0 else -math.inf
        straight = 0.0
        for k, f in enumerate(self.bank.filters):
            inn = f.innovation(u, h, road.sway_var)
            ls = ls0 + log_likelihood(inn.nu, inn.S)
            lc = (
                lc0 + log_likelihood(inn.nu, inn.S + road.curve_var)
                if lc0 > -math.inf
                else -math.inf
            )
            top = max(ls, lc)
            total = top + math.log(math.exp(ls - top) + math.exp(lc - top))
            w = math.exp(ls - total)
            if w > 1e-3:
                f.update(u, h, road.sway_var / w)
            loglik[k] += total
            straight += self.bank.mu[k] * w
        return straight

    def output(self, u: float, dtemp: float, zero: bool, straight: float) -> PlusOutput:
        """The bank's combined estimate after the step."""
        b = self.bank
        h_bias = ((BIAS, 1.0), (TEMP, dtemp))
        corr = b.mean(h_bias)
        yaw = b.mean(_H_YAW)
        self.yaw = yaw
        omega = 0.0 if zero else u - corr
        return PlusOutput(
            omega,
            yaw,
            math.sqrt(self.heading_var(yaw)),
            corr,
            math.sqrt(b.var(h_bias)),
            -b.mean(_H_OFFSET),
            zero,
            straight,
            tuple(b.mu),
        )

    def heading_var(self, yaw: float) -> float:
        """The published yaw's variance, deg^2, over the members weighted as common as their
        kinds are (:attr:`hdrd.core.plusparams.Hypothesis.share`) given the evidence so far:
        each member's own variance and its distance from the yaw published."""
        w = [m * t for m, t in zip(self.bank.mu, self.tilt)]
        total = sum(w)
        var = 0.0
        for wi, f in zip(w, self.bank.filters):
            d = f.x[YAW] - yaw
            var += wi * (f.P[YAW][YAW] + d * d)
        return var / total if total > 0.0 else 0.0


def motion_offset(state: PlusState) -> tuple[float, float]:
    """(the motion offset, its sd), deg/s, a state's bank holds: the driving bias minus the
    rest bias, combined over the members; (NaN, NaN) before the first step."""
    if not state.xs:
        return math.nan, math.nan
    fs = [Filter(x, P) for x, P in zip(state.xs, state.Ps)]
    bank = Bank(fs, state.mu, [[1.0]])
    return -bank.mean(_H_OFFSET), math.sqrt(bank.var(_H_OFFSET))


def step(
    state: PlusState, inp: StepInput, params: PlusParams = DEFAULTS
) -> tuple[PlusState, PlusOutput]:
    """Advance HDR+ by one step of inp.T seconds. Pure (the same code as :func:`run_batch`)."""
    run = _Estimator(state, params)
    u, spread, speed, temp_c, T, course_err, course_var, reset = (float(x) for x in inp)
    out = run.advance(u, spread, speed, temp_c, T, course_err, course_var, bool(reset))
    return run.state(), out


@dataclass(frozen=True)
class PlusTrace:
    """Every step's output of a batch run, as arrays (one element per step), and the final
    state. weights: steps x members."""

    omega: npt.NDArray[np.float64]
    yaw: npt.NDArray[np.float64]
    heading_sd_deg: npt.NDArray[np.float64]
    bias_corr_dps: npt.NDArray[np.float64]
    bias_sd_dps: npt.NDArray[np.float64]
    offset_dps: npt.NDArray[np.float64]
    standstill: npt.NDArray[np.bool_]
    straight: npt.NDArray[np.float64]
    weights: npt.NDArray[np.float64]
    final: PlusState


def run_batch(
    u: npt.ArrayLike,
    spread: npt.ArrayLike | None = None,
    speed: npt.ArrayLike | None = None,
    temp: npt.ArrayLike | None = None,
    T: npt.ArrayLike | None = None,
    params: PlusParams = DEFAULTS,
    state: PlusState = INITIAL_PLUS_STATE,
    heading_err: npt.ArrayLike | None = None,
    heading_err_var: npt.ArrayLike | None = None,
    heading_reset: npt.ArrayLike | None = None,
) -> PlusTrace:
    """Run HDR+ over arrays of steps: u (deg/s), spread (deg/s), speed (m/s), temp (degC),
    each per step or None (unknown throughout), T a scalar or per step (None: params.T); GPS
    courses' measurements of the heading error (deg, NaN where none), their variances (deg^2)
    and where the heading was aligned anew (:class:`hdrd.core.steps.StepInput`), or None (no
    GPS). :func:`step` looped, without building a state between steps (the same code)."""
    uu = np.asarray(u, dtype=np.float64)
    n = uu.shape[0]
    cols = [
        uu.tolist(),
        per_step(spread, n, "spread"),
        per_step(speed, n, "speed"),
        per_step(temp, n, "temp"),
        per_step(params.T if T is None else T, n, "T"),
    ]
    if heading_err is not None or heading_reset is not None:
        cols.append(per_step(heading_err, n, "heading_err"))
        cols.append(per_step(heading_err_var, n, "heading_err_var"))
        resets = [False] * n if heading_reset is None else per_step(heading_reset, n, "reset")
        cols.append([bool(r) for r in resets])
    m = len(params.bank)
    if n == 0:  # nothing ran: not even the prior is set
        e = np.empty(0)
        return PlusTrace(e, e, e, e, e, e, np.empty(0, bool), e, np.empty((0, m)), state)
    run = _Estimator(state, params)
    rows = [run.advance(*row) for row in zip(*cols, strict=True)]
    c = list(zip(*rows, strict=True))

    def f(i: int) -> npt.NDArray[np.float64]:
        return np.array(c[i], dtype=np.float64)

    return PlusTrace(
        f(0), f(1), f(2), f(3), f(4), f(5),
        standstill=np.array(c[6], dtype=np.bool_),
        straight=f(7),
        weights=np.array(c[8], dtype=np.float64).reshape(n, m),
        final=run.state(),
    )  # fmt: skip
