"""The model-gap workflow: where a gyro error model and a measured log disagree, which effect
explains it, and how much the gap shrinks once that effect is fitted (docs/model-gap.md).

Pure core (:func:`prepare`, :func:`run_gap`, :func:`to_report`, :func:`summary` and the
statistics they use) and the ``hdrd gap`` edge (:func:`main`). Rates deg/s, + = CCW (left
turn); heading compass deg, clockwise from north; time s since the first sample; temperature
deg C. The effect names and parameters are those of :mod:`hdrd.sim.gyro`.

The loop, each step visible in the report:

1. The residual r = omega - truth (truth: ``omega_truth``, else the derivative of the GPS
   course ``heading_truth``, else zero with ``standstill``) is split into the current model's
   *deterministic* prediction D (its bias, gain, lag, clipping effects applied to the true
   rate, noise off) and an unexplained part e = r - D.
2. The model is simulated under the log's conditions (same t, truth, temp_c; several seeds) and
   compared with the measurement: Allan deviation of e against that of the simulated e over
   tau; e against time, temp_c, the true rate and its sign, the rate's derivative; the
   histogram of omega (ADC lattice, clipping rails). The gap (:func:`gap_metric`) condenses it.
3. Every candidate effect not in the model is fitted (Gaussian likelihood of the block-averaged
   residual, whitened by a Kalman filter for the correlated noise effects; lattice likelihood
   for quantization), scored by BIC, and the best one is added only if BIC falls by more than
   :data:`BIC_MARGIN` and the likelihood-ratio test rejects "no such effect" at :data:`ALPHA`.
   Candidates the data cannot tell apart from the best one are reported as ambiguous.
4. The enlarged model is refitted as a whole and re-simulated; repeat until nothing is
   significant.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.analysis.allan import gauss_markov_adev
from hdrd.drivelog import DriveLog
from hdrd.sim.gyro import (
    DEFAULT_START_MODEL,
    EFFECTS,
    BiasInstability,
    Effect,
    GyroModel,
    Quantization,
    RateRandomWalk,
    Saturation,
    ScaleAsymmetry,
    ScaleFactor,
    StaticBias,
    TemperatureBias,
    TimeOffset,
    WarmupTransient,
    WhiteNoise,
)

__all__ = [
    "ALPHA",
    "AMBIGUITY_BIC",
    "AMBIGUITY_R",
    "BIC_MARGIN",
    "CANDIDATES",
    "GAP_METRIC",
    "NOISE_EFFECTS",
    "Ambiguity",
    "Fit",
    "GapData",
    "GapError",
    "GapResult",
    "Lattice",
    "Step",
    "allan_deviation_masked",
    "chi2_sf",
    "decimal_resolution",
    "detect_lattice",
    "deterministic_part",
    "fit_model",
    "gap_metric",
    "main",
    "prepare",
    "run_gap",
    "summary",
    "to_report",
    "truth_rate_from_heading",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

NOISE_EFFECTS = ("bias_instability", "rate_random_walk", "white_noise", "quantization")
"""Effects with a random (or, for quantization, sub-sample) output: they shape the residual's
covariance and histogram, not its deterministic prediction D."""

CANDIDATES = (
    "static_bias",
    "white_noise",
    "temperature_bias",
    "warmup_transient",
    "scale_factor",
    "scale_asymmetry",
    "time_offset",
    "saturation",
    "quantization",
    "bias_instability",
    "rate_random_walk",
)
"""Effects the workflow may add, in the order they are tried. ``bandwidth`` is not one: at a
vehicle's yaw dynamics (< 1 Hz) a first-order low-pass is a pure lag of 1 / (2 pi f_c) and
cannot be told from ``time_offset``; a model that has it keeps it unchanged."""

BIC_MARGIN = 10.0
"""An effect is added only if BIC falls by more than this ("very strong" evidence, Kass &
Raftery 1995: a likelihood ratio above e**5 ~ 150 after the parameter penalty)."""

ALPHA = 1e-3
"""...and only if the likelihood-ratio test rejects "effect absent" at this level."""

AMBIGUITY_BIC = 10.0
"""A significant candidate whose BIC is within this of the best one's is a rival..."""

AMBIGUITY_R = 0.8
"""...if, for two deterministic effects, their fitted contributions to the block residual
correlate at least this much (|r|): they explain the same disagreement in the same way."""

MAX_STEPS = 8
N_SIM = 4  # realisations averaged for the simulated Allan deviation
LATTICE_MIN_FRACTION = 0.999  # share of omega samples on a lattice for it to count as an ADC's
GLITCH_P = 1e-3  # per-sample probability of an off-lattice value under a quantised model
TAUS_PER_DECADE = 5
MIN_TEMP_STD_C = 0.3  # below this temp_c carries no usable information on temperature_bias

GAP_METRIC = (
    "sqrt(A**2 + H**2), dimensionless. A: root mean square over log-spaced averaging times tau "
    "(one sample to a tenth of the log, 5 per decade) of ln(ADEV_meas(tau) / ADEV_sim(tau)), "
    "the Allan deviations of the unexplained residual e = omega - truth - D (D: the model's "
    "deterministic prediction) in the measured log and in the model simulated under the same "
    "t, truth and temp_c (Allan variance averaged over 4 seeds); A = 0.69 means the two differ "
    "by a factor of 2 on average, sampling noise alone gives ~0.1-0.3. H: |fraction of "
    "measured omega on the finest ADC lattice found in either - fraction of simulated omega on "
    "it| (histogram term: quantization). Effects already in the model are refitted to the log "
    "before the gap is measured."
)


class GapError(ValueError):
    """The log cannot be analysed (no truth, too short, ...); the message says why."""


# -- the truth and the blocks -----------------------------------------------------------------


def _fixes(t: FloatArray, h: FloatArray) -> IntArray:
    """Row indices of the fixes in a heading column: finite values, a value held over several
    rows counted once (its first row)."""
    ok = np.flatnonzero(np.isfinite(h))
    if ok.shape[0] > 1:
        keep = np.concatenate(([True], h[ok[1:]] != h[ok[:-1]]))
        ok = ok[keep]
    return ok


def truth_rate_from_heading(
    t_s: npt.ArrayLike, heading_deg: npt.ArrayLike, max_gap_s: float = 2.5
) -> FloatArray:
    """True yaw rate (deg/s, + = CCW) per sample from a compass heading (deg, clockwise from
    north; NaN = unknown), e.g. a 1 Hz GPS course.

    Between two consecutive fixes at most ``max_gap_s`` apart the rate is -(heading change the
    short way round) / (time between them): CW -> CCW. It is given to the samples between the
    two fixes' rows; a fix's own row, shared by two intervals, gets the mean of both rates (the
    trapezoid rule: samples are instantaneous values, so a row between two intervals belongs
    half to each). NaN elsewhere (stops, outages, before the first fix).
    """
    t = np.asarray(t_s, dtype=np.float64)
    h = np.asarray(heading_deg, dtype=np.float64)
    out = np.full(t.shape[0], np.nan)
    ok = _fixes(t, h)
    if ok.shape[0] < 2:
        return out
    tf, hf = t[ok], h[ok]
    dt = np.diff(tf)
    dh = (np.diff(hf) + 180.0) % 360.0 - 180.0  # shortest way round: 359 -> 1 is +2 deg
    rate = -dh / dt
    good = dt <= max_gap_s
    for j in np.flatnonzero(good):
        out[ok[j] : ok[j + 1]] = rate[j]
    both = np.flatnonzero(good[1:] & good[:-1]) + 1  # fixes with a good interval on each side
    out[ok[both]] = 0.5 * (rate[both - 1] + rate[both])
    return out


@dataclass(frozen=True)
class Lattice:
    """The values' lattice: omega = offset + k * step_dps for all but a few samples."""

    step_dps: float
    offset_dps: float
    fraction: float
    """Share of samples on the lattice."""


def decimal_resolution(x: npt.ArrayLike) -> float:
    """The log's recording resolution, deg/s: the coarsest 10**-k (k = 0..9) of which every
    value is a multiple; 1e-9 for binary floating-point data that fit none."""
    v = np.asarray(x, dtype=np.float64)
    v = v[np.isfinite(v)]
    for k in range(10):
        s = v * 10.0**k
        if np.all(np.abs(s - np.round(s)) <= 1e-6 * np.maximum(1.0, np.abs(s)) * 1e-3 + 1e-6):
            return 10.0**-k
    return 1e-9


def _on_lattice(v: FloatArray, step: float, offset: float, resolution: float) -> BoolArray:
    frac = (v - offset) / step
    tol = (0.5 * resolution + 1e-12 * np.max(np.abs(v), initial=1.0)) / step + 1e-6
    return np.asarray(np.abs(frac - np.round(frac)) <= tol)


def detect_lattice(x: npt.ArrayLike, resolution: float) -> Lattice | None:
    """The coarsest value lattice (ADC codes) of the samples, if one at least 3x coarser than
    the recording ``resolution`` holds :data:`LATTICE_MIN_FRACTION` of them; else None.

    The step is guessed from the spacing of neighbouring distinct values (5th percentile),
    its offset from the circular mean phase, then the step is refined by least squares on the
    code numbers (a step read off one spacing is only good to the resolution)."""
    v = np.asarray(x, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.shape[0] < 20:
        return None
    u = np.unique(v)
    if u.shape[0] < 3:
        return None
    d = np.diff(u)
    d = d[d > 0.5 * resolution]
    if d.shape[0] == 0:
        return None
    step = float(np.percentile(d, 5))
    if not step > 3.0 * resolution:
        return None
    for _ in range(3):
        phase = np.angle(np.mean(np.exp(2j * np.pi * v / step)))
        offset = float(phase * step / (2.0 * np.pi))
        k = np.round((v - offset) / step)
        on = _on_lattice(v, step, offset, resolution)
        if on.sum() < 10 or np.all(k[on] == k[on][0]):
            return None
        kk, vv = k[on], v[on]
        # v = offset + k * step: least squares on the samples on the lattice.
        a = np.vstack([np.ones_like(kk), kk]).T
        (offset, step), *_ = np.linalg.lstsq(a, vv, rcond=None)
        step = float(abs(step))
        if not step > 3.0 * resolution:
            return None
    on = _on_lattice(v, step, float(offset), resolution)
    fraction = float(on.mean())
    if fraction < LATTICE_MIN_FRACTION:
        return None
    return Lattice(step_dps=step, offset_dps=float(offset), fraction=fraction)


@dataclass(frozen=True)
class GapData:
    """A measured log made ready for the workflow (see :func:`prepare`).

    Samples: t (s since the first sample), omega (deg/s), truth (deg/s; NaN where unknown),
    truth_filled (NaN replaced by interpolation, for simulating), temp_c (deg C or None),
    valid (truth known).

    Blocks of ``block_s`` on a regular grid from ``block_t0`` (0, or the first GPS fix when the
    truth is a heading): sample i counts with weight ``wprim[i]`` in block ``block_of[i]``
    (-1: none) and, at a heading truth's fix rows, with weight 1/2 in ``block_prev[i]`` too
    (trapezoid rule: the fix between two blocks belongs half to each). ``bvalid`` marks the
    blocks used (complete, with truth), ``bweight`` their weight sums, ``bneff`` the effective
    number of samples for white noise ((sum w)**2 / sum w**2), ``bt`` their mid times (s),
    ``btruth`` the mean true rate of each used block (deg/s; with a heading truth exactly the
    heading change between the block's end fixes over its duration).
    """

    t: FloatArray
    omega: FloatArray
    truth: FloatArray
    truth_filled: FloatArray
    temp_c: FloatArray | None
    valid: BoolArray
    truth_source: str
    fs_hz: float
    block_s: float
    block_t0: float
    nblocks: int
    block_of: IntArray
    wprim: FloatArray
    block_prev: IntArray
    bvalid: BoolArray
    bweight: FloatArray
    bneff: FloatArray
    bt: FloatArray
    btruth: FloatArray
    resolution_dps: float
    lattice: Lattice | None
    name: str = ""

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])

    @property
    def n_used(self) -> int:
        """Number of blocks in the likelihood."""
        return int(self.bvalid.sum())

    @property
    def heading_mode(self) -> bool:
        return self.truth_source.startswith("heading_truth")

    def block_mean(self, x: FloatArray) -> FloatArray:
        """Weighted mean of the sample values x over each used block."""
        sel = self.block_of >= 0
        s = np.bincount(self.block_of[sel], weights=(self.wprim * x)[sel], minlength=self.nblocks)
        sp = self.block_prev >= 0
        if sp.any():
            s += np.bincount(self.block_prev[sp], weights=0.5 * x[sp], minlength=self.nblocks)
        return np.asarray(s[self.bvalid] / self.bweight[self.bvalid])

    def block_residual(self, y: FloatArray) -> FloatArray:
        """Block means of y (a gyro output, deg/s) minus the true rate: the block residual."""
        return self.block_mean(y) - self.btruth


def _block_length(duration_s: float, truth_source: str) -> float:
    # 1 s is the paper's step T; longer logs get longer blocks to keep the filter cheap, and a
    # truth differentiated from 1 Hz GPS needs a few seconds to average its noise down.
    base = 5.0 if truth_source == "heading_truth" else 1.0
    return float(max(base, math.ceil(duration_s / 1500.0)))


def prepare(log: DriveLog, standstill: bool = False, block_s: float | None = None) -> GapData:
    """Turn a drive log into :class:`GapData`. The truth rate is ``omega_truth`` where it has
    values, else the derivative of ``heading_truth``, else zero when ``standstill``. Raises
    GapError if there is no truth or too little of it."""
    n = len(log)
    if n < 100:
        raise GapError(f"the log has {n} samples; the workflow needs at least 100")
    t = np.asarray(log.t - log.t[0], dtype=np.float64)
    omega = np.asarray(log.omega, dtype=np.float64)
    origin, fix_dt = 0.0, 1.0
    fixes = np.empty(0, dtype=np.int64)
    heading = None
    if log.omega_truth is not None and np.isfinite(log.omega_truth).any():
        truth = np.asarray(log.omega_truth, dtype=np.float64)
        source = "omega_truth"
    elif log.heading_truth is not None and np.isfinite(log.heading_truth).sum() > 2:
        heading = np.asarray(log.heading_truth, dtype=np.float64)
        truth = truth_rate_from_heading(t, heading)
        source = "heading_truth"
        fixes = _fixes(t, heading)
        origin = float(t[fixes[0]])
        fix_dt = float(np.median(np.diff(t[fixes]))) if fixes.shape[0] > 1 else 1.0
    elif standstill:
        truth = np.zeros(n)
        source = "standstill"
    else:
        raise GapError(
            "the log has no truth: it needs an omega_truth or heading_truth column, "
            "or --standstill for a log taken at rest"
        )
    if standstill and source != "standstill":
        source += " (--standstill ignored: the log has truth)"
    valid = np.isfinite(truth)
    if valid.sum() < 100:
        raise GapError(f"only {int(valid.sum())} samples have a known true rate; need >= 100")
    idx = np.arange(n)
    truth_filled = np.interp(idx, idx[valid], truth[valid])
    temp = None
    if log.temp_c is not None and np.isfinite(log.temp_c).any():
        tc = np.asarray(log.temp_c, dtype=np.float64)
        ok = np.isfinite(tc)
        temp = tc if ok.all() else np.interp(idx, idx[ok], tc[ok])
    dt = float(np.median(np.diff(t)))
    fs = 1.0 / dt
    if block_s is not None:
        bs = float(block_s)
    else:
        bs = _block_length(float(t[-1]), source)
        if heading is not None:
            bs *= max(1.0, round(fix_dt))  # whole fix intervals
    if not (math.isfinite(bs) and bs >= dt):
        raise GapError(f"block length {bs!r} s is shorter than the sample period {dt:g} s")
    nblocks = math.floor((t[-1] - origin + dt) / bs + 1e-9)
    if nblocks < 20:
        raise GapError(
            f"the log covers {nblocks} blocks of {bs:g} s; the workflow needs at least 20 "
            f"(a log of {20 * bs:g} s or more)"
        )
    # Sample i covers [t_i, t_i + dt); half a sample of margin absorbs float jitter.
    blk = np.floor((t - origin + 0.5 * dt) / bs - 1e-9).astype(np.int64)
    inside = (blk >= 0) & (blk < nblocks)
    bi = np.where(inside, blk, nblocks)  # nblocks: a bin for "outside"
    total = np.bincount(bi, minlength=nblocks + 1)[:nblocks].astype(np.float64)
    good = np.bincount(bi[valid], minlength=nblocks + 1)[:nblocks].astype(np.float64)
    bvalid = (good >= 0.8 * bs * fs) & (good == total)
    wprim = np.ones(n)
    block_prev = np.full(n, -1, dtype=np.int64)
    btruth_full = np.full(nblocks, np.nan)
    if heading is not None:
        # Each block must start on a fix and end on the next block's first row, also a fix.
        is_fix = np.zeros(n, dtype=bool)
        is_fix[fixes] = True
        first = np.full(nblocks + 1, -1, dtype=np.int64)
        rows = np.flatnonzero(inside)
        first_rows = rows[np.concatenate(([True], blk[rows][1:] != blk[rows][:-1]))]
        first[blk[first_rows]] = first_rows
        after = np.flatnonzero(blk == nblocks)
        if after.shape[0]:
            first[nblocks] = after[0]
        hu = np.full(n, np.nan)  # heading unwrapped along the fixes, deg
        dh = (np.diff(heading[fixes]) + 180.0) % 360.0 - 180.0
        hu[fixes] = heading[fixes[0]] + np.concatenate(([0.0], np.cumsum(dh)))
        for k in range(nblocks):
            a, b = first[k], first[k + 1]
            edge_ok = (
                a >= 0
                and b >= 0
                and is_fix[a]
                and is_fix[b]
                and bool(valid[a:b].all())
                and bool(valid[b])
            )
            if edge_ok and bvalid[k]:
                btruth_full[k] = -(hu[b] - hu[a]) / (t[b] - t[a])  # CW heading -> CCW rate
                wprim[a] = 0.5
                if k > 0:
                    block_prev[a] = k - 1
            else:
                bvalid[k] = False
        # The half-row that closes block k is the first row of block k + 1: give it to k even
        # when block k + 1 itself is not used.
        for kk in np.flatnonzero(bvalid).tolist():
            b = first[kk + 1]
            if b >= 0 and block_prev[b] < 0:
                block_prev[b] = kk
    block_of = np.where(inside & valid & bvalid[np.clip(blk, 0, nblocks - 1)], blk, -1)
    block_prev = np.where(
        (block_prev >= 0) & bvalid[np.clip(block_prev, 0, nblocks - 1)], block_prev, -1
    )
    wsum = np.bincount(block_of[block_of >= 0], weights=wprim[block_of >= 0], minlength=nblocks)
    w2 = np.bincount(block_of[block_of >= 0], weights=wprim[block_of >= 0] ** 2, minlength=nblocks)
    if (block_prev >= 0).any():
        wsum += np.bincount(
            block_prev[block_prev >= 0],
            weights=np.full(int((block_prev >= 0).sum()), 0.5),
            minlength=nblocks,
        )
        w2 += np.bincount(
            block_prev[block_prev >= 0],
            weights=np.full(int((block_prev >= 0).sum()), 0.25),
            minlength=nblocks,
        )
    if bvalid.sum() < 20:
        raise GapError(
            f"only {int(bvalid.sum())} blocks of {bs:g} s have a complete true rate; need >= 20"
        )
    # The writer's resolution for rates: omega's own digits can look coarse when its values
    # sit on a round ADC lattice (0.05 deg/s values are all multiples of 0.01), so the true
    # rate column, written alike, is consulted too.
    res = decimal_resolution(omega)
    if log.omega_truth is not None:
        res = min(res, decimal_resolution(log.omega_truth))
    data = GapData(
        t=t,
        omega=omega,
        truth=truth,
        truth_filled=truth_filled,
        temp_c=temp,
        valid=valid,
        truth_source=source,
        fs_hz=fs,
        block_s=bs,
        block_t0=origin,
        nblocks=nblocks,
        block_of=block_of,
        wprim=wprim,
        block_prev=block_prev,
        bvalid=bvalid,
        bweight=np.where(wsum > 0, wsum, 1.0),
        bneff=np.where(w2 > 0, wsum**2 / np.where(w2 > 0, w2, 1.0), 1.0),
        bt=origin + (np.arange(nblocks) + 0.5) * bs,
        btruth=np.empty(0),
        resolution_dps=res,
        lattice=detect_lattice(omega, res),
        name=log.name,
    )
    bt_used = btruth_full[bvalid] if heading is not None else data.block_mean(truth_filled)
    return replace(data, btruth=bt_used)


# -- Allan deviation with gaps --------------------------------------------------------------------


def allan_deviation_masked(
    x: npt.ArrayLike, valid: npt.ArrayLike, fs_hz: float, m: npt.ArrayLike
) -> FloatArray:
    """Overlapping Allan deviation (units of x) at cluster sizes ``m`` (samples), using only the
    clusters whose 2m samples are all valid; NaN where there are fewer than 4 such clusters.
    With every sample valid it equals :func:`hdrd.analysis.allan.allan_deviation`."""
    v = np.asarray(valid, dtype=bool)
    y = np.asarray(x, dtype=np.float64)
    ms = np.asarray(m, dtype=np.int64)
    mean = float(y[v].mean()) if v.any() else 0.0
    theta = np.concatenate(([0.0], np.cumsum(np.where(v, y - mean, 0.0)))) / fs_hz
    bad = np.concatenate(([0], np.cumsum(~v)))
    out = np.full(ms.shape[0], np.nan)
    for i, mi in enumerate(ms):
        if mi < 1 or 2 * mi >= theta.shape[0]:
            continue
        d = theta[2 * mi :] - 2.0 * theta[mi:-mi] + theta[: -2 * mi]
        ok = (bad[2 * mi :] - bad[: -2 * mi]) == 0
        if ok.sum() < 4:
            continue
        tau = mi / fs_hz
        dd = d[ok]
        out[i] = math.sqrt(float(np.dot(dd, dd)) / (2.0 * tau * tau * dd.shape[0]))
    return out


def _gap_ms(data: GapData, samples: bool = False) -> IntArray:
    """Cluster sizes of the gap's Allan deviation: samples, or blocks for a heading truth."""
    per_block = data.truth_source.startswith("heading_truth") and not samples
    n = data.nblocks if per_block else data.t.shape[0]
    m_max = max(1, n // 10)
    k = max(int(TAUS_PER_DECADE * math.log10(max(m_max, 2))) + 1, 2)
    return np.unique(np.round(np.logspace(0, math.log10(m_max), k))).astype(np.int64)


# -- the model's deterministic part -------------------------------------------------------------


def _det_model(model: GyroModel) -> GyroModel:
    return GyroModel(tuple(e for e in model.effects if e.name not in NOISE_EFFECTS))


_RNG0 = np.random.default_rng(0)


def deterministic_part(data: GapData, model: GyroModel) -> FloatArray:
    """D: what the model adds to the true rate with every random effect off (deg/s per sample):
    its bias, gain, lag, bandwidth and clipping effects applied to the truth, minus the truth.
    Quantization is left out: on a noisy signal it adds a small white error, not a bias."""
    det = _det_model(model)
    if not det.effects:
        return np.zeros_like(data.t)
    y = det.apply(data.t, data.truth_filled, data.temp_c, _RNG0)
    return np.asarray(y - data.truth_filled)


# -- the noise model and the whitening Kalman filter -----------------------------------------------


@dataclass(frozen=True)
class _Noise:
    """The random part of the block-mean residual: per-sample white variance (deg/s)**2,
    quantization step, Gauss-Markov sigma/tau, random-walk K, extra block variance."""

    white_var: float
    q_step: float = 0.0
    bi_sigma: float = 0.0
    bi_tau: float = 300.0
    rrw_k: float = 0.0
    extra_var: float = 0.0


class _Whitener:
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

    def __init__(self, data: GapData, noise: _Noise) -> None:
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


# -- small optimisers (numpy only) ---------------------------------------------------------------


def _levenberg_marquardt(
    fun: Callable[[FloatArray], FloatArray], x0: FloatArray, h: FloatArray, max_iter: int = 40
) -> FloatArray:
    """Minimise |fun(x)|**2 from x0 (forward-difference Jacobian with steps h)."""
    x = np.array(x0, dtype=np.float64)
    r = fun(x)
    cost = float(np.dot(r, r))
    lam = 1e-4
    for _ in range(max_iter):
        jac = np.empty((r.shape[0], x.shape[0]))
        for j in range(x.shape[0]):
            xp = x.copy()
            xp[j] += h[j]
            jac[:, j] = (fun(xp) - r) / h[j]
        # A parameter with no effect here (e.g. held at a bound) is left where it is: solving
        # for it would take round-off for a direction.
        dg = np.diag(jac.T @ jac).copy()
        act = dg > 1e-14 * max(float(dg.max()), 1e-300)
        if not act.any():
            break
        ja = jac[:, act]
        g = ja.T @ r
        a = ja.T @ ja
        accepted = False
        for _ in range(10):
            step = np.zeros_like(x)
            try:
                step[act] = -np.linalg.solve(a + lam * np.diag(dg[act]), g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            xn = x + step
            rn = fun(xn)
            cn = float(np.dot(rn, rn))
            if np.isfinite(cn) and cn <= cost:
                accepted = True
                done = cost - cn <= 1e-10 * max(cost, 1e-300)
                x, r, cost = xn, rn, cn
                lam = max(lam / 5.0, 1e-12)
                break
            lam *= 10.0
        if not accepted or done:
            break
    return x


def _nelder_mead(
    f: Callable[[FloatArray], float], x0: FloatArray, scale: float = 0.5, iters: int = 80
) -> FloatArray:
    """Minimise f from x0 (unconstrained; a small simplex method, enough for 1-3 parameters)."""
    n = x0.shape[0]
    pts = [np.array(x0, dtype=np.float64)]
    for i in range(n):
        p = pts[0].copy()
        p[i] += scale
        pts.append(p)
    vals = [f(p) for p in pts]
    for _ in range(iters):
        order = np.argsort(vals)
        pts = [pts[i] for i in order]
        vals = [vals[i] for i in order]
        if abs(vals[-1] - vals[0]) < 1e-6 and np.max(np.abs(np.array(pts) - pts[0])) < 1e-4:
            break
        c = np.mean(pts[:-1], axis=0)
        xr = c + (c - pts[-1])
        fr = f(xr)
        if fr < vals[0]:
            xe = c + 2.0 * (c - pts[-1])
            fe = f(xe)
            pts[-1], vals[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < vals[-2]:
            pts[-1], vals[-1] = xr, fr
        else:
            xc = c + 0.5 * (pts[-1] - c)
            fc = f(xc)
            if fc < vals[-1]:
                pts[-1], vals[-1] = xc, fc
            else:
                for i in range(1, n + 1):
                    pts[i] = pts[0] + 0.5 * (pts[i] - pts[0])
                    vals[i] = f(pts[i])
    return pts[int(np.argmin(vals))]


def chi2_sf(x: float, k: int) -> float:
    """P(chi-squared with k degrees of freedom > x), k a positive integer (closed forms)."""
    if x <= 0:
        return 1.0
    h = 0.5 * x
    if k % 2 == 0:
        term, s = 1.0, 1.0
        for i in range(1, k // 2):
            term *= h / i
            s += term
        return float(min(1.0, math.exp(-h) * s))
    s = math.erfc(math.sqrt(h))
    for i in range((k - 1) // 2):
        s += math.exp(-h + (i + 0.5) * math.log(h) - math.lgamma(i + 1.5))
    return float(min(1.0, s))


# -- fitting a model -------------------------------------------------------------------------------

# Free deterministic parameters: (effect, parameter) -> (transform, finite-difference step).
# "log": the optimiser works on ln(value) (positive parameters).
_DET_PARAMS: dict[str, tuple[tuple[str, str, float], ...]] = {
    "static_bias": (("bias_dps", "lin", 1e-3),),
    "scale_factor": (("error", "lin", 1e-4),),
    "scale_asymmetry": (("pos_error", "lin", 1e-4), ("neg_error", "lin", 1e-4)),
    "warmup_transient": (("amplitude_dps", "lin", 1e-3), ("tau_s", "log", 1e-3)),
    "temperature_bias": (("coeff_dps_per_c", "lin", 1e-4),),
    "time_offset": (("delay_s", "lin", 1e-3),),
}

_TAU_BOUNDS = (1.0, 1e6)
_DELAY_MAX_S = 3.0


@dataclass(frozen=True)
class Fit:
    """A model fitted to the log: its log-likelihood (Gaussian block part + lattice part),
    number of fitted parameters k, BIC = -2 lnL + k ln(n blocks), the deterministic prediction
    D (per sample) and its block means Dbar (used blocks)."""

    model: GyroModel
    lnl: float
    k: int
    bic: float
    d: FloatArray = field(repr=False)
    dbar: FloatArray = field(repr=False)
    noise: _Noise = field(repr=False)
    quad: bool = False


def _free_det(model: GyroModel, quad: bool) -> list[tuple[str, str, str, float]]:
    out = []
    for e in model.effects:
        for p, kind, h in _DET_PARAMS.get(e.name, ()):
            out.append((e.name, p, kind, h))
        if e.name == "temperature_bias" and quad:
            out.append((e.name, "quad_dps_per_c2", "lin", 1e-5))
    return out


def _with_params(
    model: GyroModel,
    free: list[tuple[str, str, str, float]],
    theta: FloatArray,
    tau_bounds: tuple[float, float] = _TAU_BOUNDS,
) -> GyroModel:
    upd: dict[str, dict[str, float]] = {}
    lo, hi = math.log(tau_bounds[0]), math.log(tau_bounds[1])
    for (eff, p, kind, _), v in zip(free, theta):
        val = float(v)
        if kind == "log":
            val = float(math.exp(min(max(val, lo), hi)))
        if eff == "time_offset":
            val = min(max(val, -_DELAY_MAX_S), _DELAY_MAX_S)
        if p in ("error", "pos_error", "neg_error"):
            val = max(val, -0.9)
        upd.setdefault(eff, {})[p] = val
    effects = []
    for e in model.effects:
        if e.name in upd:
            effects.append(replace(e, **upd[e.name]))
        else:
            effects.append(e)
    return GyroModel(tuple(effects))


def _theta(model: GyroModel, free: list[tuple[str, str, str, float]]) -> FloatArray:
    vals = []
    for eff, p, kind, _ in free:
        v = float(getattr(model.get(eff), p))
        vals.append(math.log(v) if kind == "log" else v)
    return np.asarray(vals, dtype=np.float64)


def _white_var(data: GapData, d: FloatArray, q_step: float) -> float:
    """Per-sample white-noise variance (deg/s)**2 from sample-to-sample differences of the
    unexplained residual (robust: MAD), less the quantization's q**2/12."""
    e = data.omega - data.truth_filled - d
    # Pairs of samples with the same truth value: a piecewise-constant truth (from a heading)
    # jumps at its fixes, and such a jump is no sensor noise.
    ok = data.valid[1:] & data.valid[:-1]
    if data.truth_source.startswith("heading_truth"):
        ok &= data.truth_filled[1:] == data.truth_filled[:-1]
    de = np.diff(e)[ok]
    if de.shape[0] < 10:
        return float(np.var(e[data.valid]))
    mad = float(np.median(np.abs(de - np.median(de))))
    v = (1.4826 * mad) ** 2 / 2.0
    if mad == 0.0:
        v = float(np.var(de)) / 2.0
    return float(max(v - q_step**2 / 12.0, 1e-12))


def _noise_of(data: GapData, model: GyroModel, d: FloatArray, extra_var: float) -> _Noise:
    q = model.get("quantization")
    bi = model.get("bias_instability")
    rw = model.get("rate_random_walk")
    q_step = float(q.step_dps) if isinstance(q, Quantization) else 0.0
    wv = _white_var(data, d, q_step) if "white_noise" in model else 1e-10
    return _Noise(
        white_var=wv,
        q_step=q_step,
        bi_sigma=float(bi.sigma_dps) if isinstance(bi, BiasInstability) else 0.0,
        bi_tau=float(bi.tau_s) if isinstance(bi, BiasInstability) else 300.0,
        rrw_k=float(rw.k_dps_per_sqrt_s) if isinstance(rw, RateRandomWalk) else 0.0,
        extra_var=extra_var,
    )


def _model_noise(model: GyroModel, noise: _Noise, fs_hz: float) -> GyroModel:
    """The model with its noise effects' parameters set from ``noise``."""
    out = model
    if "white_noise" in model:
        out = out.with_effect(WhiteNoise(density_dps_per_rthz=math.sqrt(noise.white_var / fs_hz)))
    if "bias_instability" in model:
        out = out.with_effect(BiasInstability(sigma_dps=noise.bi_sigma, tau_s=noise.bi_tau))
    if "rate_random_walk" in model:
        out = out.with_effect(RateRandomWalk(k_dps_per_sqrt_s=noise.rrw_k))
    return out


def _lattice_loglik(data: GapData, model: GyroModel) -> float:
    """Log-likelihood gain of the recorded values under the model's ADC lattice against a
    continuous output recorded at the log's resolution: a value on the lattice has probability
    ~ f(x) * step instead of f(x) * resolution; off it only a glitch (:data:`GLITCH_P`)."""
    q = model.get("quantization")
    if not isinstance(q, Quantization):
        return 0.0
    off = data.lattice.offset_dps if data.lattice is not None else 0.0
    on = _on_lattice(data.omega, q.step_dps, off, data.resolution_dps)
    n_on = int(on.sum())
    n_off = int(on.shape[0] - n_on)
    gain = math.log((1.0 - GLITCH_P) * q.step_dps / data.resolution_dps + GLITCH_P)
    return n_on * gain + n_off * math.log(GLITCH_P)


def _count_params(model: GyroModel, free_det: int, data: GapData) -> int:
    k = free_det
    for e in model.effects:
        k += {
            "white_noise": 1,
            "bias_instability": 2,
            "rate_random_walk": 1,
            "quantization": 1,
            "saturation": 1,
        }.get(e.name, 0)
    if data.truth_source.startswith("heading_truth"):
        k += 1  # the truth's own noise variance
    return k


class _Fitter:
    """Fits the free parameters of one model structure to one log."""

    def __init__(self, data: GapData) -> None:
        self.data = data
        self.ebar = data.block_residual(data.omega)
        self.heading = data.truth_source.startswith("heading_truth")
        # A warm-up transient must visibly decay within the log; slower it is just a trend.
        self.tau_bounds = (data.block_s, max(data.duration_s / 2.0, 2.0 * data.block_s))

    def dbar(self, model: GyroModel) -> tuple[FloatArray, FloatArray]:
        d = deterministic_part(self.data, model)
        return d, self.data.block_mean(d)

    def fit_det(self, model: GyroModel, noise: _Noise, quad: bool) -> GyroModel:
        """Weighted (whitened) least squares of the deterministic parameters, noise fixed."""
        free = _free_det(model, quad)
        if not free:
            return model
        wh = _Whitener(self.data, noise)
        wy = wh.whiten(self.ebar)

        def res(theta: FloatArray) -> FloatArray:
            _, db = self.dbar(_with_params(model, free, theta, self.tau_bounds))
            return np.asarray(wy - wh.whiten(db))

        theta = _levenberg_marquardt(res, _theta(model, free), np.array([f[3] for f in free]))
        return _with_params(model, free, theta, self.tau_bounds)

    def loglik(self, model: GyroModel, noise: _Noise, dbar: FloatArray) -> float:
        return _Whitener(self.data, noise).loglik(self.ebar - dbar) + _lattice_loglik(
            self.data, model
        )

    def fit_noise(
        self, model: GyroModel, noise: _Noise, dbar: FloatArray, which: Sequence[str]
    ) -> _Noise:
        """Maximum likelihood of the named noise parameters (log scale), others fixed."""
        which = [w for w in which if w != "extra_var" or self.heading]
        if not which:
            return noise
        y = self.ebar - dbar

        def build(x: FloatArray) -> _Noise:
            kw: dict[str, float] = {}
            for name, v in zip(which, x):
                kw[name] = float(math.exp(min(max(v, -40.0), 20.0)))
            if "bi_tau" in kw:
                kw["bi_tau"] = min(
                    max(kw["bi_tau"], 2.0 * self.data.block_s), 10.0 * self.data.duration_s
                )
            return replace(noise, **kw)

        def nll(x: FloatArray) -> float:
            return -_Whitener(self.data, build(x)).loglik(y)

        x0 = []
        for w in which:
            v = getattr(noise, w)
            x0.append(math.log(v) if v > 0 else math.log(1e-6))
        x = _nelder_mead(nll, np.array(x0), scale=0.7, iters=60 * len(which))
        return build(x)

    def finish(self, model: GyroModel, noise: _Noise, quad: bool) -> Fit:
        d, db = self.dbar(model)
        noise = replace(
            noise,
            white_var=_white_var(self.data, d, noise.q_step)
            if "white_noise" in model
            else noise.white_var,
        )
        full = _model_noise(model, noise, self.data.fs_hz)
        lnl = self.loglik(full, noise, db)
        k = _count_params(full, len(_free_det(full, quad)), self.data)
        bic = -2.0 * lnl + k * math.log(self.data.n_used)
        return Fit(model=full, lnl=lnl, k=k, bic=bic, d=d, dbar=db, noise=noise, quad=quad)

    def full(
        self, model: GyroModel, quad: bool = False, extra_var: float = 0.0, rounds: int = 2
    ) -> Fit:
        """Fit every free parameter of the model: alternate deterministic least squares and
        maximum likelihood of the noise."""
        d, db = self.dbar(model)
        noise = _noise_of(self.data, model, d, extra_var)
        if self.heading and noise.extra_var == 0.0:
            noise = replace(noise, extra_var=float(np.var(self.ebar - db)))
        which = ["extra_var"] if self.heading else []
        if "bias_instability" in model:
            which += ["bi_sigma", "bi_tau"]
        if "rate_random_walk" in model:
            which += ["rrw_k"]
        for _ in range(rounds):
            model = self.fit_det(model, noise, quad)
            d, db = self.dbar(model)
            noise = replace(
                noise,
                white_var=_white_var(self.data, d, noise.q_step)
                if "white_noise" in model
                else noise.white_var,
            )
            noise = self.fit_noise(model, noise, db, which)
            if not which:
                break
        return self.finish(model, noise, quad)


def fit_model(data: GapData, model: GyroModel) -> Fit:
    """Refit all parameters of ``model`` to the log (its structure unchanged)."""
    f = _Fitter(data)
    tb = model.get("temperature_bias")
    quad = isinstance(tb, TemperatureBias) and tb.quad_dps_per_c2 != 0.0
    if "saturation" in model and _rail(data) is not None:
        model = model.with_effect(Saturation(limit_dps=_rail(data) or 200.0))
    if "quantization" in model and data.lattice is not None:
        model = model.with_effect(Quantization(step_dps=data.lattice.step_dps))
    return f.full(model, quad=quad)


def _rail(data: GapData) -> float | None:
    """The clipping level the histogram suggests: the largest |omega| (deg/s)."""
    m = float(np.max(np.abs(data.omega)))
    return m if m > 0 else None


# -- candidates ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Cand:
    name: str
    fit: Fit
    dk: int
    dlnl: float
    dbic: float
    p: float
    contribution: FloatArray | None  # change of the block prediction, deg/s (deterministic)

    @property
    def significant(self) -> bool:
        return self.dbic < -BIC_MARGIN and self.p < ALPHA


def _not_identifiable(data: GapData, model: GyroModel) -> dict[str, str]:
    """Candidates the log's columns cannot inform, with the reason."""
    out: dict[str, str] = {}
    truth = data.truth[data.valid]
    moving = float(np.percentile(np.abs(truth), 99)) if truth.shape[0] else 0.0
    if data.temp_c is None:
        out["temperature_bias"] = "no temp_c column"
    else:
        tb = data.block_mean(data.temp_c)
        if float(np.std(tb)) < MIN_TEMP_STD_C:
            out["temperature_bias"] = f"temp_c varies by only {float(np.std(tb)):.2f} degC (std)"
    if moving < 1.0:
        why = "the true rate is (near) zero throughout: gain, lag and clipping need turns"
        for c in ("scale_factor", "scale_asymmetry", "time_offset", "saturation"):
            out[c] = why
    else:
        wb = data.btruth
        if int((wb > 1.0).sum()) < 2 or int((wb < -1.0).sum()) < 2:
            out["scale_asymmetry"] = "the drive turns one way only"
    if data.lattice is None:
        out["quantization"] = (
            f"no lattice of values coarser than the log's resolution ({data.resolution_dps:g} deg/s)"
        )
    if data.duration_s < 60.0:
        for c in ("warmup_transient", "bias_instability", "rate_random_walk"):
            out[c] = "the log is shorter than 60 s"
    return out


def _adev_excess_init(
    data: GapData, e: FloatArray, white_var: float, kind: str
) -> tuple[float, float]:
    """Start values for a correlated-noise candidate from the Allan variance of e above the
    white floor (its signature): (sigma, tau_c) for bias_instability, (K, 0) for the RRW."""
    ms = _gap_ms(data, samples=True)
    ms = ms[ms / data.fs_hz >= data.block_s]
    if ms.shape[0] == 0:
        return (1e-3, 10.0 * data.block_s)
    adev = allan_deviation_masked(e, data.valid, data.fs_hz, ms)
    taus = ms / data.fs_hz
    ok = np.isfinite(adev)
    taus, avar = taus[ok], adev[ok] ** 2
    if taus.shape[0] == 0:
        return (1e-3, 10.0 * data.block_s)
    excess = np.maximum(avar - white_var / data.fs_hz / taus, 0.0)
    w = 1.0 / np.maximum(avar, 1e-30) ** 2
    if kind == "rate_random_walk":
        g = taus / 3.0
        k2 = float(np.sum(w * g * excess) / np.sum(w * g * g))
        return (math.sqrt(max(k2, 1e-14)), 0.0)
    best = (math.inf, 1e-3, 10.0)
    for tc in np.logspace(
        math.log10(2.0 * data.block_s),
        math.log10(max(data.duration_s / 2.0, 4.0 * data.block_s)),
        12,
    ):
        g = gauss_markov_adev(taus, 1.0, float(tc)) ** 2
        s2 = float(np.sum(w * g * excess) / np.sum(w * g * g))
        sse = float(np.sum(w * (excess - s2 * g) ** 2))
        if sse < best[0]:
            best = (sse, math.sqrt(max(s2, 1e-14)), float(tc))
    return best[1], best[2]


def _candidate_fits(f: _Fitter, cur: Fit, name: str) -> list[Fit]:
    """Fitted models of the current model plus effect ``name`` (one per variant)."""
    data = f.data
    model = cur.model
    noise = cur.noise
    e_bar = f.ebar - cur.dbar
    fits: list[Fit] = []
    if name in NOISE_EFFECTS:
        e = data.omega - data.truth_filled - cur.d
        if name == "white_noise":
            m = model.with_effect(WhiteNoise(density_dps_per_rthz=0.05))
            return [f.full(m, quad=cur.quad, extra_var=noise.extra_var, rounds=1)]
        if name == "quantization":
            assert data.lattice is not None
            m = model.with_effect(Quantization(step_dps=data.lattice.step_dps))
            nz = replace(noise, q_step=data.lattice.step_dps)
            return [f.finish(m, nz, cur.quad)]
        if name == "bias_instability":
            s0, tc0 = _adev_excess_init(data, e, noise.white_var, name)
            nz = f.fit_noise(
                model, replace(noise, bi_sigma=s0, bi_tau=tc0), cur.dbar, ["bi_sigma", "bi_tau"]
            )
            m = model.with_effect(BiasInstability(sigma_dps=nz.bi_sigma, tau_s=nz.bi_tau))
        else:
            k0, _ = _adev_excess_init(data, e, noise.white_var, name)
            nz = f.fit_noise(model, replace(noise, rrw_k=k0), cur.dbar, ["rrw_k"])
            m = model.with_effect(RateRandomWalk(k_dps_per_sqrt_s=nz.rrw_k))
        m = f.fit_det(m, nz, cur.quad)
        return [f.finish(m, nz, cur.quad)]

    wh = _Whitener(data, noise)
    if name == "static_bias":
        variants = [(model.with_effect(StaticBias(bias_dps=float(np.mean(e_bar)))), cur.quad)]
    elif name == "scale_factor":
        variants = [(model.with_effect(ScaleFactor(error=0.0)), cur.quad)]
    elif name == "scale_asymmetry":
        variants = [(model.with_effect(ScaleAsymmetry(pos_error=0.0, neg_error=0.0)), cur.quad)]
    elif name == "temperature_bias":
        # Reference at the log's mean temperature: coeff is then the mean slope over the log,
        # whatever a (possibly spurious) quadratic term does at its ends.
        assert data.temp_c is not None
        ref = round(float(np.mean(data.temp_c[data.valid])), 1)
        tb = TemperatureBias(coeff_dps_per_c=0.0, ref_temp_c=ref, quad_dps_per_c2=0.0)
        variants = [
            (model.with_effect(tb), False),
            (model.with_effect(replace(tb, quad_dps_per_c2=1e-6)), True),
        ]
    elif name == "saturation":
        variants = [(model.with_effect(Saturation(limit_dps=_rail(data) or 200.0)), cur.quad)]
    elif name == "time_offset":
        # Start from the linear lag regression: e ~ -delay * d(truth)/dt.
        der = data.block_mean(np.gradient(data.truth_filled, data.t))
        wx, wy = wh.whiten(-der), wh.whiten(e_bar)
        d0 = float(np.dot(wx, wy) / max(np.dot(wx, wx), 1e-30))
        d0 = min(max(d0, -_DELAY_MAX_S), _DELAY_MAX_S)
        variants = [(model.with_effect(TimeOffset(delay_s=d0)), cur.quad)]
    elif name == "warmup_transient":
        # Grid over tau with the amplitude (and a constant) by whitened least squares.
        wy = wh.whiten(e_bar)
        one = wh.whiten(np.ones_like(e_bar))
        best = (math.inf, 0.0, 60.0)
        lo, hi = f.tau_bounds
        for tau in np.logspace(math.log10(lo), math.log10(hi), 16):
            x = wh.whiten(data.block_mean(np.exp(-data.t / tau)))
            a = np.vstack([x, one]).T
            coef, *_ = np.linalg.lstsq(a, wy, rcond=None)
            sse = float(np.sum((wy - a @ coef) ** 2))
            if sse < best[0]:
                best = (sse, float(coef[0]), float(tau))
        variants = [
            (model.with_effect(WarmupTransient(amplitude_dps=best[1], tau_s=best[2])), cur.quad)
        ]
    else:  # pragma: no cover - CANDIDATES and this function are kept in step
        raise ValueError(f"no fitting rule for {name}")
    for m, quad in variants:
        m = f.fit_det(m, noise, quad)
        fits.append(f.finish(m, noise, quad))
    return fits


def _evaluate(f: _Fitter, cur: Fit, name: str) -> _Cand:
    fits = _candidate_fits(f, cur, name)
    best = min(fits, key=lambda x: x.bic)
    dk = best.k - cur.k
    dlnl = best.lnl - cur.lnl
    dbic = best.bic - cur.bic
    p = chi2_sf(2.0 * dlnl, max(dk, 1)) if dlnl > 0 else 1.0
    contrib = None if name in NOISE_EFFECTS else best.dbar - cur.dbar
    return _Cand(name=name, fit=best, dk=dk, dlnl=dlnl, dbic=dbic, p=p, contribution=contrib)


def _corr(a: FloatArray, b: FloatArray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(np.dot(a, a)) * float(np.dot(b, b)))
    return float(np.dot(a, b) / den) if den > 0 else 0.0


# (general, special case): pos = neg = error; a Gauss-Markov bias whose correlation time
# exceeds the log is a random walk (sigma**2 / tau_c = K**2 / 2).
_NESTS = {("scale_asymmetry", "scale_factor"), ("bias_instability", "rate_random_walk")}


def _slow_gm(a: _Cand, duration_s: float) -> bool:
    gm = a.fit.model.get("bias_instability")
    return isinstance(gm, BiasInstability) and gm.tau_s >= duration_s


def _rivals(
    best: _Cand, others: list[_Cand], duration_s: float
) -> list[tuple[_Cand, float | None]]:
    """Significant candidates the data cannot tell from ``best`` (documented rule)."""
    out: list[tuple[_Cand, float | None]] = []
    for c in others:
        if c.name == best.name or not c.significant or "quantization" in (c.name, best.name):
            continue
        if (c.name, best.name) in _NESTS:
            continue  # the general form adds nothing the special case lacks: parsimony decides
        if (best.name, c.name) == ("bias_instability", "rate_random_walk") and _slow_gm(
            best, duration_s
        ):
            out.append((c, None))  # a Gauss-Markov bias slower than the log is a random walk
            continue
        if c.fit.bic - best.fit.bic >= AMBIGUITY_BIC:
            continue
        r: float | None = None
        if best.contribution is not None and c.contribution is not None:
            r = _corr(best.contribution, c.contribution)
            if abs(r) < AMBIGUITY_R:
                continue  # both real, explaining different parts: later steps add the other
        out.append((c, r))
    return out


def _special_case(e: Effect) -> Effect | None:
    """The nested special case an effect can be simplified to (same physics, fewer parameters)."""
    if isinstance(e, ScaleAsymmetry):
        return ScaleFactor(error=0.5 * (e.pos_error + e.neg_error))
    if isinstance(e, BiasInstability):
        return RateRandomWalk(k_dps_per_sqrt_s=e.sigma_dps * math.sqrt(2.0 / e.tau_s))
    return None


def _revise(f: _Fitter, cur: Fit, added: list[str], step: int) -> tuple[Fit, list[dict[str, Any]]]:
    """Backward check after a step: an effect added earlier that is no longer strongly
    supported now that the new one explains part of its disagreement is simplified to its
    nested special case or dropped (whichever has the lower BIC), if that costs less than
    :data:`BIC_MARGIN` of BIC. One change per call."""
    best: tuple[float, Fit, dict[str, Any]] | None = None
    for name in added[:-1]:
        e = cur.model.get(name)
        if e is None:
            continue
        alts: list[tuple[str, GyroModel]] = [("dropped", cur.model.without(name))]
        sc = _special_case(e)
        if sc is not None and sc.name not in cur.model:
            alts.append((f"replaced by {sc.name}", cur.model.without(name).with_effect(sc)))
        for how, m in alts:
            alt = f.full(m, quad=cur.quad, extra_var=cur.noise.extra_var)
            cost = alt.bic - cur.bic
            if cost < BIC_MARGIN and (best is None or alt.bic < best[0]):
                rec = {
                    "after_step": step,
                    "effect": name,
                    "action": how,
                    "delta_bic": round(cost, 2),
                    "why": f"{name} no longer lowers BIC by more than {BIC_MARGIN:g} once the later effects are in",
                }
                best = (alt.bic, alt, rec)
    if best is None:
        return cur, []
    return best[1], [best[2]]


# -- diagnostics: where do measurement and model disagree? -------------------------------------------


@dataclass(frozen=True)
class _Sim:
    """Allan deviations of the unexplained residual, measured and model-simulated."""

    taus: FloatArray
    adev_meas: FloatArray
    adev_sim: FloatArray
    a_term: float
    h_term: float

    @property
    def gap(self) -> float:
        return math.sqrt(self.a_term**2 + self.h_term**2)


def _simulate(data: GapData, model: GyroModel, seed: int, r: int) -> FloatArray:
    y = model.apply(data.t, data.truth_filled, data.temp_c, np.random.default_rng([seed, r]))
    if data.resolution_dps > 1e-9:
        y = np.round(y / data.resolution_dps) * data.resolution_dps  # as the log recorded it
    return np.asarray(y)


def gap_metric(
    data: GapData,
    model: GyroModel,
    seed: int = 0,
    d: FloatArray | None = None,
    truth_var: float = 0.0,
) -> _Sim:
    """The gap between the log and ``model`` (see :data:`GAP_METRIC`); model parameters as
    given. Deterministic for a seed.

    With a truth derived from a heading the Allan deviations are taken over block means (the
    truth is only known as heading changes between fixes), and the simulated block residual
    gets the truth's own error (white heading noise at the fixes, differenced: variance
    ``truth_var`` (deg/s)**2 per block, fitted with the model) so that both sides carry it."""
    d = deterministic_part(data, model) if d is None else d
    per_block = data.truth_source.startswith("heading_truth")
    ms = _gap_ms(data)
    rng_truth = np.random.default_rng([seed, 99])

    dbar = data.block_mean(d) if per_block else np.zeros(0)

    def adev(y: FloatArray, noise: bool) -> FloatArray:
        if not per_block:
            return allan_deviation_masked(y - data.truth_filled - d, data.valid, data.fs_hz, ms)
        full = np.zeros(data.nblocks)
        full[data.bvalid] = data.block_residual(y) - dbar
        if noise and truth_var > 0:
            # The truth's error: white heading noise at the fixes, differenced over a block.
            eta = math.sqrt(truth_var / 2.0) * rng_truth.standard_normal(data.nblocks + 1)
            full -= np.diff(eta)
        return allan_deviation_masked(full, data.bvalid, 1.0 / data.block_s, ms)

    adev_m = adev(data.omega, False)
    avar_s = np.zeros(ms.shape[0])
    sims = []
    for r in range(N_SIM):
        y = _simulate(data, model, seed, r)
        sims.append(y)
        avar_s += adev(y, True) ** 2
    adev_s = np.sqrt(avar_s / N_SIM)
    ok = np.isfinite(adev_m) & np.isfinite(adev_s) & (adev_m > 0) & (adev_s > 0)
    a = float(np.sqrt(np.mean(np.log(adev_m[ok] / adev_s[ok]) ** 2))) if ok.any() else 0.0
    taus = np.asarray(ms * data.block_s if per_block else ms / data.fs_hz, dtype=np.float64)
    # Histogram term: lattices found in the measurement or in the simulation.
    h = 0.0
    lattices = [data.lattice] if data.lattice is not None else []
    sim_lat = detect_lattice(sims[0], data.resolution_dps)
    if sim_lat is not None:
        lattices.append(sim_lat)
    for lat in lattices:
        fm = float(
            _on_lattice(data.omega, lat.step_dps, lat.offset_dps, data.resolution_dps).mean()
        )
        fs = float(
            np.mean(
                [
                    _on_lattice(y, lat.step_dps, lat.offset_dps, data.resolution_dps).mean()
                    for y in sims
                ]
            )
        )
        h = max(h, abs(fm - fs))
    return _Sim(taus=taus, adev_meas=adev_m, adev_sim=adev_s, a_term=a, h_term=h)


_REGRESSOR = {
    "temperature_bias": "temp_c",
    "warmup_transient": "time_s",
    "scale_factor": "true_rate",
    "scale_asymmetry": "true_rate",
    "time_offset": "rate_derivative",
    "saturation": "true_rate",
    "static_bias": "time_s",
    "bias_instability": "time_s",
    "rate_random_walk": "time_s",
    "white_noise": "time_s",
    "quantization": "omega",
}
"""The regressor each effect is read against, in the report's "where" and in the plot."""


def _regressors(data: GapData) -> dict[str, FloatArray]:
    """Block means of everything the residual is compared against."""
    w = data.truth_filled
    out = {
        "time_s": data.bt[data.bvalid],
        "true_rate": data.btruth,
        "true_rate_left": data.block_mean(np.maximum(w, 0.0)),
        "true_rate_right": data.block_mean(np.minimum(w, 0.0)),
        "rate_derivative": data.block_mean(np.gradient(w, data.t)),
    }
    if data.temp_c is not None:
        out["temp_c"] = data.block_mean(data.temp_c)
    return out


def _diagnostics(data: GapData, fit: Fit, sim: _Sim) -> dict[str, Any]:
    """Discrepancy measures for the report: Allan deviation ratio over tau, correlations of
    the unexplained block residual, residual by part of the log, histogram."""
    e = data.block_residual(data.omega) - fit.dbar
    regs = _regressors(data)
    corr = {
        k: round(_corr(e, v), 3)
        for k, v in regs.items()
        if k not in ("true_rate_left", "true_rate_right")
    }
    # Sign: separate slopes for left (+) and right (-) turns, least squares with a constant.
    a = np.vstack([regs["true_rate_left"], regs["true_rate_right"], np.ones_like(e)]).T
    coef, *_ = np.linalg.lstsq(a, e, rcond=None)
    parts = np.array_split(np.arange(e.shape[0]), 10)
    ratio = sim.adev_meas / sim.adev_sim
    rail = _rail(data)
    at_rail = int(
        np.sum(np.abs(np.abs(data.omega) - (rail or 0.0)) <= max(data.resolution_dps, 1e-9) * 1.01)
    )
    hist: dict[str, Any] = {
        "resolution_dps": data.resolution_dps,
        "max_abs_omega_dps": rail,
        "samples_at_max": at_rail,
    }
    if data.lattice is not None:
        hist["lattice_dps"] = round(data.lattice.step_dps, 9)
        hist["lattice_offset_dps"] = round(data.lattice.offset_dps, 9)
        hist["on_lattice"] = round(data.lattice.fraction, 5)
    return {
        "allan": {
            "tau_s": [round(float(x), 4) for x in sim.taus],
            "measured_dps": [
                None if not np.isfinite(x) else float(f"{x:.4g}") for x in sim.adev_meas
            ],
            "simulated_dps": [
                None if not np.isfinite(x) else float(f"{x:.4g}") for x in sim.adev_sim
            ],
            "max_ratio": None
            if not np.isfinite(ratio).any()
            else round(float(np.nanmax(ratio)), 3),
        },
        "correlation": corr,
        "slope_left_right": [round(float(coef[0]), 5), round(float(coef[1]), 5)],
        "mean_by_tenth_dps": [
            round(float(e[p].mean() - e.mean()), 5) if p.shape[0] else None for p in parts
        ],
        "histogram": hist,
    }


def _allan_phrase(sim: _Sim) -> str:
    r = sim.adev_meas / sim.adev_sim
    ok = np.isfinite(r)
    if not ok.any():
        return "Allan deviation not available"
    rr, tt = r[ok], sim.taus[ok]
    hi = rr > 1.5
    if not hi.any():
        return f"Allan deviation within 1.5x of the model's (max {float(rr.max()):.2f}x)"
    lo, top = _fmt_tau(float(tt[hi].min())), _fmt_tau(float(tt[hi].max()))
    span = lo if lo == top else f"{lo}-{top}"
    return f"Allan deviation up to {float(rr.max()):.1f}x the model's, above 1.5x at tau = {span} s"


def _fmt_tau(t: float) -> str:
    return f"{t:.2g}" if t < 10 else f"{t:.0f}"


def _where(data: GapData, cand: _Cand, sim: _Sim, diag: dict[str, Any]) -> str:
    """What disagreed, in words, for the effect that explains it."""
    allan = _allan_phrase(sim)
    c = diag["correlation"]
    n = cand.name
    if n == "temperature_bias":
        return f"{allan}; residual correlates with temp_c, r = {c.get('temp_c', 0.0):.2f}"
    if n == "warmup_transient":
        wt = cand.fit.model.get("warmup_transient")
        tau = float(wt.tau_s) if isinstance(wt, WarmupTransient) else 0.0
        parts = diag["mean_by_tenth_dps"]
        return (
            f"{allan}; residual vs time: {parts[0]:+.3f} deg/s in the first tenth of the log "
            f"against the mean (decays like exp(-t / {tau:.0f} s))"
        )
    if n == "scale_factor":
        return f"{allan}; residual correlates with the true rate, r = {c['true_rate']:.2f}"
    if n == "scale_asymmetry":
        sl, sr = diag["slope_left_right"]
        return (
            f"{allan}; residual vs true rate by sign: slope {sl:+.4f} in left turns (+), "
            f"{sr:+.4f} in right turns (-)"
        )
    if n == "time_offset":
        return f"{allan}; residual correlates with the true rate's derivative (lag), r = {c['rate_derivative']:.2f}"
    if n == "saturation":
        h = diag["histogram"]
        return (
            f"{allan}; histogram: {h['samples_at_max']} samples piled at +/-{h['max_abs_omega_dps']:.3f} deg/s "
            f"(clipping rail); residual correlates with the true rate, r = {c['true_rate']:.2f}"
        )
    if n == "quantization":
        h = diag["histogram"]
        return (
            f"histogram: {100.0 * h.get('on_lattice', 0.0):.1f} % of omega values on a lattice of "
            f"{h.get('lattice_dps', 0.0):.6g} deg/s (log resolution {data.resolution_dps:g} deg/s), "
            "the model's output is continuous"
        )
    # Noise effects and the basics: only the Allan deviation speaks.
    big = max(c.items(), key=lambda kv: abs(kv[1]))
    return (
        f"{allan}; no deterministic regressor explains it (largest |r|: {big[0]}, r = {big[1]:.2f})"
    )


# -- the workflow ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Ambiguity:
    """Effects the data could not tell apart at a step."""

    step: int
    effects: tuple[str, ...]
    chosen: str
    delta_bic: tuple[float, ...]
    """BIC of each rival minus the chosen one's."""
    contribution_r: tuple[float | None, ...]
    note: str


@dataclass(frozen=True)
class Step:
    """One accepted effect."""

    effect: str
    params: dict[str, float]
    where: str
    gap_before: float
    gap_after: float
    delta_bic: float
    p_value: float
    ambiguous_with: tuple[str, ...]
    candidates: tuple[dict[str, Any], ...]
    diagnostics: dict[str, Any]
    regressor: str
    fit_before: Fit = field(repr=False)
    fit_after: Fit = field(repr=False)
    sim_before: _Sim = field(repr=False)
    sim_after: _Sim = field(repr=False)


@dataclass(frozen=True)
class GapResult:
    """Everything :func:`run_gap` found; :func:`to_report` turns it into the report JSON."""

    data: GapData
    initial_model: GyroModel
    initial_fit: Fit
    initial_sim: _Sim
    gap_as_given: float
    steps: tuple[Step, ...]
    final_fit: Fit
    final_sim: _Sim
    remaining: tuple[dict[str, Any], ...]
    ambiguous: tuple[Ambiguity, ...]
    revisions: tuple[dict[str, Any], ...]
    not_identifiable: dict[str, str]
    final_diagnostics: dict[str, Any]

    @property
    def final_model(self) -> GyroModel:
        return self.final_fit.model


def _cand_row(c: _Cand) -> dict[str, Any]:
    eff = c.fit.model.get(c.name)
    return {
        "effect": c.name,
        "delta_bic": round(c.dbic, 2),
        "delta_loglik": round(c.dlnl, 2),
        "p_value": float(f"{c.p:.3g}"),
        "significant": c.significant,
        "params": _params(eff) if eff is not None else {},
    }


def _params(e: Effect) -> dict[str, float]:
    return {k: float(f"{v:.6g}") for k, v in e.params().items()}


def run_gap(
    log: DriveLog | GapData,
    start: GyroModel = DEFAULT_START_MODEL,
    *,
    standstill: bool = False,
    seed: int = 0,
    candidates: Sequence[str] = CANDIDATES,
    max_steps: int = MAX_STEPS,
) -> GapResult:
    """Run the model-gap workflow on a measured log from the model ``start``.

    Deterministic for a seed (it only seeds the model simulations of the gap metric)."""
    data = log if isinstance(log, GapData) else prepare(log, standstill=standstill)
    unknown = [c for c in candidates if c not in EFFECTS]
    if unknown:
        raise GapError(f"unknown candidate effect(s): {', '.join(unknown)}")
    f = _Fitter(data)
    cur = fit_model(data, start)
    sim_given = gap_metric(data, start, seed, None, cur.noise.extra_var)
    cur_sim = gap_metric(data, cur.model, seed, cur.d, cur.noise.extra_var)
    initial_fit, initial_sim = cur, cur_sim
    skip = _not_identifiable(data, cur.model)
    steps: list[Step] = []
    ambiguous: list[Ambiguity] = []
    remaining: list[_Cand] = []
    added: list[str] = []
    dropped: set[str] = set()  # revised away: never re-added (no loops)
    revisions: list[dict[str, Any]] = []
    for i in range(max_steps):
        names = [c for c in candidates if c not in cur.model and c not in skip and c not in dropped]
        cands = [_evaluate(f, cur, c) for c in names]
        sig = [c for c in cands if c.significant]
        remaining = cands
        if not sig:
            break
        best = min(sig, key=lambda c: c.fit.bic)
        for c in sig:
            # A general form must beat its special case by the same margin as any new effect.
            if (best.name, c.name) in _NESTS and c.fit.bic - best.fit.bic < BIC_MARGIN:
                best = c
        rivals = _rivals(best, cands, data.duration_s)
        diag = _diagnostics(data, cur, cur_sim)
        new = f.full(best.fit.model, quad=best.fit.quad, extra_var=best.fit.noise.extra_var)
        if new.lnl < best.fit.lnl:
            new = best.fit  # the joint refit can only keep or improve the candidate's fit
        new_sim = gap_metric(data, new.model, seed, new.d, new.noise.extra_var)
        if rivals:
            names_r = tuple(c.name for c, _ in rivals)
            ambiguous.append(
                Ambiguity(
                    step=i + 1,
                    effects=(best.name, *names_r),
                    chosen=best.name,
                    delta_bic=tuple(round(c.fit.bic - best.fit.bic, 2) for c, _ in rivals),
                    contribution_r=tuple(None if r is None else round(r, 3) for _, r in rivals),
                    note=(
                        f"{best.name} and {', '.join(names_r)} explain this disagreement about "
                        f"equally well (BIC within {AMBIGUITY_BIC:g}); {best.name} was added "
                        "because its BIC is lowest, but the log cannot tell them apart"
                    ),
                )
            )
        eff = new.model.get(best.name)
        steps.append(
            Step(
                effect=best.name,
                params=_params(eff) if eff is not None else {},
                where=_where(data, best, cur_sim, diag),
                gap_before=cur_sim.gap,
                gap_after=new_sim.gap,
                delta_bic=best.dbic,
                p_value=best.p,
                ambiguous_with=tuple(c.name for c, _ in rivals),
                candidates=tuple(_cand_row(c) for c in sorted(cands, key=lambda c: c.dbic)),
                diagnostics=diag,
                regressor=_REGRESSOR.get(best.name, "time_s"),
                fit_before=cur,
                fit_after=new,
                sim_before=cur_sim,
                sim_after=new_sim,
            )
        )
        cur, cur_sim = new, new_sim
        added.append(best.name)
        for _ in range(len(added)):
            revised, recs = _revise(f, cur, added, i + 1)
            if not recs:
                break
            rec = recs[0]
            added.remove(rec["effect"])
            dropped.add(rec["effect"])
            if rec["action"].startswith("replaced by "):
                added.append(rec["action"][len("replaced by ") :])
            cur = revised
            cur_sim = gap_metric(data, cur.model, seed, cur.d, cur.noise.extra_var)
            rec["gap_after"] = _r(cur_sim.gap)
            revisions.append(rec)
    return GapResult(
        data=data,
        initial_model=start,
        initial_fit=initial_fit,
        initial_sim=initial_sim,
        gap_as_given=sim_given.gap,
        steps=tuple(steps),
        final_fit=cur,
        final_sim=cur_sim,
        remaining=tuple(_cand_row(c) for c in sorted(remaining, key=lambda c: c.dbic)),
        ambiguous=tuple(ambiguous),
        revisions=tuple(revisions),
        not_identifiable=skip,
        final_diagnostics=_diagnostics(data, cur, cur_sim),
    )


def _r(x: float) -> float:
    return float(f"{x:.4g}")


def to_report(res: GapResult) -> dict[str, Any]:
    """The report JSON (docs/model-gap.md): the required keys first, then the details."""
    d = res.data
    return {
        "initial_model": res.initial_model.names(),
        "steps": [
            {
                "where": s.where,
                "effect": s.effect,
                "params": s.params,
                "gap_before": _r(s.gap_before),
                "gap_after": _r(s.gap_after),
                "delta_bic": round(s.delta_bic, 2),
                "p_value": float(f"{s.p_value:.3g}"),
                "ambiguous_with": list(s.ambiguous_with),
                "candidates": list(s.candidates),
                "diagnostics": s.diagnostics,
            }
            for s in res.steps
        ],
        "final_model": res.final_model.names(),
        "gap_initial": _r(res.initial_sim.gap),
        "gap_final": _r(res.final_sim.gap),
        "gap_metric": GAP_METRIC,
        "gap_as_given": _r(res.gap_as_given),
        "ambiguous": [
            {
                "step": a.step,
                "effects": list(a.effects),
                "chosen": a.chosen,
                "delta_bic": list(a.delta_bic),
                "contribution_r": list(a.contribution_r),
                "note": a.note,
            }
            for a in res.ambiguous
        ],
        "revisions": list(res.revisions),
        "not_identifiable": res.not_identifiable,
        "remaining_candidates": list(res.remaining),
        "initial_params": res.initial_fit.model.to_dict()["effects"],
        "final_params": res.final_model.to_dict()["effects"],
        "final_diagnostics": res.final_diagnostics,
        "criterion": (
            f"BIC = -2 lnL + k ln(n) on n = {d.n_used} blocks of {d.block_s:g} s; an effect is "
            f"added if BIC falls by more than {BIC_MARGIN:g} and the likelihood-ratio test gives "
            f"p < {ALPHA:g}"
        ),
        "log": {
            "name": d.name,
            "samples": int(d.t.shape[0]),
            "duration_s": round(d.duration_s, 3),
            "rate_hz": round(d.fs_hz, 4),
            "truth": d.truth_source,
            "block_s": d.block_s,
            "blocks_used": d.n_used,
            "temp_c": d.temp_c is not None,
        },
    }


def summary(res: GapResult) -> str:
    """A few lines for people: what was found, the gap before and after."""
    d = res.data
    lines = [
        (
            f"{d.name or 'log'}: {d.t.shape[0]} samples over {d.duration_s / 60.0:.1f} min, "
            f"truth from {d.truth_source}, {d.n_used} blocks of {d.block_s:g} s"
        ),
        (
            f"start: {' + '.join(res.initial_model.names()) or '(empty)'}, gap "
            f"{res.initial_sim.gap:.3g} (parameters refitted; {res.gap_as_given:.3g} as given)"
        ),
    ]
    amb = {a.step: a for a in res.ambiguous}
    for i, s in enumerate(res.steps, 1):
        ps = ", ".join(f"{k}={v:.4g}" for k, v in s.params.items())
        lines.append(f"step {i}: {s.effect} ({ps})")
        lines.append(f"  where: {s.where}")
        lines.append(f"  gap {s.gap_before:.3g} -> {s.gap_after:.3g}, dBIC {s.delta_bic:.1f}")
        if i in amb:
            lines.append(f"  AMBIGUOUS: {amb[i].note}")
    for rv in res.revisions:
        lines.append(
            f"revised after step {rv['after_step']}: {rv['effect']} {rv['action']} (dBIC {rv['delta_bic']:+.1f})"
        )
    if not res.steps:
        lines.append("no missing effect found: the model explains the log")
    best = next((c for c in res.remaining), None)
    if best is not None:
        lines.append(
            f"nothing else significant (best remaining: {best['effect']}, dBIC {best['delta_bic']:+.1f})"
        )
    lines.append(f"final: {' + '.join(res.final_model.names())}, gap {res.final_sim.gap:.3g}")
    return "\n".join(lines)


# -- the command-line edge ---------------------------------------------------------------------------


def _err(msg: str) -> None:
    print(f"hdrd gap: {msg}", file=sys.stderr)


def main(args: argparse.Namespace) -> int:
    """``hdrd gap MEASURED.csv [--model MODEL.yaml] [--out FITTED.yaml] [--report REPORT.json]
    [--plot FILE.png] [--standstill] [--seed N]``. Exit 0 ok, 1 bad input or I/O error,
    78 bad model file."""
    from hdrd.drivelog import DriveLogError, read_drive
    from hdrd.sim.gyro import load_model, save_model

    if args.plot:
        from hdrd.analysis.plots import plotting_unavailable

        problem = plotting_unavailable()
        if problem:  # said before the work, not after it
            _err(problem)
            return 1
    start = DEFAULT_START_MODEL
    if args.model:
        try:
            start = load_model(args.model)
        except OSError as e:
            _err(f"cannot read the model {args.model}: {e.strerror or e}")
            return 78
        except ValueError as e:
            _err(str(e))
            return 78
    try:
        log = read_drive(args.measured)
    except OSError as e:
        _err(f"cannot read {args.measured}: {e.strerror or e}")
        return 1
    except DriveLogError as e:
        _err(str(e))
        return 1
    try:
        res = run_gap(log, start, standstill=bool(args.standstill), seed=int(args.seed))
    except (GapError, ValueError) as e:
        _err(str(e))
        return 1
    print(summary(res))
    try:
        if args.report:
            from hdrd.calibrate import atomic_write_json

            atomic_write_json(args.report, to_report(res))
        if args.out:
            save_model(res.final_model, args.out)
    except OSError as e:
        _err(f"cannot write: {e.strerror or e} ({e.filename or ''})")
        return 1
    if args.plot:
        from hdrd.analysis.gap_plots import plot_gap
        from hdrd.analysis.plots import plot_to_file

        problem = plot_to_file(lambda path: plot_gap(res, path), args.plot)
        if problem:
            _err(problem)
            return 1
    return 0
