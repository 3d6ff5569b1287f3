"""The noise side of the model-gap workflow: Allan deviation over logs with gaps, and the
block-mean noise model with its whitening Kalman filter (exact Gaussian likelihood).

Rates deg/s, variances (deg/s)**2, times s. Pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hdrd.analysis.gap.data import GapData

__all__ = [
    "TAUS_PER_DECADE",
    "Noise",
    "Whitener",
    "adev_cluster_sizes",
    "allan_deviation_masked",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

TAUS_PER_DECADE = 5


def allan_deviation_masked(
    x: npt.ArrayLike,
    valid: npt.ArrayLike,
    fs_hz: float,
    m: npt.ArrayLike,
    breaks: npt.ArrayLike | None = None,
) -> FloatArray:
    """Overlapping Allan deviation (units of x) at cluster sizes ``m`` (samples), using only the
    clusters whose 2m samples are all valid and contiguous (``breaks[i]``: a time gap just
    before sample i, rows dropped); NaN where there are fewer than 4 such clusters. So each
    cluster lies inside one contiguous valid run. With every sample valid and no break it
    equals :func:`hdrd.analysis.allan.allan_deviation`."""
    v = np.asarray(valid, dtype=bool)
    y = np.asarray(x, dtype=np.float64)
    ms = np.asarray(m, dtype=np.int64)
    mean = float(y[v].mean()) if v.any() else 0.0
    theta = np.concatenate(([0.0], np.cumsum(np.where(v, y - mean, 0.0)))) / fs_hz
    bad = np.concatenate(([0], np.cumsum(~v)))
    # brk[j] counts the breaks before samples 1..j: a cluster over samples j..j+2m-1 has none
    # inside it when brk[j + 2m - 1] == brk[j].
    b = np.zeros(v.shape[0], dtype=bool) if breaks is None else np.asarray(breaks, dtype=bool)
    brk = np.cumsum(b)
    clean = bool(v.all()) and not bool(b[1:].any())
    out = np.full(ms.shape[0], np.nan)
    for i, mi in enumerate(ms):
        if mi < 1 or 2 * mi >= theta.shape[0]:
            continue
        d = theta[2 * mi :] - 2.0 * theta[mi:-mi]
        d += theta[: -2 * mi]
        if clean:
            count = d.shape[0]
        else:
            ok = (bad[2 * mi :] - bad[: -2 * mi]) == 0
            ok &= brk[2 * mi - 1 :] == brk[: brk.shape[0] - 2 * mi + 1]
            count = int(np.count_nonzero(ok))
            d *= ok
        if count < 4:
            continue
        tau = mi / fs_hz
        # einsum, not dot: a threaded BLAS dot of a long vector is slow on a busy machine.
        out[i] = math.sqrt(float(np.einsum("i,i->", d, d)) / (2.0 * tau * tau * count))
    return out


def adev_cluster_sizes(data: GapData, samples: bool = False) -> IntArray:
    """Cluster sizes of the gap's Allan deviation: samples, or blocks for a heading truth."""
    per_block = data.truth_source.startswith("heading_truth") and not samples
    n = data.nblocks if per_block else data.t.shape[0]
    m_max = max(1, n // 10)
    k = max(int(TAUS_PER_DECADE * math.log10(max(m_max, 2))) + 1, 2)
    return np.unique(np.round(np.logspace(0, math.log10(m_max), k))).astype(np.int64)


# -- the noise model and the whitening Kalman filter -----------------------------------------------


@dataclass(frozen=True)
class Noise:
    """The random part of the block-mean residual: per-sample white variance (deg/s)**2,
    quantization step, Gauss-Markov sigma/tau, random-walk K, extra block variance."""

    white_var: float
    q_step: float = 0.0
    bi_sigma: float = 0.0
    bi_tau: float = 300.0
    rrw_k: float = 0.0
    extra_var: float = 0.0


class Whitener:
    """Innovations of a Kalman filter over the block grid: whitening the block residual with them
    gives the exact Gaussian log-likelihood of the noise model

        y_k = D_k + gbar_k + wbar_k + v_k

    gbar: block mean of a Gauss-Markov bias g (sigma, tau_c); wbar: block mean of a rate random
    walk w (K, zero at power-on); v: white (white noise and quantization averaged over the n_k
    samples of the block, plus ``extra_var``). Both g and w are Markov, so a block mean given
    the values at the block's two ends is independent of everything else:
    gbar = gamma (g_start + g_end) + zeta_g, wbar = (w_start + w_end) / 2 + zeta_w with white
    zeta. The state is (g_start, g_end, w_start, w_end); blocks without truth are predicted
    through, not updated. With no correlated noise it reduces to dividing by the white sd."""

    def __init__(self, data: GapData, noise: Noise) -> None:
        b = data.block_s
        cnt = data.bneff[data.bvalid]
        r = (noise.white_var + noise.q_step**2 / 12.0) / cnt + noise.extra_var
        self.diag = noise.bi_sigma <= 0 and noise.rrw_k <= 0
        if self.diag:
            r = np.maximum(r, 1e-18)
            self.s = r
            self.sd = np.sqrt(r)
            return
        sig2 = noise.bi_sigma**2
        x = b / noise.bi_tau
        a = math.exp(-x)
        if x < 1e-4:
            zeta_g = x / 6.0
            c = 1.0 - 0.5 * x
        else:
            c = (1.0 - a) / x  # Cov(block mean, end value) / sigma**2
            fvar = 2.0 * (x - 1.0 + a) / (x * x)  # Var(block mean) / sigma**2
            zeta_g = max(fvar - 2.0 * c * c / (1.0 + a), 0.0)
        h = c / (1.0 + a)
        qg = sig2 * (1.0 - a * a)
        qw = noise.rrw_k**2 * b
        r = np.maximum(r + sig2 * zeta_g + qw / 12.0, 1e-18)
        rl = r.tolist()
        n = int(r.shape[0])
        s = [0.0] * n
        gains = [(0.0, 0.0, 0.0, 0.0)] * n
        # P at block 0: g at its two ends stationary with correlation a; w from zero at power-on.
        p00, p01, p02, p03 = sig2, a * sig2, 0.0, 0.0
        p11, p12, p13 = sig2, 0.0, 0.0
        w0 = noise.rrw_k**2 * data.block_t0  # the walk started at power-on, t = 0
        p22, p23, p33 = w0, w0, w0 + qw
        valid = data.bvalid.tolist()
        j = 0
        for k in range(data.nblocks):
            if k:
                p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = (
                    p11,
                    a * p11,
                    p13,
                    p13,
                    a * a * p11 + qg,
                    a * p13,
                    a * p13,
                    p33,
                    p33,
                    p33 + qw,
                )
            if not valid[k]:
                continue
            v0 = h * (p00 + p01) + 0.5 * (p02 + p03)
            v1 = h * (p01 + p11) + 0.5 * (p12 + p13)
            v2 = h * (p02 + p12) + 0.5 * (p22 + p23)
            v3 = h * (p03 + p13) + 0.5 * (p23 + p33)
            sj = h * (v0 + v1) + 0.5 * (v2 + v3) + rl[j]
            k0, k1, k2, k3 = v0 / sj, v1 / sj, v2 / sj, v3 / sj
            p00 -= k0 * v0
            p01 -= k0 * v1
            p02 -= k0 * v2
            p03 -= k0 * v3
            p11 -= k1 * v1
            p12 -= k1 * v2
            p13 -= k1 * v3
            p22 -= k2 * v2
            p23 -= k2 * v3
            p33 -= k3 * v3
            s[j] = sj
            gains[j] = (k0, k1, k2, k3)
            j += 1
        self.s = np.asarray(s)
        self.sd = np.sqrt(self.s)
        self._gains = gains
        self._a, self._h = a, h
        self._valid = valid
        self._nblocks = data.nblocks

    @property
    def logdet(self) -> float:
        return float(np.sum(np.log(self.s)))

    def whiten(self, y: FloatArray) -> FloatArray:
        """Standardised innovations of y (used blocks; 1-D, or 2-D with one column each)."""
        if self.diag:
            return (y.T / self.sd).T if y.ndim > 1 else y / self.sd
        if y.ndim == 1:
            return self._whiten1(y)
        out = np.empty_like(y)
        c = y.shape[1]
        g0, g1, w0, w1 = np.zeros(c), np.zeros(c), np.zeros(c), np.zeros(c)
        a, h = self._a, self._h
        j = 0
        for k in range(self._nblocks):
            if k:
                g0, g1, w0 = g1, a * g1, w1
            if not self._valid[k]:
                continue
            nu = y[j] - h * (g0 + g1) - 0.5 * (w0 + w1)
            out[j] = nu / self.sd[j]
            k0, k1, k2, k3 = self._gains[j]
            g0, g1, w0, w1 = g0 + k0 * nu, g1 + k1 * nu, w0 + k2 * nu, w1 + k3 * nu
            j += 1
        return out

    def _whiten1(self, y: FloatArray) -> FloatArray:
        yl = y.tolist()
        sd = self.sd.tolist()
        out = [0.0] * len(yl)
        g0 = g1 = w0 = w1 = 0.0
        a, h = self._a, self._h
        j = 0
        for k in range(self._nblocks):
            if k:
                g0, g1, w0 = g1, a * g1, w1
            if not self._valid[k]:
                continue
            nu = yl[j] - h * (g0 + g1) - 0.5 * (w0 + w1)
            out[j] = nu / sd[j]
            k0, k1, k2, k3 = self._gains[j]
            g0 += k0 * nu
            g1 += k1 * nu
            w0 += k2 * nu
            w1 += k3 * nu
            j += 1
        return np.asarray(out)

    def loglik(self, y: FloatArray) -> float:
        w = self.whiten(y)
        return -0.5 * (w.shape[0] * math.log(2.0 * math.pi) + self.logdet + float(np.dot(w, w)))
