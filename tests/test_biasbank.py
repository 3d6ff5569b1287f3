"""HDR+'s bias model (hdrd/core/biasbank.py): the filter's steps against the Kalman equations in
matrix form, and the evidence that a gyro drifts.

States (b, c, k, r, psi): bias deg/s, standstill offset deg/s, temperature coefficient
deg/s/degC, road deg/s, heading error deg.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdrd.core import biasbank as bb


def _random_filter(seed: int) -> tuple[list[float], list[float]]:
    """A mean and a symmetric positive definite covariance of the five states."""
    rng = np.random.default_rng(seed)
    scale = np.array([0.05, 0.03, 0.005, 0.05, 2.0])
    a = rng.standard_normal((5, 5)) * scale[:, None]
    P = a @ a.T + np.diag(scale**2) * 0.1
    x = rng.standard_normal(5) * scale
    return x.tolist(), P.ravel().tolist()


@given(
    seed=st.integers(0, 2**16),
    stop=st.booleans(),
    dT=st.floats(-20.0, 20.0),
    z=st.floats(-1.0, 1.0),
    r=st.floats(1e-6, 1.0),
)
def test_update_is_the_kalman_update(seed: int, stop: bool, dT: float, z: float, r: float) -> None:
    x, P = _random_filter(seed)
    hc, hr = (1.0, 0.0) if stop else (0.0, 1.0)
    X, M = np.array(x), np.array(P).reshape(5, 5)
    h = np.array([1.0, hc, dT, hr, 0.0])
    S = h @ M @ h + r
    K = M @ h / S
    want_x = X + K * (z - h @ X)
    want_P = M - np.outer(K, h @ M)
    bb.update(x, P, hc, dT, hr, z, r)
    assert np.allclose(x, want_x, rtol=1e-9, atol=1e-12)
    assert np.allclose(np.array(P).reshape(5, 5), want_P, rtol=1e-7, atol=1e-13)
    assert P[0] <= M[0, 0] + 1e-15  # a measurement never makes the bias less certain


@given(seed=st.integers(0, 2**16), T=st.floats(0.1, 5.0), dT=st.floats(-20.0, 20.0))
def test_heading_predict_is_f_p_ft(seed: int, T: float, dT: float) -> None:
    # psi' = psi - T (b + k dT): F = I - T e_psi h, h = (1, 0, dT, 0, 0)
    _, P = _random_filter(seed)
    M = np.array(P).reshape(5, 5)
    F = np.eye(5)
    F[bb.PSI, bb.B] -= T
    F[bb.PSI, bb.K] -= T * dT
    bb.heading_predict(P, T, dT)
    assert np.allclose(np.array(P).reshape(5, 5), F @ M @ F.T, rtol=1e-9, atol=1e-12)


def test_predict_prior_and_the_road() -> None:
    f = bb.prior(1e-6, 1e-4, 1e-4, 0.0025)
    M = np.array(f.P).reshape(5, 5)
    assert M[bb.B, bb.B] == pytest.approx(1e-6 + 1e-4) and M[bb.B, bb.C] == -1e-4
    assert M[bb.C, bb.C] == 1e-4 and M[bb.K, bb.K] == 1e-4 and M[bb.R, bb.R] == 0.0025
    assert M[bb.PSI, bb.PSI] == 0.0 and f.x == (0.0,) * 5
    x, P = list(f.x), list(f.P)
    x[bb.R] = 0.04
    a = math.exp(-1.0 / 120.0)
    bb.predict(x, P, 1e-6, 10.0, a, 0.0025 * (1 - a * a))
    assert P[0] == pytest.approx(1e-6 + 1e-4 + 1e-5)
    assert x[bb.R] == pytest.approx(0.04 * a)
    assert P[bb.R * 5 + bb.R] == pytest.approx(0.0025)  # stationary: the variance stays
    # A road that does not decay (a = 1) is left alone.
    x2, P2 = list(f.x), list(f.P)
    bb.predict(x2, P2, 0.0, 1.0, 1.0, 0.0)
    assert P2 == list(f.P)


def test_stops_cannot_see_the_driving_bias_through_the_offset() -> None:
    # eps0 known to 1e-6, but what a stop reads may differ from the driving bias by F = 1e-3
    # (deg/s)^2: a thousand perfect stops do not narrow b below F; straight driving does,
    # as far as the road (var 1e-4) lets it.
    f = bb.prior(1e-6, 1e-3, 0.0, 1e-4)
    x, P = list(f.x), list(f.P)
    for _ in range(1000):
        bb.update(x, P, 1.0, 0.0, 0.0, 0.0, 1e-6)
    assert P[0] > 0.9e-3
    for _ in range(200):
        bb.update(x, P, 0.0, 0.0, 1.0, 0.05, 0.05)
    assert x[bb.B] == pytest.approx(0.05, abs=0.015) and P[0] < 3e-4
    assert x[bb.B] + x[bb.C] == pytest.approx(0.0, abs=1e-3)  # the stops' reading is kept
    # ... and the road takes what the bias cannot: a bias known to 1e-8 hardly moves.
    g = bb.prior(1e-8, 0.0, 0.0, 0.0025)
    y, Q = list(g.x), list(g.P)
    for _ in range(30):
        bb.update(y, Q, 0.0, 0.0, 1.0, 0.05, 0.05)
    assert abs(y[bb.B]) < 1e-3 and y[bb.R] > 0.02


def test_log_evidence() -> None:
    # The same innovation under the same variance: no evidence. A filter that predicted the
    # measurement better (a smaller innovation at the same variance) gains; a larger variance
    # costs 0.5 ln(s1/s0) when the innovation is 0 (it spread its bet).
    assert bb.log_evidence(0.1, 0.01, 0.1, 0.01) == 0.0
    assert bb.log_evidence(0.0, 0.01, 0.2, 0.01) == pytest.approx(0.5 * 0.04 / 0.01)
    assert bb.log_evidence(0.2, 0.01, 0.0, 0.01) == pytest.approx(-2.0)
    assert bb.log_evidence(0.0, 0.04, 0.0, 0.01) == pytest.approx(-0.5 * math.log(4.0))
    # a large innovation favours the filter that allowed for it
    ratio = bb.log_evidence(0.3, 0.04, 0.3, 0.01)
    assert ratio == pytest.approx(0.5 * (0.09 / 0.01 - 0.09 / 0.04) - 0.5 * math.log(4.0))
    assert ratio > 2.0
    # No variance: no evidence either way.
    assert (
        bb.log_evidence(0.3, 0.0, 0.0, 0.01) == 0.0 and bb.log_evidence(0.0, 0.01, 0.3, 0.0) == 0.0
    )


def test_update_returns_the_innovation_and_its_variance() -> None:
    # A stop (b + c) measured at 0.1 deg/s against a prior of 0: the innovation is 0.1 and its
    # variance var(b) + 2 cov(b, c) + var(c) + r (the prior's b + c has variance p_b).
    f = bb.prior(0.01, 0.002, 0.0, 0.0025)
    x, P = list(f.x), list(f.P)
    nu, s = bb.update(x, P, 1.0, 0.0, 0.0, 0.1, 0.003)
    assert nu == pytest.approx(0.1) and s == pytest.approx(0.01 + 0.003)
    # straight driving (b + r): var(b) + var(r) + r
    g = bb.prior(0.01, 0.002, 0.0, 0.0025)
    y, Q = list(g.x), list(g.P)
    nu, s = bb.update(y, Q, 0.0, 0.0, 1.0, -0.05, 0.05)
    assert nu == pytest.approx(-0.05) and s == pytest.approx(0.012 + 0.0025 + 0.05)


def test_the_bias_at_a_temperature_and_its_variance() -> None:
    x = [0.1, -0.02, 0.003, 0.05, 0.0]  # b, c, k, r, psi
    P = [0.0] * (bb.N_STATES * bb.N_STATES)
    P[bb.BB], P[bb.KK], P[bb.BK] = 4e-4, 1e-6, -5e-6
    P[bb.at(bb.K, bb.B)] = -5e-6
    P[bb.BC] = P[bb.at(bb.C, bb.B)] = -1e-4
    P[bb.CC] = 3e-4
    assert bb.bias_at(x, 0.0) == 0.1
    assert bb.bias_at(x, 10.0) == pytest.approx(0.1 + 0.03)  # b + k dT
    assert bb.bias_var_at(P, 0.0) == 4e-4
    # var(b + k dT) = P_bb + 2 dT P_bk + dT^2 P_kk
    assert bb.bias_var_at(P, 10.0) == pytest.approx(4e-4 - 2 * 10 * 5e-6 + 100 * 1e-6)
    # what a stop reads, b + c: P_bb + 2 P_bc + P_cc
    assert bb.stop_var(P) == pytest.approx(4e-4 - 2e-4 + 3e-4)
