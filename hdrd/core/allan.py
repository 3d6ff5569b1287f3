"""Overlapping Allan deviation of a rate signal, and the noise coefficients read from it.

Pure. For a rate x sampled at fs (deg/s) and cluster time tau = m / fs, with the integrated
angle theta[k] = sum(x[:k]) / fs (IEEE Std 952-1997, Annex C; overlapping estimator)::

    AVAR(tau) = sum_k (theta[k + 2m] - 2 theta[k + m] + theta[k])**2 / (2 tau**2 (N - 2m))

Reading the log-log plot (IEEE Std 952 / El-Sheimy et al. 2008):

- white rate noise, density N (deg/s/sqrt(Hz)): slope -1/2, ADEV(tau) = N / sqrt(tau), so N is
  the -1/2 line's value at tau = 1 s (the angle random walk coefficient, deg/sqrt(s));
- bias instability B: the flat minimum, ADEV_min = B * sqrt(2 ln 2 / pi) = 0.664 B;
- rate random walk K (deg/s/sqrt(s)): slope +1/2, ADEV(tau) = K * sqrt(tau / 3);
- first-order Gauss-Markov of sigma, tau_c: :func:`gauss_markov_adev` (rises as +1/2, peaks
  near 0.62 sigma at tau ~ 1.89 tau_c, falls as -1/2).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

__all__ = [
    "allan_deviation",
    "arw_from_adev",
    "bias_instability_from_adev",
    "default_taus",
    "gauss_markov_adev",
    "rrw_adev",
    "rrw_from_adev",
    "white_noise_adev",
]

FloatArray = npt.NDArray[np.float64]

_BI_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.664


def default_taus(n: int, fs_hz: float, per_decade: int = 10) -> FloatArray:
    """Log-spaced cluster times from one sample to the longest with two full clusters, s."""
    m_max = (n - 1) // 2
    if m_max < 1:
        return np.empty(0)
    ms = np.unique(
        np.round(np.logspace(0, math.log10(m_max), max(int(per_decade * math.log10(m_max)) + 1, 2)))
    )
    return ms.astype(np.float64) / fs_hz


def allan_deviation(
    x: npt.ArrayLike, fs_hz: float, taus: npt.ArrayLike | None = None
) -> tuple[FloatArray, FloatArray]:
    """Overlapping Allan deviation of the rate samples x (units of x) at cluster times taus (s).

    Requested taus are rounded to whole samples; those shorter than one sample or longer than
    (N - 1) / 2 samples are dropped, and duplicates merged. Returns (taus actually used, adev).
    Raises ValueError on non-finite samples or a bad rate.
    """
    y = np.asarray(x, dtype=np.float64)
    if y.ndim != 1:
        raise ValueError("x must be one-dimensional")
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise ValueError(f"fs_hz must be a positive number, got {fs_hz!r}")
    if not np.all(np.isfinite(y)):
        raise ValueError("x contains NaN or infinite samples; cut or fill them first")
    n = int(y.shape[0])
    if taus is None:
        tau_req = default_taus(n, fs_hz)
    else:
        tau_req = np.atleast_1d(np.asarray(taus, dtype=np.float64))
    m = np.unique(np.round(tau_req * fs_hz).astype(np.int64))
    m = m[(m >= 1) & (m <= (n - 1) // 2)]
    # Remove the mean before the cumulative sum: AVAR is unchanged, precision is not.
    theta = np.concatenate(([0.0], np.cumsum(y - y.mean()))) / fs_hz
    adev = np.empty(m.shape[0])
    for i, mi in enumerate(m):
        d = theta[2 * mi :] - 2.0 * theta[mi:-mi] + theta[: -2 * mi]
        tau = mi / fs_hz
        adev[i] = math.sqrt(float(np.dot(d, d)) / (2.0 * tau * tau * d.shape[0]))
    return m.astype(np.float64) / fs_hz, adev


def _slopes(taus: FloatArray, adev: FloatArray) -> FloatArray:
    lt, la = np.log(taus), np.log(adev)
    return np.gradient(la, lt) if taus.shape[0] > 1 else np.zeros_like(taus)


def _on_slope(taus: FloatArray, adev: FloatArray, slope: float, at: float, tol: float) -> float:
    """Value at tau = ``at`` of the line of the given log-log slope through the curve point whose
    local slope is within tol of it and closest (in log tau) to ``at``; nan if none."""
    t = np.asarray(taus, dtype=np.float64)
    a = np.asarray(adev, dtype=np.float64)
    ok = (a > 0) & np.isfinite(a)
    t, a = t[ok], a[ok]
    if t.shape[0] < 2:
        return math.nan
    s = _slopes(t, a)
    cand = np.flatnonzero(np.abs(s - slope) <= tol)
    if cand.shape[0] == 0:
        return math.nan
    i = cand[np.argmin(np.abs(np.log(t[cand]) - math.log(at)))]
    return float(a[i] * (at / t[i]) ** slope)


def arw_from_adev(taus: FloatArray, adev: FloatArray, tol: float = 0.15) -> float:
    """White-noise density N (units of x per sqrt(Hz)): the -1/2 slope line's value at 1 s."""
    return _on_slope(taus, adev, -0.5, 1.0, tol)


def rrw_from_adev(taus: FloatArray, adev: FloatArray, tol: float = 0.15) -> float:
    """Rate random walk K (units of x per sqrt(s)): the +1/2 slope line's value at 3 s."""
    return _on_slope(taus, adev, 0.5, 3.0, tol)


def bias_instability_from_adev(taus: FloatArray, adev: FloatArray) -> tuple[float, float]:
    """Bias instability B = min(adev) / 0.664 and the tau (s) of that minimum."""
    a = np.asarray(adev, dtype=np.float64)
    if a.shape[0] == 0:
        return math.nan, math.nan
    i = int(np.argmin(a))
    return float(a[i] / _BI_FACTOR), float(np.asarray(taus)[i])


def white_noise_adev(taus: npt.ArrayLike, density: float) -> FloatArray:
    """ADEV of white noise of density N: N / sqrt(tau)."""
    return density / np.sqrt(np.asarray(taus, dtype=np.float64))


def rrw_adev(taus: npt.ArrayLike, k: float) -> FloatArray:
    """ADEV of a rate random walk K: K * sqrt(tau / 3)."""
    return k * np.sqrt(np.asarray(taus, dtype=np.float64) / 3.0)


def gauss_markov_adev(taus: npt.ArrayLike, sigma: float, tau_c: float) -> FloatArray:
    """ADEV of a stationary first-order Gauss-Markov process (variance sigma**2, correlation
    time tau_c), from its autocovariance sigma**2 exp(-|s| / tau_c)::

        AVAR(T) = sigma**2 (tau_c / T)**2 (2 T / tau_c - 3 + 4 exp(-T / tau_c) - exp(-2 T / tau_c))
    """
    T = np.asarray(taus, dtype=np.float64)
    q = T / tau_c
    # The bracket cancels to (2/3) q**3 for small q: use its series there.
    small = q < 1e-2
    qs = np.where(small, 1.0, q)
    bracket = np.where(
        small,
        q**3 * (2.0 / 3.0 - 0.5 * q + 7.0 / 30.0 * q * q),
        2.0 * qs - 3.0 + 4.0 * np.exp(-qs) - np.exp(-2.0 * qs),
    )
    avar = sigma**2 / (q * q) * bracket
    return np.sqrt(np.maximum(avar, 0.0))
