"""HDR+: the paper's HDR kept as a core, under a Kalman model of the bias that adapts to the gyro.

Pure. One step per period T on HDR's input, u_i = block mean - eps0 (paper Eqs. 2, 11),
deg/s, + = CCW, plus what HDR does not use: the samples' spread, the speed, the temperature
(each NaN when unknown) and, with GPS aiding, a course's measurement of the heading error.
docs/hdrplus.md has the reasoning and the measurements behind every default.

1. **Bias model** (:mod:`hdrd.core.biasbank`): Kalman filters of the bias b, the standstill
   offset c, the temperature coefficient k, the road's gentle curvature r and the heading
   error psi; the HDR core runs on u_c = u - (b + k dT). The filters form a bank of
   hypotheses that is data (:attr:`HdrPlusParams.bank`): a stable and a drifting gyro
   weighed by evidence (stops, straight steps) without an error model; one, of the model's
   random walk, with it; with a temperature the last member alone.
2. **The core's increment follows the bias uncertainty**: ``ic_alpha`` x the bias sd (capped
   at ``i_c_max``), with a bank only while "drifting" weighs at least half.
3. **Standstill (zero-rate) updates** publish omega = 0, fold I into b and measure b + c.
4. **Straight-driving measurements**: a step the turn switch lets I move (W = 1), its rate
   within ``straight_gate_dps``, measures b + r.
5. **GPS**: once aligned, each course measures psi (the one owner of bias and heading error;
   docs/hdrplus.md, "GPS: one estimator").

Settings: :mod:`hdrd.core.plusparams` (what a gyro's fit sets, the bank, the constants).
:func:`step` (immutable :class:`PlusState`, the daemon's) and :func:`run_batch` (arrays,
evaluate's) run the same code (:class:`_Run`), so they agree to the bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from hdrd.core import biasbank as bb
from hdrd.core.biasbank import INITIAL_BANK, BankState, Filter
from hdrd.core.hdr import INITIAL_STATE, HdrState, kernel
from hdrd.core.plusparams import DEFAULTS, HdrPlusParams
from hdrd.core.standstill import block_mean_variance, standstill_candidate
from hdrd.core.steps import StepInput, per_step

__all__ = [
    "INITIAL_PLUS_STATE",
    "HdrPlusParams",
    "PlusOutput",
    "PlusState",
    "PlusTrace",
    "run_batch",
    "step",
]


class PlusState(NamedTuple):
    """State carried between steps. Immutable.

    core: the paper HDR state (x, I, yaw, r, s, n). bank: the bias model
    (:class:`hdrd.core.biasbank.BankState`). still: consecutive standstill-candidate steps.
    aided: the heading has been aligned to a GPS course (its error is then tracked and
    corrected every step, whatever the bank). u_prev: the last step's input, deg/s (NaN
    before one), for what a turn's onset adds to the heading's error.
    """

    core: HdrState = INITIAL_STATE
    bank: BankState = INITIAL_BANK
    still: int = 0
    aided: bool = False
    u_prev: float = math.nan


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
    the weight of the bank's last, most drifting member (1 with one). heading_fix_deg: the
    heading correction made in this step, deg CCW.
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
    """A step's correction in force (after predict): ws the members' weights ([1] when not
    mixing); corrs each member's b + k dT, deg/s, and corr their weighted mean; inc the core's
    increment, deg/s; qs the random walks in force, (deg/s)^2/s; mixing: the bank weighs its
    members this step (several, and no temperature)."""

    ws: list[float]
    corrs: list[float]
    corr: float
    inc: float
    qs: list[float]
    mixing: bool


class _Run:
    """The filter on mutable locals: :func:`step` runs one step of it from a state,
    :func:`run_batch` many. :meth:`advance` calls the phases in order (predict, mixture,
    standstill test, then a standstill or a driving update, heading fix, output); each phase
    is a method below. Any change here changes both forms alike."""

    def __init__(self, state: PlusState, p: HdrPlusParams) -> None:
        self.p, self.t, self.f = p, p.tuning, p.fit
        c = state.core
        self.x, self.I, self.yaw, self.r, self.s, self.n = c.x, c.I, c.yaw, c.r, c.s, c.n
        self.still = state.still
        self.aided = state.aided
        self.u_prev = state.u_prev
        self.measured = False  # a GPS course measured the heading error in this step
        self.need = 0  # consecutive candidates the current standstill test asks for
        q = self.f.quant_step_dps
        self.q2 = q * q / 12.0
        k = state.bank
        n = len(p.bank)
        # A state from another bank (a reconfigured daemon): members are matched from the
        # last (the one in force with a known model); the others start from the prior.
        have = k.filters[-n:] if k.filters else ()
        init = bb.prior(self.f.bias_p0 + self.q2, self.f.stop_offset_var,
                        self.f.temp_coeff_sd**2, self.t.road_var)  # fmt: skip
        fs = [init] * (n - len(have)) + list(have)
        self.xs = [list(f.x) for f in fs]
        self.Ps = [list(f.P) for f in fs]
        p0 = p.bank[0].prior
        lo = [math.log(h.prior / p0) for h in p.bank]
        lo[0] = 0.0
        keep = k.log_odds[-n:] if len(k.log_odds) >= n else ()
        self.lo = [0.0, *keep[1:]] if keep else lo
        self.t_ref = k.t_ref
        self.qs = [h.q for h in p.bank]  # the members' random walks without a temperature
        self.qs_temp = [*self.qs[:-1], self.f.bias_q]  # ... and with one
        self.road_a = math.nan  # the road's decay over the last T (cached)
        self.road_T = math.nan

    def state(self) -> PlusState:
        core = HdrState(x=self.x, I=self.I, yaw=self.yaw, r=self.r, s=self.s, n=self.n)
        filters = tuple(Filter(tuple(x), tuple(P)) for x, P in zip(self.xs, self.Ps))
        bank = BankState(filters, tuple(self.lo), self.t_ref)
        return PlusState(core, bank, self.still, self.aided, self.u_prev)

    def advance(
        self,
        u: float,
        sp: float,
        v: float,
        te: float,
        T: float,
        herr: float = math.nan,
        hvar: float = math.nan,
        reset: bool = False,
    ) -> PlusOutput:
        """One step of T seconds: u deg/s CCW, the samples' spread sp deg/s, speed v m/s,
        temperature te degC (NaN = unknown); a GPS course's measurement of the heading error
        at the step before (herr deg, of variance hvar deg^2; NaN: none), the heading aligned
        anew before it (reset)."""
        dT, have_temp = self.temperature(te)
        self.measured = herr == herr  # a GPS course measures the heading error this step
        if reset or self.measured:
            self.aid(herr, hvar, reset)
        mix = self.predict(T, dT, have_temp)
        zero = self.standstill_test(u - mix.corr, sp, v, mix)
        if zero:
            out = self.standstill_update(u, sp, dT, mix)
        else:
            out = self.driving_update(u, sp, T, dT, mix)
        self.u_prev = u
        heading = self.heading_fix(mix) if mix.mixing or self.aided else 0.0
        m = self.t.drift_odds_max
        lo = self.lo
        for i in range(1, len(lo)):
            lo[i] = min(max(lo[i], -m), m)
        return self.output(out, zero, dT, mix, heading)

    # -- the phases ------------------------------------------------------------------------

    def aid(self, herr: float, hvar: float, reset: bool) -> None:
        """A GPS course: the heading aligned anew (psi restarts at 0, of variance hvar), and/or
        a measurement of psi, herr deg of variance hvar, moving each member's bias by their
        covariance; it does the integrator's work (I folded into b, b - I unchanged). Not
        weighed as evidence: each course corrects the heading the next is compared with, so
        the innovations would count only the members' spreads (docs/hdrplus.md)."""
        var = hvar if hvar > 0.0 else 0.0
        if reset:
            for x, P in zip(self.xs, self.Ps):
                bb.reset_heading(x, P, var)
            self.aided = True
        if herr == herr and self.aided:
            for x, P in zip(self.xs, self.Ps):
                x[bb.B] -= self.I
                bb.update_heading(x, P, herr, var)
            self.I = 0.0

    def temperature(self, te: float) -> tuple[float, bool]:
        """(dT, a temperature is used): degC above the first one seen, 0 without."""
        have_temp = not math.isnan(te)
        if have_temp and math.isnan(self.t_ref):
            self.t_ref = te
        return (te - self.t_ref if have_temp else 0.0), have_temp

    def predict(self, T: float, dT: float, have_temp: bool) -> _Mix:
        """Let T pass (the random walks, the road's decay) and weigh the bank: the correction
        and the core's increment in force for this step. With a temperature the last member
        runs at the walk the temperature model leaves and is in force alone."""
        t = self.t
        qs = self.qs_temp if have_temp else self.qs
        if T != self.road_T:
            self.road_T = T
            self.road_a = math.exp(-T / t.road_tau_s) if t.road_var > 0.0 else 1.0
        a = self.road_a
        road_q = t.road_var * (1.0 - a * a)
        for x, P, q in zip(self.xs, self.Ps, qs):
            bb.predict(x, P, q, T, a, road_q)
        corrs = [bb.bias_at(x, dT) for x in self.xs]
        if len(qs) > 1 and not have_temp:
            ws = bb.weights(self.lo)
            inc = 0.0 if self.measured else self.bank_increment(ws[-1])
            return _Mix(ws, corrs, bb.weighted(ws, corrs), inc, qs, True)
        inc = 0.0 if self.measured else self.increment(bb.bias_var_at(self.Ps[-1], dT), qs[-1])
        return _Mix([1.0], corrs, corrs[-1], inc, qs, False)

    def increment(self, var_t: float, q_i: float) -> float:
        """The core's increment of one member in force, deg/s (module docstring, 2)."""
        t = self.t
        if t.ic_alpha > 0.0:
            inc = min(t.i_c_max, t.ic_alpha * math.sqrt(var_t if var_t > 0.0 else 0.0))
        else:
            inc = self.p.hdr.i_c
        ratio = self.f.ic_drift_ratio
        if ratio > 0.0 and q_i * t.road_tau_s < ratio * t.road_var:
            inc = 0.0
        return inc

    def bank_increment(self, w_last: float) -> float:
        """The core's increment with a bank of several, deg/s: ``ic_alpha`` x the most drifting
        member's bias sd (capped at ``i_c_max``) while it weighs at least 0.5, else 0."""
        t, v1 = self.t, self.Ps[-1][bb.BB]
        sd1 = math.sqrt(v1 if v1 > 0.0 else 0.0)
        return min(t.i_c_max, t.ic_alpha * sd1) if w_last >= 0.5 else 0.0

    def standstill_test(self, uc: float, sp: float, v: float, mix: _Mix) -> bool:
        """Is this step a zero-rate update? A standstill candidate (:func:`hdrd.core.standstill.
        standstill_candidate`) whose corrected level is within ``stop_gate_sigma`` of what
        the model allows at rest, for ``steps_speed`` (or ``steps_gyro``) steps running."""
        p, t = self.p, self.t
        level = uc + self.I
        cand, need = standstill_candidate(level, sp, v, p.standstill)
        if cand and t.stop_gate_sigma > 0.0:
            hv = bb.stop_var(self.Ps[-1])
            if mix.mixing:  # the widest member, and how far apart the members are
                for P in self.Ps[:-1]:
                    hv = max(hv, bb.stop_var(P))
                hv += (max(mix.corrs) - min(mix.corrs)) ** 2
            bv = self.f.block_var
            if math.isnan(bv):  # no calibration (a given bias): this step's own spread
                bv = block_mean_variance(sp, p.standstill)
            allow = bv + (hv if hv > 0.0 else 0.0) + mix.inc * mix.inc
            allow += t.gate_floor_dps**2
            cand = abs(level) <= t.stop_gate_sigma * math.sqrt(allow)
        self.still = self.still + 1 if cand else 0
        self.need = need
        return cand and self.still >= need

    def weigh(self, evidence: list[tuple[float, float]], floor2: float) -> None:
        """Each member's log-odds gain how much better than the first it predicted a
        measurement (innovation, its variance), every variance widened by floor2."""
        nu0, s0 = evidence[0]
        for i in range(1, len(evidence)):
            nu, s = evidence[i]
            self.lo[i] += bb.log_evidence(nu, s + floor2, nu0, s0 + floor2)

    def standstill_update(
        self, u: float, sp: float, dT: float, mix: _Mix
    ) -> tuple[float, float, int, float, int, float]:
        """A zero-rate update: the true rate is 0, so u measures what a stop reads, b + c.
        I is folded into b first (omega = u - b + I = u - (b - I)); I, a sum of +-i_c steps,
        is only known to about one increment. The core restarts; omega = 0 is published."""
        p = self.p
        rv = block_mean_variance(sp, p.standstill)
        bv = self.f.block_var
        if not math.isnan(bv) and bv > rv:
            rv = bv
        first = self.still == self.need
        evidence = []
        for x, P in zip(self.xs, self.Ps):
            x[bb.B] -= self.I
            if first:
                P[bb.BB] += mix.inc * mix.inc
            evidence.append(bb.update(x, P, 1.0, dT, 0.0, u, rv + self.q2))
        if mix.mixing:  # both allow a calibration error: stop_floor_dps
            self.weigh(evidence, self.t.stop_floor_dps**2)
        self.x, self.I, self.r, self.s, self.n = 0.0, 0.0, 1, 0, self.n + 1
        return 0.0, 0.0, 0, 1.0, 1, 0.0

    def driving_update(
        self, u: float, sp: float, T: float, dT: float, mix: _Mix
    ) -> tuple[float, float, int, float, int, float]:
        """The paper's step (:func:`hdrd.core.hdr.kernel`) on u_c = u - the correction, with the
        increment in force; then, on a straight step, a measurement of b + r. The heading's
        correction grows by the bias's uncertainty and, once aided, by the step's rate noise
        integrated (its block mean's variance x T^2) and by what a turn adds: ``turn_err``
        of the angle turned in the step (scale factor, a point-sampled gyro's aliasing)."""
        t = self.t
        if mix.mixing or self.aided:
            q_psi = 0.0
            if self.aided:
                q_psi = self.heading_noise(u - mix.corr, u, sp, T)
            for P in self.Ps:
                bb.heading_predict(P, T, dT, q_psi)
        I_out = self.I
        x, self.I, self.yaw, r, s, W, R, y, omega = kernel(
            u - mix.corr, self.x, I_out, self.yaw, self.r, self.s, mix.inc, T, self.p.hdr
        )
        self.x, self.r, self.s, self.n = x, r, s, self.n + 1
        if len(self.xs) > 1 and self.aided:
            # The yaw integrated the bank's correction, not each member's: each member's
            # heading correction moves by what its own bias says the yaw missed (once a course
            # measures the heading: each member is then compared with the same heading).
            for x_ in self.xs:
                x_[bb.PSI] += T * ((u - bb.bias_at(x_, dT)) - omega)
        if t.straight_r > 0.0 and W and abs(omega) <= t.straight_gate_dps and not self.measured:
            evidence = [
                bb.update(x_, P_, 0.0, dT, 1.0, u, t.straight_r) for x_, P_ in zip(self.xs, self.Ps)
            ]
            if mix.mixing:  # which member predicted this step (and its road) better
                self.weigh(evidence, 0.0)
        return omega, I_out, W, R, r, y

    def heading_noise(self, uc: float, u: float, sp: float, T: float) -> float:
        """What one step adds to the heading's error beside the bias, deg^2: the rate noise
        integrated (the block mean's variance at rest x T^2: the calibration's, else this
        step's spread's), ``turn_err`` of the angle turned (a
        scale factor's error), and a turn's onset between samples that the block mean
        misses (the rate's change from the last step x T / (2 x samples per step): a 1 Hz
        point-sampled gyro's aliasing)."""
        bv = self.f.block_var  # the noise at rest (while driving, a step's spread is the road's)
        if bv != bv and sp == sp:
            bv = block_mean_variance(sp, self.p.standstill)
        turned = self.t.turn_err * uc * T
        q = (bv * T * T if bv == bv else 0.0) + turned * turned
        if self.u_prev == self.u_prev:
            onset = (u - self.u_prev) * T / (2.0 * self.p.standstill.samples_per_step)
            q += onset * onset
        return q

    def heading_fix(self, mix: _Mix) -> float:
        """Correct the yaw by the heading error the measurements revealed (the bank's
        weighted psi), deg CCW; once aided each member's correction keeps what the bank's did
        not take (else, and with one member, psi restarts at 0)."""
        heading = bb.weighted(mix.ws, [x[bb.PSI] for x in self.xs])
        self.yaw += heading
        for x in self.xs:
            x[bb.PSI] = x[bb.PSI] - heading if self.aided and len(self.xs) > 1 else 0.0
        return heading

    def output(
        self,
        core: tuple[float, float, int, float, int, float],
        zero: bool,
        dT: float,
        mix: _Mix,
        heading: float,
    ) -> PlusOutput:
        """What is published: the core's output and the bias model after this step (the
        bank's mixture: within and between its members)."""
        if mix.mixing:
            ws = mix.ws
            bs = [bb.bias_at(x, dT) for x in self.xs]
            bc = bb.weighted(ws, bs)
            spread = [bb.bias_var_at(P, dT) + (b - bc) ** 2 for P, b in zip(self.Ps, bs)]
            var_b = bb.weighted(ws, spread)
            kc = bb.weighted(ws, [x[bb.K] for x in self.xs])
            q_in = bb.weighted(ws, mix.qs)
            w_last = ws[-1]
        else:
            x1 = self.xs[-1]
            bc, var_b = bb.bias_at(x1, dT), bb.bias_var_at(self.Ps[-1], dT)
            kc, q_in, w_last = x1[bb.K], mix.qs[-1], 1.0
        sd = math.sqrt(var_b if var_b > 0.0 else 0.0)
        omega, I_out, W, R, r, y = core
        return PlusOutput(omega, self.yaw, I_out, W, R, r, y, bc, zero, sd, kc, mix.inc, q_in,
                          w_last, heading)  # fmt: skip


def step(
    state: PlusState, inp: StepInput, params: HdrPlusParams = DEFAULTS
) -> tuple[PlusState, PlusOutput]:
    """Advance HDR+ by one step of inp.T seconds. Pure (the same code as :func:`run_batch`)."""
    run = _Run(state, params)
    u, sp, v, te, T, herr, hvar, reset = (float(x) for x in inp)
    out = run.advance(u, sp, v, te, T, herr, hvar, bool(reset))
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


def run_batch(
    u: npt.ArrayLike,
    spread: npt.ArrayLike | None = None,
    speed: npt.ArrayLike | None = None,
    temp: npt.ArrayLike | None = None,
    T: npt.ArrayLike | None = None,
    params: HdrPlusParams = DEFAULTS,
    state: PlusState = INITIAL_PLUS_STATE,
    heading_err: npt.ArrayLike | None = None,
    heading_err_var: npt.ArrayLike | None = None,
    heading_reset: npt.ArrayLike | None = None,
) -> PlusTrace:
    """Run HDR+ over arrays of steps: u (deg/s), spread (deg/s), speed (m/s), temp (degC),
    each per step or None (unknown throughout), T a scalar or per step (None: params.hdr.T);
    GPS courses' measurements of the heading error (deg, NaN where none), their variances
    (deg^2) and where the heading was aligned anew (:class:`hdrd.core.steps.StepInput`), or
    None (no GPS). :func:`step` looped, without building a state between steps (the same
    code)."""
    uu = np.asarray(u, dtype=np.float64)
    n = uu.shape[0]
    cols = [
        uu.tolist(),
        per_step(spread, n, "spread"),
        per_step(speed, n, "speed"),
        per_step(temp, n, "temp"),
        per_step(params.hdr.T if T is None else T, n, "T"),
    ]
    if heading_err is not None or heading_reset is not None:
        cols.append(per_step(heading_err, n, "heading_err"))
        cols.append(per_step(heading_err_var, n, "heading_err_var"))
        resets = [False] * n if heading_reset is None else per_step(heading_reset, n, "reset")
        cols.append([bool(r) for r in resets])
    if n == 0:  # nothing ran: not even the prior is set
        return PlusTrace(*(np.empty(0, dt) for dt in _DTYPES), final=state)  # type: ignore[misc, arg-type]
    run = _Run(state, params)
    rows = [run.advance(*row) for row in zip(*cols, strict=True)]
    outs: list[npt.NDArray[np.generic]] = [
        np.array(col, dtype=dt) for col, dt in zip(zip(*rows, strict=True), _DTYPES, strict=True)
    ]
    return PlusTrace(*outs, final=run.state())  # type: ignore[misc, arg-type]
