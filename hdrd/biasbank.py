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
whose bias stays put) and *drifting* (q_drifting, a gyro that warms up or wanders). Their
weight follows evidence (:func:`log_evidence`), from two kinds of residuals of the stable
filter: each stop's mean against what it predicted (clean: no road in it), and the mean of
each window of straight steps against its bias (roads in it: a floor allows for them). Under
"stable" such a residual has variance A, under "drifting" A + D, D the drift the stable
filter cannot follow: their likelihood ratio moves the log-odds of "drifting".

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
    "heading_predict",
    "log_evidence",
    "predict",
    "prior",
    "update",
]

N_STATES = 5
B, C, K, R, PSI = range(N_STATES)
"""Indices of the states: bias b, standstill offset c, temperature coefficient k, road r,
heading error psi."""


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
    P[B * 5 + B] = p_b + f
    P[B * 5 + C] = P[C * 5 + B] = -f
    P[C * 5 + C] = f
    P[K * 5 + K] = k_var
    P[R * 5 + R] = road_var
    return Filter((0.0,) * N_STATES, tuple(P))


def predict(x: list[float], P: list[float], q: float, T: float, a: float, road_q: float) -> None:
    """Let T seconds pass, in place: the bias performs a random walk of q (deg/s)^2/s; the road
    decays by a (exp(-T / tau)) and gains road_q = road_var (1 - a^2) of variance."""
    P[0] += q * T
    if a != 1.0:
        x[R] *= a
        for i in range(N_STATES):
            P[R * 5 + i] *= a
            P[i * 5 + R] *= a
        P[R * 5 + R] += road_q


def heading_predict(P: list[float], T: float, dT: float) -> None:
    """The yaw integrated T seconds with the bias estimate at dT degC above T_ref: psi' = psi -
    T (b + k dT). Only the covariance changes (the estimate's own error has mean 0)."""
    g = [P[i * 5 + B] + dT * P[i * 5 + K] for i in range(N_STATES)]  # P h, h = (1, 0, dT, 0, 0)
    hph = g[B] + dT * g[K]
    p44 = P[PSI * 5 + PSI] - 2.0 * T * g[PSI] + T * T * hph
    for j in range(N_STATES):
        v = P[PSI * 5 + j] - T * g[j]
        P[PSI * 5 + j] = v
        P[j * 5 + PSI] = v
    P[PSI * 5 + PSI] = p44


def update(
    x: list[float], P: list[float], hc: float, hk: float, hr: float, z: float, r: float
) -> None:
    """Kalman update in place with a measurement z (deg/s) of variance r ((deg/s)^2) of
    b + hc c + hk k + hr r (a stop: hc = 1, hr = 0; straight driving: hc = 0, hr = 1; hk =
    the temperature above T_ref)."""
    ph = [P[i * 5] + hc * P[i * 5 + 1] + hk * P[i * 5 + 2] + hr * P[i * 5 + 3] for i in range(5)]
    s = ph[0] + hc * ph[1] + hk * ph[2] + hr * ph[3] + r
    innov = z - (x[0] + hc * x[1] + hk * x[2] + hr * x[3])
    for i in range(N_STATES):
        g = ph[i] / s
        x[i] += g * innov
        row = i * 5
        for j in range(N_STATES):
            P[row + j] -= g * ph[j]


def log_evidence(residual: float, var: float, drift_var: float) -> float:
    """log p(residual | drifting) - log p(residual | stable) for a Gaussian residual of variance
    var under "stable" and var + drift_var under "drifting" (all in deg/s and (deg/s)^2)."""
    if not (var > 0.0) or not (drift_var > 0.0):
        return 0.0
    z2 = residual * residual
    return 0.5 * z2 * (1.0 / var - 1.0 / (var + drift_var)) - 0.5 * math.log1p(drift_var / var)


class BankState(NamedTuple):
    """The bias model between steps. Immutable.

    drifting: the filter in force with a known error model or a temperature (its random walk
    then the model's), and the bank's "drifting" one (None until the first step sets the
    prior). stable: the bank's "stable" filter (None when the bank is off). log_odds: log of
    the odds that the gyro drifts (NaN until the first step). t_ref: the reference
    temperature, degC (NaN until one is seen). since: seconds driven since the last stop
    closed. stop_z, stop_w: the open stop's inverse-variance weighted sums (deg/s/(deg/s)^2,
    1/(deg/s)^2); stop_pred, stop_var: what the stable filter predicted it would read, and
    that prediction's variance. win_n, win_sum, win_var: the open window of straight steps:
    steps, the sum of (u - the stable filter's bias), deg/s, and that bias's variance.
    """

    drifting: Filter | None = None
    stable: Filter | None = None
    log_odds: float = math.nan
    t_ref: float = math.nan
    since: float = 0.0
    stop_z: float = 0.0
    stop_w: float = 0.0
    stop_pred: float = 0.0
    stop_var: float = 0.0
    win_n: int = 0
    win_sum: float = 0.0
    win_var: float = 0.0


INITIAL_BANK = BankState()
