"""The small Kalman filters and their bank (hdrd/core/kalman.py), against dense numpy
arithmetic: the textbook equations, computed another way."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.core.kalman import Bank, Filter, log_likelihood

N = 5
vals = st.floats(-3.0, 3.0, allow_nan=False)


@st.composite
def covariances(draw: st.DrawFn) -> np.ndarray:
    a = np.array(draw(st.lists(vals, min_size=N * N, max_size=N * N))).reshape(N, N)
    return a @ a.T + 0.01 * np.eye(N)


@settings(max_examples=80)
@given(
    P=covariances(),
    x=st.lists(vals, min_size=N, max_size=N),
    T=st.floats(0.1, 2.0),
    a=st.floats(0.0, 1.0),
    k=st.floats(-1.0, 1.0),
    q=st.floats(0.0, 1.0),
)
def test_predict_is_F_P_Ft_plus_Q(
    P: np.ndarray, x: list[float], T: float, a: float, k: float, q: float
) -> None:
    # A yaw row that integrates a bias and a temperature term, a decaying road: the shape
    # HDR+ uses, each changed row referring besides itself to unchanged rows only.
    F = np.eye(N)
    F[0, 1], F[0, 4] = -T, k
    F[3, 3] = a
    f = Filter(x, P.tolist())
    f.predict({0: ((0, 1.0), (1, -T), (4, k)), 3: ((3, a),)}, [(1, 1, q), (0, 0, 2 * q)])
    want = F @ P @ F.T
    want[1, 1] += q
    want[0, 0] += 2 * q
    assert np.allclose(f.P, want, rtol=1e-12, atol=1e-12)
    assert np.allclose(f.x, F @ np.array(x), rtol=1e-12, atol=1e-12)


@settings(max_examples=80)
@given(
    P=covariances(),
    x=st.lists(vals, min_size=N, max_size=N),
    z=vals,
    R=st.floats(1e-4, 10.0),
    h=st.lists(
        st.tuples(st.integers(0, N - 1), st.floats(-2.0, 2.0)),
        min_size=1,
        max_size=3,
        unique_by=lambda t: t[0],
    ),
)
def test_update_is_the_kalman_update(
    P: np.ndarray, x: list[float], z: float, R: float, h: list[tuple[int, float]]
) -> None:
    H = np.zeros(N)
    for i, v in h:
        H[i] = v
    S = H @ P @ H + R
    K = P @ H / S
    f = Filter(x, P.tolist())
    inn = f.update(z, h, R)
    assert inn.nu == pytest.approx(z - H @ np.array(x), abs=1e-9)
    assert inn.S == pytest.approx(S, rel=1e-9)
    assert np.allclose(f.x, np.array(x) + K * inn.nu, rtol=1e-9, atol=1e-9)
    want = P - np.outer(K, H @ P)
    np.fill_diagonal(want, np.maximum(np.diag(want), 0.0))
    assert np.allclose(f.P, want, rtol=1e-9, atol=1e-9)
    # innovation() is the same without moving the filter
    g = Filter(x, P.tolist())
    again = g.innovation(z, h, R)
    assert again.nu == pytest.approx(inn.nu) and again.S == pytest.approx(inn.S)
    assert g.x == x


def test_log_likelihood_is_the_normal_density() -> None:
    assert log_likelihood(0.0, 1.0) == pytest.approx(-0.5 * math.log(2 * math.pi))
    assert log_likelihood(2.0, 4.0) == pytest.approx(
        math.log(math.exp(-0.5) / math.sqrt(8 * math.pi))
    )


def test_a_bank_weighs_by_likelihood_and_its_transition_keeps_every_member_alive() -> None:
    a = Filter([0.0, 0.0], [[1.0, 0.0], [0.0, 1.0]])
    b = Filter([1.0, 0.0], [[4.0, 0.0], [0.0, 1.0]])
    s = 1e-3
    bank = Bank([a, b], [0.5, 0.5], [[1 - s, s], [s, 1 - s]])
    bank.weigh([math.log(0.2), math.log(0.6)])
    assert bank.mu == pytest.approx([0.25, 0.75])
    for _ in range(50):  # overwhelming evidence against b ...
        bank.transition()
        bank.weigh([0.0, -50.0])
    assert 0.0 < bank.mu[1] < 2 * s and sum(bank.mu) == pytest.approx(1.0)  # ... never kills it
    # the transition alone is M' mu
    bank.mu = [0.9, 0.1]
    bank.transition()
    assert bank.mu == pytest.approx([0.9 * (1 - s) + 0.1 * s, 0.9 * s + 0.1 * (1 - s)])


def test_the_bank_s_mean_and_variance_are_the_mixture_s() -> None:
    a = Filter([0.0, 2.0], [[1.0, 0.5], [0.5, 2.0]])
    b = Filter([3.0, -1.0], [[4.0, 0.0], [0.0, 1.0]])
    bank = Bank([a, b], [0.25, 0.75], [[1.0, 0.0], [0.0, 1.0]])
    h = ((0, 1.0), (1, 2.0))
    ma, mb = 0.0 + 4.0, 3.0 - 2.0
    va, vb = 1.0 + 4 * 0.5 + 4 * 2.0, 4.0 + 4 * 1.0
    mean = 0.25 * ma + 0.75 * mb
    assert bank.mean(h) == pytest.approx(mean)
    assert bank.var(h) == pytest.approx(
        0.25 * (va + (ma - mean) ** 2) + 0.75 * (vb + (mb - mean) ** 2)
    )
