"""The ``clock`` surface's inputs of tools/fuzz (tools/fuzz/inputs.py says how inputs are
made): a healthy frame stream whose sequence numbers and device clock are broken now and then,
with the host time each frame arrives and what the daemon must do with it."""

from __future__ import annotations

import random
from typing import Any

import numpy as np

from hdrd.io.wire.codec import FRAME_DTYPE

__all__ = ["CLOCK_QUIET_S", "CLOCK_ROW", "clock_input"]


CLOCK_QUIET_S = 12.0
"""After a break that moves the device clock against the host's, the frames of this many host
seconds may be dropped or kept (the tracker confirms a break, the host-clock check waits
5 s before it follows a jump)."""
CLOCK_ROW = np.dtype([("frame", FRAME_DTYPE), ("arrival", "<f8"), ("label", "u1")])
"""A clock input's rows: the frame (its ``rate`` is its row number), the host time it is in
hand (s), and what the daemon must do with it: 0 integrate, 1 drop, 2 either."""


def _clock_break(rng: random.Random, st: dict[str, Any], rows: list[tuple[Any, ...]]) -> None:
    """One break of a healthy stream (``st``: seq, t, wall, interval), appended to ``rows``.
    Frames that must be dropped are labelled 1, but 2 while the checks have not settled
    since the last break (``st["quiet"]``): then anything may be."""
    kind = rng.choice(("repeat", "frozen", "rate", "random", "restart", "jump", "gap", "late"))
    m = rng.choice((1, 2, 3, 5, 12))  # fewer than BREAK_REBASE_FRAMES: a new rate is not taken
    drop = 1 if st["wall"] > st["quiet"] else 2
    if kind == "gap":
        _lost_frames(st, m, drop)
        return
    if kind == "late":
        _late_burst(rng, st, rows, drop)
        return
    if kind == "repeat":  # the last frame again and again; the device's own go unheard
        _repeated(st, rows, m, drop)
    elif kind in ("frozen", "rate"):  # the sequence advancing, the clock frozen, slow or fast
        _clock_rate(rng, st, rows, kind, m, drop)
    elif kind == "random":  # a random frame that passed the CRC
        rows.append((rng.getrandbits(16), rng.getrandbits(32), st["wall"], drop))
    elif kind == "restart":
        st["seq"], st["t"] = rng.randrange(10), rng.getrandbits(20)
    else:  # a jump
        st["t"] += rng.choice((10**7, 10**9, 2**31 - 1))
    if kind not in ("random", "repeat") or drop == 2:
        st["quiet"] = st["wall"] + CLOCK_QUIET_S


def _repeated(st: dict[str, Any], rows: list[tuple[Any, ...]], m: int, drop: int) -> None:
    """The last frame ``m`` times again, a frame interval apart."""
    step = st["interval"]
    seq, t = st["seq"], st["t"]
    for _ in range(m):
        st["seq"] += 1
        st["t"] += step
        st["wall"] += step / 1e6
        rows.append((seq, t, st["wall"], drop))


def _clock_rate(
    rng: random.Random,
    st: dict[str, Any],
    rows: list[tuple[Any, ...]],
    kind: str,
    m: int,
    drop: int,
) -> None:
    """``m`` frames whose clock is frozen, or runs 0.01x to 100x."""
    step = st["interval"]
    factor = 0.0 if kind == "frozen" else rng.choice((0.01, 0.3, 3.0, 100.0))
    for j in range(m):
        st["seq"] += 1
        st["t"] += int(step * factor)
        st["wall"] += step / 1e6
        # the last one's clock is where the device's runs on from: a jump, believed
        rows.append((st["seq"], st["t"], st["wall"], drop if j < m - 1 else 2))


def _lost_frames(st: dict[str, Any], m: int, drop: int) -> None:
    """Frames lost, the clock agreeing: kept."""
    step = st["interval"]
    st["seq"] += m * 5
    st["t"] += m * 5 * step
    st["wall"] += m * 5 * step / 1e6
    if drop == 2:  # the checks had not settled: they start again
        st["quiet"] = st["wall"] + CLOCK_QUIET_S


def _late_burst(
    rng: random.Random, st: dict[str, Any], rows: list[tuple[Any, ...]], drop: int
) -> None:
    """A stalled reader: a burst read at once, up to 2 s late (within the tolerance)."""
    step = st["interval"]
    n = max(1, int(rng.choice((0.05, 0.5, 2.0)) / (step / 1e6)))
    label = 0 if drop == 1 else 2
    for _ in range(n):
        st["seq"] += 1
        st["t"] += step
        rows.append((st["seq"], st["t"], st["wall"] + n * step / 1e6, label))
    st["wall"] += n * step / 1e6
    if label == 2:  # the host clock's check had not settled: it starts again
        st["quiet"] = st["wall"] + CLOCK_QUIET_S


def clock_input(rng: random.Random) -> bytes:
    """A healthy stream (10 Hz, 100 Hz or 1 kHz; each frame in hand a millisecond or two
    after its device time) broken now and then: the last frame repeated, the sequence
    advancing while the clock is frozen or runs 100x slow or fast, a random frame, a device
    restart, a jump of the clock, frames lost, a burst delivered late. Rows of
    :data:`CLOCK_ROW`."""
    st: dict[str, Any] = {
        "interval": rng.choice((1_000, 10_000, 100_000)),
        "seq": rng.getrandbits(16),
        "t": rng.getrandbits(32),
        "wall": 1000.0,
        "quiet": 0.0,
    }
    rows: list[tuple[Any, ...]] = []

    def healthy(n: int) -> None:
        for _ in range(n):
            st["seq"] += 1
            st["t"] += st["interval"]
            st["wall"] += st["interval"] / 1e6
            label = 0 if st["wall"] > st["quiet"] else 2
            rows.append((st["seq"], st["t"], st["wall"] + rng.random() * 0.002, label))

    healthy(rng.randint(5, 60))
    for _ in range(rng.randint(0, 8)):
        _clock_break(rng, st, rows)
        healthy(rng.randint(5, 60))
    out = np.zeros(len(rows), CLOCK_ROW)
    for i, (seq, t, wall, label) in enumerate(rows):
        out[i] = ((seq & 0xFFFF, t % 2**32, i & 0xFFFF, 0, 2500), wall, label)
    return out.tobytes()
