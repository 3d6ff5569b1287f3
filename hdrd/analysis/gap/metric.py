"""The gap number: the model simulated under the log's conditions and compared with it
(Allan deviation of the unexplained residual, share of values on the ADC lattice). Pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hdrd.analysis.gap.data import GapData
from hdrd.analysis.gap.fit import deterministic_part
from hdrd.analysis.gap.lattice import detect_lattice, on_lattice
from hdrd.analysis.gap.noise import adev_cluster_sizes, allan_deviation_masked
from hdrd.sim.gyro import GyroModel

__all__ = ["GAP_METRIC", "N_SIM", "GapMeasure", "gap_metric", "sim_truth", "simulate_like"]

FloatArray = npt.NDArray[np.float64]

N_SIM = 4  # realisations averaged for the simulated Allan deviation

GAP_METRIC = (
    "sqrt(A**2 + H**2), dimensionless. A: root mean square over log-spaced averaging times tau "
    "(one sample to a tenth of the log, 5 per decade) of ln(ADEV_meas(tau) / ADEV_sim(tau)), "
    "the Allan deviations of the unexplained residual e = omega - truth - D (D: the model's "
    "deterministic prediction; each at least what the log's rounding alone gives) in the "
    "measured log and in the model simulated under the same t, truth and temp_c (Allan variance averaged over 4 seeds); A = 0.69 means the two differ "
    "by a factor of 2 on average, sampling noise alone gives ~0.1-0.3. H: |fraction of "
    "measured omega on the finest ADC lattice found in either - fraction of simulated omega on "
    "it| (histogram term: quantization). Effects already in the model are refitted to the log "
    "before the gap is measured."
)


@dataclass(frozen=True)
class GapMeasure:
    """Allan deviations of the unexplained residual, measured and model-simulated."""

    taus: FloatArray
    adev_meas: FloatArray
    adev_sim: FloatArray
    a_term: float
    h_term: float

    @property
    def gap(self) -> float:
        return math.sqrt(self.a_term**2 + self.h_term**2)


def sim_truth(data: GapData) -> FloatArray:
    """The true rate the model is simulated with (deg/s per sample): ``truth_filled``, and with
    a heading truth corrected by a constant per block so that its block means are exactly the
    blocks' true rates. Sampled at uneven times (0.2 and 0.3 s steps) a rate that steps at
    every fix would otherwise average to something else over a block than the heading change
    says, an error the measured gyro, whose rate is smooth, does not make."""
    truth = data.truth_filled
    if not data.heading_mode:
        return truth
    used = np.flatnonzero(data.bvalid)
    blk = np.full(data.nblocks, -1, dtype=np.int64)
    blk[used] = np.arange(used.shape[0])
    rows = data.block_of >= 0
    corr = np.zeros(used.shape[0])
    out = truth
    for _ in range(6):  # a fix row counts half in the block before it: a few sweeps converge
        corr += data.btruth - data.block_mean(out)
        out = truth.copy()
        out[rows] += corr[blk[data.block_of[rows]]]
    return out


def simulate_like(data: GapData, model: GyroModel, seed: int, r: int) -> FloatArray:
    truth = sim_truth(data)
    y = model.apply(data.t, truth, data.temp_c, np.random.default_rng([seed, r]), data.speed)
    if data.resolution_dps > 1e-9:
        y = np.round(y / data.resolution_dps) * data.resolution_dps  # as the log recorded it
    return np.asarray(y)


def gap_metric(
    data: GapData,
    model: GyroModel,
    seed: int = 0,
    d: FloatArray | None = None,
    truth_var: float = 0.0,
) -> GapMeasure:
    """The gap between the log and ``model`` (see :data:`GAP_METRIC`); model parameters as
    given. Deterministic for a seed.

    With a truth derived from a heading the Allan deviations are taken over block means (the
    truth is only known as heading changes between fixes), and the simulated block residual
    gets the truth's own error (white heading noise at the fixes, differenced: variance
    ``truth_var`` (deg/s)**2 per block, fitted with the model) so that both sides carry it."""
    d = deterministic_part(data, model) if d is None else d
    per_block = data.truth_source.startswith("heading_truth")
    ms = adev_cluster_sizes(data)
    rng_truth = np.random.default_rng([seed, 99])

    dbar = data.block_mean(d) if per_block else np.zeros(0)

    def adev(y: FloatArray, noise: bool) -> FloatArray:
        if not per_block:
            return allan_deviation_masked(
                y - data.truth_filled - d, data.valid, data.fs_hz, ms, data.time_gap
            )
        full = np.zeros(data.nblocks)
        full[data.bvalid] = data.block_residual(y) - dbar
        if noise and truth_var > 0:
            # The truth's error: white heading noise at the fixes, differenced over a block.
            eta = math.sqrt(truth_var / 2.0) * rng_truth.standard_normal(data.nblocks + 1)
            full -= np.where(data.brest, 0.0, np.diff(eta)) if data.brest.any() else np.diff(eta)
        return allan_deviation_masked(full, data.bvalid, 1.0 / data.block_s, ms)

    adev_m = adev(data.omega, False)
    avar_s = np.zeros(ms.shape[0])
    sims = []
    for r in range(N_SIM):
        y = simulate_like(data, model, seed, r)
        sims.append(y)
        avar_s += adev(y, True) ** 2
    adev_s = np.sqrt(avar_s / N_SIM)
    taus = np.asarray(ms * data.block_s if per_block else ms / data.fs_hz, dtype=np.float64)
    # A deviation of zero (a residual that never leaves its ADC code) is a disagreement
    # with one that moves, not a tau without information: both are held at least at what
    # the log's own rounding gives, the deviation of white noise of resolution**2 / 12.
    floor = data.resolution_dps / np.sqrt(12.0 * np.maximum(taus * data.fs_hz, 1.0))
    am, asim = np.maximum(adev_m, floor), np.maximum(adev_s, floor)
    ok = np.isfinite(am) & np.isfinite(asim)
    a = float(np.sqrt(np.mean(np.log(am[ok] / asim[ok]) ** 2))) if ok.any() else 0.0
    h = _histogram_term(data, sims)
    return GapMeasure(taus=taus, adev_meas=adev_m, adev_sim=adev_s, a_term=a, h_term=h)


def _histogram_term(data: GapData, sims: list[FloatArray]) -> float:
    """The histogram term: over the lattices found in the measurement or in the (first)
    simulation, the largest difference between the shares of values on the lattice."""
    h = 0.0
    lattices = [data.lattice] if data.lattice is not None else []
    sim_lat = detect_lattice(sims[0], data.resolution_dps)
    if sim_lat is not None:
        lattices.append(sim_lat)
    for lat in lattices:
        fm = float(on_lattice(data.omega, lat.step_dps, lat.offset_dps, data.resolution_dps).mean())
        fs = float(
            np.mean(
                [
                    on_lattice(y, lat.step_dps, lat.offset_dps, data.resolution_dps).mean()
                    for y in sims
                ]
            )
        )
        h = max(h, abs(fm - fs))
    return h
