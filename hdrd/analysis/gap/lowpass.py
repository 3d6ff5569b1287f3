"""The sample-level side of the noise: a sensor low-pass (bandwidth) seen in the differences of
neighbouring samples, fitted by the Whittle likelihood of their spectrum. Pure.

At rest the unexplained residual e (omega - truth - D, deg/s) is white noise of variance W per
sample seen through the sensor's first-order low-pass y[k] = a y[k-1] + (1 - a) x[k]
(a = exp(-2 pi f_c dt), the simulator's ``bandwidth``), plus the ADC's white q**2/12 after it,
plus slow processes (bias instability, random walk). First differences within contiguous
valid runs take the slow part away but for a small flat floor c, and have the spectrum

    S(w) = (2 - 2 cos w) [W (1 - a)**2 / (1 - 2 a cos w + a**2) + q**2 / 12] + c

per sample (w in rad per sample), s**2 the white noise after the low-pass (the ADC's q**2/12,
or more: a quantiser fed with noise narrower than its step is not uniform), fitted. The
Whittle log-likelihood ln L = -sum_k [ln S(w_k) + I_k / S(w_k)] over the periodogram I_k of
the differences is the Gaussian one to O(1) for a long series; it is summed over narrow
frequency bins (the spectrum is smooth across each), from the block frequency up: below it
the slow processes dominate, and the block likelihood speaks for those frequencies. The white
model is the same with a = 0 (one white level).

Seen through the low-pass, neighbouring differences understate the white noise: their
variance is 2 W (1 - a)**2 / (1 + a) + 2 q**2 / 12, so W is (1 + a) / (1 - a)**2 times what
white noise alone would give (:func:`white_factor`; 130x at a = 0.88).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["A_MAX", "A_MIN", "LowpassFit", "cutoff_hz", "fit_lowpass", "pole", "white_factor"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

A_MIN = 1e-3
"""Smallest pole fitted: a cutoff above ~1.1 x the sample rate is no low-pass in the data."""
A_MAX = 0.999
"""Largest pole: a cutoff of 1.6e-4 x the sample rate (a 1000-sample time constant)."""
_BINS = 4000


def pole(cutoff_hz_: float, dt_s: float) -> float:
    """The low-pass pole a = exp(-2 pi f_c dt) per sample."""
    return math.exp(-2.0 * math.pi * cutoff_hz_ * dt_s)


def cutoff_hz(a: float, dt_s: float) -> float:
    """The cutoff (Hz, -3 dB) of the pole a at the sample period dt_s."""
    return -math.log(a) / (2.0 * math.pi * dt_s)


def white_factor(a: float) -> float:
    """Input white variance over the white-equivalent variance of neighbouring differences."""
    return (1.0 + a) / (1.0 - a) ** 2


def differences(e: FloatArray, valid: BoolArray, time_gap: BoolArray) -> FloatArray:
    """Differences of neighbouring samples, both valid and with no time gap between them."""
    ok = valid[1:] & valid[:-1] & ~time_gap[1:]
    return np.asarray(np.diff(e)[ok])


@dataclass(frozen=True)
class LowpassFit:
    """Whittle fit of the differences: pole a (0 = no low-pass), input white variance W
    (deg/s)**2 per sample, its log-likelihood, and that of the best white model (a = 0);
    ``after_var``: the white variance per sample after the low-pass beyond the ADC's
    q**2/12, (deg/s)**2 (the output stage's own noise: ``bandwidth``'s output noise)."""

    a: float
    white_var: float
    loglik: float
    loglik_white: float
    after_var: float = 0.0

    @property
    def gain(self) -> float:
        """Log-likelihood gained by the low-pass over white noise alone."""
        return self.loglik - self.loglik_white


class _Spectrum:
    """The binned periodogram of the differences and the Whittle likelihood of a model."""

    def __init__(self, de: FloatArray, w_min: float) -> None:
        n = de.shape[0]
        x = de - de.mean()
        per = np.abs(np.fft.rfft(x)) ** 2 / n
        k = np.arange(per.shape[0])
        keep = (k > 0) & (k < n / 2.0) & (2.0 * math.pi * k / n >= w_min)
        w = 2.0 * math.pi * k[keep] / n
        per = per[keep]
        nb = min(_BINS, w.shape[0])
        edges = np.linspace(0, w.shape[0], nb + 1).astype(np.int64)
        self.m = np.diff(edges).astype(np.float64)
        self.i = np.add.reduceat(per, edges[:-1]) / self.m
        self.w = np.add.reduceat(w, edges[:-1]) / self.m
        self.d2 = 2.0 - 2.0 * np.cos(self.w)

    def shape(self, a: float) -> FloatArray:
        """Spectrum of the differences per unit input white variance, pole a."""
        return np.asarray(self.d2 * (1.0 - a) ** 2 / (1.0 - 2.0 * a * np.cos(self.w) + a * a))

    def loglik(self, s: FloatArray) -> float:
        return -float(np.sum(self.m * (np.log(s) + self.i / s)))

    def best_linear(self, gs: list[FloatArray], g0: FloatArray) -> tuple[FloatArray, float]:
        """(c, ln L) maximising the likelihood of S = sum_j c_j gs[j] + g0 over c >= 0, by
        coordinate ascent: one coefficient at a time by Fisher scoring (the spectrum is linear
        in it), clipped at zero, until a sweep gains less than 1e-4."""
        mtot = float(np.sum(self.m))
        c = [
            max(float(np.sum(self.m * np.maximum(self.i - g0, 0.0) / gj)) / mtot, 1e-30)
            for gj in gs
        ]
        c = [x / len(gs) for x in c]
        sp = sum(cj * gj for cj, gj in zip(c, gs)) + g0
        ll = self.loglik(sp)
        for _ in range(60):
            start = ll
            for j, gj in enumerate(gs):
                for _ in range(8):
                    r = self.m / (sp * sp)
                    score = float(np.sum(gj * r * (self.i - sp)))
                    info = float(np.sum(gj * gj * r))
                    new = max(c[j] + score / info, 0.0)
                    while True:  # halve the step until the likelihood does not fall
                        sp_new = sp + (new - c[j]) * gj
                        ll_new = self.loglik(sp_new) if np.all(sp_new > 0) else -math.inf
                        if ll_new >= ll or abs(new - c[j]) <= 1e-12 * max(c[j], 1e-30):
                            break
                        new = 0.5 * (new + c[j])
                    if ll_new < ll:
                        break
                    moved = ll_new - ll
                    c[j], sp, ll = new, sp_new, ll_new
                    if moved < 1e-6:
                        break
            if ll - start < 1e-4:
                break
        return np.asarray(c), ll


def fit_lowpass(
    de: FloatArray,
    block_samples: float,
    q_var: float = 0.0,
    floor: float = 0.0,
    a: float | None = None,
) -> LowpassFit:
    """Whittle fit of the differences ``de`` (deg/s) from the block frequency (one cycle per
    ``block_samples``) up: the pole a (given, or fitted over [A_MIN, A_MAX]), the input white
    variance W and the white variance after the low-pass (at least the ADC's ``q_var`` =
    q**2/12), with the slow processes' flat ``floor`` ((deg/s)**2) known."""
    sp = _spectrum(np.asarray(de, dtype=np.float64), 2.0 * math.pi / max(block_samples, 2.0))
    if not float(np.sum(sp.m)) > 0:  # no frequency above the block's: nothing to fit a pole to
        white = max(float(np.var(de)) / 2.0 - q_var, 0.0) if len(de) else 0.0
        return LowpassFit(
            a=A_MIN if a is None else a, white_var=white, loglik=0.0, loglik_white=0.0
        )
    g0 = sp.d2 * q_var + floor
    _, ll_white = sp.best_linear([sp.d2], g0)

    def at(av: float) -> tuple[float, float, float]:
        c, ll = sp.best_linear([sp.shape(av), sp.d2], g0)
        return float(c[0]), ll, float(c[1])

    if a is None:
        # Grid over ln(1 - a), then golden-section refinement around the best point.
        grid = 1.0 - np.logspace(math.log10(1.0 - A_MAX), math.log10(1.0 - A_MIN), 40)
        vals = [at(float(x))[1] for x in grid]
        j = int(np.argmax(vals))
        lo = math.log(1.0 - float(grid[min(j + 1, 39)]))
        hi = math.log(1.0 - float(grid[max(j - 1, 0)]))
        g = (math.sqrt(5.0) - 1.0) / 2.0
        x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
        f1, f2 = at(1.0 - math.exp(x1))[1], at(1.0 - math.exp(x2))[1]
        for _ in range(25):
            if f1 > f2:
                hi, x2, f2 = x2, x1, f1
                x1 = hi - g * (hi - lo)
                f1 = at(1.0 - math.exp(x1))[1]
            else:
                lo, x1, f1 = x1, x2, f2
                x2 = lo + g * (hi - lo)
                f2 = at(1.0 - math.exp(x2))[1]
        a = 1.0 - math.exp(0.5 * (lo + hi))
        if vals[j] > at(a)[1]:
            a = float(grid[j])
    a = min(max(a, A_MIN), A_MAX)
    w, ll, after = at(a)
    return LowpassFit(a=a, white_var=w, loglik=ll, loglik_white=ll_white, after_var=after)


_CACHE: dict[tuple[int, float, bytes], _Spectrum] = {}


def _spectrum(de: FloatArray, w_min: float) -> _Spectrum:
    """The binned periodogram of ``de``, remembered for the last few series (a fit asks for
    the same residual's spectrum many times)."""
    key = (de.shape[0], w_min, hashlib.blake2b(de.tobytes(), digest_size=16).digest())
    sp = _CACHE.get(key)
    if sp is None:
        if len(_CACHE) >= 8:
            _CACHE.pop(next(iter(_CACHE)))
        sp = _CACHE[key] = _Spectrum(de, w_min)
    return sp
