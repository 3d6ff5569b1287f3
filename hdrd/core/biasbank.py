"""HDR+'s bias model: Kalman filters of the gyro's bias, and the evidence that it drifts. Pure.

One filter (:class:`Filter`) estimates, relative to the start-up static bias eps0 (paper Eq. 2):

- ``b``: the bias while driving minus eps0, deg/s;
- ``c``: the *standstill offset*, what a stop reads minus the driving bias, deg/s (a quantised
  gyro reads the same code at every stop; vibration shifts a MEMS bias while driving);
- ``k``: the temperature coefficient, deg/s/degC (bias(T) = eps0 + b + k (T - T_ref));
- ``r``: the *road*: the yaw rate of gentle curves that pass for straight driving, deg/s, a
  Gauss-Markov process (variance ``road_var``, correlation time ``road_tau_s``). A straight
  step measures b + r, a stop b + c: so the bias learns from roads only as far as its own
  uncertainty exceeds the road's, and from stops freely;
- ``psi``: the heading error the bias estimate in use has caused since it was last corrected,
  deg (psi' = psi - T (b + k dT) while the yaw integrates). When a measurement moves b, the
  same update moves psi by their covariance: the heading is corrected for what the old
  estimate bent it (``heading_fix``).

The start-up calibration was itself a stop, so at start b = -c + (calibration error): prior
var(b) = p0 + F, var(c) = F, cov(b, c) = -F, var(k) = sd(k)^2, var(r) = road_var, psi = 0.

A *bank* is a list of such filters, one per :class:`Hypothesis` (data: a name, a bias random
walk q and a prior weight), in the spirit of filterpy's ``IMMEstimator``: adding a hypothesis
is adding a list element. The default bank has two, *stable* (a gyro whose bias stays put) and
*drifting* (a gyro that warms up or wanders); a known error model is a bank of one. Every
member takes every measurement; their weights follow how well each predicted it
(:func:`log_evidence`, a multiple-model estimator): each member's log-odds against the first
gain log N(nu_i; S_i) - log N(nu_0; S_0) from each measurement's innovations nu and their
variances S (:func:`weights` turns them into weights). A stop's reading is allowed a shared
floor in every S (a start-up calibration error is a constant, not a drift). The road state is
in every filter: a gently curving road is predicted by each alike, and only a bias that moves
further than the stable filter allows counts for "drifting".

State as flat tuples (mean: 5 floats; covariance: 25, row-major) so that a step is an
immutable value; the functions below work on lists in place, for the batch form's speed.
Units: rates deg/s, + = counter-clockwise seen from above; temperature degC; time s; angles
deg.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

__all__ = [
    "B",
    "C",
    "INITIAL_BANK",
    "K",
    "N_STATES",
    "PSI",
    "R",
    "BankState",
    "Filter",
    "Hypothesis",
    "at",
    "bias_at",
    "bias_var_at",
    "heading_predict",
    "reset_heading",
    "update_heading",
    "log_evidence",
    "predict",
    "prior",
    "stop_var",
    "update",
    "weighted",
    "weights",
]

N_STATES = 5
B, C, K, R, PSI = range(N_STATES)
"""Indices of the states: bias b, standstill offset c, temperature coefficient k, road r,
heading error psi."""


def at(i: int, j: int) -> int:
    """Index of the covariance entry (i, j) in a row-major P."""
    return i * N_STATES + j


BB, BC, BK, CC, KK, RR, PP = (
    at(B, B),
    at(B, C),
    at(B, K),
    at(C, C),
    at(K, K),
    at(R, R),
    at(PSI, PSI),
)
"""The covariance entries read by name: var(b), cov(b, c), cov(b, k), var(c), var(k), var(r),
var(psi)."""

_ROWS = tuple(at(i, 0) for i in range(N_STATES))
"""Where each row of a row-major P starts (the hot loops index P[row + state])."""


def bias_at(x: list[float] | tuple[float, ...], dT: float) -> float:
    """The bias correction b + k dT at dT degC above T_ref, deg/s."""
    return x[B] + x[K] * dT


def bias_var_at(P: list[float] | tuple[float, ...], dT: float) -> float:
    """Its variance, var(b + k dT) = P_bb + dT (2 P_bk + dT P_kk), (deg/s)^2."""
    return P[BB] + dT * (2.0 * P[BK] + dT * P[KK])


def stop_var(P: list[float] | tuple[float, ...]) -> float:
    """Variance of what a stop reads, var(b + c) = P_bb + 2 P_bc + P_cc, (deg/s)^2."""
    return P[BB] + 2.0 * P[BC] + P[CC]


class Filter(NamedTuple):
    """One Kalman filter of the bias model: mean x (b, c, k, r, psi) and covariance P (row-major
    5 x 5), in deg/s, deg/s/degC and deg (see the module docstring)."""

    x: tuple[float, ...]
    P: tuple[float, ...]


def prior(p_b: float, offset_var: float, k_var: float, road_var: float) -> Filter:
    """The prior after the start-up calibration: var(b) = p_b + F, var(c) = F, cov(b, c) = -F
    (F = offset_var, (deg/s)^2), var(k) = k_var ((deg/s/degC)^2), var(r) = road_var, psi 0."""
    f = offset_var
    P = [0.0] * (N_STATES * N_STATES)
    P[BB] = p_b + f
    P[BC] = P[at(C, B)] = -f
    P[CC] = f
    P[KK] = k_var
    P[RR] = road_var
    return Filter((0.0,) * N_STATES, tuple(P))


def predict(x: list[float], P: list[float], q: float, T: float, a: float, road_q: float) -> None:
    """Let T seconds pass, in place: the bias performs a random walk of q (deg/s)^2/s; the road
    decays by a (exp(-T / tau)) and gains road_q = road_var (1 - a^2) of variance."""
    P[BB] += q * T
    if a != 1.0:
        x[R] *= a
        r_row = _ROWS[R]
        for i, row in enumerate(_ROWS):
            P[r_row + i] *= a
            P[row + R] *= a
        P[RR] += road_q


def heading_predict(P: list[float], T: float, dT: float, q_psi: float = 0.0) -> None:
    """The yaw integrated T seconds with the bias estimate at dT degC above T_ref: psi' = psi -
    T (b + k dT), plus the rate noise integrated over the step, of variance q_psi, deg^2. Only
    the covariance changes (the estimate's own error has mean 0)."""
    g = [P[row + B] + dT * P[row + K] for row in _ROWS]  # P h, h = (1, 0, dT, 0, 0)
    hph = g[B] + dT * g[K]
    p44 = P[PP] - 2.0 * T * g[PSI] + T * T * hph
    psi_row = _ROWS[PSI]
    for j, row in enumerate(_ROWS):
        v = P[psi_row + j] - T * g[j]
        P[psi_row + j] = v
        P[row + PSI] = v
    P[PP] = p44 + q_psi


def reset_heading(x: list[float], P: list[float], var: float) -> None:
    """The heading was aligned anew: psi = 0, of variance var (deg^2), and uncorrelated with
    the rest."""
    x[PSI] = 0.0
    psi_row = _ROWS[PSI]
    for j, row in enumerate(_ROWS):
        P[psi_row + j] = 0.0
        P[row + PSI] = 0.0
    P[PP] = var


def update_heading(x: list[float], P: list[float], z: float, r: float) -> tuple[float, float]:
    """Kalman update in place with a measurement z (deg) of variance r (deg^2) of psi, the
    heading correction (a GPS course: the published heading minus the course). Returns the
    innovation (deg) and its variance (deg^2), from before the update."""
    ph = [P[row + PSI] for row in _ROWS]
    s = ph[PSI] + r
    innov = z - x[PSI]
    for i, row in enumerate(_ROWS):
        g = ph[i] / s
        x[i] += g * innov
        for j in range(N_STATES):
            P[row + j] -= g * ph[j]
    return innov, s


def update(
    x: list[float], P: list[float], hc: float, hk: float, hr: float, z: float, r: float
) -> tuple[float, float]:
    """Kalman update in place with a measurement z (deg/s) of variance r ((deg/s)^2) of
    b + hc c + hk k + hr r (a stop: hc = 1, hr = 0; straight driving: hc = 0, hr = 1; hk =
    the temperature above T_ref). Returns the innovation (deg/s) and its variance
    ((deg/s)^2), from before the update."""
    # P H' with H = (1, hc, hk, hr, 0); S = H P H' + r.
    ph = [P[row + B] + hc * P[row + C] + hk * P[row + K] + hr * P[row + R] for row in _ROWS]
    s = ph[B] + hc * ph[C] + hk * ph[K] + hr * ph[R] + r
    innov = z - (x[B] + hc * x[C] + hk * x[K] + hr * x[R])
    for i, row in enumerate(_ROWS):
        g = ph[i] / s
        x[i] += g * innov
        for j in range(N_STATES):
            P[row + j] -= g * ph[j]
    return innov, s


def log_evidence(nu1: float, s1: float, nu0: float, s0: float) -> float:
    """log N(nu1; 0, s1) - log N(nu0; 0, s0): how much better the drifting filter (innovation
    nu1, deg/s, of variance s1, (deg/s)^2) predicted a measurement than the stable one (nu0,
    s0). 0 when either variance is not positive."""
    if not (s1 > 0.0) or not (s0 > 0.0):
        return 0.0
    return -0.5 * (nu1 * nu1 / s1 - nu0 * nu0 / s0) - 0.5 * math.log(s1 / s0)


@dataclass(frozen=True, slots=True)
class Hypothesis:
    """One member of the bank: what the gyro's bias is believed to do, as data.

    name: what it stands for (``stable``, ``drifting``, ``model``). q: its bias random walk
    without a temperature, (deg/s)^2/s. prior: its weight at start (a bank's priors sum to
    1). A bank lists its members from the most stable to the most drifting: the first is the
    reference of the log-odds, the last is the one a temperature model puts in force alone.
    """

    name: str
    q: float
    prior: float

    def __post_init__(self) -> None:
        q, prior = float(self.q), float(self.prior)
        if not (math.isfinite(q) and q >= 0.0):
            raise ValueError(f"hypothesis {self.name}: q must be a number >= 0, got {self.q!r}")
        if not 0.0 < prior <= 1.0:
            raise ValueError(f"hypothesis {self.name}: prior must be in (0, 1], got {prior!r}")
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "prior", prior)


def weights(log_odds: list[float]) -> list[float]:
    """The members' weights from their log-odds against the first (log_odds[0] = 0): w_i =
    1 / (1 + sum_j!=i exp(lo_j - lo_i)) for i >= 1, and the first takes what is left."""
    n = len(log_odds)
    if n == 1:
        return [1.0]
    if n == 2:
        w1 = 1.0 / (1.0 + math.exp(log_odds[0] - log_odds[1]))
        return [1.0 - w1, w1]
    ws = [0.0] * n
    w0 = 1.0
    for i in range(1, n):
        s = 1.0
        for j in range(n):
            if j != i:
                s += math.exp(log_odds[j] - log_odds[i])
        ws[i] = 1.0 / s
        w0 -= ws[i]
    ws[0] = w0
    return ws


def weighted(ws: list[float], values: list[float]) -> float:
    """sum_i w_i values_i, in member order."""
    acc = ws[0] * values[0]
    for i in range(1, len(ws)):
        acc += ws[i] * values[i]
    return acc


class BankState(NamedTuple):
    """The bias model between steps. Immutable.

    filters: one :class:`Filter` per member of the bank, in the bank's order (empty until the
    first step sets the priors). log_odds: each member's log-odds against the first (the
    first's is 0). t_ref: the reference temperature, degC (NaN until one is seen).
    """

    filters: tuple[Filter, ...] = ()
    log_odds: tuple[float, ...] = ()
    t_ref: float = math.nan


INITIAL_BANK = BankState()
