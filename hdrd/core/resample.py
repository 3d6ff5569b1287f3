"""Block averaging of raw gyro samples into one value per step T (paper Eq. 11).

Pure. Blocks are cut by the device's timestamps, not by counting frames: step i averages
the samples whose device time falls in [t0 + i*T, t0 + (i+1)*T), t0 being the first sample's
time. A dropped frame only shortens its block; a block without samples is reported as
:class:`Missing`, never as a zero rate. The device clock is a 32-bit microsecond counter that
wraps every 2**32 us (71.6 min); :class:`hdrd.io.wire.clocks.DeviceClock` unwraps it into a monotonic integer
count so block edges are exact integers.

One block mean, in two forms that give bit-identical results: :meth:`BlockAverager.feed`
(the live daemon, one sample at a time, sums in arrival order) and
:meth:`BlockAverager.feed_many` (whole captures and drive logs; ``numpy.bincount`` also sums
in order, one bin per non-empty block, so memory follows the number of samples, not the
device time they span).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

__all__ = [
    "Block",
    "BlockAverager",
    "Missing",
]


@dataclass(frozen=True, slots=True)
class Block:
    """One step's averaged rate (Eq. 11).

    index: step number i since t0. t_start, t_end: the block's edges in device seconds since
    the first sample. mean: mean of the samples averaged, in the unit fed (deg/s for the
    gyro; NaN when none was). n: number of samples averaged. temp_c: their mean board
    temperature, deg C, None if unknown. saturated: samples flagged saturated, and faults:
    samples flagged faulty, neither averaged (a block of only those has n = 0); fault_lo,
    fault_hi: the lowest and highest reading that made a sample faulty (NaN: none). sumsq: sum
    of the squared samples averaged, from which :attr:`std` (the samples' spread, same unit
    as mean) follows.
    """

    index: int
    t_start: float
    t_end: float
    mean: float
    n: int
    temp_c: float | None = None
    saturated: int = 0
    sumsq: float = field(default=math.nan, compare=False)
    faults: int = 0
    fault_lo: float = field(default=math.nan, compare=False)
    fault_hi: float = field(default=math.nan, compare=False)

    @property
    def std(self) -> float:
        """Population standard deviation of the block's samples (NaN if unknown)."""
        if not self.n:
            return math.nan
        return math.sqrt(max(self.sumsq / self.n - self.mean * self.mean, 0.0))


@dataclass(frozen=True, slots=True)
class Missing:
    """A run of ``count`` steps, from step ``first``, in which no sample arrived."""

    first: int
    count: int
    t_start: float
    t_end: float


class BlockAverager:
    """Streaming block averager: ``feed`` samples, get closed blocks back.

    A block closes when the first sample of a later block arrives (that sample's arrival is
    the moment the step can be published). Times are unwrapped device microseconds
    (see :class:`hdrd.io.wire.clocks.DeviceClock`); ``T_s`` is the step period (paper: 1 s).
    A sample flagged saturated or faulty is counted in its block, not averaged: it still
    makes its block a block (of n = 0 when nothing else came), never a :class:`Missing`.
    """

    def __init__(self, T_s: float = 1.0) -> None:
        if not T_s > 0:
            raise ValueError(f"T must be > 0 s, got {T_s!r}")
        self.T_us = round(T_s * 1_000_000)
        self.t0_us: int | None = None
        self._index = 0
        self._sum = 0.0
        self._sumsq = 0.0
        self._n = 0
        self._temp_sum = 0.0
        self._temp_n = 0
        self._sat = 0
        self._faults = 0
        self._fault_lo = math.nan
        self._fault_hi = math.nan
        self._seen = 0  # samples of the open block, averaged or not
        self.late = 0  # samples in a step already closed (only after flush, with DeviceClock)

    @property
    def open_block(self) -> tuple[int, int, int] | None:
        """The open block: (start, end) in unwrapped device us and its sample count (averaged
        or not); None before the first sample."""
        if self.t0_us is None:
            return None
        start = self.t0_us + self._index * self.T_us
        return start, start + self.T_us, self._seen

    def _edges(self, index: int, count: int = 1) -> tuple[float, float]:
        T = self.T_us
        return index * T / 1e6, (index + count) * T / 1e6

    def _close(self) -> Block:
        t_start, t_end = self._edges(self._index)
        temp = self._temp_sum / self._temp_n if self._temp_n else None
        mean = self._sum / self._n if self._n else math.nan
        block = Block(
            self._index, t_start, t_end, mean, self._n, temp, self._sat, self._sumsq,
            self._faults, self._fault_lo, self._fault_hi,
        )  # fmt: skip
        self._sum = 0.0
        self._sumsq = 0.0
        self._n = self._seen = 0
        self._temp_sum = 0.0
        self._temp_n = 0
        self._sat = self._faults = 0
        self._fault_lo = self._fault_hi = math.nan
        return block

    def feed(
        self,
        t_us: int,
        value: float,
        temp_c: float | None = None,
        saturated: bool = False,
        fault: float | None = None,
    ) -> list[Block | Missing]:
        """Add one sample at unwrapped device time t_us; return the blocks this closed.
        saturated: the sample is beyond what the sensor measures; fault: the reading that
        makes it faulty (the supply monitor's volts), None when it is not: either is counted
        and not averaged."""
        if self.t0_us is None:
            self.t0_us = t_us
        index = (t_us - self.t0_us) // self.T_us
        if index < self._index:
            self.late += 1
            return []
        out = self._advance(index)
        self._seen += 1
        if fault is not None:
            self._faults += 1
            self._fault_lo = fault if not fault >= self._fault_lo else self._fault_lo
            self._fault_hi = fault if not fault <= self._fault_hi else self._fault_hi
            return out
        if saturated:
            self._sat += 1
            return out
        self._sum += value
        self._sumsq += value * value
        self._n += 1
        if temp_c is not None:
            self._temp_sum += temp_c
            self._temp_n += 1
        return out

    def feed_many(
        self,
        t_us: npt.NDArray[np.int64],
        values: npt.NDArray[np.float64],
        temp_c: npt.NDArray[np.float64] | None = None,
        saturated: npt.NDArray[np.bool_] | None = None,
        faults: npt.NDArray[np.float64] | None = None,
    ) -> list[tuple[int, Block | Missing]]:
        """:meth:`feed` over arrays of increasing unwrapped times; bit-identical results.

        Returns (position of the sample that closed it, block) pairs. temp_c: NaN = unknown.
        faults: each sample's fault reading, NaN where it is not faulty. Samples joining the
        open block are added one by one (sequential sums); the blocks after it are summed
        with ``numpy.bincount``, which also adds in order from 0.0 (a sample not averaged
        adds 0.0, which leaves a sum as it is).
        """
        n = t_us.shape[0]
        out: list[tuple[int, Block | Missing]] = []
        if n == 0:
            return out
        temps = np.full(n, np.nan) if temp_c is None else np.asarray(temp_c, np.float64)
        sat = np.zeros(n, bool) if saturated is None else np.asarray(saturated, bool)
        bad = np.full(n, np.nan) if faults is None else np.asarray(faults, np.float64)
        if self.t0_us is None:
            self.t0_us = int(t_us[0])
        idx = (t_us - self.t0_us) // self.T_us
        # Samples up to the first one beyond the open block take the scalar path (few).
        # Times that go back anywhere (not from a DeviceClock) take it all the way: a sample
        # before j could otherwise close a block that nobody reports.
        j = int(np.searchsorted(idx, self._index, side="right"))
        if j == n or np.any(np.diff(idx) < 0):
            for i in range(n):
                for b in self._feed_one(t_us, values, temps, sat, bad, i):
                    out.append((i, b))
            return out
        for i in range(j):
            self._feed_one(t_us, values, temps, sat, bad, i)
        # One bin per non-empty block, not per step index: memory follows the samples,
        # never the device time they span (a clock that jumps 2**31 us per frame).
        starts, labels = _runs(idx[j:])
        sums = _BlockSums(labels, starts, values[j:], temps[j:], sat[j:], bad[j:])
        first_pos = j + starts
        block_index = idx[j:][starts]
        # Close the block that was open before these samples (as the j-th sample's feed would).
        closer = j
        last = len(starts) - 1
        for k, index in enumerate(block_index.tolist()):
            for item in self._advance(index):
                out.append((closer, item))
            sums.load(self, k)
            if k < last:
                closer = int(first_pos[k + 1])
        return out

    def _feed_one(
        self,
        t_us: npt.NDArray[np.int64],
        values: npt.NDArray[np.float64],
        temps: npt.NDArray[np.float64],
        sat: npt.NDArray[np.bool_],
        bad: npt.NDArray[np.float64],
        i: int,
    ) -> list[Block | Missing]:
        """:meth:`feed` of sample i of :meth:`feed_many`'s arrays."""
        tc, f = float(temps[i]), float(bad[i])
        return self.feed(
            int(t_us[i]), float(values[i]), None if tc != tc else tc, bool(sat[i]),
            None if f != f else f,
        )  # fmt: skip

    def _advance(self, index: int) -> list[Block | Missing]:
        """Move the open block to ``index`` (> the open one): close it, report the gap."""
        out: list[Block | Missing] = []
        if index <= self._index:
            return out
        if self._seen:
            out.append(self._close())
            first = self._index + 1
        else:
            first = self._index
        if index > first:
            out.append(Missing(first, index - first, *self._edges(first, index - first)))
        self._index = index
        return out

    def flush(self) -> list[Block | Missing]:
        """Close the open block at end of input (a partial block is still a block).

        The flushed block is final: a later sample in the same step counts as ``late``, and
        one in a later step reports only the steps after it as missing.
        """
        if not self._seen:
            return []
        block = self._close()
        self._index += 1
        return [block]


class _BlockSums:
    """Each block's sums over runs of samples (:func:`_runs`), as :meth:`BlockAverager.feed`
    would have added them one by one."""

    def __init__(
        self,
        labels: npt.NDArray[np.int64],
        starts: npt.NDArray[np.int64],
        values: npt.NDArray[np.float64],
        temps: npt.NDArray[np.float64],
        sat: npt.NDArray[np.bool_],
        bad: npt.NDArray[np.float64],
    ) -> None:
        faulty = ~np.isnan(bad)
        avg = ~(faulty | sat)  # the samples averaged
        w = np.where(avg, values, 0.0)
        self.sums = np.bincount(labels, weights=w)
        self.sumsq = np.bincount(labels, weights=w * w)
        self.counts = np.bincount(labels, weights=avg.astype(np.float64))
        self.seen = np.bincount(labels)
        has_t = avg & ~np.isnan(temps)
        self.tsum = np.bincount(labels, weights=np.where(has_t, temps, 0.0))
        self.tn = np.bincount(labels, weights=has_t.astype(np.float64))
        self.sn = np.bincount(labels, weights=(sat & ~faulty).astype(np.float64))
        self.fn = np.bincount(labels, weights=faulty.astype(np.float64))
        self.lo = np.fmin.reduceat(bad, starts)
        self.hi = np.fmax.reduceat(bad, starts)

    def load(self, avg: BlockAverager, k: int) -> None:
        """Block k's sums into the averager's open block."""
        avg._sum, avg._sumsq, avg._n = (
            float(self.sums[k]),
            float(self.sumsq[k]),
            int(self.counts[k]),
        )
        avg._temp_sum, avg._temp_n, avg._sat = float(self.tsum[k]), int(self.tn[k]), int(self.sn[k])
        avg._faults, avg._seen = int(self.fn[k]), int(self.seen[k])
        avg._fault_lo, avg._fault_hi = float(self.lo[k]), float(self.hi[k])


def _runs(idx: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """For non-decreasing block indices: (position where each run of equal indices starts,
    each sample's run number 0, 1, ...). ``numpy.bincount`` over run numbers sums each block
    in sample order, as over the indices themselves, with one bin per non-empty block."""
    n = idx.shape[0]
    change = np.empty(n, bool)
    change[:1] = True
    np.not_equal(idx[1:], idx[:-1], out=change[1:])
    labels = np.cumsum(change, dtype=np.int64)
    labels -= 1
    return np.flatnonzero(change), labels
