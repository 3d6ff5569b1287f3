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
    equals :func:`hdrd.core.allan.allan_deviation`."""
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
    """The random part of the block-mean residual: per-sample white variance (deg/s)**2 at
    the sensor's input, quantization step, Gauss-Markov sigma/tau, random-walk K, extra block
    variance, and the per-sample white variance after the low-pass (``bandwidth``'s output
    noise, (deg/s)**2)."""

    white_var: float
    q_step: float = 0.0
    bi_sigma: float = 0.0
    bi_tau: float = 300.0
    rrw_k: float = 0.0
    extra_var: float = 0.0
    after_var: float = 0.0

    @property
    def sample_var(self) -> float:
        """The white variance per sample that block means average down, (deg/s)**2: the
        sensor's, the output stage's and the ADC's."""
        return self.white_var + self.after_var + self.q_step**2 / 12.0


def _gauss_markov_block(b: float, tau: float) -> tuple[float, float, float]:
    """A Gauss-Markov bias of correlation time ``tau`` over a block of ``b`` seconds, per
    sigma**2: a = its correlation between the block's ends, c = Cov(block mean, end value),
    zeta_g = the block mean's variance left given both ends."""
    x = b / tau
    a = math.exp(-x)
    if x < 1e-4:
        zeta_g = x / 6.0
        c = 1.0 - 0.5 * x
    else:
        c = (1.0 - a) / x  # Cov(block mean, end value) / sigma**2
        fvar = 2.0 * (x - 1.0 + a) / (x * x)  # Var(block mean) / sigma**2
        zeta_g = max(fvar - 2.0 * c * c / (1.0 + a), 0.0)
    return a, c, zeta_g


def _filter4(
    rl: list[float], valid: list[bool], a: float, h: float, sig2: float, qw: float, w0: float
) -> tuple[list[float], list[tuple[float, float, float, float]]]:
    """:class:`Whitener`'s filter over the blocks, written out on the state (g_start, g_end,
    w_start, w_end): each used block's innovation variance and gains. ``rl``: the white
    variance of each used block; ``w0``: the walk's variance at the first block's start."""
    qg = sig2 * (1.0 - a * a)
    n = len(rl)
    s = [0.0] * n
    gains = [(0.0, 0.0, 0.0, 0.0)] * n
    # P at block 0: g at its two ends stationary with correlation a; w from zero at power-on.
    p00, p01, p02, p03 = sig2, a * sig2, 0.0, 0.0
    p11, p12, p13 = sig2, 0.0, 0.0
    p22, p23, p33 = w0, w0, w0 + qw
    j = 0
    for k in range(len(valid)):
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
    return s, gains


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
    through, not updated. With no correlated noise it reduces to dividing by the white sd.

    With a heading truth, ``extra_var`` is the truth's own error: white heading noise eta at
    the fixes (variance extra_var / 2, in rate units over a block), entering block k as
    eta_k - eta_(k+1). Neighbouring blocks share a fix, so this error is negatively
    correlated between them and does not accumulate; white gyro noise does. The filter then
    carries the noise at the block's two end fixes as two more states
    (:class:`_HeadingKalman`), which keeps the two apart (a random walk of the heading from
    the gyro's white noise against a course that is only noisy at each fix)."""

    def __init__(self, data: GapData, noise: Noise) -> None:
        b = data.block_s
        cnt = data.bneff[data.bvalid]
        self._heading: _HeadingKalman | None = None
        if data.heading_mode and noise.extra_var > 0:
            # The truth's error is white heading noise at the fixes, differenced over a
            # block: neighbouring blocks share a fix, so it is not white per block.
            self.diag = False
            self._heading = _HeadingKalman(data, noise)
            self.s = self._heading.s
            self.sd = np.sqrt(self.s)
            return
        r = noise.sample_var / cnt + noise.extra_var
        self.diag = noise.bi_sigma <= 0 and noise.rrw_k <= 0
        if self.diag:
            r = np.maximum(r, 1e-18)
            self.s = r
            self.sd = np.sqrt(r)
            return
        sig2 = noise.bi_sigma**2
        a, c, zeta_g = _gauss_markov_block(b, noise.bi_tau)
        h = c / (1.0 + a)
        qw = noise.rrw_k**2 * b
        r = np.maximum(r + sig2 * zeta_g + qw / 12.0, 1e-18)
        valid = data.bvalid.tolist()
        w0 = noise.rrw_k**2 * data.block_t0  # the walk started at power-on, t = 0
        s, gains = _filter4(r.tolist(), valid, a, h, sig2, qw, w0)
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
        if self._heading is not None:
            return self._heading.whiten(y)
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


def _heading_transition(a: float) -> FloatArray:
    """:class:`_HeadingKalman`'s transition from a block to the next: the end states become
    the start states; the Gauss-Markov bias decays by ``a``, the walk holds."""
    f_mat = np.zeros((8, 8))
    f_mat[0, 1] = 1.0
    f_mat[1, 1] = a
    f_mat[2, 3] = 1.0
    f_mat[3, 3] = 1.0
    f_mat[4, 5] = 1.0
    f_mat[6, 7] = 1.0
    return f_mat


def _heading_start(
    a: float, sig2: float, qw: float, w0: float, se2: float, sw2: float
) -> FloatArray:
    """:class:`_HeadingKalman`'s covariance at block 0: the bias stationary at the block's
    two ends with correlation ``a``; the walk from power-on (``w0`` at the start); the fixes'
    and the fix rows' white noise."""
    p = np.zeros((8, 8))
    p[0, 0] = p[1, 1] = sig2
    p[0, 1] = p[1, 0] = a * sig2
    p[2, 2] = p[2, 3] = p[3, 2] = w0
    p[3, 3] = w0 + qw
    p[4, 4] = p[5, 5] = se2
    p[6, 6] = p[7, 7] = sw2
    return p


class _HeadingKalman:
    """The block likelihood's Kalman filter with a heading truth: state
    (g_start, g_end, w_start, w_end, eta_start, eta_end, eps_start, eps_end), the Gauss-Markov
    bias and the random walk at the block's two ends (as in :class:`Whitener`), the heading
    truth's white noise at its two end fixes (variance extra_var / 2 each, rate units:
    heading deg / block s) and the gyro's white noise at the two fix rows, which count half in
    each of the blocks they close and open (trapezoid rule). Consecutive blocks share their
    fix (the end states become the next block's start states); after a block without truth
    the next block's start fix is a fresh one, as in the simulated truth. A block at rest
    (``GapData.brest``: the vehicle stands, the true rate is zero at every sample) has neither
    the heading's error nor fix rows, so after it too the next fix is a fresh one."""

    def __init__(self, data: GapData, noise: Noise) -> None:
        b = data.block_s
        sig2 = noise.bi_sigma**2
        a, c, zeta_g = _gauss_markov_block(b, noise.bi_tau)
        h = c / (1.0 + a) if sig2 > 0 else 0.0
        qg = sig2 * (1.0 - a * a)
        qw = noise.rrw_k**2 * b
        se2 = noise.extra_var / 2.0
        sw2 = noise.sample_var  # per sample
        wsum = data.bweight[data.bvalid]
        # A block at rest has no heading error and no fix rows: its true rate is zero at
        # every sample, and its samples all weigh 1.
        fix = ~data.brest[data.bvalid] if data.brest.shape[0] else np.ones(wsum.shape[0], bool)
        # The two fix rows weigh 1/2 each: their noise is in the eps states, the rest in r.
        inner = np.maximum(1.0 / data.bneff[data.bvalid] - np.where(fix, 0.5 / wsum**2, 0.0), 0.0)
        r = np.maximum(sw2 * inner + sig2 * zeta_g + qw / 12.0, 1e-18)
        cfix = np.where(fix, 0.5 / wsum, 0.0)
        f_mat = _heading_transition(a)
        q_mat = np.diag([0.0, qg, 0.0, qw, 0.0, se2, 0.0, sw2])
        w0 = noise.rrw_k**2 * data.block_t0  # the walk started at power-on, t = 0
        p = _heading_start(a, sig2, qw, w0, se2, sw2)
        n = int(r.shape[0])
        hrows = np.empty((n, 8))
        hrows[:, :4] = [h, h, 0.5, 0.5]
        hrows[:, 4] = np.where(fix, 1.0, 0.0)
        hrows[:, 5] = -hrows[:, 4]
        hrows[:, 6] = hrows[:, 7] = cfix
        s = np.empty(n)
        gains = np.empty((n, 8))
        valid = data.bvalid.tolist()
        j = 0
        for k in range(data.nblocks):
            if k:
                p = f_mat @ p @ f_mat.T + q_mat
            if not valid[k]:
                continue
            v = p @ hrows[j]
            sj = float(hrows[j] @ v) + float(r[j])
            kg = v / sj
            p = p - np.outer(kg, v)
            s[j] = sj
            gains[j] = kg
            j += 1
        self.s = s
        self._f = f_mat
        self._hrows = hrows
        self._gains = gains
        self._valid = valid
        self._nblocks = data.nblocks

    def whiten(self, y: FloatArray) -> FloatArray:
        """Standardised innovations of y (used blocks; 1-D, or 2-D with one column each)."""
        two = y.ndim > 1
        yy = y if two else y[:, None]
        out = np.empty(yy.shape, dtype=np.float64)
        st = np.zeros((8, yy.shape[1]))
        sd = np.sqrt(self.s)
        f_mat, hrows, gains = self._f, self._hrows, self._gains
        j = 0
        for k in range(self._nblocks):
            if k:
                st = f_mat @ st
            if not self._valid[k]:
                continue
            nu = yy[j] - hrows[j] @ st
            out[j] = nu / sd[j]
            st = st + np.outer(gains[j], nu)
            j += 1
        return out if two else out[:, 0]
