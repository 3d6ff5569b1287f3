"""Small linear Kalman filters and a bank of them (a multiple-model estimator), pure.

In the shape of filterpy's ``KalmanFilter`` and ``IMMEstimator``: a :class:`Filter` holds a
state x and its covariance P; :meth:`Filter.predict` lets time pass through a transition F and
a process noise Q, and :meth:`Filter.update` takes one measurement z of h . x with variance R,
the measurement model passed as data (a sparse row h), and returns its innovation and the
innovation's variance. A :class:`Bank` is a list of filters of one state layout, each a
hypothesis about the system (filterpy's ``filters``), with the probability of each (``mu``) and
a Markov transition between them (``M``): :meth:`Bank.transition` moves the probabilities by
it before each step, :meth:`Bank.weigh` moves them by
how well each member predicted the step's measurements, and :meth:`Bank.mean` /
:meth:`Bank.var` give the combined estimate. A hypothesis is added by adding a list element,
never a branch.

Plain Python floats and lists: the filters here have a handful of states and run once a
second, where numpy's per-call cost would exceed the arithmetic (bench/RESULTS.md, "HDR
kernel: CPU time per step"). Nothing here knows units; :mod:`hdrd.core.hdrplus` gives its
states their meaning.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple

__all__ = ["Bank", "Filter", "Innovation", "Row", "log_likelihood"]

Row = Sequence[tuple[int, float]]
"""A sparse row of a matrix: (column, value) for each nonzero entry."""

_LOG_2PI = math.log(2.0 * math.pi)


class Innovation(NamedTuple):
    """What a measurement showed: nu = z - h . x before the update, S = h P h' + R."""

    nu: float
    S: float


def log_likelihood(nu: float, S: float) -> float:
    """log N(nu; 0, S): how well a filter predicted a measurement (S > 0)."""
    return -0.5 * (_LOG_2PI + math.log(S) + nu * nu / S)


class Filter:
    """One linear Kalman filter over n states: x (list) and P (n lists of n), mutable."""

    __slots__ = ("P", "x")

    def __init__(self, x: Sequence[float], P: Sequence[Sequence[float]]) -> None:
        self.x = list(x)
        self.P = [list(row) for row in P]

    def copy(self) -> Filter:
        return Filter(self.x, self.P)

    def predict(self, F: Mapping[int, Row], Q: Sequence[tuple[int, int, float]]) -> None:
        """x <- F x, P <- F P F' + Q. F: the sparse rows that differ from the identity's, by
        state (a transition moves few states), applied in their order as shears of x and P in
        place (O(n) each instead of the O(n^3) of a full product): a row may refer to states
        whose rows come later or not at all, which still hold their old values when it is
        applied, never to one changed before it; Q: (i, j, value) entries added to P (give both
        (i, j) and (j, i) off the diagonal)."""
        x, P = self.x, self.P
        n = len(x)
        for i, row in F.items():
            d = 1.0
            others = []
            for k, v in row:
                if k == i:
                    d = v
                else:
                    others.append((k, v))
            # the new row i of P: d P[i] + sum v P[k], then its column, then its diagonal
            Pi = P[i]
            new = [d * Pi[j] + sum(v * P[k][j] for k, v in others) for j in range(n)]
            diag = d * new[i] + sum(v * new[k] for k, v in others)
            for j in range(n):
                P[j][i] = new[j]
            P[i] = new
            P[i][i] = diag
            x[i] = d * x[i] + sum(v * x[k] for k, v in others)
        for i, j, q in Q:
            P[i][j] += q

    def innovation(self, z: float, h: Row, R: float) -> Innovation:
        """The innovation of a measurement z of h . x with variance R, without updating."""
        P = self.P
        S = R + sum(a * b * P[i][j] for i, a in h for j, b in h)
        return Innovation(z - sum(v * self.x[i] for i, v in h), S)

    def update(self, z: float, h: Row, R: float) -> Innovation:
        """One measurement z of h . x with variance R (> 0): the Kalman update. P stays
        symmetric (P - Ph Ph' / S is, to rounding: both halves are computed alike) and no
        variance is left negative by rounding. Returns its innovation."""
        x, P = self.x, self.P
        n = len(x)
        Ph = [sum(row[i] * v for i, v in h) for row in P]
        S = R + sum(v * Ph[i] for i, v in h)
        nu = z - sum(v * x[i] for i, v in h)
        if S <= 0.0:
            return Innovation(nu, S)
        g = nu / S
        self.x = [xi + g * pi for xi, pi in zip(x, Ph)]
        for r in range(n):
            k = Ph[r] / S
            P[r] = [a - k * b for a, b in zip(P[r], Ph)]
            if P[r][r] < 0.0:
                P[r][r] = 0.0
        return Innovation(nu, S)


class Bank:
    """A bank of filters, one per hypothesis, with its mode probabilities ``mu`` and the
    Markov transition ``M`` (M[i][j]: the probability that hypothesis i at one step is j at
    the next), as filterpy's ``IMMEstimator``."""

    __slots__ = ("M", "filters", "mu")

    def __init__(
        self, filters: Sequence[Filter], mu: Sequence[float], M: Sequence[Sequence[float]]
    ) -> None:
        self.filters = list(filters)
        self.mu = list(mu)
        self.M = [list(r) for r in M]

    def transition(self) -> None:
        """The Markov transition of the probabilities before a step: mu <- M' mu. The members'
        states are not mixed (filterpy's IMM would): here each member is a kind of unit, not
        a mode the system switches between, and a member given the others' state would forget
        what kind it stands for; the transition only keeps every probability from dying, so
        that later evidence can always turn the bank round."""
        mu, M = self.mu, self.M
        m = len(mu)
        if m > 1:
            self.mu = [sum(M[i][j] * mu[i] for i in range(m)) for j in range(m)]

    def weigh(self, log_lik: Sequence[float]) -> None:
        """Bayes' rule on the mode probabilities: mu_i <- mu_i L_i / sum (one step's
        log-likelihood of each member's measurements)."""
        top = max(log_lik)
        post = [p * math.exp(ll - top) for p, ll in zip(self.mu, log_lik)]
        total = sum(post)
        if total > 0.0 and math.isfinite(total):
            self.mu = [p / total for p in post]

    def mean(self, h: Row) -> float:
        """The combined estimate of h . x: the members' weighted by mu."""
        return sum(p * sum(v * f.x[i] for i, v in h) for p, f in zip(self.mu, self.filters))

    def var(self, h: Row) -> float:
        """The combined variance of h . x: within each member and between them."""
        mean = self.mean(h)
        total = 0.0
        for p, f in zip(self.mu, self.filters):
            e = sum(v * f.x[i] for i, v in h) - mean
            total += p * (sum(a * b * f.P[i][j] for i, a in h for j, b in h) + e * e)
        return total if total > 0.0 else 0.0
