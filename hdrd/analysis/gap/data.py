"""A drive log made ready for the model-gap workflow: the true rate, the blocks, the lattice.

Rates deg/s, + = CCW (left turn); heading compass deg, clockwise from north; time s since the
first sample (= power-on); temperature deg C. Pure.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.analysis.gap.lattice import Lattice, decimal_resolution, detect_lattice
from hdrd.analysis.gap.truth import (
    STOP_MARGIN_S,
    STOP_SPEED_MPS,
    GapError,
    Truth,
    lead_in_s,
    read_truth,
    standing_rows,
    truth_rate_from_heading,
)
from hdrd.io.files.drivelog import DriveLog
from hdrd.sim.effects import MotionOffset
from hdrd.sim.gyro import GyroModel

__all__ = [
    "STOP_MARGIN_S",
    "STOP_SPEED_MPS",
    "TIME_GAP_FACTOR",
    "GapData",
    "GapError",
    "excluded_samples",
    "moving_indicator",
    "prepare",
    "stop_interior",
    "truth_rate_from_heading",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


TIME_GAP_FACTOR = 2.5
"""A step between two rows longer than this many median sample periods is a time gap (rows
dropped; a jittery clock's steps stay below it): statistics over consecutive samples (Allan deviation, neighbouring differences)
do not reach across it."""


@dataclass(frozen=True)
class GapData:
    """A measured log made ready for the workflow (see :func:`prepare`).

    Samples: t (s since the first sample), omega (deg/s), truth (deg/s; NaN where unknown),
    truth_filled (NaN replaced by interpolation, for simulating), temp_c (deg C or None),
    valid (truth known and the sample not excluded), excluded (marked ``valid`` = 0 in the log or
    inside an excluded period), time_gap (a time gap, rows dropped, just before the sample).

    speed: the vehicle's speed (m/s, NaN unknown) or None.

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
    excluded: BoolArray
    time_gap: BoolArray
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
    speed: FloatArray | None = None
    """The vehicle's speed, m/s (NaN = unknown), when the log has it: at a stop the true rate
    is zero at every sample (:func:`stop_interior`)."""
    standing: BoolArray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    """Samples at which the vehicle stands (a stop, the start-up standstill): their true rate
    is zero (:func:`stop_interior`)."""
    brest: BoolArray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    """With a heading truth, the blocks (of all ``nblocks``) that lie wholly where the vehicle
    stands: their true rate is exactly zero at every sample, with none of the heading's
    error; all False otherwise."""

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

    @property
    def sample_truth(self) -> BoolArray:
        """Samples whose true rate is known at the sample itself: every valid one, but with a
        heading truth only where the vehicle stands (between fixes only the mean over the
        interval is known)."""
        return self.standing & self.valid if self.heading_mode else self.valid

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


def stop_interior(data: GapData) -> BoolArray:
    """Samples at which the vehicle stands (:func:`hdrd.analysis.gap.truth.standing_rows`):
    inside a stop (the speed at most :data:`STOP_SPEED_MPS`, at least :data:`STOP_MARGIN_S`
    from the stop's edges) or within the log's start-up standstill (``lead_in_s``); never
    excluded. There the true yaw rate is zero at every sample, whatever the heading truth says
    (a GPS course is unknown at a stop)."""
    return data.standing


def moving_indicator(data: GapData) -> FloatArray | None:
    """1 at the samples where the vehicle moves as ``motion_offset`` sees it (speed above its
    default moving_mps, m/s; the speed's gaps interpolated), 0 where it stands; None without
    a speed. The regressor of a motion-dependent bias."""
    if data.speed is None or not np.isfinite(data.speed).any():
        return None
    unit = GyroModel((MotionOffset(offset_dps=1.0),))
    zero = np.zeros_like(data.t)
    return unit.apply(data.t, zero, None, np.random.default_rng(0), speed_mps=data.speed)


def _block_length(duration_s: float, truth_source: str) -> float:
    # 1 s is the paper's step T; longer logs get longer blocks to keep the filter cheap, and a
    # truth differentiated from 1 Hz GPS needs a few seconds to average its noise down.
    base = 5.0 if truth_source == "heading_truth" else 1.0
    return float(max(base, math.ceil(duration_s / 1500.0)))


def excluded_samples(log: DriveLog, exclude: Sequence[tuple[float, float]] = ()) -> BoolArray:
    """Samples left out: ``valid`` = 0 in the log, or t (the log's own time, s) inside one of the
    ``exclude`` periods (T0, T1), ends included."""
    out = np.zeros(len(log), dtype=bool) if log.valid is None else np.asarray(log.valid == 0.0)
    for t0, t1 in exclude:
        if not (math.isfinite(t0) and math.isfinite(t1) and t1 >= t0):
            raise GapError(f"excluded period {t0:g}:{t1:g} s: need finite T0 <= T1")
        out = out | ((log.t >= t0) & (log.t <= t1))
    return out


def _filled_temp(log: DriveLog, idx: IntArray) -> FloatArray | None:
    """The temperature column with its gaps interpolated; None without one."""
    if log.temp_c is None or not np.isfinite(log.temp_c).any():
        return None
    tc = np.asarray(log.temp_c, dtype=np.float64)
    ok = np.isfinite(tc)
    return tc if ok.all() else np.interp(idx, idx[ok], tc[ok])


def _block_size(block_s: float | None, t: FloatArray, dt: float, truth: Truth) -> float:
    """The block length, s: as asked, else by the log's length and truth (whole fix intervals
    with a heading truth); GapError when shorter than a sample period."""
    if block_s is not None:
        bs = float(block_s)
    else:
        bs = _block_length(float(t[-1]), truth.source)
        if truth.heading is not None:
            bs *= max(1.0, round(truth.fix_dt))  # whole fix intervals
    if not (math.isfinite(bs) and bs >= dt):
        raise GapError(f"block length {bs!r} s is shorter than the sample period {dt:g} s")
    return bs


@dataclass
class _Blocks:
    """The block grid of :class:`GapData` (its fields of the same names) while it is made;
    ``wsum`` and ``w2``: each block's sum of weights and of squared weights, ``btruth_full``
    each block's true rate from the heading (NaN without), ``brest`` the blocks wholly at
    rest (with a heading truth)."""

    nblocks: int
    blk: IntArray
    inside: BoolArray
    bvalid: BoolArray
    wprim: FloatArray
    block_prev: IntArray
    btruth_full: FloatArray
    brest: BoolArray
    block_of: IntArray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    wsum: npt.NDArray[Any] = field(default_factory=lambda: np.empty(0))
    w2: npt.NDArray[Any] = field(default_factory=lambda: np.empty(0))


def _grid_origin(truth: Truth, bs: float) -> float:
    """Where the block grid starts, s: at t = 0, or with a heading truth on the first fix and
    as many whole blocks before it as the log has (so that a standstill before the first fix
    is in blocks too)."""
    if truth.heading is None:
        return truth.origin
    return truth.origin - bs * math.floor(truth.origin / bs + 1e-9)


def _blocks(
    t: FloatArray, dt: float, bs: float, truth: Truth, valid: BoolArray, standing: BoolArray
) -> _Blocks:
    """The blocks of ``bs`` seconds on the grid of :func:`_grid_origin`: which are used
    (complete, with truth; GapError when fewer than 20 are, or the log covers fewer than 20),
    each sample's block and weight."""
    n = t.shape[0]
    origin = _grid_origin(truth, bs)
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
    still = np.bincount(bi[standing], minlength=nblocks + 1)[:nblocks].astype(np.float64)
    bvalid = (good >= 0.8 * bs * (1.0 / dt)) & (good == total)
    b = _Blocks(
        nblocks=nblocks,
        blk=blk,
        inside=inside,
        bvalid=bvalid,
        wprim=np.ones(n),
        block_prev=np.full(n, -1, dtype=np.int64),
        btruth_full=np.full(nblocks, np.nan),
        brest=bvalid & (still == total) & (truth.heading is not None),
    )
    if truth.heading is not None:
        _heading_blocks(b, t, truth.heading, truth.fixes, valid)
    bvalid = b.bvalid
    b.block_of = np.where(inside & valid & bvalid[np.clip(blk, 0, nblocks - 1)], blk, -1)
    b.block_prev = np.where(
        (b.block_prev >= 0) & bvalid[np.clip(b.block_prev, 0, nblocks - 1)], b.block_prev, -1
    )
    _block_weights(b)
    if bvalid.sum() < 20:
        raise GapError(
            f"only {int(bvalid.sum())} blocks of {bs:g} s have a complete true rate; need >= 20"
        )
    return b


def _first_rows(b: _Blocks) -> IntArray:
    """The first row of each block, and of the rows after the last (nblocks + 1 entries; -1:
    a block without rows)."""
    nblocks, blk = b.nblocks, b.blk
    first = np.full(nblocks + 1, -1, dtype=np.int64)
    rows = np.flatnonzero(b.inside)
    first_rows = rows[np.concatenate(([True], blk[rows][1:] != blk[rows][:-1]))]
    first[blk[first_rows]] = first_rows
    after = np.flatnonzero(blk == nblocks)
    if after.shape[0]:
        first[nblocks] = after[0]
    return first


def _closed_by_fixes(
    k: int, first: IntArray, is_fix: BoolArray, valid: BoolArray, rest: BoolArray
) -> bool:
    """Whether block k starts on a fix and ends on the next block's first row, also a fix,
    with a truth at every row, and shares no row with a block at rest."""
    a, e = int(first[k]), int(first[k + 1])
    return (
        a >= 0
        and e >= 0
        and bool(is_fix[a])
        and bool(is_fix[e])
        and bool(valid[a:e].all())
        and bool(valid[e])
        and not (k + 1 < rest.shape[0] and rest[k + 1])
    )


def _heading_blocks(
    b: _Blocks, t: FloatArray, heading: FloatArray, fixes: IntArray, valid: BoolArray
) -> None:
    """With a heading truth: a block wholly at rest (``brest``) has a true rate of zero at
    every sample; any other must start on a fix and end on the next block's first row, also a
    fix, and its true rate is the heading change between them. Sets ``btruth_full``, the fix
    rows' weights (half in each of the two blocks they close and open) and drops the blocks
    whose edges are not fixes. A block at rest shares no row with a heading block (the one
    before it is dropped if its closing fix would be the rest block's first row)."""
    n, bvalid, rest = t.shape[0], b.bvalid, b.brest
    is_fix = np.zeros(n, dtype=bool)
    is_fix[fixes] = True
    first = _first_rows(b)
    hu = np.full(n, np.nan)  # heading unwrapped along the fixes, deg
    dh = (np.diff(heading[fixes]) + 180.0) % 360.0 - 180.0
    hu[fixes] = heading[fixes[0]] + np.concatenate(([0.0], np.cumsum(dh)))
    for k in range(b.nblocks):
        if rest[k]:
            b.btruth_full[k] = 0.0
        elif bvalid[k] and _closed_by_fixes(k, first, is_fix, valid, rest):
            a, e = first[k], first[k + 1]
            b.btruth_full[k] = -(hu[e] - hu[a]) / (t[e] - t[a])  # CW heading -> CCW rate
            b.wprim[a] = 0.5
            if k > 0 and not rest[k - 1]:
                b.block_prev[a] = k - 1
        else:
            bvalid[k] = False
    # The half-row that closes block k is the first row of block k + 1: give it to k even
    # when block k + 1 itself is not used.
    for kk in np.flatnonzero(bvalid & ~rest).tolist():
        e = first[kk + 1]
        if e >= 0 and b.block_prev[e] < 0:
            b.block_prev[e] = kk


def _block_weights(b: _Blocks) -> None:
    """Each block's sum of weights and of squared weights (a fix row's half counted in the
    block it closes too)."""
    block_of, block_prev, wprim, nblocks = b.block_of, b.block_prev, b.wprim, b.nblocks
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
    b.wsum, b.w2 = wsum, w2


def prepare(
    log: DriveLog,
    standstill: bool = False,
    block_s: float | None = None,
    exclude: Sequence[tuple[float, float]] = (),
) -> GapData:
    """Turn a drive log into :class:`GapData`. The truth rate is ``omega_truth`` where it has
    values, else the derivative of ``heading_truth``, else zero when ``standstill``; and zero
    wherever the vehicle stands (:func:`stop_interior`), with or without a truth there. Samples
    marked ``valid`` = 0 or inside an ``exclude`` period (s, the log's own t) count as having
    no truth. Raises GapError if there is no truth or too little of it."""
    n = len(log)
    if n < 100:
        raise GapError(f"the log has {n} samples; the workflow needs at least 100")
    t = np.asarray(log.t - log.t[0], dtype=np.float64)
    omega = np.asarray(log.omega, dtype=np.float64)
    excluded = excluded_samples(log, exclude)
    dt = float(np.median(np.diff(t)))
    time_gap = np.concatenate(([False], np.diff(t) > TIME_GAP_FACTOR * dt))
    speed = None if log.speed is None else np.asarray(log.speed, dtype=np.float64)
    res, lattice = _lattice(log, omega, omega[~excluded])  # the values while they count
    step = lattice.step_dps if lattice is not None else 0.0
    standing = standing_rows(t, speed, excluded, time_gap, lead_in_s(log), omega, step)
    tr, truth = _at_rest_zero(read_truth(log, t, standstill), standing, excluded)
    valid = np.isfinite(truth)
    idx = np.arange(n)
    truth_filled = np.interp(idx, idx[valid], truth[valid])
    bs = _block_size(block_s, t, dt, tr)
    b = _blocks(t, dt, bs, tr, valid, standing)
    origin = _grid_origin(tr, bs)
    data = GapData(
        t=t,
        omega=omega,
        truth=truth,
        truth_filled=truth_filled,
        temp_c=_filled_temp(log, idx),
        valid=valid,
        excluded=excluded,
        time_gap=time_gap,
        truth_source=tr.source,
        fs_hz=1.0 / dt,
        block_s=bs,
        block_t0=origin,
        **_grid_fields(b, origin, bs),
        resolution_dps=res,
        lattice=lattice,
        name=log.name,
        speed=speed,
        standing=standing,
        brest=b.brest,
    )
    heading = tr.heading is not None
    return replace(
        data, btruth=b.btruth_full[b.bvalid] if heading else data.block_mean(truth_filled)
    )


def _grid_fields(b: _Blocks, origin: float, bs: float) -> dict[str, Any]:
    """:class:`GapData`'s fields of the block grid (its true rates, ``btruth``, set after)."""
    return {
        "nblocks": b.nblocks,
        "block_of": b.block_of,
        "wprim": b.wprim,
        "block_prev": b.block_prev,
        "bvalid": b.bvalid,
        "bweight": np.where(b.wsum > 0, b.wsum, 1.0),
        "bneff": np.where(b.w2 > 0, b.wsum**2 / np.where(b.w2 > 0, b.w2, 1.0), 1.0),
        "bt": np.asarray(origin + (np.arange(b.nblocks) + 0.5) * bs),
        "btruth": np.empty(0),
    }


def _at_rest_zero(tr: Truth, standing: BoolArray, excluded: BoolArray) -> tuple[Truth, FloatArray]:
    """The truth with a rate of zero where the vehicle stands (a car at rest does not turn),
    and the rate as counted (:func:`_counted_truth`)."""
    if tr.source != "standstill":
        tr = replace(tr, rate=np.where(standing, 0.0, tr.rate))
    return tr, _counted_truth(tr.rate, excluded)


def _counted_truth(truth: FloatArray, excluded: BoolArray) -> FloatArray:
    """The true rate unknown (NaN) at the excluded samples; GapError when every sample is
    excluded or fewer than 100 have a known true rate."""
    if excluded.all():
        raise GapError("every sample is excluded (valid = 0 or inside an excluded period)")
    if excluded.any():
        truth = np.where(excluded, np.nan, truth)
    valid = np.isfinite(truth)
    if valid.sum() < 100:
        raise GapError(f"only {int(valid.sum())} samples have a known true rate; need >= 100")
    return truth


def _lattice(log: DriveLog, omega: FloatArray, kept: FloatArray) -> tuple[float, Lattice | None]:
    """The recording's resolution for rates (deg/s) and the ADC lattice of the rates that
    count (``kept``), if any. When the true rate column is written with more digits than
    omega, omega's own digits are tried too: a step that is no round decimal (0.01 rad/s)
    written with 7 decimals beside a truth with 9 is a lattice at omega's resolution only."""
    res = _resolution(log, omega)
    lattice = detect_lattice(kept, res)
    own = decimal_resolution(omega)
    if lattice is None and own > res:
        found = detect_lattice(kept, own)
        if found is not None:
            return own, found
    return res, lattice


def _resolution(log: DriveLog, omega: FloatArray) -> float:
    """The writer's resolution for rates, deg/s: omega's own digits can look coarse when its
    values sit on a round ADC lattice (0.05 deg/s values are all multiples of 0.01), so the
    true rate column, written alike, is consulted too."""
    res = decimal_resolution(omega)
    if log.omega_truth is not None:
        res = min(res, decimal_resolution(log.omega_truth))
    return res
