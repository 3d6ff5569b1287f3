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

A *bank* of two such filters differs only in the bias random walk: *stable* (q_stable, a gyro
whose bias stays put) and *drifting* (q_drifting, a gyro that warms up or wanders). Both take
every measurement; their weight follows how well each predicted it (:func:`log_evidence`,
a multiple-model estimator): the log-odds of "drifting" gain log N(nu1; S1) - log N(nu0; S0)
from each measurement's innovations nu and their variances S. A stop's reading is allowed a
shared floor in both S (a start-up calibration error is a constant, not a drift). The road
state is in both filters: a gently curving road is predicted by each alike, and only a bias
that moves further than the stable filter allows counts for "drifting".

State as flat tuples (mean: 5 floats; covariance: 25, row-major) so that a step is an
immutable value; the functions below work on lists in place, for the batch form's speed.
Units: rates deg/s, + = counter-clockwise seen from above; temperature degC; time s; angles
deg.
"""

from __future__ import annotations

import math
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
    "at",
    "bias_at",
    "bias_var_at",
    "heading_predict",
    "log_evidence",
    "predict",
    "prior",
    "stop_var",
    "update",
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
        for i in range(N_STATES):
            P[at(R, i)] *= a
            P[at(i, R)] *= a
        P[RR] += road_q


def heading_predict(P: list[float], T: float, dT: float) -> None:
    """The yaw integrated T seconds with the bias estimate at dT degC above T_ref: psi' = psi -
    T (b + k dT). Only the covariance changes (the estimate's own error has mean 0)."""
    g = [P[at(i, B)] + dT * P[at(i, K)] for i in range(N_STATES)]  # P h, h = (1, 0, dT, 0, 0)
    hph = g[B] + dT * g[K]
    p44 = P[PP] - 2.0 * T * g[PSI] + T * T * hph
    for j in range(N_STATES):
        v = P[at(PSI, j)] - T * g[j]
        P[at(PSI, j)] = v
        P[at(j, PSI)] = v
    P[PP] = p44


def update(
    x: list[float], P: list[float], hc: float, hk: float, hr: float, z: float, r: float
) -> tuple[float, float]:
    """Kalman update in place with a measurement z (deg/s) of variance r ((deg/s)^2) of
    b + hc c + hk k + hr r (a stop: hc = 1, hr = 0; straight driving: hc = 0, hr = 1; hk =
    the temperature above T_ref). Returns the innovation (deg/s) and its variance
    ((deg/s)^2), from before the update."""
    # P H' with H = (1, hc, hk, hr, 0); S = H P H' + r.
    ph = [
        P[at(i, B)] + hc * P[at(i, C)] + hk * P[at(i, K)] + hr * P[at(i, R)]
        for i in range(N_STATES)
    ]
    s = ph[B] + hc * ph[C] + hk * ph[K] + hr * ph[R] + r
    innov = z - (x[B] + hc * x[C] + hk * x[K] + hr * x[R])
    for i in range(N_STATES):
        g = ph[i] / s
        x[i] += g * innov
        row = at(i, 0)
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


class BankState(NamedTuple):
    """The bias model between steps. Immutable.

    drifting: the filter in force with a known error model or a temperature (its random walk
    then the model's), and the bank's "drifting" one (None until the first step sets the
    prior). stable: the bank's "stable" filter (None when the bank is off). log_odds: log of
    the odds that the gyro drifts (NaN until the first step). t_ref: the reference
    temperature, degC (NaN until one is seen). moved: the bank's third filter, *moved* (None
    when off: ``Ablation.moved_prior``); moved_log_odds: log of its weight over the stable
    filter's (NaN until the first step).
    """

    drifting: Filter | None = None
    stable: Filter | None = None
    log_odds: float = math.nan
    t_ref: float = math.nan
    moved: Filter | None = None
    moved_log_odds: float = math.nan


INITIAL_BANK = BankState()
