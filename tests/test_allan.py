"""Overlapping Allan deviation: exact hand cases, noise coefficients read back, GM shape."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hdrd.core.allan import (
    allan_deviation,
    arw_from_adev,
    bias_instability_from_adev,
    default_taus,
    gauss_markov_adev,
    rrw_adev,
    rrw_from_adev,
    white_noise_adev,
)


def _slope(taus: np.ndarray, adev: np.ndarray, lo: float, hi: float) -> float:
    m = (taus >= lo) & (taus <= hi)
    return float(np.polyfit(np.log(taus[m]), np.log(adev[m]), 1)[0])


def test_constant_signal_has_zero_deviation() -> None:
    taus, adev = allan_deviation(np.full(1000, 3.7), 10.0)
    assert taus.shape == adev.shape and taus.shape[0] > 5
    np.testing.assert_allclose(adev, 0.0, atol=1e-12)


def test_rate_ramp_is_exact() -> None:
    # x = a t: each cluster mean rises by a*tau, so AVAR = (a tau)^2 / 2 exactly.
    fs, a = 10.0, 0.02
    x = a * np.arange(5000) / fs
    taus, adev = allan_deviation(x, fs, np.array([0.1, 1.0, 10.0, 100.0]))
    np.testing.assert_allclose(taus, [0.1, 1.0, 10.0, 100.0])
    np.testing.assert_allclose(adev, a * taus / math.sqrt(2.0), rtol=1e-9)


def test_square_wave_hand_case() -> None:
    # Alternating +1/-1 at fs = 1: tau = 1 -> successive differences 2 -> AVAR = 2; tau = 2 -> 0.
    x = np.tile([1.0, -1.0], 50)
    _, adev = allan_deviation(x, 1.0, np.array([1.0, 2.0]))
    np.testing.assert_allclose(adev, [math.sqrt(2.0), 0.0], atol=1e-12)


def test_taus_are_rounded_filtered_and_merged() -> None:
    taus, _ = allan_deviation(
        np.zeros(101), 10.0, np.array([0.01, 0.1, 0.12, 0.5, 5.0, 5.1, 100.0])
    )
    # 0.01 s < one sample; 5.1 s = 51 samples > (101 - 1) / 2; 0.12 rounds to 0.1.
    np.testing.assert_allclose(taus, [0.1, 0.5, 5.0])


def test_default_taus_span_one_sample_to_half_the_record() -> None:
    t = default_taus(1001, 10.0)
    assert t[0] == pytest.approx(0.1) and t[-1] == pytest.approx(50.0)
    assert np.all(np.diff(t) > 0)
    assert default_taus(2, 10.0).shape == (0,)


@pytest.mark.parametrize("bad", [np.array([1.0, np.nan, 2.0]), np.array([1.0, np.inf])])
def test_non_finite_input_is_refused(bad: np.ndarray) -> None:
    with pytest.raises(ValueError, match="NaN or infinite"):
        allan_deviation(bad, 10.0)


def test_bad_rate_is_refused() -> None:
    with pytest.raises(ValueError, match="fs_hz"):
        allan_deviation(np.zeros(10), 0.0)


def test_white_noise_density_read_back() -> None:
    fs, n_density = 10.0, 0.05
    x = np.random.default_rng(1).standard_normal(100_000) * n_density * math.sqrt(fs)
    taus, adev = allan_deviation(x, fs)
    assert arw_from_adev(taus, adev) == pytest.approx(n_density, rel=0.05)
    assert _slope(taus, adev, 0.1, 100.0) == pytest.approx(-0.5, abs=0.05)
    np.testing.assert_allclose(
        adev[taus <= 100], white_noise_adev(taus[taus <= 100], n_density), rtol=0.15
    )


def test_rate_random_walk_read_back() -> None:
    fs, k = 10.0, 0.01
    x = np.cumsum(np.random.default_rng(2).standard_normal(200_000) * k / math.sqrt(fs))
    taus, adev = allan_deviation(x, fs)
    assert _slope(taus, adev, 1.0, 1000.0) == pytest.approx(0.5, abs=0.1)
    assert rrw_from_adev(taus, adev) == pytest.approx(k, rel=0.25)
    m = (taus > 1) & (taus < 300)
    np.testing.assert_allclose(adev[m], rrw_adev(taus[m], k), rtol=0.3)


def test_gauss_markov_formula_limits_and_peak() -> None:
    sigma, tc = 0.3, 50.0
    # tau << tc: looks like a rate random walk with K^2 = 2 sigma^2 / tc.
    small = np.array([1e-6, 1e-3, 0.05]) * tc
    np.testing.assert_allclose(
        gauss_markov_adev(small, sigma, tc), sigma * np.sqrt(2 * small / (3 * tc)), rtol=0.03
    )
    # tau >> tc: white noise with N^2 = 2 sigma^2 tc.
    big = np.array([1e3, 1e4]) * tc
    np.testing.assert_allclose(
        gauss_markov_adev(big, sigma, tc), np.sqrt(2 * sigma**2 * tc / big), rtol=0.01
    )
    # Continuous across the series/closed-form switch at tau = 0.01 tc.
    a, b = gauss_markov_adev(np.array([0.00999999, 0.01000001]) * tc, sigma, tc)
    assert a == pytest.approx(b, rel=1e-5)
    q = np.linspace(0.5, 4.0, 3501)
    g = gauss_markov_adev(q * tc, sigma, tc)
    assert q[np.argmax(g)] == pytest.approx(1.89, abs=0.01)
    assert g.max() == pytest.approx(0.617 * sigma, rel=0.01)


def test_simulated_gauss_markov_matches_formula() -> None:
    fs, sigma, tc, n = 10.0, 0.1, 20.0, 100_000
    rng = np.random.default_rng(3)
    a = math.exp(-1.0 / (fs * tc))
    w = rng.standard_normal(n) * sigma * math.sqrt(1 - a * a)
    x = np.empty(n)
    x[0] = sigma * rng.standard_normal()
    for i in range(1, n):  # independent reference recursion (not the simulator's code)
        x[i] = a * x[i - 1] + w[i]
    taus, adev = allan_deviation(x, fs, np.logspace(0, 2.3, 12))
    np.testing.assert_allclose(adev, gauss_markov_adev(taus, sigma, tc), rtol=0.15)


def test_bias_instability_reads_the_floor() -> None:
    taus = np.array([1.0, 10.0, 100.0, 1000.0])
    adev = np.array([0.05, 0.02, 0.0133, 0.03])
    b, at = bias_instability_from_adev(taus, adev)
    assert b == pytest.approx(0.0133 / 0.6643, rel=1e-3)
    assert at == 100.0
    assert math.isnan(bias_instability_from_adev(np.empty(0), np.empty(0))[0])


def test_arw_is_nan_without_a_minus_half_slope() -> None:
    taus = np.logspace(0, 3, 20)
    assert math.isnan(arw_from_adev(taus, rrw_adev(taus, 0.01)))
    assert math.isnan(rrw_from_adev(taus, white_noise_adev(taus, 0.01)))
