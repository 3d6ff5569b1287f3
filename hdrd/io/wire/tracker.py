"""Which frames of a stream are new: the sequence number and device clock, in one place.

Pure. :class:`FrameTracker` decides, by the rule :func:`keeps` (docs/protocol.md, "Sequence and
clock"), which good frames are kept and counts the rest in :class:`ParserStats`; the push parser
(:mod:`hdrd.io.wire.parser`) and the vectorised decoder (:mod:`hdrd.io.wire.capture`) hand it their frames.
"""

from __future__ import annotations

import collections
import itertools
from dataclasses import dataclass, fields
from typing import Any, overload

import numpy as np
import numpy.typing as npt

from hdrd.io.wire.protocol import (
    BREAK_CONFIRM_FRAMES,
    BREAK_REBASE_FRAMES,
    CLOCK_WRAP_US,
    REBASE_RATIO,
    SEQ_CLOCK_RATIO,
    SEQ_GAP_WINDOW,
    SEQ_REORDER_WINDOW,
)

__all__ = ["FrameTracker", "ParserStats", "agrees", "keeps"]


@dataclass(slots=True, eq=False)
class ParserStats:
    """Counters of a parser (or a source), since it was made. frames: good frames returned.
    bad_frames: frames that started with a sync pattern but failed their CRC, checksum or
    syntax. garbage_bytes: bytes not part of a good frame (bad frames' included; bytes still
    buffered count at ``flush``). Of the sequence and the clock (:class:`FrameTracker`):
    seq_gaps, lost_frames (events of frames lost, and how many); seq_resets (a device
    restart); clock_wraps (of the device clock at 2**32 us); and the good frames dropped:
    seq_repeats (not new), seq_clock_mismatch (the clock disagrees with the sequence).
    """

    frames: int = 0
    bad_frames: int = 0
    garbage_bytes: int = 0
    seq_gaps: int = 0
    lost_frames: int = 0
    seq_repeats: int = 0
    seq_resets: int = 0
    clock_wraps: int = 0
    seq_clock_mismatch: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters by name."""
        return {f: getattr(self, f) for f in _COUNTERS}

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ParserStats):
            return NotImplemented
        return self.as_dict() == other.as_dict()


_COUNTERS = tuple(f.name for f in fields(ParserStats))


_SEQ_BACK = 0x10000 - SEQ_REORDER_WINDOW  # k >= this: at most SEQ_REORDER_WINDOW behind
_HALF_WRAP = CLOCK_WRAP_US >> 1
_R = SEQ_CLOCK_RATIO
_GAP = SEQ_GAP_WINDOW


_Ints = npt.NDArray[np.int64]
_Bools = npt.NDArray[np.bool_]


@overload
def agrees(d: int, k: int, d0: int, k0: int, r: int = _R) -> bool: ...
@overload
def agrees(d: _Ints, k: _Ints, d0: _Ints, k0: int, r: int = _R) -> _Bools: ...
def agrees(d: Any, k: Any, d0: Any, k0: int, r: int = _R) -> Any:
    """Whether d us over k sequence steps keep to the interval d0 us per k0 steps within a
    factor r (:data:`SEQ_CLOCK_RATIO`); any step does when there is no interval yet (k0 = 0).
    Python ints, or numpy arrays element by element."""
    return (k0 == 0) | ((r * d * k0 >= d0 * k) & (d * k0 <= r * d0 * k))


@overload
def keeps(k: int, d: int, d0: int, k0: int) -> bool: ...
@overload
def keeps(k: _Ints, d: _Ints, d0: _Ints, k0: int) -> _Bools: ...
def keeps(k: Any, d: Any, d0: Any, k0: int) -> Any:
    """The rule: a frame k sequence steps (mod 2**16) and d us (mod 2**32) after the last frame
    kept is kept when 0 < k <= :data:`SEQ_GAP_WINDOW`, d is forward (0 < d < 2**31) and d / k
    keeps to the interval d0 / k0 (:func:`agrees`). Python ints, or numpy arrays element by
    element (the vectorised decoder's form of the same rule)."""
    return (0 < k) & (k <= _GAP) & (0 < d) & (d < _HALF_WRAP) & agrees(d, k, d0, k0)


_At = collections.namedtuple("_At", "seq t_us i")  # a frame of an array, for run: its place i


class FrameTracker:
    """The sequence number and device clock of a stream of frames, in one place: which frames
    are kept, and the sequence/clock counters of :class:`ParserStats`. Pure. The rule
    (docs/protocol.md, "Sequence and clock"), for a frame k sequence steps and d us after the
    last frame kept: **kept** if 0 < k <= :data:`SEQ_GAP_WINDOW`, d forward and d / k within
    :data:`SEQ_CLOCK_RATIO` of the interval (the last single step's d; any before it);
    **dropped, not new** (``seq_repeats``) if k = 0 or at most :data:`SEQ_REORDER_WINDOW`
    behind, d not forward; else a **break**: held with the frames after it that continue it
    by their own clock, released when :data:`BREAK_CONFIRM_FRAMES` do at the interval agreed on
    (or none was) or :data:`BREAK_REBASE_FRAMES` at their own within :data:`REBASE_RATIO`
    of it (a restart: ``seq_resets``; a
    jump: a gap), dropped by a frame kept or a break that does not continue them
    (``seq_clock_mismatch``). :meth:`run` (a batch of frames) and :meth:`run_array` (a whole
    capture, numpy where each step agrees) decide alike; :meth:`flush` drops what is held.
    """

    __slots__ = ("_agreed", "_d", "_held", "_held_off", "_k", "_kept_run", "_seq", "_t", "stats")

    def __init__(self, stats: ParserStats | None = None) -> None:
        self.stats = ParserStats() if stats is None else stats
        self._seq: int | None = None  # the last frame kept: its sequence number, device time
        self._t = 0
        self._d = 0  # the interval: device us over _k sequence steps (0: none yet)
        self._k = 0
        self._agreed = 0  # steps kept since the start or the last break
        self._kept_run = 0  # frames kept by the rule in a row, to the last one judged
        self._held: list[tuple[Any, int, int, int]] = []  # (item, seq, t_us, bad) after a break
        self._held_off = False  # a held step off the interval agreed on

    def run(self, items: list[Any], bads: list[int]) -> tuple[list[Any], list[int]]:
        """Judge frames (each with ``seq`` and ``t_us``; ``bads``: bad frames before each): those
        kept, in order, with their bads (held ones released now first). :meth:`_run_all`
        takes over from the first frame that the common case does not keep."""
        seq0, t0, d0, k0 = self._seq, self._t, self._d, self._k
        if seq0 is None or self._held:
            return self._run_all(items, bads, 0)
        st = self.stats
        j = 0
        for f in items:
            s, t = f.seq, f.t_us
            k = (s - seq0) & 0xFFFF
            d = (t - t0) & 0xFFFFFFFF
            if not keeps(k, d, d0, k0):
                break
            if k > 1:
                st.seq_gaps += 1
                st.lost_frames += k - 1
            if t < t0:
                st.clock_wraps += 1
            seq0, t0 = s, t
            if k == 1:  # the interval: a single step's (a gap's average may hide a skip)
                d0, k0 = d, 1
            j += 1
        self._seq, self._t, self._d, self._k = seq0, t0, d0, k0
        self._agreed += j
        self._kept_run += j
        if j == len(items):
            return items, bads
        out, out_bad = self._run_all(items, bads, j)
        return items[:j] + out, bads[:j] + out_bad

    def _run_all(
        self, items: list[Any], bads: list[int], start: int
    ) -> tuple[list[Any], list[int]]:
        """:meth:`run` from ``items[start]`` on, breaks and repeats included."""
        out: list[Any] = []
        out_bad: list[int] = []
        st = self.stats
        for j in range(start, len(items)):
            f, b = items[j], bads[j]
            seq0 = self._seq
            if seq0 is None:  # the first frame: nothing to judge it by
                self._seq, self._t, self._kept_run = f.seq, f.t_us, 1
                out.append(f)
                out_bad.append(b)
                continue
            k = (f.seq - seq0) & 0xFFFF
            d = (f.t_us - self._t) & 0xFFFFFFFF
            if keeps(k, d, self._d, self._k):
                self._gap(k)
                if f.t_us < self._t:
                    st.clock_wraps += 1
                self._seq, self._t = f.seq, f.t_us
                if k == 1:
                    self._d, self._k = d, 1
                self._agreed += 1
                self._kept_run += 1
                self._drop_held()
                out.append(f)
                out_bad.append(b)
                continue
            self._kept_run = 0
            back = k == 0 or k >= _SEQ_BACK
            if back and not 0 < d < _HALF_WRAP and not self._continues_held(f.seq, f.t_us):
                st.seq_repeats += 1
                continue
            for it, bb in self._on_break(f, f.seq, f.t_us, b):
                out.append(it)
                out_bad.append(bb)
        return out, out_bad

    def _continues_held(self, s: int, t: int) -> bool:
        """Whether a frame continues the held ones (by their own clock: class doc)."""
        held = self._held
        if not held:
            return False
        _, ps, pt, _ = held[-1]
        d0 = k0 = 0
        if len(held) >= 2:
            d0, k0 = (pt - held[-2][2]) & 0xFFFFFFFF, (ps - held[-2][1]) & 0xFFFF
        k, d = (s - ps) & 0xFFFF, (t - pt) & 0xFFFFFFFF
        return keeps(k, d, d0, k0)

    def _on_break(self, item: Any, s: int, t: int, b: int) -> list[tuple[Any, int]]:
        """A frame that breaks the sequence or the clock: held (after what is held, if it
        continues it; else in its place); the held frames released once
        :data:`BREAK_CONFIRM_FRAMES` continue one another at the interval agreed on (or none
        was), or :data:`BREAK_REBASE_FRAMES` at one of their own near it."""
        if self._continues_held(s, t):
            _, ps, pt, _ = self._held[-1]
            self._held_off |= not agrees((t - pt) & 0xFFFFFFFF, (s - ps) & 0xFFFF, self._d, self._k)
        else:
            self._drop_held()
        self._held.append((item, s, t, b))
        n = len(self._held)
        if n >= BREAK_CONFIRM_FRAMES and (self._agreed < 2 or not self._held_off):
            return self._release()
        if n < BREAK_REBASE_FRAMES:
            return []
        (_, sa, ta, _), (_, sb, tb, _) = self._held[-2:]  # their interval: near the old one?
        if agrees((tb - ta) & 0xFFFFFFFF, (sb - sa) & 0xFFFF, self._d, self._k, REBASE_RATIO):
            return self._release()
        self._held.pop(0)  # far from it: never taken, the oldest dropped as the next comes
        self.stats.seq_clock_mismatch += 1
        return []

    def _release(self) -> list[tuple[Any, int]]:
        """The held frames are kept; the interval agreed on stays if they kept to it."""
        held, st = self._held, self.stats
        assert self._seq is not None  # a break follows a kept frame
        k = (held[0][1] - self._seq) & 0xFFFF
        if k >= 0x8000:
            st.seq_resets += 1
        else:
            self._gap(k)
        keep_interval = self._agreed >= 2 and not self._held_off
        for (_, sa, ta, _), (_, sb, tb, _) in itertools.pairwise(held):
            kk = (sb - sa) & 0xFFFF
            self._gap(kk)
            if tb < ta:
                st.clock_wraps += 1
            self._seq, self._t = sb, tb
            if kk == 1 and not keep_interval:
                self._d, self._k = (tb - ta) & 0xFFFFFFFF, 1
        self._agreed = len(held) - 1
        out = [(it, bb) for it, _, _, bb in held]
        held.clear()
        self._held_off = False
        return out

    def _gap(self, k: int) -> None:
        if k > 1:
            self.stats.seq_gaps += 1
            self.stats.lost_frames += k - 1

    def _drop_held(self) -> None:
        self.stats.seq_clock_mismatch += len(self._held)
        self._held.clear()
        self._held_off = False

    def flush(self) -> None:
        """End of the input (or of a connection): the frames held after a break are dropped
        (never confirmed), the interval forgotten (another device may come); the last frame
        kept stays, so that a gap across a reconnection is still counted."""
        self._drop_held()
        self._kept_run = self._agreed = self._d = self._k = 0

    def run_array(self, arr: npt.NDArray[np.void]) -> npt.NDArray[np.int64]:
        """:meth:`run` over a :data:`FRAME_DTYPE` array (a whole capture): the positions of the
        frames kept. Numpy over the runs ``run`` would keep whole, ``run`` around the rest."""
        n = arr.shape[0]
        if n == 0:
            return np.empty(0, np.int64)
        seq = arr["seq"].astype(np.int64)
        t = arr["t_us"].astype(np.int64)
        k = np.zeros(n, np.int64)
        d = np.zeros(n, np.int64)
        np.bitwise_and(np.diff(seq), 0xFFFF, out=k[1:])
        np.bitwise_and(np.diff(t), 0xFFFFFFFF, out=d[1:])
        # The interval for each step: the last single step's before it (as run has it when
        # it kept that step; a run through numpy starts only there).
        one = np.maximum.accumulate(np.where(k == 1, np.arange(n), -1))
        prev = np.empty(n, np.int64)
        prev[0], prev[1:] = -1, one[:-1]
        good = (prev >= 0) & keeps(k, d, d[np.maximum(prev, 0)], 1)
        breaks = np.flatnonzero(~good)  # never empty: good[0] is False
        # calm[j]: steps calm[j] .. calm[j] + w - 1 all keep the rule; after w in a row the
        # tracker is at rest
        w = 2 * BREAK_CONFIRM_FRAMES + 2
        n_bad = np.concatenate(([0], np.cumsum(~good)))
        calm = np.flatnonzero(n_bad[w:] == n_bad[:-w])
        kept: list[npt.NDArray[np.int64]] = []
        i = 0
        while i < n:
            if i and self._kept_run >= 2 and k[i - 1] == 1 and good[i]:  # i - 2, i - 1 kept
                j = int(breaks[np.searchsorted(breaks, i)]) if breaks[-1] >= i else n
                self._numpy_run(k[i:j], t[i - 1 : j])
                self._seq, self._t = int(seq[j - 1]), int(t[j - 1])
                self._d, self._k = int(d[one[j - 1]]), 1
                kept.append(np.arange(i, j, dtype=np.int64))
                i = j
                continue
            at = int(np.searchsorted(calm, i))  # run to the end of the next calm stretch
            hi = max(min(n, int(calm[at]) + w) if at < calm.shape[0] else n, i + 1)
            kept.append(self._run_slice(seq, t, i, hi))
            i = hi
        return np.concatenate(kept)

    def _run_slice(
        self, seq: npt.NDArray[np.int64], t: npt.NDArray[np.int64], lo: int, hi: int
    ) -> npt.NDArray[np.int64]:
        """:meth:`run` over frames lo .. hi - 1 of an array: the positions kept."""
        rows = [_At(*x) for x in zip(seq[lo:hi].tolist(), t[lo:hi].tolist(), range(lo, hi))]
        got, _ = self.run(rows, [0] * len(rows))
        return np.fromiter((r.i for r in got), np.int64, len(got))

    def _numpy_run(self, k: npt.NDArray[np.int64], t: npt.NDArray[np.int64]) -> None:
        """Count the steps ``k`` (into the frames at ``t[1:]``) of a run kept whole."""
        st = self.stats
        jumps = k[k > 1]
        st.seq_gaps += int(jumps.size)
        st.lost_frames += int((jumps - 1).sum())
        st.clock_wraps += int(np.count_nonzero(t[1:] < t[:-1]))
        self._agreed += int(k.size)
        self._kept_run += int(k.size)
